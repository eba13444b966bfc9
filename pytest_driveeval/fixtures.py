"""The fixtures scenario items request.  Override any of them in conftest.py.

``driveeval_dataset``, ``driveeval_model`` and ``driveeval_pointclouds`` default
to what the scenario's use case builds from the scenario; a conftest.py that
defines a fixture of the same name replaces it for the items below it, which
is how a team evaluates its own model or point-cloud filter.

A plain Python test gets the same fixtures by naming a scenario:
``@pytest.mark.driveeval_scenario("demo.scenario.yaml", dataset="name")``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

from .deadline import time_limit
from .errors import DriveEvalError
from .execute import ExecutorSpec, executor_from_option
from .outcome import OUTCOME_ATTR, Outcome
from .progress import item_progress
from .report.attachments import allure_wanted, attach_to_allure, junit_properties
from .scenario import Scenario, load_scenario
from .search.spec import SearchOptions
from .runs import start_run
from .settings import get_settings, item_seed
from .usecase import Case, RunContext


_EXECUTOR_KEY = pytest.StashKey["ExecutorSpec | None"]()


def session_executor(config: pytest.Config) -> ExecutorSpec | None:
    """The executor --driveeval-executor (or ini driveeval_executor) sets for the session, or None."""
    if _EXECUTOR_KEY not in config.stash:
        text = get_settings(config).executor
        try:
            config.stash[_EXECUTOR_KEY] = executor_from_option(text) if text else None
        except ValueError as exc:
            raise pytest.UsageError(f"--driveeval-executor / driveeval_executor: {exc}") from None
    return config.stash[_EXECUTOR_KEY]


def _binding(request: pytest.FixtureRequest) -> tuple[Scenario, Case]:
    node = request.node
    if getattr(node, "driveeval_case", None) is not None:
        return node.driveeval_scenario, node.driveeval_case
    mark = node.get_closest_marker("driveeval_scenario")
    if mark is None or not mark.args:
        pytest.fail(
            f"{node.nodeid} uses a driveeval fixture but is not a scenario item; "
            "mark it with @pytest.mark.driveeval_scenario('file.scenario.yaml', dataset=...)",
            pytrace=False,
        )
    path = Path(str(node.path)).parent / mark.args[0]
    scenario = load_scenario(path, data_root=get_settings(request.config).data_root)
    cases = scenario.cases()
    wanted = mark.kwargs.get("dataset")
    chosen = [c for c in cases if wanted is None or (c.dataset is not None and c.dataset.name == wanted)]
    if not chosen:
        names = [c.dataset.name for c in cases if c.dataset is not None]
        pytest.fail(f"{path}: no dataset named {wanted!r}; it has {names}", pytrace=False)
    node.driveeval_scenario, node.driveeval_case = scenario, chosen[0]
    return scenario, chosen[0]


@pytest.fixture
def driveeval_scenario(request: pytest.FixtureRequest) -> Scenario:
    """The validated scenario this item evaluates."""
    return _binding(request)[0]


@pytest.fixture
def driveeval_output_dir(request: pytest.FixtureRequest) -> Path:
    """This item's own artefact folder under the output directory."""
    settings = get_settings(request.config)
    start_run(settings.output_dir, settings.run)
    path = settings.item_dir(request.node.nodeid)
    path.mkdir(parents=True, exist_ok=True)
    return path


@pytest.fixture
def driveeval_seed(request: pytest.FixtureRequest) -> int:
    """This item's seed: the same with or without xdist, whatever the order."""
    return item_seed(get_settings(request.config).seed, request.node.nodeid)


@pytest.fixture
def driveeval_context(request: pytest.FixtureRequest, driveeval_scenario: Scenario,
                      driveeval_output_dir: Path, driveeval_seed: int) -> Iterator[RunContext]:
    _, case = _binding(request)
    line = item_progress(request.node)
    settings = get_settings(request.config)
    search = SearchOptions(examples=settings.search_examples, replay=settings.replay,
                           profile=settings.search_profile, database=settings.search_database,
                           seed=settings.seed)
    yield RunContext(scenario=driveeval_scenario, dataset=case.dataset, case=case,
                     output_dir=driveeval_output_dir, seed=driveeval_seed,
                     allow_code=settings.allow_scenario_code, nodeid=request.node.nodeid, search=search,
                     executor=session_executor(request.config), progress=line.progress if line else None)
    if line is not None:
        line.clear()


@pytest.fixture
def driveeval_dataset(driveeval_context: RunContext) -> Any:
    """The dataset the scenario names, as its use case opens it."""
    return driveeval_context.scenario.usecase.load_dataset(driveeval_context)


@pytest.fixture
def driveeval_model(request: pytest.FixtureRequest, driveeval_context: RunContext) -> Any:
    """The model (policy) under test: --driveeval-model if given, else the scenario's."""
    spec = get_settings(request.config).model
    return driveeval_context.scenario.usecase.load_model(driveeval_context, spec)


@pytest.fixture
def driveeval_pointclouds(driveeval_context: RunContext, driveeval_dataset: Any) -> Any:
    """The point clouds under test, as the use case reads them from the dataset
    (the ``driveeval_dataset`` fixture, so an override of it applies here too)."""
    driveeval_context.fixtures.setdefault("driveeval_dataset", driveeval_dataset)
    return driveeval_context.scenario.usecase.load_pointclouds(driveeval_context)


def _keep(request: pytest.FixtureRequest, ctx: RunContext, outcome: Outcome) -> None:
    """Keep the outcome on the item for the summary, and give it to the reports
    that run inside the test (allure) or read the item (JUnit properties)."""
    if outcome.scenario is None:
        outcome.scenario = f"{ctx.scenario.name} [{ctx.case.name}]"
    setattr(request.node, OUTCOME_ATTR, outcome)
    request.node.user_properties.extend(junit_properties(outcome))
    if allure_wanted(request.config):
        attach_to_allure(outcome, ctx.scenario, ctx.dataset.name if ctx.dataset is not None else None)


@pytest.fixture
def driveeval_run(request: pytest.FixtureRequest, driveeval_context: RunContext) -> Callable[..., Outcome]:
    """Run the scenario's evaluation with the current fixtures; return its Outcome.

    The outcome is kept on the item so that it reaches the reports, also when
    the evaluation stops on bad input after computing part of it.
    """

    def run(**overrides: Any) -> Outcome:
        ctx = driveeval_context
        usecase = ctx.scenario.usecase
        seconds = ctx.scenario.time_limit or get_settings(request.config).time_limit
        try:
            with time_limit(seconds, f"scenario '{ctx.scenario.name}' ({ctx.case.name})"):
                for name in usecase.fixtures:
                    ctx.fixtures[name] = overrides[name] if name in overrides else request.getfixturevalue(name)
                outcome = usecase.run(ctx.scenario.config, ctx)
        except DriveEvalError as exc:
            if isinstance(exc.outcome, Outcome):
                _keep(request, ctx, exc.outcome)
            raise
        _keep(request, ctx, outcome)
        return outcome

    return run
