"""Per-item records: made where the item ran, gathered on the controller.

Workers never write the summary: each report carries its item's record as the
``driveeval`` attribute (xdist serialises report attributes), and only the
process that is not an xdist worker writes ``summary.json``.  An item's
outcome (and its html extras) travels once, with the report of the phase
that produced it; the controller merges an item's records.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from ..baseline.gate import COMPARISON_ATTR, PAYLOAD_ATTR, prune, unused_baselines, update_baselines
from .collect import InvalidScenarioItem, scenario_item_names
from ..core.errors import DriveEvalError, display_path
from .failure import Failure
from ..baseline.session import COMPARE_KEY, session_gate
from ..core.outcome import OUTCOME_ATTR, Outcome, replaced_model
from ..report.attachments import comparison_cell, html_extras, html_wanted
from ..report.summary import SUMMARY_NAME, TERMINAL_MARKUP, policy_table_html, terminal_rows, verdict_reason
from ..report.trends import DEFAULT_RUNS, trend_png
from .runs import HISTORY_NAME, finish_run
from .settings import RUN_KEY, get_settings

REPORT_ATTR = "driveeval"
SCHEMA_VERSION = 2  # 2: run identity; artefacts under runs/<run id>/
# Set on an item once its outcome went out with a report, so it goes out once.
SENT_ATTR = "driveeval_outcome_sent"


def item_record(item: pytest.Item, failure: Failure | None, with_outcome: bool) -> dict | None:
    """The item's entry in summary.json (its outcome's fields only when
    ``with_outcome``), or None for a test that is not ours."""
    scenario = getattr(item, "driveeval_scenario", None)
    outcome: Outcome | None = getattr(item, OUTCOME_ATTR, None)
    if scenario is None and outcome is None and not isinstance(item, InvalidScenarioItem):
        return None
    root = item.config.rootpath
    record: dict = {"file": Path(item.path).relative_to(root).as_posix() if Path(item.path).is_relative_to(root)
                    else str(item.path)}
    if scenario is not None:
        case = getattr(item, "driveeval_case", None)
        record.update(scenario=scenario.name, use_case=scenario.use_case,
                      dataset=case.dataset.name if case is not None and case.dataset is not None else None)
    if isinstance(item, InvalidScenarioItem):
        record.update(scenario=None, use_case=None, message=str(item.error))
    if outcome is not None and with_outcome:
        record.update(outcome.to_json(relative_to=get_settings(item.config).output_dir))
        payload = getattr(item, PAYLOAD_ATTR, None)
        if payload is not None:
            record["baseline"] = payload
    comparison = getattr(item, COMPARISON_ATTR, None)
    if comparison is not None:
        record["comparison"] = comparison.to_json()
    if failure is not None:
        record.update(failure.to_json())
    return record


def item_trend(item: pytest.Item) -> bytes | None:
    """The item's key figures over the output folder's last runs and this one (a PNG), or None:
    no earlier run has it, or its outcome made no comparable record."""
    payload = getattr(item, PAYLOAD_ATTR, None)
    if not payload or not payload.get("figures"):
        return None
    settings = get_settings(item.config)
    return trend_png(settings.output_dir / HISTORY_NAME, item.nodeid, payload["figures"], settings.run.id,
                     settings.keep_runs or DEFAULT_RUNS)


def annotate_report(item: pytest.Item, call: pytest.CallInfo, report: pytest.TestReport) -> None:
    """Give a phase's report what it carries for us: our errors as a located
    failure (no traceback), the item's record, html extras."""
    expected = hasattr(report, "wasxfail")
    error = call.excinfo.value if call.excinfo is not None and (report.failed or expected) else None
    failure = Failure.of(item, error) if error is not None else None
    if isinstance(error, DriveEvalError):
        # Bad input, in any phase (a fixture that cannot open a dataset fails
        # in setup, where repr_failure is not asked), and an expected failure
        # (pytest-html shows its longrepr): the message, no traceback.
        report.longrepr = failure
    outcome = getattr(item, OUTCOME_ATTR, None)
    model = replaced_model(outcome.details) if outcome is not None else None
    if model and report.failed and error is None and str(report.longrepr).startswith("[XPASS(strict)]"):
        # The expected failure was the scenario's own model's; say why it passed.
        report.longrepr = f"{report.longrepr}\n  {model}"
    fresh = outcome is not None and not getattr(item, SENT_ATTR, False)
    record = item_record(item, failure, with_outcome=fresh)
    if fresh:
        setattr(item, SENT_ATTR, True)
        if html_wanted(item.config):
            report.extras = list(getattr(report, "extras", [])) + html_extras(outcome, record, item_trend(item))
    if record is not None:
        setattr(report, REPORT_ATTR, record)


