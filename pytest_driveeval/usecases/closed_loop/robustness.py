"""The closed-loop robustness search: which start perturbation makes a scene fail?

An example is one of the item's scenes with its start moved off the log
(:class:`~pytest_driveeval.strategies.StartPerturbation`); it fails when
that scene fails the scenario's conditions.  A generation of examples is
one unroll: the scenes are stacked once, and each generation takes its rows
from that stack, so the examples of a generation step through the policy
together.
"""
from __future__ import annotations

from functools import lru_cache
from typing import Any, Callable, Sequence

import numpy as np

from pytest_driveeval.core.outcome import Finding, Outcome
from pytest_driveeval.sim.logreplay.agents import LogCells
from pytest_driveeval.sim.logreplay.logarrays import LogArrays, window_columns
from pytest_driveeval.search.engine import Example, Verdict
from pytest_driveeval.search.item import Searchable
from pytest_driveeval.strategies import StartPerturbation, start_perturbations
from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig
from pytest_driveeval.usecases.closed_loop.score import SceneMaps
from pytest_driveeval.usecases.closed_loop.evaluate import SceneVerdict, judge_scene, stack_log, unroll_config, unroll_log
from pytest_driveeval.usecases.closed_loop.names import name_findings, named, scene_identity

__all__ = ["closed_loop_searchable", "example_verdict"]


def example_verdict(verdict: SceneVerdict, names: dict[int, str] | None = None) -> Verdict:
    """A scene's verdict as the search sees it: the first reason, where it happened; ``names``
    (scene index -> names.named) names the scene in the reason as the item's findings name it."""
    if verdict.passed:
        return Verdict(False)
    first = min(verdict.findings, key=lambda f: (f.frame is None, f.frame or 0))
    where = {"scene": verdict.scene}
    if first.frame is not None:
        where["frame"] = int(first.frame)
    reason = Finding(first.message, scene=first.scene)
    name_findings([reason], names or {})
    return Verdict(True, reason.message, where)


def closed_loop_searchable(config: ClosedLoopConfig, dataset: Any, model: Callable, ids: Sequence[int],
                           agents: Any, show: Callable[[int, StartPerturbation], Outcome] | None,
                           distribute: Callable[[list[Example]], list[Verdict]] | None = None) -> Searchable:
    """The search over ``ids`` (scene indices); ``show(scene, perturbation)`` is the item's own
    evaluation of one scene, with its animation.  ``distribute``: judges a generation's examples
    elsewhere (chunks on an executor, each judged by this same function on a worker) instead
    of here (the scenes are then not stacked in this process at all)."""
    return Searchable(case_name="scene", case_labels=[int(i) for i in ids], perturbation_type=StartPerturbation,
                      perturbations=start_perturbations(**config.Perturbation.ranges()),
                      evaluate_many=distribute or _judged_here(config, dataset, model, ids, agents),
                      show=lambda example: show(int(ids[example.case]), example.perturbation) if show else None)


def _judged_here(config: ClosedLoopConfig, dataset: Any, model: Callable, ids: Sequence[int], agents: Any
                 ) -> Callable[[list[Example]], list[Verdict]]:
    """``evaluate_many`` in this process: the scenes stacked once, each generation unrolled on copies."""
    spec = config.Unroll
    log = stack_log(dataset, ids, spec.StartFrame, agents)
    options = spec.unroll_options()
    options.pop("raster")  # the config refuses a search with raster inputs
    options.pop("vector_map")  # and with map inputs
    settings = unroll_config(**options)

    # Packed once: every generation's rows are copies of these scenes.
    cells = LogCells(log)
    columns, columns_ok = window_columns(log, spec.HistoryFrames)
    maps = SceneMaps(dataset)
    names = {int(s): named(int(s), scene_identity(dataset, int(s))) for s in ids}
    # An example's verdict needs the score only where the conditions bound it (about 4 ms a scene)
    scored = config.Conditions.Score is not None

    @lru_cache(maxsize=8)
    def copies(rows: tuple[int, ...]) -> Any:
        # A generation's rows repeat (a one-scene item's are all 0): copying the
        # stacked scenes for each generation was 40 % of a batch's harness time.
        # The engine never writes into the log it is given; read-only arrays make sure of it.
        if len(set(rows)) == 1:  # one scene (a one-scene item): views, no copy at all
            return LogArrays(*(np.broadcast_to(getattr(log, name)[rows[0]], (len(rows),) + getattr(log, name).shape[1:])
                               for name in log.__dataclass_fields__))
        taken = log.take(np.array(rows, dtype=np.int64))
        for name in taken.__dataclass_fields__:
            getattr(taken, name).flags.writeable = False
        return taken

    def evaluate_many(examples: list[Example]) -> list[Verdict]:
        rows = np.array([e.case for e in examples], dtype=np.int64)
        unrolled = unroll_log(copies(tuple(rows.tolist())), model, settings, [e.perturbation for e in examples],
                              cells=cells.rows_of(rows), candidates=(columns[rows], columns_ok[rows]),
                              dataset=dataset, maps=maps)
        unrolled.maps = maps
        return [example_verdict(judge_scene(unrolled, i, config.Conditions, score=scored), names)
                for i in range(len(examples))]

    return evaluate_many
