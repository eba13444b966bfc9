"""The session's summary from its item records: summary.json, summary.md (also
a CI step summary) and the verdict table in the terminal.

Reads records only (see :mod:`pytest_driveeval.harness.results` for where they come
from); files are written atomically, so a reader sees the old summary or the
new one, never half of one.
"""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from ..core.atomic import write_json_atomic, write_text_atomic
from ..core.outcome import format_figure, replaced_model
from .deltas import COMPARED, MARKDOWN_MARK, comparison_of, figure_deltas, status_text, status_tone
from .paired import paired_table
from .score_table import score_markdown

SUMMARY_NAME = "summary.json"
MARKDOWN_NAME = "summary.md"
STEP_SUMMARY_ENV = "GITHUB_STEP_SUMMARY"
#: what stands in a policy's cell instead of a verdict mark when the policy is a baseline (not judged)
BASELINE_MARK = "baseline:"
STATUS_MARK = {"passed": "✅", "failed": "❌", "error": "💥", "skipped": "⏭️", "xfailed": "✔️", "xpassed": "⚠️"}


def _key_figures(record: dict[str, Any], limit: int = 4) -> str:
    figures = record.get("figures") or {}
    return ", ".join(f"{k}={format_figure(v)}" for k, v in list(figures.items())[:limit])


def verdict_reason(record: dict[str, Any]) -> str:
    """What decided an item's verdict, in a line: an expected failure's reason first, then the first
    condition that failed (and how many more did), else its outcome's summary, else the error or the
    skip's reason (a failure's message without the line that names the scenario)."""
    expected = record.get("expected_to_fail")
    parts = [("expected to fail: " + expected) if isinstance(expected, str) and expected
             else "expected to fail" if expected else ""]
    findings = record.get("findings") or []
    if record.get("verdict") == "failed" and findings and findings[0].get("message"):
        more = len(findings) - 1
        parts.append(findings[0]["message"] + (f" (and {more} more)" if more > 0 else ""))
    elif record.get("summary"):
        parts.append(record["summary"])
    else:
        parts.append(_message_reason(record) if record.get("message") != expected else "")
    return "; ".join(p for p in parts if p)


def _message_reason(record: dict[str, Any]) -> str:
    lines = [line.strip() for line in (record.get("message") or "").splitlines() if line.strip()]
    if lines and lines[0].startswith("scenario '") and len(lines) > 1:
        lines = lines[1:]
    if len(lines) > 1 and lines[0].endswith(":"):  # "invalid scenario file x:" and its first problem
        return f"{lines[0]} {lines[1]}"
    return lines[0] if lines else ""


#: a terminal segment: its text and its tone (deltas.Delta.tone, deltas.STATUS_TONE), None: plain
Segment = tuple[str, "str | None"]
#: pytest TerminalWriter markup per tone
TERMINAL_MARKUP = {"worse": {"red": True, "bold": True}, "better": {"green": True, "bold": True},
                   "note": {"yellow": True}}


def _figure_segments(record: dict[str, Any], limit: int = 4) -> list[Segment]:
    """Key figures; with a comparison, each beside its reference's value and the change."""
    deltas = figure_deltas(record)
    if not deltas:
        text = _key_figures(record, limit)
        return [(text, None)] if text else []
    out: list[Segment] = []
    for i, delta in enumerate(deltas):
        out += [(", ", None)] if i else []
        out.append((delta.text(), delta.tone))
    return out