def comparison_counts(records: list[dict[str, Any]], gate: Any) -> str:
    """One line: how the items compared with their references."""
    counts: dict[str, int] = {}
    for record in records:
        status = (record.get("comparison") or {}).get("status")
        if status:
            counts[status] = counts.get(status, 0) + 1
    against = (f"run {display_path(gate.options.compare_with)}" if gate.options.compare_with is not None
               else display_path(gate.options.folder))
    parts = [f"{n} {status}" for status, n in sorted(counts.items())] or ["no item compared"]
    line = f"driveeval baselines ({against}): " + ", ".join(parts)
    if counts.get("missing") and gate.options.compare_with is None and not gate.options.update:
        line += "; missing ones: run with --driveeval-baseline-update"
    return line


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
        if hasattr(report, "wasxfail"):
            # The evaluation's own verdict stays as it was; this says that pytest expected it to fail.
            record["expected_to_fail"] = report.wasxfail or True
            if report.wasxfail:
                record.setdefault("message", report.wasxfail)

    def sorted_records(self) -> list[dict[str, Any]]:
        return [self.records[k] for k in sorted(self.records)]

    def counts(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for record in self.records.values():
            counts[record.get("status", "unknown")] = counts.get(record.get("status", "unknown"), 0) + 1
        return dict(sorted(counts.items()))

    def summary(self, exitstatus: int, seed: int, run: dict[str, Any] | None = None) -> dict[str, Any]:
        return {
            "schema": SCHEMA_VERSION,
            "run": run,
            "seed": seed,
            "exit_status": int(exitstatus),
            "counts": self.counts(),
            "duration": round(time.time() - self.started, 3),
            "results": self.sorted_records(),
        }


class ResultsReporter:
    """Controller-side plugin: gathers records, writes the summary, prints the table."""

    def __init__(self, config: pytest.Config) -> None:
        self.settings = get_settings(config)
        self.collector = ResultCollector()
        self.warnings: list[str] = []
        self.config = config
        self.baseline_lines: list[str] = []

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        self.collector.add(report)

    @pytest.hookimpl(optionalhook=True)
    def pytest_configure_node(self, node) -> None:
        """xdist: every worker writes into this session's run folder."""
        node.workerinput[RUN_KEY] = self.settings.run.to_json()
        gate = session_gate(self.config)
        if gate is not None and gate.options.compare_with is not None:
            node.workerinput[COMPARE_KEY] = str(gate.options.compare_with)

    @pytest.hookimpl(optionalhook=True)
    def pytest_html_results_summary(self, prefix: list, summary: list, postfix: list, session) -> None:
        """pytest-html: the policies side by side, above the list of tests."""
        table = policy_table_html(self.collector.sorted_records())
        if table:
            postfix.append(table)

    @pytest.hookimpl(optionalhook=True)
    def pytest_html_results_table_header(self, cells: list) -> None:
        """pytest-html: a column with each item's comparison, when the session compares."""
        if session_gate(self.config) is not None:
            cells.append('<th class="col-driveeval-baseline">baseline</th>')

    @pytest.hookimpl(optionalhook=True)
    def pytest_html_results_table_row(self, report: pytest.TestReport, cells: list) -> None:
        if session_gate(self.config) is not None:
            cells.append(comparison_cell(getattr(report, REPORT_ATTR, None)))

    def pytest_sessionfinish(self, session: pytest.Session, exitstatus: int) -> None:
        # A run without scenario items leaves the results alone: no run folder.
        if not self.collector.records:
            return
        run = self.settings.run
        self.warnings = finish_run(self.settings.output_dir, run,
                                   self.collector.summary(exitstatus, self.settings.seed, run.to_json()),
                                   self.settings.keep_runs)
        self.baseline_lines = self._baselines(run.to_json())

    def _baselines(self, run: dict[str, Any]) -> list[str]:
        """Update and prune the baseline folder as asked; lines for the terminal."""
        gate = session_gate(self.config)
        if gate is None:
            return []
        records = self.collector.sorted_records()
        lines = [comparison_counts(records, gate)]
        if gate.options.rootdir_moved:
            self.warnings.append(gate.options.rootdir_moved)
        folder = gate.options.folder
        if folder is None:
            return lines
        if gate.options.rootdir_moved:
            # Under node ids of another rootdir, every baseline looks like one of an item gone: an
            # update would write a second set beside them, a prune would delete the good ones.
            if gate.options.update:
                lines.append(f"driveeval baselines: none written or removed in {display_path(folder)}: the node "
                             "ids moved with pytest's rootdir (see the warning below)")
            return lines
        if gate.options.update:
            updated = update_baselines(folder, records, run)
            lines.append(updated.line(folder))
            self.warnings += updated.problems
        unused = unused_baselines(folder, self.config.rootpath, lambda path: scenario_item_names(path, self.config))
        if unused and gate.options.prune:
            self.warnings += prune(unused, folder)
            lines.append(f"driveeval baselines: removed {len(unused)} of items that no longer exist")
        elif unused:
            shown = ", ".join(display_path(p) for p in unused[:3]) + (" ..." if len(unused) > 3 else "")
            lines.append(f"driveeval baselines: {len(unused)} of items that no longer exist ({shown}); "
                         "--driveeval-baseline-update --driveeval-baseline-prune removes them")
        return lines

    def pytest_terminal_summary(self, terminalreporter, exitstatus: int, config: pytest.Config) -> None:
        records = self.collector.sorted_records()
        if not records:
            return
        tr = terminalreporter
        tr.write_sep("-", f"driveeval: {len(records)} scenario item(s)")
        for line in terminal_rows(records, tr._tw.fullwidth):
            tr.ensure_newline()
            for text, tone in line:
                tr.write(text, **TERMINAL_MARKUP.get(tone or "", {}))
            tr.line("")
        tr.write_line(f"results: {self.settings.output_dir / SUMMARY_NAME} (run {self.settings.run.id})")
        for line in self.baseline_lines:
            tr.write_line(line)
        for warning in self.warnings:
            tr.write_line(f"driveeval warning: {warning}", yellow=True)
        for record in records:
            replay = (record.get("details") or {}).get("replay")
            # pytest shows a failure's text itself, but of an expected failure or a pass only a letter.
            if replay and record.get("status") not in ("failed", "error"):
                tr.write_sep("-", f"driveeval: replayed {replay} ({record.get('status')})")
                for line in (record.get("message") or verdict_reason(record)).splitlines():
                    tr.write_line(line)
