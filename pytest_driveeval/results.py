"""Per-item records, gathered from test reports on the controller, and the
session summary written from them.

Workers never write the summary: each report carries its item's record as the
``driveeval`` attribute (xdist serialises report attributes), and only the
process that is not an xdist worker writes ``summary.json``, atomically.
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import pytest

from .outcome import format_figure
from .settings import get_settings, safe_name

SUMMARY_NAME = "summary.json"
MARKDOWN_NAME = "summary.md"
STEP_SUMMARY_ENV = "GITHUB_STEP_SUMMARY"
STATUS_MARK = {"passed": "✅", "failed": "❌", "error": "💥", "skipped": "⏭️", "xfailed": "✔️", "xpassed": "⚠️"}
REPORT_ATTR = "driveeval"
SCHEMA_VERSION = 1


def pytest_status(report: pytest.TestReport) -> str | None:
    """The item's final word as pytest counts it, from one phase's report."""
    if report.when == "call":
        if hasattr(report, "wasxfail"):
            return "xfailed" if report.skipped else "xpassed"
        return report.outcome
    if report.failed:
        return "error"
    if report.skipped:
        return "xfailed" if hasattr(report, "wasxfail") else "skipped"
    return None


class ResultCollector:
    def __init__(self) -> None:
        self.records: dict[str, dict[str, Any]] = {}
        self.started = time.time()

    def add(self, report: pytest.TestReport) -> None:
        payload = getattr(report, REPORT_ATTR, None)
        if not payload:
            return
        record = self.records.setdefault(report.nodeid, {"nodeid": report.nodeid, "duration": 0.0})
        record.update(payload)
        record["duration"] = round(record["duration"] + report.duration, 6)
        status = pytest_status(report)
        # An error in teardown does not hide a failure in call.
        if status is not None and record.get("status") in (None, "passed"):
            record["status"] = status
        if status == "skipped" and isinstance(report.longrepr, tuple):
            record["message"] = str(report.longrepr[2]).removeprefix("Skipped: ")
        if hasattr(report, "wasxfail") and report.wasxfail:
            record.setdefault("message", report.wasxfail)

    def sorted_records(self) -> list[dict[str, Any]]:
        return [self.records[k] for k in sorted(self.records)]

    def counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for record in self.records.values():
            counts[record.get("status", "unknown")] = counts.get(record.get("status", "unknown"), 0) + 1
        return dict(sorted(counts.items()))

    def summary(self, exitstatus: int, seed: int) -> dict[str, Any]:
        return {
            "schema": SCHEMA_VERSION,
            "seed": seed,
            "exit_status": int(exitstatus),
            "counts": self.counts(),
            "duration": round(time.time() - self.started, 3),
            "results": self.sorted_records(),
        }


def write_text_atomic(path: Path, text: str) -> None:
    """Readers see the old file or the new one, never half of one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json_atomic(path: Path, data: Any) -> None:
    write_text_atomic(path, json.dumps(data, indent=2, allow_nan=False) + "\n")


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
    lines = [f"## pytest-driveeval: {counts}", "",
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


class ResultsReporter:
    """Controller-side plugin: gathers records, writes the summary, prints the table."""

    def __init__(self, config: pytest.Config) -> None:

        self.settings = get_settings(config)
        self.collector = ResultCollector()

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        self.collector.add(report)

    def pytest_sessionfinish(self, session: pytest.Session, exitstatus: int) -> None:
        # A run without scenario items leaves the last results alone; one with
        # them replaces the summary and drops item folders it did not produce.
        if not self.collector.records:
            return
        summary = self.collector.summary(exitstatus, self.settings.seed)
        write_json_atomic(self.settings.output_dir / SUMMARY_NAME, summary)
        markdown = markdown_summary(summary)
        write_text_atomic(self.settings.output_dir / MARKDOWN_NAME, markdown)
        step_summary = os.environ.get(STEP_SUMMARY_ENV)
        if step_summary:
            # CI systems show this file on the run's page; others may have written to it too.
            with open(step_summary, "a", encoding="utf-8") as handle:
                handle.write(markdown)
        items = self.settings.output_dir / "items"
        produced = {safe_name(nodeid) for nodeid in self.collector.records}
        for folder in items.iterdir() if items.is_dir() else ():
            if folder.name not in produced:
                shutil.rmtree(folder, ignore_errors=True)

    def pytest_terminal_summary(self, terminalreporter, exitstatus: int, config: pytest.Config) -> None:
        records = self.collector.sorted_records()
        if not records:
            return
        tr = terminalreporter
        tr.write_sep("-", f"driveeval: {len(records)} scenario item(s)")
        for line in terminal_table(records, tr._tw.fullwidth):
            tr.write_line(line)
        tr.write_line(f"results: {self.settings.output_dir / SUMMARY_NAME}")
