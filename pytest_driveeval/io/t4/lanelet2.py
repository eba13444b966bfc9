"""Road lanelets of a Lanelet2 ``.osm`` map, without the lanelet2 library.

Autoware maps give every node metric ``local_x`` / ``local_y`` tags (the map
frame of the bag's TF), so no projection is needed.  A lanelet is a relation
``type=lanelet`` with ``left`` and ``right`` way members; its outline is the
left bound followed by the reversed right bound, as lanelet2's ``polygon2d()``.
``road_lanelets`` keeps ``subtype=road`` (lanelet2_extension's ``roadLanelets``),
the set driving_log_replayer intersects the non-detection area with.
"""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.errors import DataError

__all__ = ["Lanelet2Error", "Lanelet", "LaneletMap", "load_lanelet_map", "road_lanelets"]


class Lanelet2Error(DataError, ValueError):
    """A map that cannot be read, or a lanelet that points at missing ways/nodes."""


@dataclass(frozen=True)
class Lanelet:
    id: int
    subtype: str
    polygon: np.ndarray  # (K, 2) map-frame outline


@dataclass
class LaneletMap:
    path: Path
    lanelets: list[Lanelet]

    def road(self) -> list[Lanelet]:
        return [ll for ll in self.lanelets if ll.subtype == "road"]

    def near(self, lanelets: list[Lanelet], lo: np.ndarray, hi: np.ndarray) -> list[Lanelet]:
        """Those whose bounding box meets the axis-aligned box [lo, hi] (map frame)."""
        if not lanelets:
            return []
        bounds = self._bounds(lanelets)
        keep = np.all(bounds[:, :2] <= hi, axis=1) & np.all(bounds[:, 2:] >= lo, axis=1)
        return [ll for ll, k in zip(lanelets, keep) if k]

    def _bounds(self, lanelets: list[Lanelet]) -> np.ndarray:
        key = tuple(ll.id for ll in lanelets)
        cache = getattr(self, "_bounds_cache", {})
        if key not in cache:
            cache[key] = np.array([[*ll.polygon.min(axis=0), *ll.polygon.max(axis=0)] for ll in lanelets])
            self._bounds_cache = cache
        return cache[key]


def load_lanelet_map(path: str | os.PathLike) -> LaneletMap:
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except FileNotFoundError:
        raise Lanelet2Error(f"{path}: no such map file") from None
    except ET.ParseError as exc:
        raise Lanelet2Error(f"{path}: not a valid OSM XML file ({exc})") from None
    nodes: dict[int, tuple[float, float]] = {}
    for node in root.iter("node"):
        tags = {t.get("k"): t.get("v") for t in node.iter("tag")}
        try:
            nodes[int(node.get("id"))] = (float(tags["local_x"]), float(tags["local_y"]))
        except KeyError:
            raise Lanelet2Error(f"{path}: node {node.get('id')} has no local_x/local_y tags; only Autoware "
                                "maps with metric local coordinates are supported") from None
        except (TypeError, ValueError) as exc:
            raise Lanelet2Error(f"{path}: node {node.get('id')}: bad coordinates ({exc})") from None
    ways = {int(w.get("id")): [int(nd.get("ref")) for nd in w.iter("nd")] for w in root.iter("way")}
    lanelets = []
    for rel in root.iter("relation"):
        tags = {t.get("k"): t.get("v") for t in rel.iter("tag")}
        if tags.get("type") != "lanelet":
            continue
        rid = int(rel.get("id"))
        bounds = {m.get("role"): int(m.get("ref")) for m in rel.iter("member") if m.get("type") == "way"}
        try:
            left = [nodes[n] for n in ways[bounds["left"]]]
            right = [nodes[n] for n in ways[bounds["right"]]]
        except KeyError as exc:
            raise Lanelet2Error(f"{path}: lanelet {rid} refers to a missing left/right way or node {exc}") from None
        outline = np.array(left + right[::-1], dtype=np.float64)
        lanelets.append(Lanelet(rid, tags.get("subtype", ""), outline))
    return LaneletMap(path, lanelets)


def road_lanelets(path: str | os.PathLike) -> list[Lanelet]:
    return load_lanelet_map(path).road()
