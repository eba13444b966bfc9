"""Two runs (or a run and a baseline folder) read for ``compare`` (cli.py), and their rows: each
item's status of B against A by the plugin's rules, and its key figures side by side."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..core.errors import display_path
from ..core.outcome import is_number
from ..harness.runs import RUN_FILE, RUNS_FOLDER
from .compare import ERROR, IMPROVED, REGRESSED, STALE, UNCHANGED, Comparison, against_text, compare
from .rules import FigureRule, Rules, effective_rules
from .store import (LAST, BaselineError, BaselineStore, RunReference, check_baseline, read_text,
                    resolve_compare)

ONLY_A, ONLY_B, NOT_COMPARED = "only in A", "only in B", "not compared"
SUMMARY = "summary.json"
# The order rows are counted in the footer: the worst first.
ORDER = (REGRESSED, ERROR, STALE, IMPROVED, UNCHANGED, ONLY_A, ONLY_B, NOT_COMPARED)


class CompareError(Exception):
    """A or B names nothing readable: the message names what and where."""


@dataclass
class Side:
    spec: str                 # as given on the command line
    title: str                # "run <id> (`<commit>`, <date>)" or "baselines <folder> (...)"
    source: str               # the file or folder read
    payloads: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: items the side knows but kept no comparable record of, and why
    absent: dict[str, str] = field(default_factory=dict)
    #: files that could not be read (a baseline folder's)
    problems: list[str] = field(default_factory=list)

    def knows(self, nodeid: str) -> bool:
        return nodeid in self.payloads or nodeid in self.absent


def load_side(spec: str, output_dir: Path) -> Side:
    path = Path(spec)
    last = LAST.fullmatch(spec)
    is_run_id = "/" not in spec and (output_dir / RUNS_FOLDER / spec / SUMMARY).is_file()
    if not last and not is_run_id and path.is_dir() and not (path / SUMMARY).is_file():
        return _baseline_side(spec, path)
    try:
        summary = resolve_compare(spec, output_dir)
    except ValueError as exc:
        # The plugin's message, with the names only this command takes.
        raise CompareError(str(exc) if last else f"{exc}, nor a run folder or a baseline folder") from None
    return _run_side(spec, summary)


def _run_side(spec: str, summary: Path) -> Side:
    try:
        reference = RunReference(summary)
    except BaselineError as exc:
        raise CompareError(str(exc)) from None
    side = Side(spec, against_text({"run": reference.run}, "run"), display_path(summary))
    for nodeid, record in reference.records.items():
        if not isinstance(nodeid, str):
            continue
        try:
            found = reference.read(nodeid)
        except BaselineError:
            side.absent[nodeid] = f"{record.get('status') or 'no status'}: kept no comparable record"
            continue
        if found is not None:
            side.payloads[nodeid] = found
    return side


def _baseline_side(spec: str, folder: Path) -> Side:
    store = BaselineStore(folder)
    files = store.files()
    if not any(files.values()):  # no .json file there says which item it is the baseline of
        state = ""
        if (folder / RUN_FILE).is_file():
            state = " (a run folder without its summary: that session did not finish)"
        raise CompareError(f"{display_path(folder)} holds neither a {SUMMARY} nor baseline files{state}")
    side = Side(spec, "", display_path(folder))
    for path, nodeid in files.items():
        if nodeid is not None and path == store.path_for(nodeid):
            try:
                found = store.read(nodeid)
            except BaselineError as exc:
                side.problems.append(str(exc))
                side.absent[nodeid] = "its baseline file cannot be read"
                continue
            if found is not None:
                side.payloads[nodeid] = found
            continue
        try:
            check_baseline(read_text(path), path, nodeid or "(unknown item)")
        except BaselineError as exc:
            side.problems.append(str(exc))
            continue
        side.problems.append(f"baseline {display_path(path)} says it is the baseline of {nodeid!r}, whose file "
                             f"is {display_path(store.path_for(nodeid or ''))}; move or rewrite it")
    side.title = _baselines_title(side)
    return side


def _baselines_title(side: Side) -> str:
    runs = {(p.get("run") or {}).get("id"): p for p in side.payloads.values()}
    newest = max(runs.values(), key=lambda p: str((p.get("run") or {}).get("started") or ""), default=None)
    title = f"baselines {side.source}: {len(side.payloads)} file(s)"
    if newest is None:
        return title
    many = f" {len(runs)} runs, the newest" if len(runs) > 1 else ""
    return f"{title} from{many} {against_text(newest, 'run')}"


def _with_rules(current: dict[str, Any], reference: dict[str, Any]) -> dict[str, Any]:
    """``current`` with the rules to judge it by: its own, else the reference's, else its use case's."""
    if current.get("rules"):
        return current
    rules = reference.get("rules")
    if not rules:
        from ..core.usecase import get_usecase

        name = current.get("use_case")
        use_case = get_usecase(name) if isinstance(name, str) else None
        rules = effective_rules(getattr(use_case, "regression_figures", {}), None).to_json()
    return {**current, "rules": rules}


@dataclass
class Figure:
    name: str
    a: Any
    b: Any
    worse: bool | None   # from the comparison's changes: the rules' word, not the sign of the delta
    #: the move is within the figure's tolerance: shown as no change (float noise is not news)
    within: bool = False

    @property
    def delta(self) -> float | None:
        if is_number(self.a) and is_number(self.b):
            return self.b - self.a
        return None


@dataclass
class Row:
    nodeid: str
    status: str
    verdicts: tuple[Any, Any]
    figures: list[Figure]
    comparison: Comparison | None = None
    note: str = ""

    @property
    def changed(self) -> bool:
        return self.status != UNCHANGED or self.verdicts[0] != self.verdicts[1] \
            or any(f.a != f.b and not f.within for f in self.figures)

    def details(self) -> list[str]:
        """What changed, in the comparison's words."""
        if self.comparison is None:
            return [self.note] if self.note else []
        if self.comparison.note:
            return [self.comparison.note]
        return [c.text for c in self.comparison.changes if c.worse is not None]


