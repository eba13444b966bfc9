"""States, trajectories and occupancy sets of CommonRoad obstacles and planning problems, as the format
allows them (``state``/``initialState``/``occupancy`` in the XSD, commonroad-io's ``StateFactory``).

A state's position is a ``<point>`` or, in a set-valued state, shapes (rectangles, circles, polygons)
or lanelets; any other value is ``<exact>`` or an ``<intervalStart>``/``<intervalEnd>`` interval.  A
set-valued state is read at its middle, as commonroad-io's ``Shape.center`` and an interval's middle:
a rectangle's or circle's centre, a polygon's centroid, for several shapes their area-weighted centroid,
an interval's midpoint.  The sets themselves stay on the state (``State.set``) for the checks that must
be conservative.  A point-mass state (commonroad-io's ``PMState``) gives ``velocity`` and ``velocityY``
and no orientation: its speed is their norm and its heading ``atan2(velocityY, velocity)``; a state
with an orientation keeps ``velocity`` as its speed (commonroad-io's custom and single-track states).  Fields the
replay does not use (steering angle, wheel speeds, roll, ...) are counted in the notes and not kept.

An occupancy-set obstacle (``<occupancySet>`` instead of ``<trajectory>``) occupies, at each time step
its ``<occupancy>`` elements cover (an exact step or a step interval), the union of their shapes.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections import Counter

import numpy as np

from .commonroad_types import Circle, Interval, Lanelet, Occupancy, Polygon, Rectangle, Shape, State, StateSet
from .commonroad_xml import XmlDoc

__all__ = ["StateReader", "shape_centre"]

#: time steps count from a recording's start; far beyond this, step arithmetic leaves int64
MAX_TIME_STEP = 10 ** 9
_NAN = float("nan")
#: State fields and their XML tags
FIELDS = (("orientation", "orientation"), ("velocity", "velocity"), ("acceleration", "acceleration"),
          ("yaw_rate", "yawRate"), ("slip_angle", "slipAngle"))
_KNOWN = {"position", "time", "velocityY"} | {tag for _, tag in FIELDS}
_SHAPES = ("rectangle", "circle", "polygon")


def _area_centroid(shape: Shape) -> tuple[float, np.ndarray]:
    if isinstance(shape, Rectangle):
        return shape.length * shape.width, np.asarray(shape.center, float)
    if isinstance(shape, Circle):
        return math.pi * shape.radius ** 2, np.asarray(shape.center, float)
    v = shape.vertices
    x, y = v[:, 0], v[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum()
    if abs(area) < 1e-12:  # a degenerate polygon: its vertices' mean
        return 0.0, v.mean(axis=0)
    return abs(area), np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6.0 * area)


def shape_centre(shapes: tuple[Shape, ...]) -> np.ndarray:
    """The centre of a set of shapes: one shape's centre (a polygon's centroid, as shapely's), several
    shapes' area-weighted centroid (overlaps counted twice)."""
    parts = [_area_centroid(s) for s in shapes]
    total = sum(a for a, _ in parts)
    if total <= 0:
        return np.mean([c for _, c in parts], axis=0)
    return sum(a * c for a, c in parts) / total


