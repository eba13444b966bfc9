"""Use cases and their registry.

A use case names itself (``UseCaseName`` in a scenario), declares the
``UseCaseFormatVersion`` values it reads, a pydantic model for its part of the
``Evaluation`` mapping, the fixtures its ``run`` needs, and how to build the
default dataset / model / point clouds when a ``conftest.py`` does not override
them.  Other packages add use cases through the ``pytest_driveeval.usecases``
entry-point group.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, ClassVar

from pydantic import BaseModel, ConfigDict, ValidationError
from pydantic_core import InitErrorDetails, PydanticCustomError

from .errors import DataError, ModelError
from .section import Section

if TYPE_CHECKING:
    from .outcome import Outcome
    from ..scenario.loaded import DatasetRef, Scenario

ENTRY_POINT_GROUP = "pytest_driveeval.usecases"
#: RunContext.notes key of the --driveeval-model spec, so that the reports say it ran; a use case
#: whose load_model keeps the scenario's own model for an item removes it
MODEL_OPTION_NOTE = "model_option"

# Built-in use cases live in modules that import heavy libraries; they are
# imported only when a scenario names them.
_BUILTIN: dict[str, str] = {
    "closed_loop": "pytest_driveeval.usecases.closed_loop",
    "obstacle_segmentation": "pytest_driveeval.usecases.obstacle_segmentation",
    "policy_benchmark": "pytest_driveeval.usecases.policy_benchmark",
}


class ConditionsModel(Section):
    """Base for use-case models (a :class:`Section`)."""

    model_config = ConfigDict(arbitrary_types_allowed=True)


def located_error(loc: str | tuple, value: Any, message: str) -> ValidationError:
    """A validation error at ``loc`` of the model being validated, raised from a validator of
    it, so that the scenario names the line of that key rather than of the whole mapping."""
    loc = loc if isinstance(loc, tuple) else (loc,)
    return ValidationError.from_exception_data("Evaluation", [InitErrorDetails(
        type=PydanticCustomError("located", "{message}", {"message": message}), loc=loc, input=value)])


# The memory one item may plan to use, in bytes (0: unchecked; None: the default, half this machine's
# memory).  Set once per process from --driveeval-memory-limit / driveeval_memory_limit (the plugin's
# configure); read by the config models' validators, which run when a scenario file is loaded.
_memory_budget: int | None = None
MEMORY_KEYS = "--driveeval-memory-limit / driveeval_memory_limit"


def set_memory_budget(limit: int | None) -> None:
    global _memory_budget
    _memory_budget = limit


def _physical_memory() -> int | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):  # not POSIX
        return None


def memory_budget() -> tuple[int | None, str]:
    """(bytes one item may plan to use or None for no check, where that figure comes from)."""
    if _memory_budget is not None:
        return (_memory_budget or None), MEMORY_KEYS
    physical = _physical_memory()
    if physical is None:
        return None, "unchecked"
    return physical // 2, f"half this machine's memory; {MEMORY_KEYS} sets another, 0: no check"


def gib(size: float) -> str:
    for unit, scale in (("TiB", 2 ** 40), ("GiB", 2 ** 30), ("MiB", 2 ** 20)):
        if size >= scale:
            return f"{size / scale:.3g} {unit}"
    return f"{size / 2 ** 10:.3g} KiB"


def check_fits(loc: str | tuple, value: Any, needed: float, what: str) -> None:
    """Raise a located error at ``loc`` when ``what`` (about ``needed`` bytes) exceeds the memory
    budget: refused at the scenario's line, before anything is allocated."""
    budget, source = memory_budget()
    if budget is not None and needed > budget:
        raise located_error(loc, value, f"{what} would need about {gib(needed)} of memory, more than the "
                                        f"{gib(budget)} an item may use ({source})")


@dataclass
class Case:
    """One collected item of a scenario: usually one dataset."""

    name: str
    dataset: "DatasetRef | None" = None
    params: dict[str, Any] = field(default_factory=dict)


