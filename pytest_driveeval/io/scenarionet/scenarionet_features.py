"""A ScenarioNet scenario's map features as read: each one drawable, or skipped with the reason.

Real converted maps hold features nothing can be drawn from: Waymo's map has lanes whose centre
line is a single point (a real scene has five ``LANE_SURFACE_STREET`` ones), Argoverse 2's drivable
outline is cut into pieces of 20 points and its last piece may hold one.  Such a feature is
skipped, and listed (:class:`Skipped`: id, type, why), and the scene is read without it; where only
one of a feature's polyline and polygon is unusable, the feature is kept from the other.

A line needs two points that are not all one point; a surface needs three that are not all one
point; coordinates must be finite.  A stop sign is its ``position`` (three numbers, or two).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from .scenarionet_types import feature_group

#: the keys read into a MapFeature's fields; the others are kept, as given, in ``extra``
_READ_KEYS = frozenset(("type", "polyline", "polygon", "position", "speed_limit_kmh"))


class Skipped(NamedTuple):
    """Something in the file not read as written: its id and type, why (with what was kept, when part
    of it was), and what it is (``what``: "map feature", "track", "traffic light")."""
    id: str
    type: str
    reason: str
    what: str = "map feature"

    def __str__(self) -> str:
        return f"{self.what} {self.id} ({self.type}): {self.reason}"


@dataclass
class MapFeature:
    id: str
    type: str
    group: str
    polyline: np.ndarray | None = None  # (K, 2 or 3); nuScenes' lane centre lines carry (x, y, heading)
    polygon: np.ndarray | None = None   # (K, 2 or 3)
    position: np.ndarray | None = None  # a stop sign's point
    speed_limit_kmh: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)  # entry / exit lanes, neighbours, ... as given


def _shape_problem(value: Any, key: str) -> tuple[np.ndarray | None, str | None]:
    """(the points as floats, None) or (None, why they cannot be drawn)."""
    try:
        points = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        return None, f"its {key} is not an array of numbers"
    if points.size == 0:
        return None, f"its {key} is empty"
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        return None, f"its {key} has shape {points.shape}, not (K, 2 or 3)"
    # one sum finds a NaN or an infinity (or an overflow, which the full check then tells apart)
    if not math.isfinite(points.sum()) and not np.isfinite(points).all():
        return None, f"its {key} holds NaN or infinite coordinates"
    return points, None


def _one_point(points: np.ndarray) -> bool:
    """Whether every point has the first one's x and y.  A point half-way along that differs says no
    at the cost of two comparisons, which is every real feature; only then are all compared."""
    k = len(points) // 2
    if points[k, 0] != points[0, 0] or points[k, 1] != points[0, 1]:
        return False
    return not (points[1:, :2] != points[0, :2]).any()  # x, y: nuScenes' third is a heading


def _line(value: Any) -> tuple[np.ndarray | None, str | None]:
    points, why = _shape_problem(value, "polyline")
    if why is None and len(points) < 2:
        return None, f"its polyline has {len(points)} point(s); a line needs 2"
    if why is None and _one_point(points):
        return None, f"its polyline has zero length (its {len(points)} points coincide)"
    return (None, why) if why else (points, None)


def _surface(value: Any) -> tuple[np.ndarray | None, str | None]:
    points, why = _shape_problem(value, "polygon")
    if why is None and len(points) < 3:
        return None, f"its polygon has {len(points)} point(s); a surface needs 3"
    # Points on one line are not refused: nothing is inside them, so they change no check, and
    # finding them would cost every polygon of every scene an area.
    if why is None and _one_point(points):
        return None, f"its polygon is one point (its {len(points)} points coincide)"
    return (None, why) if why else (points, None)


def _position(value: Any) -> tuple[np.ndarray | None, str | None]:
    try:
        point = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        return None, "its position is not an array of numbers"
    if point.size not in (2, 3) or not np.isfinite(point).all():
        return None, f"its position {np.array2string(point, precision=3)[:60]} is not a finite point (x, y[, z])"
    return point, None


def _speed(value: Any) -> float | None:
    try:
        speed = float(value)
    except (TypeError, ValueError, OverflowError):
        return None
    return speed if np.isfinite(speed) and speed >= 0 else None


def read_feature(fid: str, feature: Any, skipped: list[Skipped]) -> MapFeature | None:
    """Map feature ``fid`` as read, or None when nothing of it can be drawn; what was not read is
    appended to ``skipped``."""
    kind = feature.get("type") if isinstance(feature, dict) else None
    if not isinstance(kind, str):
        found = f"a {type(feature).__name__}" if not isinstance(feature, dict) else f"type {str(kind)[:40]!r}"
        skipped.append(Skipped(fid, str(kind)[:40] if kind is not None else "no type",
                               f"not read: not a mapping with a text 'type' (found {found})"))
        return None
    out = MapFeature(fid, str(kind), feature_group(kind))
    if out.group == "other":
        skipped.append(Skipped(fid, out.type, "not read: not a map-feature type ScenarioNet's converters write "
                                              "(see io/scenarionet/scenarionet_types.py)"))
        return None
    unusable: list[tuple[str, str]] = []
    for key, read in (("polyline", _line), ("polygon", _surface), ("position", _position)):
        if feature.get(key) is not None:
            points, why = read(feature[key])
            if why is None:
                setattr(out, key, points)
            else:
                unusable.append((key, why))
    kept = [key for key in ("polyline", "polygon", "position") if getattr(out, key) is not None]
    if out.group != "point":
        kept = [key for key in kept if key != "position"]
    if not kept:
        reason = "; ".join(why for _, why in unusable) or \
            f"no {'position, ' if out.group == 'point' else ''}polyline or polygon"
        skipped.append(Skipped(fid, out.type, f"not read: {reason}"))
        return None
    for key, why in unusable:
        skipped.append(Skipped(fid, out.type, f"{key} not read ({why}); kept from its {' and '.join(kept)}"))
    limit = feature.get("speed_limit_kmh")
    if limit is not None:
        out.speed_limit_kmh = _speed(limit)
        if out.speed_limit_kmh is None:
            skipped.append(Skipped(fid, out.type, f"speed_limit_kmh {str(limit)[:40]!r} is not a speed in km/h: "
                                                  "read without a speed limit"))
    out.extra = {k: v for k, v in feature.items() if k not in _READ_KEYS}
    return out
