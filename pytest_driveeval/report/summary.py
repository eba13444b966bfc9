"""The session's summary from its item records: summary.json, summary.md (also
a CI step summary) and the verdict table in the terminal.

Reads records only (see :mod:`pytest_driveeval.results` for where they come
from); files are written atomically, so a reader sees the old summary or the
new one, never half of one.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from ..atomic import write_json_atomic, write_text_atomic
from ..outcome import format_figure

SUMMARY_NAME = "summary.json"
MARKDOWN_NAME = "summary.md"
STEP_SUMMARY_ENV = "GITHUB_STEP_SUMMARY"
STATUS_MARK = {"passed": "✅", "failed": "❌", "error": "💥", "skipped": "⏭️", "xfailed": "✔️", "xpassed": "⚠️"}


def _key_figures(record: dict[str, Any], limit: int = 4) -> str:
    figures = record.get("figures") or {}
    return ", ".join(f"{k}={format_figure(v)}" for k, v in list(figures.items())[:limit])


def terminal_table(records: list[dict[str, Any]], width: int) -> list[str]:
    rows = [(r.get("status", "?"), r["nodeid"], _key_figures(r) or (r.get("summary") or "")) for r in records]
    id_width = max(len("scenario"), *(len(r[1]) for r in rows))
    header = f"{'verdict':<8}  {'scenario':<{id_width}}  key figures"
    lines = [header if len(header) <= width else f"{'verdict':<8}  scenario / key figures"]
    for status, nodeid, figures in rows:
        line = f"{status:<8}  {nodeid:<{id_width}}  {figures}".rstrip()
        if len(line) > width and figures:
            # Narrow terminal: figures go on their own line rather than being cut.
            lines.append(f"{status:<8}  {nodeid}")
            line = f"{'':<8}  {figures}"
        lines.append(line if len(line) <= width else line[: width - 3] + "...")
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
        text = r.get("summary") or (r.get("message") or "").splitlines()[0:1]
        text = text if isinstance(text, str) else " ".join(text)
        lines.append(f"| {STATUS_MARK.get(status, '')} {status} | `{_cell(r['nodeid'])}` | {_cell(r.get('use_case') or '')}"
                     f" | {_cell(text)} | {_cell(_key_figures(r, limit=6))} |")
    return "\n".join(lines + policy_table(summary["results"])) + "\n"


def policy_table(records: list[dict[str, Any]]) -> list[str]:
    """Policies side by side on the same data: one row per (use case, dataset),
    one column per policy, when an evaluation names its policy in details."""
    cells: dict[tuple, dict[str, str]] = {}
    for r in records:
        policy = (r.get("details") or {}).get("policy")
        if policy is None or r.get("dataset") is None:
            continue
        cell = f"{STATUS_MARK.get(r.get('status', ''), '')} {_cell(_key_figures(r, limit=4))}"
        cells.setdefault((r.get("use_case"), r["dataset"]), {})[policy] = cell
    if not any(len(by_policy) > 1 for by_policy in cells.values()):
        return []
    policies = sorted({p for by_policy in cells.values() for p in by_policy})
    lines = ["", "### Policies by scenario", "",
             "| use case | dataset | " + " | ".join(f"`{_cell(p)}`" for p in policies) + " |",
             "|---|---|" + "---|" * len(policies)]
    for (use_case, dataset), by_policy in sorted(cells.items()):
        lines.append(f"| {_cell(use_case)} | {_cell(dataset)} | "
                     + " | ".join(by_policy.get(p, "") for p in policies) + " |")
    return lines


def write_summary(output_dir: Path, summary: dict[str, Any], step_summary: bool = True) -> None:
    """summary.json and summary.md in ``output_dir``; the Markdown also goes to
    the CI step summary when ``step_summary``."""
    write_json_atomic(output_dir / SUMMARY_NAME, summary)
    markdown = markdown_summary(summary)
    write_text_atomic(output_dir / MARKDOWN_NAME, markdown)
    step_file = os.environ.get(STEP_SUMMARY_ENV)
    if step_summary and step_file:
        # CI systems show this file on the run's page; others may have written to it too.
        with open(step_file, "a", encoding="utf-8") as handle:
            handle.write(markdown)
