"""A policy_benchmark scenario's ``Blueprint: {CommonRoad: file.xml, PlanningProblem: id}``: which
items it makes and the scene each item runs (sim.commonroad_scene).

The file is read when the items are collected, to make one item per planning problem when the
scenario names none; a file that cannot be read then still makes its items (one per policy), and
each fails with the reader's error when it runs, so the scenario's other items run.  Errors name
the scenario file and the line of the key at fault (``CommonRoad``, or ``PlanningProblem`` for a
planning problem the file does not have), then the CommonRoad file and its element.  The scene's
arrays are bounded before they are allocated: its steps (``StepLimit``, ``Params.max_steps`` or the
goal's time interval) times its obstacles must fit the item's memory budget, and the drivable
area's raster at ``Params.resolution`` the raster's cell limit.  An ``idm_expert`` policy the item
runs needs a route to the planning problem's goal (sim.commonroad_route): without one the item fails
at that policy's line, saying why, before any episode runs.
"""
from __future__ import annotations

from typing import Any

from pytest_driveeval.core.errors import DataError, display_path
from pytest_driveeval.core.usecase import gib, memory_budget
from pytest_driveeval.io.commonroad.commonroad import CommonRoadError, no_problem_message, planning_problem

__all__ = ["check_expert_routes", "planning_problems", "scene_for"]


def planning_problems(scenario: Any) -> list[int] | None:
    """The planning problems to make items for, or None: one item per policy (a blueprint, a named
    planning problem, or a file that does not read, whose items report why when they run)."""
    from pytest_driveeval.sim.commonroad_scene import read_cached

    spec = scenario.config.Blueprint
    if spec.CommonRoad is None or spec.PlanningProblem is not None:
        return None
    try:
        return sorted(read_cached(scenario.resolve(spec.CommonRoad)).planning_problems) or None
    except (OSError, CommonRoadError):
        return None


def scene_for(config: Any, ctx: Any, params: dict) -> Any:
    """The item's CommonRoad scene; a DataError naming the YAML line, the file and the element."""
    from pytest_driveeval.sim.blueprints import ParameterError
    from pytest_driveeval.sim.commonroad_scene import commonroad_scene, read_cached

    spec = config.Blueprint
    path = ctx.scenario.resolve(spec.CommonRoad)
    problem = ctx.case.params.get("problem", spec.PlanningProblem)
    key: tuple = ("Blueprint", "CommonRoad")
    try:
        if problem is None:
            ids = sorted(read_cached(path).planning_problems)
            if not ids:
                raise CommonRoadError(no_problem_message(read_cached(path)))
            if len(ids) != 1:
                raise CommonRoadError(f"{display_path(path)} holds {len(ids)} planning problems "
                                      f"({', '.join(map(str, ids)) or 'none'}): name one in PlanningProblem")
            problem = ids[0]
        elif "problem" not in ctx.case.params and problem not in read_cached(path).planning_problems:
            key = ("Blueprint", "PlanningProblem")
        _check_fits(config, ctx, path, problem, params)
        return commonroad_scene(path, problem, traffic=spec.Traffic or "replay", **params)
    except OSError as exc:
        raise DataError(f"{_where(ctx, key)}: CommonRoad scenario {display_path(path)} cannot be read: "
                        f"{exc.strerror or exc}") from None
    except CommonRoadError as exc:
        raise DataError(f"{_where(ctx, key)}: {exc}") from None
    except ParameterError as exc:
        given = exc.parameter in spec.Params
        where = _where(ctx, ("Blueprint", "Params", exc.parameter) if given else key)
        raise DataError(f"{where}: {str(exc).split(': ', 2)[-1]}"
                        + ("" if given else f" (Params.{exc.parameter} sets it)")) from None


def check_expert_routes(config: Any, ctx: Any, scene: Any, names: list[str]) -> None:
    """Refuse, at its ``Policies`` line, an ``idm_expert`` among ``names`` when no route reaches the goal."""
    from pytest_driveeval.sim.commonroad_route import RouteError, plan_route

    for name in names:
        if config.Policies.get(name) != "idm_expert":
            continue
        try:
            plan_route(scene.scenario, scene.problem)
        except RouteError as exc:
            raise DataError(f"{_where(ctx, ('Policies', name))}: idm_expert cannot drive this planning problem: "
                            f"{exc}") from None


def _check_fits(config: Any, ctx: Any, path: Any, problem: int, params: dict) -> None:
    """Refuse, at the key that set them, steps times obstacles whose arrays exceed the memory budget."""
    from pytest_driveeval.sim.commonroad_scene import read_cached, scene_bytes, step_limit

    scenario = read_cached(path)
    steps = params.get("max_steps")
    if steps is None:
        steps = step_limit(planning_problem(scenario, problem))
        key, whose = ("Blueprint", "CommonRoad"), f"the end of planning problem {problem}'s goal time interval"
    elif config.StepLimit is not None:
        key, whose = ("StepLimit",), "StepLimit"
    else:
        key, whose = ("Blueprint", "Params", "max_steps"), "max_steps"
    needed = scene_bytes(int(steps), len(scenario.obstacles))
    budget, source = memory_budget()
    if budget is not None and needed > budget:
        raise DataError(f"{_where(ctx, key)}: {int(steps)} steps ({whose}) of the {len(scenario.obstacles)} recorded "
                        f"obstacles of {display_path(path)} would need about {gib(needed)} of memory, more than the "
                        f"{gib(budget)} an item may use ({source}): give fewer steps")


def _where(ctx: Any, keys: tuple) -> str:
    line = ctx.scenario.line_of("Evaluation", *keys)
    place = display_path(ctx.scenario.path)
    dotted = ".".join(map(str, ("Evaluation", *keys)))
    return f"{place}:{line}: {dotted}" if line else f"{place}: {dotted}"
