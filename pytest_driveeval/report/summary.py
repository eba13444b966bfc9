"""The session's summary from its item records: summary.json, summary.md (also
a CI step summary) and the verdict table in the terminal.

Reads records only (see :mod:`pytest_driveeval.results` for where they come
from); files are written atomically, so a reader sees the old summary or the
new one, never half of one.
"""
from __future__ import annotations

import os
import textwrap
from pathlib import Path
from typing import Any

from ..atomic import write_json_atomic, write_text_atomic
from ..outcome import format_figure, replaced_model

SUMMARY_NAME = "summary.json"
MARKDOWN_NAME = "summary.md"
STEP_SUMMARY_ENV = "GITHUB_STEP_SUMMARY"
STATUS_MARK = {"passed": "✅", "failed": "❌", "error": "💥", "skipped": "⏭️", "xfailed": "✔️", "xpassed": "⚠️"}


def _key_figures(record: dict[str, Any], limit: int = 4) -> str:
    figures = record.get("figures") or {}
    return ", ".join(f"{k}={format_figure(v)}" for k, v in list(figures.items())[:limit])


def verdict_reason(record: dict[str, Any]) -> str:
    """What decided an item's verdict, in a line: its outcome's summary, else the error or the
    skip's reason (a failure's message without the line that names the scenario)."""
    if record.get("summary"):
        return record["summary"]
    lines = [line.strip() for line in (record.get("message") or "").splitlines() if line.strip()]
    if lines and lines[0].startswith("scenario '") and len(lines) > 1:
        lines = lines[1:]
    if len(lines) > 1 and lines[0].endswith(":"):  # "invalid scenario file x:" and its first problem
        return f"{lines[0]} {lines[1]}"
    return lines[0] if lines else ""


def terminal_table(records: list[dict[str, Any]], width: int) -> list[str]:
    """A row per item: verdict, node id, then what decided the verdict, the model when it was not
    the scenario's own, and key figures.  Nothing is cut: a row that does not fit the terminal's
    ``width`` puts the node id on its own line and wraps the rest below it."""
    rows = []
    for r in records:
        parts = [verdict_reason(r), replaced_model(r.get("details") or {}), _key_figures(r)]
        rows.append((r.get("status", "?"), r["nodeid"], [p for p in parts if p]))
    id_width = max(len("scenario"), *(len(r[1]) for r in rows))
    header = f"{'verdict':<8}  {'scenario':<{id_width}}  what decided it; key figures"
    lines = [header if len(header) <= width else f"{'verdict':<8}  scenario / what decided it; key figures"]
    indent = " " * 10
    for status, nodeid, parts in rows:
        line = f"{status:<8}  {nodeid:<{id_width}}  {'; '.join(parts)}".rstrip()
        if len(line) <= width:
            lines.append(line)
            continue
        lines.append(f"{status:<8}  {nodeid}")
        for part in parts:
            lines += textwrap.wrap(part, width=max(width, 40), initial_indent=indent, subsequent_indent=indent + "  ",
                                   break_on_hyphens=False, break_long_words=False)
    return lines


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ").strip()


def markdown_summary(summary: dict[str, Any]) -> str:
    """The session as Markdown: counts, then one row per scenario item."""
    counts = ", ".join(f"{n} {status}" for status, n in summary["counts"].items())
    run = summary.get("run") or {}
    where = f" (run `{run['id']}`" + (f", commit `{run['commit'][:12]}`" if run.get("commit") else "") + ")" \
        if run.get("id") else ""
    lines = [f"## pytest-driveeval: {counts}{where}", "",
             "| verdict | scenario | use case | summary | key figures |", "|---|---|---|---|---|"]
    for r in summary["results"]:
        status = r.get("status", "?")
        text = "; ".join(p for p in (verdict_reason(r), replaced_model(r.get("details") or {})) if p)
        lines.append(f"| {STATUS_MARK.get(status, '')} {status} | `{_cell(r['nodeid'])}` | {_cell(r.get('use_case') or '')}"
                     f" | {_cell(text)} | {_cell(_key_figures(r, limit=6))} |")
    return "\n".join(lines + policy_table(summary["results"]) + search_list(summary["results"])) + "\n"


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
        cells.setdefault((r.get("use_case"), where), {})[policy] = f"{STATUS_MARK.get(r.get('status', ''), '')} {shown}"
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
    head = "".join(f"<th>{escape(p)}</th>" for p in policies)
    rows = "".join(f"<tr><td>{escape(str(u))}</td><td>{escape(str(w))}</td>"
                   + "".join(f"<td>{escape(by_policy.get(p, ''))}</td>" for p in policies) + "</tr>"
                   for (u, w), by_policy in sorted(cells.items()))
    return (f"<div class='driveeval-policies'><h3>Policies by scenario</h3><table><tr><th>use case</th>"
            f"<th>data</th>{head}</tr>{rows}</table></div>")


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
