"""``python -m pytest_driveeval compare A B``: two runs side by side, without rerunning anything.

    python -m pytest_driveeval compare last~1 last          # the run before the last against the last
    python -m pytest_driveeval compare baselines last       # the committed baselines against the last run
    python -m pytest_driveeval compare 20261126T101500.123Z-a1b2c3 other/summary.json --only-changed
    python -m pytest_driveeval compare main-run/ last --format markdown >> "$GITHUB_STEP_SUMMARY"

A and B each name a run or a set of baselines:

    last, last~N      the newest finished run in the output folder's history.jsonl, or N runs before it
    <run id>          runs/<run id>/summary.json in the output folder
    <path>            a summary.json, a run folder holding one, or a baseline folder (the files
                      --driveeval-baseline-update wrote)

Options: ``--output DIR`` (the output folder that ``last`` and run ids are looked up in; default
driveeval-results, relative to the working directory), ``--only-changed`` (leave out the items whose
status is unchanged and whose verdict and figures are equal within the figure's tolerance, list the
regressions first, and sum up the items only one side ran in a line each), ``--format text|markdown|json``.

One row per item (node id) present in either: B's status against A by the plugin's own rules, as
``pytest --driveeval-compare A`` would have judged B (regressed, improved, unchanged, stale, error),
or "only in A" / "only in B"; then each key figure as ``A -> B (change)``, marked worse or better
where the rules say so, and below the row what changed (the episodes, scenes or frames named).
The rules are B's (the scenario as B ran it); a baseline file keeps none, so when B is a baseline
folder A's apply, and the use case's defaults when neither side has any.

Exit status: 0; 1 when an item of B regressed against A (so the command can gate CI); 2 when the
command line is wrong or A or B cannot be read (an unknown run, an unreadable summary or baseline
file: the message names it).  It reads files only, and writes none.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import textwrap
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import display_path
from ..outcome import format_figure, is_number
from ..report.deltas import within_tolerance
from ..runs import RUN_FILE, RUNS_FOLDER
from ..settings import DEFAULT_OUTPUT
from .compare import ERROR, IMPROVED, REGRESSED, STALE, UNCHANGED, Comparison, against_text, compare
from .rules import effective_rules
from .store import (LAST, BaselineError, BaselineStore, RunReference, check_baseline, read_text,
                    resolve_compare)

ONLY_A, ONLY_B, NOT_COMPARED = "only in A", "only in B", "not compared"
SUMMARY = "summary.json"
FORMATS = ("text", "markdown", "json")
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
        from ..usecase import get_usecase

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
            rules = ((current.get("rules") or {}).get("figures") or {})
            figures = []
            for n in _figure_names(current, pa):
                fa, fb = (pa.get("figures") or {}).get(n), (pb.get("figures") or {}).get(n)
                figures.append(Figure(n, fa, fb, worse.get(n), worse.get(n) is None and within_tolerance(rules.get(n),
                                                                                                        fa, fb)))
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


def _arrows() -> tuple[str, str, str]:
    try:
        "↑↓≈".encode(sys.stdout.encoding or "utf-8")
        return "↑", "↓", "≈"
    except (UnicodeEncodeError, LookupError):
        return "^", "v", "~"


def _value(value: Any) -> str:
    return "none" if value is None else format_figure(value)


def figure_text(figure: Figure, status: str, arrows: tuple[str, str, str]) -> str:
    if status in (ONLY_A, ONLY_B, NOT_COMPARED):
        return f"{figure.name} {_value(figure.a if figure.a is not None else figure.b)}"
    delta = figure.delta
    if delta is None:
        change = "=" if figure.a == figure.b else "?"
    elif delta == 0:
        change = "="
    elif figure.within:
        change = f"{arrows[2]} within tolerance"
    else:
        change = f"{'+' if delta > 0 else ''}{format_figure(delta)} {arrows[0] if delta > 0 else arrows[1]}"
        change += {True: " worse", False: " better", None: ""}[figure.worse]
    return f"{figure.name} {_value(figure.a)} -> {_value(figure.b)} ({change})"


def verdict_text(row: Row) -> str:
    a, b = row.verdicts
    if row.status == ONLY_B:
        return str(b)
    if row.status == NOT_COMPARED and (a is None) != (b is None):
        return f"{a} in A" if b is None else f"{b} in B"
    if a == b or b is None:
        return str(a)
    if a is None:
        return str(b)
    return f"{a} -> {b}"


def _counts(rows: list[Row]) -> str:
    counts = {status: sum(r.status == status for r in rows) for status in ORDER}
    counts.update({r.status: sum(x.status == r.status for x in rows) for r in rows if r.status not in counts})
    return ", ".join(f"{n} {status}" for status, n in counts.items() if n) or "no item in either"


@dataclass
class Selection:
    """The rows to print, and the lines that stand for the rows folded into one line each."""
    shown: list[Row]
    folded: list[str] = field(default_factory=list)
    hidden: int = 0  # unchanged rows left out

    def footer(self, rows: list[Row]) -> str:
        return _counts(rows) + (f" ({self.hidden} unchanged not shown)" if self.hidden else "")


def select(rows: list[Row], a: Side, b: Side, only_changed: bool) -> Selection:
    """Every row; with ``only_changed``, the changed ones worst first (regressions at the top),
    and the items only one side ran summed up in a line each: after a subset run they are most of
    the rows, and would bury the regressions."""
    if not only_changed:
        return Selection(rows)
    changed = [r for r in rows if r.changed]
    rank = {status: i for i, status in enumerate(ORDER)}
    shown = sorted((r for r in changed if r.status not in (ONLY_A, ONLY_B)),
                   key=lambda r: (rank.get(r.status, len(ORDER)), r.nodeid))
    folded = []
    for status, side, other in ((ONLY_A, a, b), (ONLY_B, b, a)):
        n = sum(r.status == status for r in changed)
        if n:
            name, other_name = ("A", "B") if side is a else ("B", "A")
            folded.append(f"{n} item(s) only in {name} (not run in {other_name}, {other.source}); without "
                          "--only-changed they are listed")
    return Selection(shown, folded, len(rows) - len(changed))


def render_text(a: Side, b: Side, rows: list[Row], selection: Selection, width: int) -> list[str]:
    shown = selection.shown
    arrows = _arrows()
    width = max(width, 40)
    lines = []
    for name, side in (("A", a), ("B", b)):
        lines += textwrap.wrap(f"{name}: {side.title}  [{side.source}]", width=width, subsequent_indent="   ",
                               break_on_hyphens=False, break_long_words=False)
    status_width = max([len("status"), *(len(r.status) for r in shown)])
    id_width = max([len("item"), *(len(r.nodeid) for r in shown)])
    header = f"{'status':<{status_width}}  {'item':<{id_width}}  verdict; key figures: A -> B (change)"
    lines += [header] if len(header) <= width else textwrap.wrap(
        f"{'status':<{status_width}}  item / verdict; key figures: A -> B (change)", width=width)
    indent = " " * (status_width + 2)
    for row in shown:
        # A Python test that made no outcome has no verdict: nothing to say, rather than "None".
        parts = [p for p in (verdict_text(row),) if p != "None"] + [figure_text(f, row.status, arrows)
                                                                      for f in row.figures]
        line = f"{row.status:<{status_width}}  {row.nodeid:<{id_width}}  {'; '.join(parts)}".rstrip()
        if len(line) <= width:
            lines.append(line)
        else:
            # Nothing is cut: the node id on its own line, each figure wrapped below it.
            head = f"{row.status:<{status_width}}  {row.nodeid}"
            lines += [head] if len(head) <= width else [row.status, indent + row.nodeid]
            for part in parts:
                lines += textwrap.wrap(part, width=width, initial_indent=indent, subsequent_indent=indent + "  ",
                                       break_on_hyphens=False, break_long_words=False)
        for detail in row.details():
            lines += textwrap.wrap(detail, width=width, initial_indent=indent + "  ", subsequent_indent=indent + "    ",
                                   break_on_hyphens=False, break_long_words=False)
    lines += selection.folded
    lines.append(selection.footer(rows))
    return lines


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ").strip()


def render_markdown(a: Side, b: Side, rows: list[Row], selection: Selection) -> list[str]:
    shown = selection.shown
    arrows = _arrows()
    lines = [f"**A**: {_cell(a.title)} (`{_cell(a.source)}`)  ", f"**B**: {_cell(b.title)} (`{_cell(b.source)}`)", "",
             "| status | item | verdict | key figures: A -> B (change) | what changed |", "|---|---|---|---|---|"]
    for row in shown:
        figures = "<br>".join(_cell(figure_text(f, row.status, arrows)) for f in row.figures)
        status = f"**{row.status}**" if row.status in (REGRESSED, ERROR) else row.status
        lines.append(f"| {status} | `{_cell(row.nodeid)}` | {_cell(verdict_text(row))} | {figures} | "
                     f"{'<br>'.join(_cell(d) for d in row.details())} |")
    lines += [""] + [f"{line}  " for line in selection.folded] + [selection.footer(rows)]
    return lines


def render_json(a: Side, b: Side, rows: list[Row], selection: Selection) -> str:
    shown = selection.shown
    def side(s: Side) -> dict[str, Any]:
        return {"spec": s.spec, "title": s.title, "source": s.source, "problems": s.problems}

    def row(r: Row) -> dict[str, Any]:
        return {"nodeid": r.nodeid, "status": r.status, "verdict": {"a": r.verdicts[0], "b": r.verdicts[1]},
                "figures": {f.name: {"a": f.a, "b": f.b, "delta": f.delta, "worse": f.worse,
                                     "within_tolerance": f.within} for f in r.figures},
                "details": r.details(),
                "comparison": r.comparison.to_json() if r.comparison is not None else None}

    counts = {status: sum(r.status == status for r in rows) for status in {r.status for r in rows}}
    return json.dumps({"a": side(a), "b": side(b), "rows": [row(r) for r in shown], "folded": selection.folded,
                       "counts": counts,
                       "regressed": any(r.status == REGRESSED for r in rows)}, indent=1, ensure_ascii=False)


def run(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except Exception:
        # Exit status 1 says "B regressed": a crash must not say it (CI would blame the model).
        traceback.print_exc()
        print(f"{args.prog}: error: could not compare {args.a} with {args.b} (the traceback above is a bug of "
              "pytest-driveeval's: please report it)", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    output_dir = Path(args.output).absolute()
    try:
        a, b = load_side(args.a, output_dir), load_side(args.b, output_dir)
    except CompareError as exc:
        print(f"{args.prog}: error: {exc}", file=sys.stderr)
        return 2
    rows = compare_sides(a, b)
    selection = select(rows, a, b, args.only_changed)
    if args.format == "json":
        text = render_json(a, b, rows, selection)
    elif args.format == "markdown":
        text = "\n".join(render_markdown(a, b, rows, selection))
    else:
        text = "\n".join(render_text(a, b, rows, selection, shutil.get_terminal_size().columns))
    problems = a.problems + b.problems
    status = 2 if problems else 1 if any(r.status == REGRESSED for r in rows) else 0
    try:
        print(text, flush=True)
    except BrokenPipeError:
        # Piped into head: the reader has what it wanted; the status still says how B compared.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    for problem in problems:
        print(f"{args.prog}: error: {problem}", file=sys.stderr)
    return status


def add_compare_command(commands: Any, prog: str) -> None:
    parser = commands.add_parser(
        "compare", help="print two runs side by side (exit 1 when B regressed against A)",
        description="Print two runs side by side: B's status against A by the plugin's rules and each key "
                    "figure as A -> B (change). Exit status 1 when an item of B regressed against A, 2 when A or "
                    "B cannot be read.")
    parser.add_argument("a", metavar="A", help="the reference: last, last~N, a run id, a summary.json, a run folder "
                                                "or a baseline folder")
    parser.add_argument("b", metavar="B", help="the run judged against A (the same kinds of names)")
    parser.add_argument("--output", metavar="DIR", default=DEFAULT_OUTPUT,
                        help=f"the output folder that holds history.jsonl and runs/ (default: {DEFAULT_OUTPUT})")
    parser.add_argument("--only-changed", action="store_true",
                        help="leave out the items whose status is unchanged and whose verdict and figures are equal "
                             "(within the figure's tolerance); list the regressions first and sum up the items only "
                             "one side ran in a line each")
    parser.add_argument("--format", choices=FORMATS, default="text", help="text (default), markdown or json")
    parser.set_defaults(run=run, prog=f"{prog} compare")
