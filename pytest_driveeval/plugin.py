"""pytest hooks of pytest-driveeval.  Hooks only: the work is in the modules they call."""
from __future__ import annotations

from pathlib import Path

import pytest

from .collect import InvalidScenarioItem, ScenarioFile, failure_message, is_scenario_file
from .errors import DriveEvalError
from .outcome import OUTCOME_ATTR
from .report.attachments import html_extras, html_wanted
from .results import REPORT_ATTR, ResultsReporter
from .settings import add_options, get_settings

pytest_plugins = ["pytest_driveeval.fixtures"]

def _is_worker(config: pytest.Config) -> bool:
    return hasattr(config, "workerinput")


def pytest_addoption(parser: pytest.Parser) -> None:
    add_options(parser)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "driveeval_scenario(path, dataset=None): bind a Python test to a scenario file, "
        "so it gets that scenario's driveeval_* fixtures",
    )
    get_settings(config)  # fail early on a bad option value
    if not _is_worker(config):
        config.pluginmanager.register(ResultsReporter(config), "driveeval-results")


def pytest_collect_file(file_path: Path, parent: pytest.Collector):
    if is_scenario_file(file_path, get_settings(parent.config).patterns):
        return ScenarioFile.from_parent(parent, path=file_path)
    return None


def _item_record(item: pytest.Item, with_outcome: bool) -> dict | None:
    scenario = getattr(item, "driveeval_scenario", None)
    outcome = getattr(item, OUTCOME_ATTR, None)
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
    return record


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call):
    report = yield
    error = call.excinfo.value if call.excinfo is not None and report.failed else None
    if isinstance(error, DriveEvalError):
        # Bad input, in any phase (a fixture that cannot open a dataset fails
        # in setup, where repr_failure is not asked): the message, no traceback.
        report.longrepr = failure_message(item, error)
    # The outcome (and its html extras) travels once, with the report of the
    # phase that produced it; the controller merges an item's records.
    outcome = getattr(item, OUTCOME_ATTR, None)
    fresh = outcome is not None and not getattr(item, "_driveeval_outcome_sent", False)
    if fresh:
        item._driveeval_outcome_sent = True
        if html_wanted(item.config):
            report.extras = list(getattr(report, "extras", [])) + html_extras(outcome)
    record = _item_record(item, with_outcome=fresh)
    if record is not None:
        if error is not None:
            # Built from the exception, not from report.longrepr, which xdist
            # prefixes with the worker's name.
            record["message"] = failure_message(item, error)
        setattr(report, REPORT_ATTR, record)
    return report
