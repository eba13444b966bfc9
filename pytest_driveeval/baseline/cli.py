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

from ..core.outcome import format_figure
from ..harness.settings import DEFAULT_OUTPUT
from .compare import ERROR, REGRESSED
from .sides import (NOT_COMPARED, ONLY_A, ONLY_B, ORDER, CompareError, Figure, Row, Side, compare_sides,  # noqa: F401
                    load_side)

FORMATS = ("text", "markdown", "json")

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