class StateReader:
    """Reads states of one file and counts what it met, for the scenario's notes."""

    def __init__(self, doc: XmlDoc, lanelets: dict[int, Lanelet]):
        self.doc = doc
        self.lanelets = lanelets
        self.set_valued: Counter = Counter()  # what, e.g. "position as shapes" -> states
        self.unused: Counter = Counter()      # XML tag -> states that give it
        self.point_mass = 0
        self.first_line: dict[str, int] = {}

    def _count(self, counter: Counter, key: str, node: ET.Element) -> None:
        counter[key] += 1
        self.first_line.setdefault(key, self.doc.lines.get(node, 0))

    def _time(self, node: ET.Element, owner: ET.Element) -> int:
        doc = self.doc
        time_node = node.find("time")
        if time_node is None:
            raise doc.error(owner, f"<{node.tag}> without <time>")
        if time_node.find("exact") is None and time_node.find("intervalStart") is not None:
            start, end = (doc.child_number(time_node, t) for t in ("intervalStart", "intervalEnd"))
            if start != end:
                raise doc.error(owner, f"<{node.tag}>: its <time> is the interval [{start:g}, {end:g}]: a state "
                                       "of a trajectory needs one time step (a set over time is an "
                                       "<occupancySet>)")
        time = doc.value(time_node, owner, exact=False).start
        return self._step(time, node, owner)

    def _step(self, time: float, node: ET.Element, owner: ET.Element) -> int:
        doc = self.doc
        if time != int(time):
            raise doc.error(owner, f"<{node.tag}>: time step {time} is not an integer")
        if abs(time) > MAX_TIME_STEP:
            raise doc.error(owner, f"<{node.tag}>: time step {time:g} is beyond {MAX_TIME_STEP:g} (over three years "
                                   "of 0.1 s steps): give the step's number, counted from the recording's start")
        return int(time)

    def _position(self, node: ET.Element, owner: ET.Element) -> tuple[float, float, tuple[Shape, ...]]:
        doc = self.doc
        position = node.find("position")
        time = node.findtext("time/exact", node.findtext("time/intervalStart", "?")).strip()
        if position is None:
            raise doc.error(owner, f"<{node.tag}> needs a <position> (time step {time})")
        point = position.find("point")
        if point is not None:
            return doc.child_number(point, "x"), doc.child_number(point, "y"), ()
        shapes = tuple(doc.shapes(position))
        refs = [int(doc.number(r, r.get("ref"), "ref")) for r in position.findall("lanelet")]
        missing = [r for r in refs if r not in self.lanelets]
        if missing:
            raise doc.error(owner, f"<{node.tag}> at time step {time}: its position names lanelet(s) {missing} "
                                   "that the file does not define")
        shapes += tuple(Polygon(self.lanelets[r].polygon) for r in refs)
        if not shapes:
            raise doc.error(owner, f"<{node.tag}> at time step {time}: <position> holds no <point>, shape "
                                   "(rectangle, circle, polygon) or lanelet")
        self._count(self.set_valued, "position as lanelets" if refs else "position as shapes", node)
        x, y = shape_centre(shapes)
        return float(x), float(y), shapes

    def state(self, node: ET.Element | None, owner: ET.Element) -> State:
        """The state of ``node`` (an ``<initialState>`` or a trajectory's ``<state>``) of ``owner``."""
        doc = self.doc
        if node is None:
            raise doc.error(owner, "<initialState> missing")
        x, y, position_set = self._position(node, owner)
        time = self._time(node, owner)
        values: dict[str, float] = {}
        intervals: list[tuple[str, Interval]] = []
        for name, tag in (*FIELDS, ("velocity_y", "velocityY")):
            child = node.find(tag)
            if child is None:
                continue
            value = doc.value(child, owner, exact=False)
            if not math.isfinite(value.middle):
                raise doc.error(owner, f"<{tag}> at time step {time}: the interval [{value.start:g}, {value.end:g}] "
                                       "is open: a state's interval needs two finite ends")
            if value.start != value.end:
                intervals.append((name, value))
                self._count(self.set_valued, f"{tag} as an interval", node)
            values[name] = value.middle
        for child in node:
            if child.tag not in _KNOWN:
                self._count(self.unused, child.tag, node)
        vy = values.pop("velocity_y", None)
        if vy is not None and "velocity" in values and "orientation" not in values:
            # A point-mass state: velocity and velocityY are the world x and y components.  With an
            # orientation (custom, single-track states) velocity stays the speed along the heading.
            vx = values["velocity"]
            values["velocity"], values["orientation"] = math.hypot(vx, vy), math.atan2(vy, vx)
            self.point_mass += 1
            self.first_line.setdefault("point mass", doc.lines.get(node, 0))
        sets = StateSet(position_set, tuple(intervals)) if position_set or intervals else None
        return State(time, x, y, **{k: values.get(k, _NAN) for k, _ in FIELDS}, set=sets)

    def occupancies(self, node: ET.Element, owner: ET.Element) -> tuple[Occupancy, ...]:
        """The ``<occupancy>`` elements of an ``<occupancySet>``, in time order."""
        doc = self.doc
        found = []
        for occ in node.findall("occupancy"):
            shape_node = occ.find("shape")
            shapes = tuple(doc.shapes(shape_node)) if shape_node is not None else ()
            if not shapes:
                raise doc.error(owner, f"<occupancy> at line {doc.lines.get(occ, '?')} holds no shape "
                                       "(rectangle, circle, polygon)")
            time = doc.value(occ.find("time"), owner, exact=False)
            if time is None:
                raise doc.error(owner, f"<occupancy> at line {doc.lines.get(occ, '?')} without <time>")
            found.append(Occupancy(self._step(time.start, occ, owner), self._step(time.end, occ, owner), shapes))
        if not found:
            raise doc.error(owner, "<occupancySet> without <occupancy>")
        return tuple(sorted(found, key=lambda o: (o.start, o.end)))
