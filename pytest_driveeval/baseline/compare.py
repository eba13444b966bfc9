"""One item's record against its reference (a baseline file or an earlier run): what got worse.

Pure: two payloads (``payload.make_payload``) in, a :class:`Comparison` out; the rules are the current
payload's (the scenario as it is now decides what counts as worse).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.outcome import format_figure, is_number
from .paired import paired_rate
from .rules import FigureRule, Rules
from .units import Units, unit_changes

REGRESSED, IMPROVED, UNCHANGED = "regressed", "improved", "unchanged"
MISSING, STALE, ERROR = "missing", "stale", "error"
#: how many units a message names before "... and N more"
NAMED = 8


@dataclass
class Change:
    what: str            # the figure, "scene 3", "search", "verdict"
    before: Any
    after: Any
    worse: bool | None   # True: a regression, False: an improvement, None: neither
    text: str

    def to_json(self) -> dict[str, Any]:
        return {"what": self.what, "before": self.before, "after": self.after, "worse": self.worse,
                "text": self.text}


@dataclass
class Comparison:
    status: str
    against: str = ""    # "baseline `<commit>` (<date>)" or "run <id>"
    source: str = ""     # the file it came from
    changes: list[Change] = field(default_factory=list)
    note: str = ""       # why it was not compared (missing, stale, error)
    #: the reference's key figures, for the reports' "now (before, change)" (only when compared)
    reference_figures: dict[str, Any] = field(default_factory=dict)

    @property
    def regressed(self) -> bool:
        return self.status == REGRESSED

    @property
    def worse(self) -> list[Change]:
        return [c for c in self.changes if c.worse]

    @property
    def better(self) -> list[Change]:
        return [c for c in self.changes if c.worse is False]

    def message(self) -> str:
        if self.status in (MISSING, STALE, ERROR):
            return self.note
        # One change per line: a regression of a benchmark names three rates and their episodes.
        if self.status == REGRESSED:
            return f"regression against {self.against}:" + "".join(f"\n    {c.text}" for c in self.worse)
        if self.status == IMPROVED:
            return f"improvement against {self.against}:" + "".join(f"\n    {c.text}" for c in self.better)
        return f"no change against {self.against}"

    def to_json(self) -> dict[str, Any]:
        return {"status": self.status, "against": self.against, "source": self.source, "message": self.message(),
                "changes": [c.to_json() for c in self.changes], "reference_figures": self.reference_figures}


def against_text(reference: dict[str, Any], kind: str = "baseline") -> str:
    run = reference.get("run") or {}
    commit = (run.get("commit") or "")[:12] or "no commit"
    dirty = " with uncommitted changes" if run.get("dirty") else ""
    when = run.get("started") or "unknown date"
    return f"{kind} `{commit}`{dirty} ({when})" if kind == "baseline" else f"run {run.get('id')} (`{commit}`, {when})"


def compare(reference: dict[str, Any], current: dict[str, Any], against: str = "", source: str = "") -> Comparison:
    stale = stale_reasons(reference.get("fingerprint"), current.get("fingerprint"))
    if stale:
        return Comparison(STALE, against, source, note=f"stale {against or 'reference'}: {'; '.join(stale)} "
                                                        "since it was made; not compared (update the baseline)")
    rules = Rules.from_json(current.get("rules") or {})
    changes: list[Change] = []
    if reference.get("search") or current.get("search"):
        changes += _search_changes(reference.get("search"), current.get("search"), rules)
    else:
        before_units, after_units = _units(reference), _units(current)
        for name, rule in rules.figures.items():
            before, after = (reference.get("figures") or {}).get(name), (current.get("figures") or {}).get(name)
            if not is_number(before) or not is_number(after):
                continue
            if rule.paired and before_units is not None and after_units is not None \
                    and rule.paired[0] in before_units.columns and rule.paired[0] in after_units.columns:
                changes += _paired_change(name, rule, before, after, before_units, after_units, rules.confidence)
            elif rule.paired:
                # A rate over episodes without them on both sides cannot be tested paired, and
                # compared as a bare figure any noise would be a regression: shown, not judged.
                if before != after:
                    changes.append(Change(name, before, after, None, f"{name} {format_figure(before)} -> "
                                          f"{format_figure(after)} (not judged: no per-episode outcomes on both sides)"))
            else:
                changes += _figure_change(name, rule, before, after)
        stochastic = any(rule.paired for rule in rules.figures.values())
        if rules.units and before_units is not None and after_units is not None and not stochastic:
            changes += _unit_changes(before_units, after_units)
        if not stochastic and not any(c.worse for c in changes) \
                and reference.get("verdict") == "passed" and current.get("verdict") != "passed":
            changes.append(Change("verdict", "passed", current.get("verdict"), True,
                                  f"verdict passed -> {current.get('verdict')}: {current.get('summary')}"))
    status = REGRESSED if any(c.worse for c in changes) else IMPROVED if any(c.worse is False for c in changes) \
        else UNCHANGED
    return Comparison(status, against, source, changes, reference_figures=dict(reference.get("figures") or {}))


def _units(payload: dict[str, Any]) -> Units | None:
    data = payload.get("units")
    return Units.from_json(data) if data else None


def stale_reasons(before: dict | None, after: dict | None) -> list[str]:
    """What differs between two fingerprints, as people read it; nothing when one is unknown."""
    if not before or not after:
        return []
    out = []
    if before.get("use_case") != after.get("use_case"):
        out.append(f"the use case changed ({before.get('use_case')} -> {after.get('use_case')})")
    if before.get("dataset") != after.get("dataset"):
        b, a = before.get("dataset") or {}, after.get("dataset") or {}
        out.append(f"the dataset changed ({b.get('name')} sha256 {b.get('sha256')}, {b.get('bytes')} bytes -> "
                   f"{a.get('name')} sha256 {a.get('sha256')}, {a.get('bytes')} bytes)")
    if before.get("seed") != after.get("seed"):
        out.append(f"the seed changed ({before.get('seed')} -> {after.get('seed')})")
    diffs = _dict_diff(before.get("settings") or {}, after.get("settings") or {}, "Evaluation")
    if diffs:
        shown = ", ".join(diffs[:3]) + (f" and {len(diffs) - 3} more" if len(diffs) > 3 else "")
        out.append(f"the settings changed ({shown})")
    if before.get("format_version") != after.get("format_version") and not diffs:
        out.append(f"the format version changed ({before.get('format_version')} -> {after.get('format_version')})")
    return out


def _dict_diff(before: Any, after: Any, path: str) -> list[str]:
    if isinstance(before, dict) and isinstance(after, dict):
        out = []
        for key in sorted(set(before) | set(after), key=str):
            out += _dict_diff(before.get(key, "(absent)"), after.get(key, "(absent)"), f"{path}.{key}")
        return out
    return [] if before == after else [f"{path} {_short(before)} -> {_short(after)}"]


def _short(value: Any) -> str:
    text = format_figure(value) if not isinstance(value, (dict, list)) else str(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _figure_change(name: str, rule: FigureRule, before: float, after: float) -> list[Change]:
    moved = rule.worse_by(before, after)
    if abs(moved) <= rule.tolerance(before):
        return []
    arrow = f"{name} {format_figure(before)} -> {format_figure(after)}"
    tol = f"tolerance {format_figure(rule.tolerance(before))}"
    if moved > 0:
        return [Change(name, before, after, True, f"{arrow} ({rule.better} is better; {tol})")]
    return [Change(name, before, after, False, f"{arrow} (better; {tol})")]


def _paired_change(name: str, rule: FigureRule, before: float, after: float, bu: Units, au: Units,
                   confidence: float) -> list[Change]:
    column, event = rule.paired
    position = {unit: i for i, unit in enumerate(bu.ids)}
    shared = [(position[u], j, u) for j, u in enumerate(au.ids) if u in position]
    if not shared:
        return []
    was = np.array([bu.columns[column][i] in event for i, _, _ in shared])
    now = np.array([au.columns[column][j] in event for _, j, _ in shared])
    test = paired_rate(was, now, confidence)
    if not test.significant():
        return []
    # The rate counts ``event``; which direction of it is worse is the rule's.  The direction is the
    # counts' (at the knife edge p == alpha an end of the interval is exactly zero).
    worse = (test.worse > test.better) == (rule.better == "lower")
    word = " / ".join(au.word(code) for code in event)
    gained = [u for (i, j, u), w, n in zip(shared, was, now) if n and not w]
    lost = [u for (i, j, u), w, n in zip(shared, was, now) if w and not n]
    listed = []
    if gained:
        listed.append(f"{bu.kind}s {_names(gained)} now end in {word}")
    if lost:
        listed.append(f"{bu.kind}s {_names(lost)} no longer end in {word}")
    text = (f"{name} {format_figure(before)} % -> {format_figure(after)} % [paired {confidence:g} % interval of "
            f"the difference {test.low:.1f}, {test.high:.1f}; McNemar exact p = {test.p_value:.2g}], "
            + ", ".join(listed))
    return [Change(name, before, after, worse, text)]


def _names(ids: list[str]) -> str:
    shown = ", ".join(ids[:NAMED])
    return shown + (f" and {len(ids) - NAMED} more" if len(ids) > NAMED else "")


def _unit_changes(before: Units, after: Units) -> list[Change]:
    out = []
    for change in unit_changes(before, after):
        label = f"{before.kind} {change.unit}" + ("" if change.column == before.kind else f" {change.column}")
        if change.worse:
            why = f": {change.reason}" if change.reason else ""
            text = f"{label} {change.before} before, {change.after} now{why}"
        else:
            text = f"{label} {change.before} before, {change.after} now"
        out.append(Change(label, change.before, change.after, change.worse, text))
    return out


def _search_changes(before: dict | None, after: dict | None, rules: Rules) -> list[Change]:
    if not before or not after:
        return []
    now = f"{after.get('text')}; replay: {after.get('replay')}" if after.get("replay") else str(after.get("text"))
    if not before.get("broke") and after.get("broke"):
        return [Change("search", "passed", "broke", True,
                       f"the search found nothing before ({before.get('examples')} examples) and breaks it now: "
                       f"{now}")]
    if before.get("broke") and not after.get("broke"):
        return [Change("search", "broke", "passed", False,
                       f"the search broke it before ({before.get('text')}), finds nothing now "
                       f"({after.get('examples')} examples)")]
    if not before.get("broke"):
        return []
    b_min, a_min = before.get("minimal") or {}, after.get("minimal") or {}
    out = []
    for parameter in sorted(set(b_min) | set(a_min)):
        b, a = b_min.get(parameter, 0.0), a_min.get(parameter, 0.0)
        if not (is_number(b) and is_number(a)):
            continue
        allowed = rules.search.allowed(parameter, b)
        closer = abs(b) - abs(a)
        side = f"smallest breaking {parameter} {format_figure(b)} before, {format_figure(a)} now"
        if closer > allowed:
            out.append(Change(f"minimal_{parameter}", b, a, True,
                              f"{side} (towards zero by {format_figure(closer)}, tolerance {format_figure(allowed)}); "
                              f"before: {before.get('text')}; now: {now}"))
        elif -closer > allowed:
            out.append(Change(f"minimal_{parameter}", b, a, False, f"{side} (further from zero: harder to break)"))
    return out