def terminal_rows(records: list[dict[str, Any]], width: int) -> list[list[Segment]]:
    """A row per item: verdict, node id, then what decided the verdict, the comparison with its
    baseline, the model when it was not the scenario's own, and key figures (with their baseline's).
    Nothing is cut: a row that does not fit the terminal's ``width`` puts the node id on its own
    line and wraps the rest below it.  Each line is segments, so the deltas can be coloured."""
    rows = []
    for r in records:
        parts = [[(verdict_reason(r), None)], [(status_text(r, why=True), status_tone(r))],
                 [(replaced_model(r.get("details") or {}) or "", None)], _figure_segments(r)]
        rows.append((r.get("status", "?"), r["nodeid"], [p for p in parts if "".join(t for t, _ in p)]))
    id_width = max(len("scenario"), *(len(r[1]) for r in rows))
    header = f"{'verdict':<8}  {'scenario':<{id_width}}  what decided it; key figures"
    lines: list[list[Segment]] = [[(header if len(header) <= width else
                                    f"{'verdict':<8}  scenario / what decided it; key figures", None)]]
    indent = " " * 10
    for status, nodeid, parts in rows:
        line: list[Segment] = [(f"{status:<8}  {nodeid:<{id_width}}  ", None)]
        for i, part in enumerate(parts):
            line += ([("; ", None)] if i else []) + part
        if len("".join(t for t, _ in line).rstrip()) <= width:
            lines.append(_rstrip(line))
            continue
        lines.append([(f"{status:<8}  {nodeid}", None)])
        for part in parts:
            lines += _wrap(part, max(width, 40), indent, indent + "  ")
    return lines


def terminal_table(records: list[dict[str, Any]], width: int) -> list[str]:
    """:func:`terminal_rows` as plain lines."""
    return ["".join(text for text, _ in line) for line in terminal_rows(records, width)]


def _rstrip(line: list[Segment]) -> list[Segment]:
    text, tone = line[-1]
    return line[:-1] + [(text.rstrip(), tone)] if text.rstrip() else _rstrip(line[:-1]) if len(line) > 1 else []


def _wrap(part: list[Segment], width: int, first: str, rest: str) -> list[list[Segment]]:
    """Greedy word wrap of segments (words never broken, like textwrap with break_long_words off);
    each word keeps the tone of its characters."""
    text = "".join(t for t, _ in part)
    tones = [tone for t, tone in part for _ in t]
    out: list[list[tuple[int, int]]] = []
    current: list[tuple[int, int]] = []
    used = len(first)
    for match in re.finditer(r"\S+", text):
        start, end = match.span()
        need = end - start + (1 if current else 0)
        if current and used + need > width:
            out.append(current)
            current, used, need = [], len(rest), end - start
        current.append((start, end))
        used += need
    if current:
        out.append(current)
    lines = []
    for n, words in enumerate(out):
        line: list[Segment] = [(first if n == 0 else rest, None)]
        for i, (start, end) in enumerate(words):
            if i:  # a space inside one coloured figure stays coloured
                line.append((" ", tones[start - 1] if tones[start - 1] == tones[start] else None))
            line += [(text[k], tones[k]) for k in range(start, end)]
        lines.append(_merge(line))
    return lines


def _merge(line: list[Segment]) -> list[Segment]:
    out: list[Segment] = []
    for text, tone in line:
        if out and out[-1][1] == tone:
            out[-1] = (out[-1][0] + text, tone)
        else:
            out.append((text, tone))
    return out


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ").strip()


def markdown_summary(summary: dict[str, Any]) -> str:
    """The session as Markdown: counts, then one row per scenario item (with a baseline column when
    items were compared), then what the comparisons found."""
    counts = ", ".join(f"{n} {status}" for status, n in summary["counts"].items())
    run = summary.get("run") or {}
    where = f" (run `{run['id']}`" + (f", commit `{run['commit'][:12]}`" if run.get("commit") else "") + ")" \
        if run.get("id") else ""
    compared = any(comparison_of(r) for r in summary["results"])
    extra = (" baseline |", "---|") if compared else ("", "")
    lines = [f"## pytest-driveeval: {counts}{where}", "",
             f"| verdict | scenario | use case | summary | key figures |{extra[0]}", f"|---|---|---|---|---|{extra[1]}"]
    for r in summary["results"]:
        status = r.get("status", "?")
        text = "; ".join(p for p in (verdict_reason(r), replaced_model(r.get("details") or {})) if p)
        row = (f"| {STATUS_MARK.get(status, '')} {status} | `{_cell(r['nodeid'])}` | {_cell(r.get('use_case') or '')}"
               f" | {_cell(text)} | {_cell(_markdown_figures(r))} |")
        if compared:
            comparison = comparison_of(r)
            mark = MARKDOWN_MARK.get(status_tone(r) or "", "")
            row += f" {mark} {comparison['status']} |" if comparison else " |"
        lines.append(row)
    scores = [line for r in summary["results"] for line in score_markdown(r["nodeid"], r.get("details") or {})]
    return "\n".join(lines + comparison_sections(summary["results"]) + policy_table(summary["results"])
                     + paired_table(summary["results"]) + search_list(summary["results"]) + scores) + "\n"


