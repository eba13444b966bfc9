"""pytest hooks of pytest-driveeval.  Hooks only: the work is in the modules they call."""
from __future__ import annotations

from pathlib import Path

import pytest

from .baseline.session import session_gate
from .harness.collect import ScenarioFile, broken_scenario_links, is_scenario_file
from .core.deadline import session, session_ended, session_finishing
from .execute import disconnect
from .harness.progress import close_terminal, open_terminal, share_with_worker
from .harness.results import ResultsReporter, annotate_report
from .harness.settings import add_options, check_output_dir, get_settings, time_limit_header
from .core.usecase import set_memory_budget

pytest_plugins = ["pytest_driveeval.harness.fixtures"]


def pytest_addoption(parser: pytest.Parser) -> None:
    add_options(parser)


@pytest.hookimpl(wrapper=True)
def pytest_cmdline_main(config: pytest.Config):
    with session():
        exit_code = yield
    session_ended(exit_code)
    return exit_code


@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session: pytest.Session) -> None:
    session_finishing(session.exitstatus, (getattr(session.config, "workerinput", None) or {}).get("workerid"))


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "driveeval_scenario(path, dataset=None): bind a Python test to a scenario file, "
        "so it gets that scenario's driveeval_* fixtures",
    )
    # Not imported at the top: pytest imports fixtures.py itself (pytest_plugins above) to rewrite
    # its asserts, and warns that it cannot when this module has imported it first.
    from .harness.fixtures import session_executor, session_search_options

    settings = get_settings(config)  # fail early on a bad option value
    set_memory_budget(settings.memory_limit)
    session_executor(config)
    session_search_options(config)
    session_gate(config)  # --driveeval-compare names a run that exists, before collection
    open_terminal(config)
    if not hasattr(config, "workerinput"):  # only the controller (or a plain run) writes results
        check_output_dir(settings.output_dir)
        config.pluginmanager.register(ResultsReporter(config), "driveeval-results")


def pytest_report_header(config: pytest.Config) -> list[str]:
    return [time_limit_header(get_settings(config))]


def pytest_unconfigure(config: pytest.Config) -> None:
    # Each process (the controller, every xdist worker) closes the Ray connection it opened, if any.
    disconnect()
    close_terminal(config)


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node) -> None:
    """(pytest-xdist) whether a worker draws its items' status lines."""
    share_with_worker(node.config, node.workerinput)


def pytest_collect_file(file_path: Path, parent: pytest.Collector):
    if is_scenario_file(file_path, get_settings(parent.config).patterns):
        return ScenarioFile.from_parent(parent, path=file_path)
    return None


@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector: pytest.Collector):
    report = yield
    if isinstance(collector, pytest.Directory) and report.passed:
        patterns = get_settings(collector.config).patterns
        report.result.extend(ScenarioFile.from_parent(collector, path=link)
                             for link in broken_scenario_links(collector.path, patterns))
    return report


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo):
    report = yield
    annotate_report(item, call, report)
    return report
