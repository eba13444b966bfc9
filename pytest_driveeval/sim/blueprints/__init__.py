"""Blueprints: highway, merging and intersection scenarios generated from a seed.

BARK-ML's blueprints no longer install, so these rebuild them in numpy: a
fixed road per blueprint (:mod:`.road`) and a ``spawn`` that draws one
episode's traffic, ego start and goal from that episode's own generator.
``make_blueprint(name, **params)`` is the registry; every module documents
where it differs from BARK-ML.

    >>> bp = make_blueprint("merging", gap=(12, 17))
    >>> bp.params.merge_end
    100.0
"""
from __future__ import annotations

import difflib
from collections.abc import Callable
from dataclasses import fields

from pytest_driveeval.sim.blueprints.base import (
    Blueprint,
    BlueprintParams,
    Goal,
    ParameterError,
    Spawn,
)
from pytest_driveeval.sim.blueprints.highway import HighwayParams, highway
from pytest_driveeval.sim.blueprints.intersection import (
    IntersectionParams,
    intersection,
)
from pytest_driveeval.sim.blueprints.merging import MergingParams, merging
from pytest_driveeval.sim.blueprints.road import (
    RoadTooLarge,
    DrivableGrid,
    Lane,
    LaneProjection,
    Road,
)

__all__ = ["BLUEPRINTS", "Blueprint", "BlueprintParams", "DrivableGrid", "Goal", "Lane", "LaneProjection",
           "ParameterError", "Road", "Spawn", "make_blueprint"]

BLUEPRINTS: dict[str, tuple[type[BlueprintParams], Callable[..., Blueprint]]] = {
    "highway": (HighwayParams, highway),
    "merging": (MergingParams, merging),
    "intersection": (IntersectionParams, intersection),
}


def _suggest(word: str, choices) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def make_blueprint(name: str, **params) -> Blueprint:
    """The blueprint ``name`` with ``params`` overriding its defaults.

    Raises ``ValueError`` for an unknown name, and :class:`ParameterError`
    (a ``ValueError`` with ``.parameter``) for an unknown parameter or a bad value.
    """
    if name not in BLUEPRINTS:
        raise ValueError(f"unknown blueprint {name!r}{_suggest(name, BLUEPRINTS)}; "
                         f"known: {', '.join(sorted(BLUEPRINTS))}")
    cls, build = BLUEPRINTS[name]
    known = {f.name for f in fields(cls)}
    for key in params:
        if key not in known:
            raise ParameterError(name, key, f"unknown parameter{_suggest(key, known)}; "
                                            f"known: {', '.join(sorted(known))}")
    checked = cls(**params)
    try:
        return build(checked)
    except RoadTooLarge as exc:
        # Name the size the scenario set (or the first that makes the road large).
        given = [key for key in cls.EXTENT if key in params] or list(cls.EXTENT)
        raise ParameterError(name, given[0], str(exc)) from None