def _markdown_figures(record: dict[str, Any]) -> str:
    deltas = figure_deltas(record)
    if not deltas:
        return _key_figures(record, limit=6)
    return ", ".join(f"{MARKDOWN_MARK[d.tone]} {d.text()}" if d.tone else d.text() for d in deltas)


def comparison_sections(records: list[dict[str, Any]]) -> list[str]:
    """Per reference ("Compared with baseline `<commit>` (<date>)"): the regressions and the
    improvements with their lines, and how many did not change; then the items not compared."""
    by_against: dict[str, list[tuple[dict, dict]]] = {}
    others = []
    for r in records:
        comparison = comparison_of(r)
        if comparison is None:
            continue
        if comparison["status"] in COMPARED:
            by_against.setdefault(comparison.get("against") or "the reference", []).append((r, comparison))
        else:
            others.append((r, comparison))
    lines: list[str] = []
    for against, found in sorted(by_against.items()):
        lines += ["", f"### Compared with {_cell(against)}", ""]
        for status, mark, worse in (("regressed", "🔴", True), ("improved", "🟢", False)):
            for r, comparison in found:
                if comparison["status"] == status:
                    lines.append(f"- {mark} {status}: `{_cell(r['nodeid'])}`")
                    lines += [f"  - {_cell(c.get('text'))}" for c in comparison.get("changes") or []
                              if c.get("worse") is worse]
        unchanged = sum(1 for _, comparison in found if comparison["status"] == "unchanged")
        if unchanged:
            lines.append(f"- {unchanged} unchanged")
    if others:
        lines += ["", "### Not compared", ""]
        for r, comparison in others:
            mark = MARKDOWN_MARK.get(status_tone(r) or "", "")
            note = (comparison.get("message") or "").splitlines()
            lines.append(f"- {mark} {comparison['status']}: `{_cell(r['nodeid'])}`: {_cell(note[0] if note else '')}")
    return lines


def search_list(records: list[dict[str, Any]]) -> list[str]:
    """The robustness searches that found a failure: the smallest perturbation and its replay line."""
    found = [(r["nodeid"], (r.get("details") or {}).get("search") or {}) for r in records]
    found = [(nodeid, s) for nodeid, s in found if s.get("minimal_text")]
    if not found:
        return []
    lines = ["", "### Robustness searches that broke a policy or filter", ""]
    for nodeid, s in found:
        where = ", ".join(f"{k} {v}" for k, v in (s.get("where") or {}).items())
        lines.append(f"- `{_cell(nodeid)}`: **{_cell(s['minimal_text'])}** ({_cell(where)}; {s.get('examples')} "
                     f"examples, {s.get('seconds')} s). Replay: `{_cell(s.get('replay'))}`")
    return lines


def _interval_cell(intervals: dict[str, Any]) -> str:
    parts = []
    for key, label in (("goal_rate", "goal"), ("collision_rate", "collision")):
        v = intervals.get(key)
        if v:
            parts.append(f"{label} {v['point']:.0f} % [{v['low']:.0f}, {v['high']:.0f}]")
    return ", ".join(parts)


