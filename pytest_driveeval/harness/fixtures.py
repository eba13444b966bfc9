"""The fixtures scenario items request.  Override any of them in conftest.py.

``driveeval_dataset``, ``driveeval_model`` and ``driveeval_pointclouds`` default
to what the scenario's use case builds from the scenario; a conftest.py that
defines a fixture of the same name replaces it for the items below it, which
is how a team evaluates its own model or point-cloud filter.

A plain Python test gets the same fixtures by naming a scenario:
``@pytest.mark.driveeval_scenario("demo.scenario.yaml", dataset="name")``.
"""
from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest

from ..baseline.gate import PAYLOAD_ATTR, ItemBaseline
from ..baseline.payload import make_payload
from ..baseline.session import session_gate
from ..core.deadline import time_limit
from ..core.errors import DriveEvalError, display_path
from ..execute import ExecutorSpec, executor_from_option
from ..core.outcome import OUTCOME_ATTR, Outcome
from .progress import item_progress
from ..report.attachments import allure_wanted, attach_to_allure, junit_properties
from .results import item_trend
from ..scenario import Scenario, load_scenario
from ..search.spec import SearchOptions, parse_replay
from ..sim.torch_threads import one_torch_thread
from .runs import start_run
from .settings import TIME_LIMIT_KEYS, Settings, get_settings, item_seed
from ..core.usecase import MODEL_OPTION_NOTE, Case, RunContext, usecase_of


_EXECUTOR_KEY = pytest.StashKey["ExecutorSpec | None"]()
_SEARCH_KEY = pytest.StashKey[SearchOptions]()


def session_executor(config: pytest.Config) -> ExecutorSpec | None:
    """The executor --driveeval-executor (or ini driveeval_executor) sets for the session, or None."""
    if _EXECUTOR_KEY not in config.stash:
        text = get_settings(config).executor
        try:
            config.stash[_EXECUTOR_KEY] = executor_from_option(text) if text else None
        except ValueError as exc:
            raise pytest.UsageError(f"--driveeval-executor / driveeval_executor: {exc}") from None
    return config.stash[_EXECUTOR_KEY]


def session_search_options(config: pytest.Config) -> SearchOptions:
    """What the session's options set for every robustness search; a malformed --driveeval-replay is a
    usage error here, before collection, rather than one failure per item."""
    if _SEARCH_KEY not in config.stash:
        settings = get_settings(config)
        if settings.replay:
            try:
                parse_replay(settings.replay)
            except ValueError as exc:
                raise pytest.UsageError(f"--driveeval-replay: {exc}") from None
        config.stash[_SEARCH_KEY] = SearchOptions(
            examples=settings.search_examples, replay=settings.replay, profile=settings.search_profile,
            database=settings.search_database, seed=settings.seed)
    return config.stash[_SEARCH_KEY]


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
    cases = usecase_of(scenario).cases(scenario)
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
    search = session_search_options(request.config)
    yield RunContext(scenario=driveeval_scenario, dataset=case.dataset, case=case,
                     output_dir=driveeval_output_dir, seed=driveeval_seed,
                     allow_code=settings.allow_scenario_code, nodeid=request.node.nodeid, search=search,
                     executor=session_executor(request.config), progress=line.progress if line else None)
    if line is not None:
        line.clear()


@pytest.fixture
def driveeval_dataset(driveeval_context: RunContext) -> Any:
    """The dataset the scenario names, as its use case opens it."""
    return usecase_of(driveeval_context.scenario).load_dataset(driveeval_context)


@pytest.fixture
def driveeval_model(request: pytest.FixtureRequest, driveeval_context: RunContext) -> Any:
    """The model (policy) under test: --driveeval-model if given, else the scenario's."""
    spec = get_settings(request.config).model
    if spec is not None:  # the reports name it; a use case that keeps an item's own model drops the note
        driveeval_context.notes[MODEL_OPTION_NOTE] = spec
    return usecase_of(driveeval_context.scenario).load_model(driveeval_context, spec)


@pytest.fixture
def driveeval_pointclouds(driveeval_context: RunContext, driveeval_dataset: Any) -> Any:
    """The point clouds under test, as the use case reads them from the dataset
    (the ``driveeval_dataset`` fixture, so an override of it applies here too)."""
    driveeval_context.fixtures.setdefault("driveeval_dataset", driveeval_dataset)
    return usecase_of(driveeval_context.scenario).load_pointclouds(driveeval_context)