def _figure_names(*payloads: dict[str, Any] | None) -> list[str]:
    names: list[str] = []
    for payload in payloads:
        if payload:
            for name in [*((payload.get("rules") or {}).get("figures") or {}), *(payload.get("figures") or {})]:
                if name not in names:
                    names.append(name)
    return names


def _within(rule: FigureRule | None, a: Any, b: Any) -> bool:
    """Whether B's figure is within a deterministic rule's tolerance of A's (a paired rate has no
    such tolerance: its test decides, and a move it did not count is still shown)."""
    return rule is not None and not rule.paired and is_number(a) and is_number(b) and abs(b - a) <= rule.tolerance(a)


def compare_sides(a: Side, b: Side) -> list[Row]:
    rows = []
    for nodeid in sorted(set(a.payloads) | set(a.absent) | set(b.payloads) | set(b.absent)):
        pa, pb = a.payloads.get(nodeid), b.payloads.get(nodeid)
        verdicts = ((pa or {}).get("verdict"), (pb or {}).get("verdict"))
        if pa is not None and pb is not None:
            current = _with_rules(pb, pa)
            try:
                comparison = compare(pa, current, a.title, a.source)
            except (ValueError, KeyError, TypeError, AttributeError) as exc:
                # A hand-edited record may be valid JSON and still hold what no comparison reads.
                comparison = Comparison(ERROR, a.title, a.source, note=f"cannot compare the records of {nodeid} "
                                                                        f"({a.source}, {b.source}): {exc!r}")
            worse = {c.what: c.worse for c in comparison.changes}
            rules = Rules.from_json(current.get("rules") or {}).figures
            figures = []
            for n in _figure_names(current, pa):
                fa, fb = (pa.get("figures") or {}).get(n), (pb.get("figures") or {}).get(n)
                figures.append(Figure(n, fa, fb, worse.get(n), worse.get(n) is None and _within(rules.get(n), fa, fb)))
            rows.append(Row(nodeid, comparison.status, verdicts, figures, comparison))
            continue
        if not a.knows(nodeid):
            status, note = ONLY_B, f"not in A ({a.source})"
        elif not b.knows(nodeid):
            status, note = ONLY_A, f"not in B ({b.source})"
        else:
            status = NOT_COMPARED
            note = "; ".join(f"{name}: {side.absent[nodeid]}" for name, side in (("A", a), ("B", b))
                             if nodeid in side.absent)
        figures = [Figure(n, ((pa or {}).get("figures") or {}).get(n), ((pb or {}).get("figures") or {}).get(n), None)
                   for n in _figure_names(pb, pa)]
        rows.append(Row(nodeid, status, verdicts, figures, note=note))
    return rows
