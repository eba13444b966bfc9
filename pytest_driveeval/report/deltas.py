"""An item's key figures beside its reference's, as the terminal table, summary.md and the html
report show them: ``goal_rate=94 (100, ▼6)``, marked worse or better.

Reads records only: ``record["comparison"]`` (the comparison with its reference's figures) and
``record["baseline"]`` (the item's key figures and the rules that say which way is better).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..core.outcome import format_figure, is_number

#: the statuses under which figures were compared (missing, stale and error ones were not)
COMPARED = ("regressed", "improved", "unchanged")
STATUS_TONE = {"regressed": "worse", "improved": "better", "error": "worse", "missing": "note", "stale": "note"}
MARKDOWN_MARK = {"worse": "🔴", "better": "🟢", "note": "🟡"}
UP, DOWN = "▲", "▼"
#: a move within the figure's tolerance
WITHIN = "≈"


@dataclass(frozen=True)
class Delta:
    name: str
    now: Any
    before: Any
    #: the direction the rules call it ("worse", "better"; None: no move, or no rule)
    direction: str | None
    #: whether the comparison counted the move (beyond the tolerance, or the paired test's interval);
    #: only counted moves are coloured, so noise inside the tolerance does not look like news
    counted: bool
    #: the move is within the figure's tolerance (``Atol + Rtol * |before|``): shown as ``≈``, not
    #: as a number, so float noise (``▼1.058e-07``) does not read as a change
    within_tolerance: bool = False

    @property
    def tone(self) -> str | None:
        return self.direction if self.counted else None

    @property
    def change(self) -> str:
        if not is_number(self.before) or not is_number(self.now):
            return "new" if self.before is None else "changed" if self.before != self.now else "="
        moved = self.now - self.before
        if moved == 0:
            return "="
        if self.within_tolerance and not self.counted:
            return WITHIN
        return f"{UP if moved > 0 else DOWN}{format_figure(abs(moved))}"

    def text(self) -> str:
        before = "" if self.before is None else f"{format_figure(self.before)}, "
        return f"{self.name}={format_figure(self.now)} ({before}{self.change})"


def comparison_of(record: dict[str, Any]) -> dict[str, Any] | None:
    comparison = record.get("comparison")
    return comparison if isinstance(comparison, dict) and comparison.get("status") else None


def figure_deltas(record: dict[str, Any]) -> list[Delta]:
    """The item's key figures with their reference's, in the rules' order; nothing when the item
    was not compared (no reference, a stale one, an error)."""
    comparison = comparison_of(record)
    if comparison is None or comparison["status"] not in COMPARED:
        return []
    payload = record.get("baseline") if isinstance(record.get("baseline"), dict) else {}
    rules = (payload.get("rules") or {}).get("figures") or {}
    figures = payload.get("figures") or {}
    before = comparison.get("reference_figures") or {}
    counted = {c.get("what"): c.get("worse") for c in comparison.get("changes") or []
               if isinstance(c, dict) and c.get("worse") is not None}
    out = []
    for name in [n for n in rules if n in figures] + [n for n in figures if n not in rules]:
        now, was = figures[name], before.get(name)
        direction = _direction(now, was, (rules.get(name) or {}).get("better"))
        if name in counted:
            direction = "worse" if counted[name] else "better"
        out.append(Delta(name, now, was, direction, name in counted, within_tolerance(rules.get(name), was, now)))
    return out


def within_tolerance(rule: Any, before: Any, now: Any) -> bool:
    """Whether ``now`` is within a deterministic figure's tolerance of ``before`` (a rule as
    ``Rules.to_json`` writes it).  A paired rate has no such tolerance: its test decides, and a move
    it did not count is still shown."""
    if not isinstance(rule, dict) or rule.get("paired") or not (is_number(before) and is_number(now)):
        return False
    try:
        tolerance = float(rule.get("atol") or 0) + float(rule.get("rtol") or 0) * abs(before)
    except (TypeError, ValueError):
        return False
    return abs(now - before) <= tolerance


def _direction(now: Any, before: Any, better: str | None) -> str | None:
    if not (is_number(now) and is_number(before)) or now == before or better not in ("lower", "higher"):
        return None
    return "better" if (now < before) == (better == "lower") else "worse"


def status_text(record: dict[str, Any], why: bool = False) -> str:
    """The comparison in a word or two ("baseline: regressed"), or nothing.  With ``why``, a stale
    one also says what changed since its baseline was made: a passing item shows no failure text,
    and "stale" alone leaves the user to guess which input moved."""
    comparison = comparison_of(record)
    if comparison is None:
        return ""
    if why and comparison["status"] == "stale" and comparison.get("message"):
        return f"baseline: {comparison['message']}"
    return f"baseline: {comparison['status']}"


def status_tone(record: dict[str, Any]) -> str | None:
    comparison = comparison_of(record)
    return STATUS_TONE.get(comparison["status"]) if comparison is not None else None