def model_origin(request: pytest.FixtureRequest, ctx: RunContext, overrides: dict[str, Any]) -> str | None:
    """What stood in for the scenario's own model, as the reports name it; None when it ran its own.

    A conftest.py fixture or --driveeval-model changes what a verdict is about (a baseline's
    expected failure may pass), so every report says which one ran."""
    if "driveeval_model" not in usecase_of(ctx.scenario).fixtures:
        return None
    if "driveeval_model" in overrides:
        return "the model given to driveeval_run()"
    info = getattr(request.node, "_fixtureinfo", None)
    defs = info.name2fixturedefs.get("driveeval_model") if info is not None else None
    func = defs[-1].func if defs else None
    if func is not None and getattr(func, "__module__", __name__) != __name__:
        try:
            where = f"{display_path(inspect.getsourcefile(func))}:{inspect.getsourcelines(func)[1]}"
        except (TypeError, OSError):
            where = func.__module__
        return f"the driveeval_model fixture of {where}"
    spec = ctx.notes.get(MODEL_OPTION_NOTE)
    return f"--driveeval-model {spec}" if spec else None


def _keep(request: pytest.FixtureRequest, ctx: RunContext, outcome: Outcome, origin: str | None = None) -> None:
    """Keep the outcome on the item for the summary, and give it to the reports
    that run inside the test (allure) or read the item (JUnit properties)."""
    if outcome.scenario is None:
        outcome.scenario = f"{ctx.scenario.name} [{ctx.case.name}]"
    if origin:
        outcome.details["model"] = origin
    setattr(request.node, OUTCOME_ATTR, outcome)
    root = request.config.rootpath
    file = ctx.scenario.path.relative_to(root).as_posix() if ctx.scenario.path.is_relative_to(root) \
        else str(ctx.scenario.path)
    setattr(request.node, PAYLOAD_ATTR, make_payload(
        outcome, request.node.nodeid, use_case=usecase_of(ctx.scenario), scenario=ctx.scenario, dataset=ctx.dataset,
        seed=ctx.seed, search=ctx.search, item=ctx.case.name, file=file))
    request.node.user_properties.extend(junit_properties(outcome))
    if allure_wanted(request.config):
        attach_to_allure(outcome, ctx.scenario, ctx.dataset.name if ctx.dataset is not None else None,
                         trend=item_trend(request.node), case=ctx.case)


def _item_time_limit(scenario: Scenario, settings: Settings) -> tuple[float | None, str]:
    """The item's time limit (None: none) and what the message says about where it comes from."""
    if scenario.time_limit is not None:
        return scenario.time_limit or None, (f"TimeLimit at {display_path(scenario.path)}:"
                                             f"{scenario.line_of('TimeLimit')}")
    if settings.time_limit_source == "default":
        return settings.time_limit, (f"the default of {settings.time_limit:g} s; set TimeLimit in the scenario "
                                     f"or {TIME_LIMIT_KEYS}, 0 for none")
    return settings.time_limit, TIME_LIMIT_KEYS


@pytest.fixture
def driveeval_baseline(request: pytest.FixtureRequest) -> ItemBaseline:
    """This item's baseline (or earlier run) under the session's --driveeval-baseline / --driveeval-compare."""
    return ItemBaseline(session_gate(request.config), request.node)


@pytest.fixture
def driveeval_run(request: pytest.FixtureRequest, driveeval_context: RunContext) -> Callable[..., Outcome]:
    """Run the scenario's evaluation with the current fixtures; return its Outcome.

    The outcome is kept on the item so that it reaches the reports, also when
    the evaluation stops on bad input after computing part of it.
    """

    def run(**overrides: Any) -> Outcome:
        ctx = driveeval_context
        usecase = usecase_of(ctx.scenario)
        seconds, source = _item_time_limit(ctx.scenario, get_settings(request.config))
        origin = None
        try:
            with time_limit(seconds, f"scenario '{ctx.scenario.name}' ({ctx.case.name})", source):
                for name in usecase.fixtures:
                    ctx.fixtures[name] = overrides[name] if name in overrides else request.getfixturevalue(name)
                origin = model_origin(request, ctx, overrides)
                with one_torch_thread(if_imported=True):
                    outcome = usecase.run(ctx.scenario.config, ctx)
        except DriveEvalError as exc:
            if isinstance(exc.outcome, Outcome):
                _keep(request, ctx, exc.outcome, origin)
            raise
        _keep(request, ctx, outcome, origin)
        return outcome

    return run