class UseCase:
    name: ClassVar[str] = ""
    format_versions: ClassVar[tuple[str, ...]] = ("0.1.0",)
    config_model: ClassVar[type[BaseModel]] = ConditionsModel
    #: fixtures ``run`` receives in ``ctx.fixtures`` (overridable in conftest.py)
    fixtures: ClassVar[tuple[str, ...]] = ()
    #: model names the use case builds itself (no file), and what it calls a model
    baselines: ClassVar[tuple[str, ...]] = ()
    model_noun: ClassVar[str] = "model"
    #: key figures compared with a baseline: name -> pytest_driveeval.baseline.rules.FigureRule
    regression_figures: ClassVar[dict[str, Any]] = {}

    def regression_units(self, outcome: "Outcome") -> Any:
        """How each unit (scene, frame, episode) of ``outcome`` ended, as
        ``pytest_driveeval.baseline.units.Units``, for a comparison to name the ones that changed; None."""
        return None

    def vet_model_option(self, ctx: "RunContext", spec: str, own: str | None) -> None:
        """Before loading --driveeval-model ``spec`` for an item whose own model is ``own``: another
        use case's baseline is refused as that, and the item's own model named again replaces
        nothing, so the reports do not say it was replaced."""
        mistaken = foreign_baseline(spec, self)
        if mistaken is not None:
            raise mistaken
        if spec == own:
            ctx.notes.pop(MODEL_OPTION_NOTE, None)

    def cases(self, scenario: "Scenario") -> list[Case]:
        if not scenario.datasets:
            return [Case(self.name)]
        return [Case(f"{self.name}[{ref.name}]", ref) for ref in scenario.datasets]

    # Defaults behind the driveeval_* fixtures.  A use case that needs one of
    # them implements it; a user can always override the fixture instead.
    def load_dataset(self, ctx: "RunContext") -> Any:
        ref = ctx.dataset
        if ref is None:
            raise DataError(f"scenario {ctx.scenario.path} names no dataset (Evaluation.Datasets)")
        if not ref.path.exists():
            raise DataError(
                f"dataset '{ref.name}' not found at {ref.path} "
                f"(scenario {ctx.scenario.path}:{ref.line}; set --driveeval-data-root or "
                "DRIVEEVAL_DATA_ROOT, or give the dataset a Path)"
            )
        return ref.path

    def load_model(self, ctx: "RunContext", spec: str | None) -> Any:
        raise ModelError(
            f"use case '{self.name}' has no default model; "
            "override the driveeval_model fixture in conftest.py or pass --driveeval-model"
        )

    def load_pointclouds(self, ctx: "RunContext") -> Any:
        raise DataError(
            f"use case '{self.name}' reads no point clouds; override driveeval_pointclouds in conftest.py"
        )

    def run(self, config: Any, ctx: "RunContext") -> "Outcome":
        raise NotImplementedError


@dataclass
class RunContext:
    """What a use case's ``run`` gets besides its config."""

    scenario: "Scenario"
    dataset: "DatasetRef | None"
    case: Case
    output_dir: Path
    seed: int
    fixtures: dict[str, Any] = field(default_factory=dict)
    #: what a default fixture learnt that run() reports (e.g. which model was loaded)
    notes: dict[str, Any] = field(default_factory=dict)
    #: the person running pytest lets scenario files name code to run (pickle, module:factory)
    allow_code: bool = False
    #: the pytest node id of the item (for the one-line replay of a failure)
    nodeid: str = ""
    #: the session's options for robustness searches (search.item.SearchOptions)
    search: Any = None
    #: the session's executor (execute.ExecutorSpec from --driveeval-executor / ini), or None: each key it
    #: sets replaces the scenario's own
    executor: Any = None
    #: ``progress(what)`` -> a ``(done, total)`` callback drawing how far the item is in ``what``
    #: (steps, episodes, examples, frames, chunks) where a person watches a terminal; None where no one does
    progress: Any = None

    def progress_of(self, what: str) -> Callable[[int, int], None] | None:
        """The callback for a loop over ``what``, or None (nothing to draw: skip the calls)."""
        return self.progress(what) if self.progress is not None else None

    def artefact(self, filename: str) -> Path:
        self.output_dir.mkdir(parents=True, exist_ok=True)
        return self.output_dir / filename


_registry: dict[str, UseCase] = {}
_entry_points_loaded = False


def register_usecase(usecase: type[UseCase] | UseCase, name: str | None = None) -> type[UseCase] | UseCase:
    """Register a use case (class or instance).  Usable as a class decorator."""
    instance = usecase() if isinstance(usecase, type) else usecase
    key = name or instance.name
    if not key:
        raise ValueError(f"{usecase!r} has no name")
    _registry[key] = instance
    return usecase


def register_builtin(name: str, module: str) -> None:
    _BUILTIN[name] = module


def _load_entry_points() -> None:
    global _entry_points_loaded
    if _entry_points_loaded:
        return
    _entry_points_loaded = True
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name not in _registry:
            register_usecase(ep.load(), ep.name)


def get_usecase(name: str) -> UseCase | None:
    if name not in _registry and name in _BUILTIN:
        __import__(_BUILTIN[name])
    if name not in _registry:
        _load_entry_points()
    return _registry.get(name)


def usecase_of(scenario: "Scenario") -> UseCase:
    """The use case a loaded scenario names (``load_scenario`` refuses a name that is not registered)."""
    found = get_usecase(scenario.use_case)
    if found is None:
        raise LookupError(f"scenario {scenario.path} names use case '{scenario.use_case}', which is not registered")
    return found


def foreign_baseline(spec: str, usecase: UseCase) -> ModelError | None:
    """The error for a --driveeval-model that names another use case's baseline (a session
    holds several use cases; the option reaches them all), or None: said as that, not as a
    missing model file."""
    if spec in usecase.baselines or Path(spec).suffix or ":" in spec or Path(spec).exists():
        return None
    owners = [name for name in known_usecases()
              if name != usecase.name and spec in getattr(get_usecase(name), "baselines", ())]
    if not owners:
        return None
    own = f"its baselines are {', '.join(usecase.baselines)}; " if usecase.baselines else ""
    return ModelError(f"--driveeval-model {spec} names a {' / '.join(owners)} baseline, not a {usecase.name} "
                      f"{usecase.model_noun} ({own}give a model file or package.module:factory, or run "
                      f"the {usecase.name} scenarios without the option)")


def known_usecases() -> list[str]:
    _load_entry_points()
    return sorted(set(_registry) | set(_BUILTIN))