def policy_grid(records: list[dict[str, Any]]) -> tuple[list[str], dict[tuple, dict[str, str]]]:
    """Policies side by side on the same data: cells by (use case, dataset or
    blueprint and scenario) and policy, when an evaluation names its policy in
    details; a policy benchmark's cell holds its rates with their intervals."""
    cells: dict[tuple, dict[str, str]] = {}
    for r in records:
        details = r.get("details") or {}
        policy = details.get("policy")
        where = r.get("dataset") or (f"{details['blueprint']} ({r.get('scenario')})" if details.get("blueprint")
                                     else None)
        if policy is None or where is None:
            continue
        shown = _interval_cell(details.get("intervals") or {}) or _key_figures(r, limit=4)
        # A baseline is not judged: its item passes whatever it does, and a ✅ beside 22 % collisions
        # would read as a verdict on it.
        mark = BASELINE_MARK if details.get("judged") is False else STATUS_MARK.get(r.get("status", ""), "")
        cells.setdefault((r.get("use_case"), where), {})[policy] = f"{mark} {shown}"
    cells = {key: by_policy for key, by_policy in cells.items() if len(by_policy) > 1}
    return sorted({p for by_policy in cells.values() for p in by_policy}), cells


def policy_table(records: list[dict[str, Any]]) -> list[str]:
    """The policy grid as Markdown (nothing when no data has two policies)."""
    policies, cells = policy_grid(records)
    if not cells:
        return []
    lines = ["", "### Policies by scenario", "",
             "| use case | data | " + " | ".join(f"`{_cell(p)}`" for p in policies) + " |",
             "|---|---|" + "---|" * len(policies)]
    for (use_case, where), by_policy in sorted(cells.items()):
        lines.append(f"| {_cell(use_case)} | {_cell(where)} | "
                     + " | ".join(_cell(by_policy.get(p, "")) for p in policies) + " |")
    return lines


def policy_table_html(records: list[dict[str, Any]]) -> str:
    """The policy grid as an HTML table, for the html report's summary."""
    from html import escape

    policies, cells = policy_grid(records)
    if not cells:
        return ""
    head = "".join(f"<th{_CELL}>{escape(p)}</th>" for p in policies)
    rows = "".join(f"<tr><td{_CELL}>{escape(str(u))}</td><td{_CELL}>{escape(str(w))}</td>"
                   + "".join(f"<td{_CELL}>{escape(by_policy.get(p, ''))}</td>" for p in policies) + "</tr>"
                   for (u, w), by_policy in sorted(cells.items()))
    return (f"<div class='driveeval-policies'><h3>Policies by scenario</h3><table style='{_TABLE_STYLE}'><tr>"
            f"<th{_CELL}>use case</th><th{_CELL}>data</th>{head}</tr>{rows}</table></div>")


#: inline styles: pytest-html's stylesheet gives a table in its summary no borders or padding, and a
#: self-contained report carries no stylesheet of ours
_TABLE_STYLE = "border-collapse:collapse;margin:4px 0"
_CELL = " style='border:1px solid #bbb;padding:3px 8px;text-align:left;vertical-align:top'"


def write_summary(output_dir: Path, summary: dict[str, Any], step_summary: bool = True) -> None:
    """summary.json and summary.md in ``output_dir``; the Markdown also goes to
    the CI step summary when ``step_summary``.  One that cannot be written
    does not keep the others from being written; its error is raised last."""
    markdown = markdown_summary(summary)
    failed: OSError | None = None
    for name, write, content in ((SUMMARY_NAME, write_json_atomic, summary),
                                 (MARKDOWN_NAME, write_text_atomic, markdown)):
        try:
            write(output_dir / name, content)
        except OSError as exc:
            failed = failed or exc
    step_file = os.environ.get(STEP_SUMMARY_ENV)
    if step_summary and step_file:
        # CI systems show this file on the run's page; others may have written to it too.
        with open(step_file, "a", encoding="utf-8") as handle:
            handle.write(markdown)
    if failed is not None:
        raise failed
