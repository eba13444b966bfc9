"""A tf2-like transform buffer without ROS.

Each frame has one parent; an edge (parent -> child) holds either one static
transform or a time-sorted series.  Lookups compose edges along the tree path
and interpolate each dynamic edge (linear translation, quaternion slerp).
A failed lookup raises :class:`TransformError`: evaluating against a silent
identity transform would score detections in the wrong frame without anyone
noticing.

Conventions: quaternions are ROS order (x, y, z, w); ``lookup(target, source)``
returns T such that ``p_target = T @ p_source`` (tf2's lookupTransform).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...core.errors import DataError
from ...geometry.quaternions import rigid_inverse, slerp, transform_matrix

__all__ = ["TransformError", "TFBuffer"]

DEFAULT_TOLERANCE_NS = 10_000_000  # tf2 accepts lookups only inside the data; we allow 10 ms


class TransformError(DataError, LookupError):
    """A transform cannot be resolved (unknown/unconnected frame, stamp out of range)."""


@dataclass
class _Edge:
    parent: str
    child: str
    static: bool
    stamps: list | np.ndarray = field(default_factory=list)
    trans: list | np.ndarray = field(default_factory=list)
    quats: list | np.ndarray = field(default_factory=list)
    dirty: bool = True

    def finalize(self) -> None:
        if not self.dirty:
            return
        stamps = np.asarray(np.concatenate([np.atleast_1d(s) for s in self.stamps])
                            if isinstance(self.stamps, list) else self.stamps, dtype=np.int64)
        trans = np.concatenate([np.reshape(t, (-1, 3)) for t in self.trans]) \
            if isinstance(self.trans, list) else self.trans
        quats = np.concatenate([np.reshape(q, (-1, 4)) for q in self.quats]) \
            if isinstance(self.quats, list) else self.quats
        # Stable sort then keep the last sample of equal stamps (latest write wins).
        order = np.argsort(stamps, kind="stable")
        stamps, trans, quats = stamps[order], trans[order], quats[order]
        keep = np.append(stamps[1:] != stamps[:-1], True)
        self.stamps, self.trans, self.quats = stamps[keep], trans[keep], quats[keep]
        norms = np.linalg.norm(self.quats, axis=1, keepdims=True)
        if np.any(norms < 1e-9):
            raise TransformError(f"zero quaternion on edge {self.parent!r} -> {self.child!r}")
        self.quats = self.quats / norms
        self.dirty = False


class TFBuffer:
    """Static + dynamic transforms, looked up by (target, source, stamp_ns)."""

    def __init__(self, tolerance_ns: int = DEFAULT_TOLERANCE_NS):
        self.tolerance_ns = int(tolerance_ns)
        self._edges: dict[str, _Edge] = {}  # keyed by child frame

    # -- filling -----------------------------------------------------------
    def add_transforms(self, parent: str, child: str, stamps_ns, translations, rotations_xyzw,
                       static: bool = False) -> None:
        """Add one or many samples of the edge parent -> child (child pose in parent)."""
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if parent == child:
            raise TransformError(f"transform from frame {parent!r} to itself")
        edge = self._edges.get(child)
        if edge is None:
            edge = self._edges[child] = _Edge(parent, child, static)
            self._check_no_cycle(child)
        elif edge.parent != parent:
            raise TransformError(f"frame {child!r} already has parent {edge.parent!r}, "
                                 f"cannot also be a child of {parent!r}")
        elif edge.static != static:
            raise TransformError(f"edge {parent!r} -> {child!r} mixes static and dynamic data")
        if static:  # a re-published static transform replaces the previous one
            edge.stamps, edge.trans, edge.quats = [], [], []
        if not isinstance(edge.stamps, list):
            edge.stamps, edge.trans, edge.quats = [edge.stamps], [edge.trans], [edge.quats]
        edge.stamps.append(np.atleast_1d(np.asarray(stamps_ns, dtype=np.int64)))
        edge.trans.append(np.reshape(np.asarray(translations, dtype=np.float64), (-1, 3)))
        edge.quats.append(np.reshape(np.asarray(rotations_xyzw, dtype=np.float64), (-1, 4)))
        if static:
            edge.stamps[-1] = edge.stamps[-1][-1:]
            edge.trans[-1], edge.quats[-1] = edge.trans[-1][-1:], edge.quats[-1][-1:]
        edge.dirty = True

    def add_transform(self, parent, child, stamp_ns, translation, rotation_xyzw, static=False):
        self.add_transforms(parent, child, [stamp_ns], [translation], [rotation_xyzw], static)

    def add_tf_message(self, msg, static: bool = False) -> None:
        """Add every TransformStamped of a tf2_msgs/TFMessage (rosbags object)."""
        for ts in msg.transforms:
            s = ts.header.stamp
            t, r = ts.transform.translation, ts.transform.rotation
            self.add_transform(ts.header.frame_id, ts.child_frame_id,
                               s.sec * 1_000_000_000 + s.nanosec,
                               (t.x, t.y, t.z), (r.x, r.y, r.z, r.w), static)

    def _check_no_cycle(self, child: str) -> None:
        seen, frame = {child}, child
        while frame in self._edges:
            frame = self._edges[frame].parent
            if frame in seen:
                del self._edges[child]
                raise TransformError(f"adding parent of {child!r} creates a cycle through {frame!r}")
            seen.add(frame)

    # -- introspection -----------------------------------------------------
    @property
    def frames(self) -> set[str]:
        return set(self._edges) | {e.parent for e in self._edges.values()}

    def edges(self) -> list[tuple[str, str, bool]]:
        """(parent, child, is_static) for every edge."""
        return [(e.parent, c, e.static) for c, e in self._edges.items()]

    def time_range(self, parent: str, child: str) -> tuple[int, int]:
        edge = self._edges.get(child.lstrip("/"))
        if edge is None or edge.parent != parent.lstrip("/"):
            raise TransformError(f"no edge {parent!r} -> {child!r}")
        edge.finalize()
        return int(edge.stamps[0]), int(edge.stamps[-1])

    def can_transform(self, target: str, source: str, stamp_ns) -> bool:
        try:
            self.lookup(target, source, stamp_ns)
        except TransformError:
            return False
        return True

    # -- lookup ------------------------------------------------------------
    def _chain(self, frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in self._edges:
            chain.append(self._edges[chain[-1]].parent)
        return chain

    def _edge_at(self, child: str, stamps: np.ndarray, target: str, source: str) -> np.ndarray:
        """(N, 4, 4) parent<-child transforms of one edge at ``stamps``."""
        edge = self._edges[child]
        edge.finalize()
        n = stamps.size
        if edge.static:
            return np.broadcast_to(transform_matrix(edge.trans[0], edge.quats[0]), (n, 4, 4))
        s = edge.stamps
        bad = (stamps < s[0] - self.tolerance_ns) | (stamps > s[-1] + self.tolerance_ns)
        if np.any(bad):
            first = int(stamps[np.argmax(bad)])
            raise TransformError(
                f"cannot transform {source!r} -> {target!r} at stamp {first} ns: edge "
                f"{edge.parent!r} -> {child!r} has data only in [{s[0]}, {s[-1]}] ns "
                f"(tolerance {self.tolerance_ns} ns, {int(bad.sum())} of {n} stamps outside)")
        q = np.clip(stamps, s[0], s[-1])  # inside tolerance: hold the end sample
        hi = np.clip(np.searchsorted(s, q, side="left"), 1, max(len(s) - 1, 1))
        lo = hi - 1
        if len(s) == 1:
            lo = hi = np.zeros(n, dtype=np.intp)
            frac = np.zeros(n)
        else:
            span = (s[hi] - s[lo]).astype(np.float64)
            frac = np.clip((q - s[lo]).astype(np.float64) / span, 0.0, 1.0)
        trans = edge.trans[lo] + frac[:, None] * (edge.trans[hi] - edge.trans[lo])
        quats = slerp(edge.quats[lo], edge.quats[hi], frac)
        return transform_matrix(trans, quats)

    def lookup(self, target_frame: str, source_frame: str, stamp_ns) -> np.ndarray:
        """4x4 (or (N,4,4) for an array of stamps) mapping source coords to target coords."""
        target, source = target_frame.lstrip("/"), source_frame.lstrip("/")
        scalar = np.ndim(stamp_ns) == 0
        stamps = np.atleast_1d(np.asarray(stamp_ns, dtype=np.int64))
        for frame in (target, source):
            if frame not in self.frames:
                raise TransformError(f"cannot transform {source!r} -> {target!r} at stamp "
                                     f"{stamp_ns}: frame {frame!r} unknown; known frames: "
                                     f"{sorted(self.frames)}")
        up_src, up_tgt = self._chain(source), self._chain(target)
        common = next((f for f in up_src if f in set(up_tgt)), None)
        if common is None:
            raise TransformError(f"cannot transform {source!r} -> {target!r} at stamp "
                                 f"{stamp_ns}: frames are not connected (roots "
                                 f"{up_src[-1]!r} and {up_tgt[-1]!r})")
        eye = np.broadcast_to(np.eye(4), (stamps.size, 4, 4))

        def to_common(chain):  # common <- frame, composed down the chain
            out = eye
            for child in chain[: chain.index(common)]:
                out = self._edge_at(child, stamps, target, source) @ out
            return out

        result = rigid_inverse(to_common(up_tgt)) @ to_common(up_src)
        return result[0] if scalar else result

    def transform_points(self, points: np.ndarray, target: str, source: str, stamp_ns) -> np.ndarray:
        """(N, 3) points from ``source`` to ``target`` at one stamp."""
        m = self.lookup(target, source, stamp_ns)
        pts = np.asarray(points, dtype=np.float64)
        return pts @ m[:3, :3].T + m[:3, 3]
