"""Degrade a raw point cloud as a sensor or the weather may, before the filter under test sees it.

    cloud = perturb_cloud(raw, CloudPerturbation(dropout=0.2, range_noise=0.03, ghost_points=12),
                          example_rng(seed, frame), origin=lidar_xyz, ghost=GhostRegion(area, boxes))

- Dropout: each point is dropped with that probability (absorbing or wet
  surfaces, blocked beams, lost packets).
- Range noise: Gaussian noise of that standard deviation (m) added to each
  point's range along its ray from ``origin``, the sensor's position in the
  cloud's frame; the ray's direction is kept, as a lidar's error is in range.
  The caller decides the origin (robustness.py: the lidar's calibrated
  position when the cloud is in base_link, else the cloud frame's origin,
  which is then taken to be the sensor's own frame).
- Ghost cluster: that many points in a compact blob (0.25 m across-track
  spread, 0.15 m vertically) centred inside the non-detection area, outside
  every ground-truth box, at a height an obstacle's body has (centre 0.5-1.2 m above
  base_link, within the area's z range).  It models spurious returns where
  nothing is: spray thrown up by a vehicle ahead, a dust or exhaust plume, a
  multipath reflection.  A filter that keeps everything above the ground
  reports them as an obstacle; one that rejects small clusters tolerates a
  few, and the search finds how many it takes.  The ghosts' other fields
  (intensity, ring ...) are copied from raw points drawn at random, so that
  a filter reading them sees plausible values.

The same random numbers serve every magnitude: the rng is split into one
stream per effect, each drawing the same values whatever the perturbation
(a uniform and a standard normal per raw point, the ghosts' centre, offsets
and donors).  For one rng seed a larger dropout therefore drops a superset of
the points, the noise scales with its standard deviation and more ghost
points extend the same cluster, so a verdict changes with the magnitude
alone; this is what lets the search's bisection find an edge instead of a
fresh random draw at every value.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...metrics.pointcloud import Area, BoxSet, evaluate_cloud, xyz_columns
from ...strategies import CloudPerturbation

__all__ = ["GhostRegion", "example_rng", "perturb_cloud"]

OBSTACLE_BAND = (0.5, 1.2)          # m above base_link: where a ghost cluster's centre may be
GHOST_SPREAD = (0.25, 0.25, 0.15)   # m, standard deviation of a ghost point around the centre
CENTRE_TRIES = 256                   # candidate centres drawn in the area's bounding box
_SALT = 0x0B57AC1E                   # keeps these streams apart from other users of the same seed


def example_rng(seed: int, case: int) -> np.random.Generator:
    """The rng of one frame of a search: from the item's seed and the frame only (SeedSequence,
    never Python's salted ``hash``), so every magnitude tried on a frame reuses its numbers."""
    return np.random.default_rng([_SALT, int(seed) & (2**64 - 1), int(case)])


@dataclass(frozen=True)
class GhostRegion:
    """Where a ghost cluster may appear: ``area`` (base_link) outside every box of ``boxes``.
    ``cloud_T_base`` (4x4) moves base_link points into the cloud's frame; None: the cloud is in
    base_link."""

    area: Area
    boxes: BoxSet
    cloud_T_base: np.ndarray | None = None

    def contains(self, xyz: np.ndarray) -> np.ndarray:
        """Which base_link points the judgement would count in the non-detection area."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        found = evaluate_cloud(xyz, self.boxes, self.area).area_points
        inside = {tuple(p) for p in np.asarray(found, dtype=np.float64)}
        return np.array([tuple(p) in inside for p in xyz], dtype=bool)


def perturb_cloud(points: np.ndarray, perturbation: CloudPerturbation, rng: np.random.Generator, *,
                  origin=(0.0, 0.0, 0.0), ghost: GhostRegion | None = None) -> np.ndarray:
    """``points`` (structured with x, y, z, ... or (N, >=3)) under ``perturbation``, same dtype and
    fields.  No change returns ``points`` itself.  ``ghost`` is needed for ghost points."""
    p = perturbation
    if p.dropout == 0 and p.range_noise == 0 and p.ghost_points == 0:
        return points
    if p.ghost_points and ghost is None:
        raise ValueError("ghost points need a GhostRegion (the non-detection area) to be placed in")
    drop_rng, noise_rng, centre_rng, offset_rng, donor_rng = (
        np.random.default_rng(s) for s in rng.integers(0, 2**63, size=5))
    # One generator per effect, seeded up front: an effect left at no change draws nothing
    # and the others draw the same numbers.
    n = len(points)
    out = points
    if p.range_noise:
        out = _range_noise(out, noise_rng.standard_normal(n) * p.range_noise, np.asarray(origin, dtype=np.float64))
    if p.dropout:
        out = out[drop_rng.random(n) >= p.dropout]
    if p.ghost_points:
        out = _add_ghosts(out, points, p.ghost_points, ghost, centre_rng, offset_rng, donor_rng)
    return out


def _range_noise(points: np.ndarray, delta: np.ndarray, origin: np.ndarray) -> np.ndarray:
    x, y, z = xyz_columns(points)
    ray = np.stack([x, y, z], axis=1).astype(np.float64) - origin
    r = np.linalg.norm(ray, axis=1)
    # A point at the origin has no ray; it keeps its place.
    scale = np.divide(r + delta, r, out=np.ones_like(r), where=r > 0)
    moved = origin + ray * np.maximum(scale, 0.0)[:, None]   # noise never flips a point behind the sensor
    out = points.copy()
    _set_xyz(out, moved)
    return out


def _set_xyz(cloud: np.ndarray, xyz: np.ndarray) -> None:
    if cloud.dtype.names:
        for k, name in enumerate("xyz"):
            cloud[name] = xyz[:, k]
    else:
        cloud[:, :3] = xyz


def _stored(xyz: np.ndarray, like: np.ndarray) -> np.ndarray:
    """``xyz`` as the cloud will hold it (e.g. rounded to float32), back in float64."""
    dtype = like.dtype["x"] if like.dtype.names else like.dtype
    return xyz.astype(dtype).astype(np.float64)


def _add_ghosts(cloud: np.ndarray, raw: np.ndarray, count: int, region: GhostRegion, centre_rng, offset_rng,
                donor_rng) -> np.ndarray:
    ghosts = _ghost_cluster(region, count, centre_rng, offset_rng, raw)
    if region.cloud_T_base is not None:
        m = np.asarray(region.cloud_T_base, dtype=np.float64)
        ghosts = ghosts @ m[:3, :3].T + m[:3, 3]
    extra = np.zeros(count, dtype=cloud.dtype) if cloud.dtype.names else np.zeros((count,) + cloud.shape[1:],
                                                                                    dtype=cloud.dtype)
    if len(raw):
        extra[:] = raw[donor_rng.integers(0, len(raw), size=count)]
    _set_xyz(extra, ghosts)
    return np.concatenate([cloud, extra])


def _ghost_cluster(region: GhostRegion, count: int, centre_rng, offset_rng, like: np.ndarray) -> np.ndarray:
    """``count`` base_link points around a centre in the area, each pulled towards the centre
    until the judgement counts it in the area (a non-convex area may need a few halvings)."""
    area = region.area
    x0, y0, z0, x1, y1, z1 = area.aabb()
    lo, hi = max(z0, OBSTACLE_BAND[0]), min(z1, OBSTACLE_BAND[1])
    if lo > hi:  # an area below or above the band: its own height range
        lo, hi = z0, z1
    candidates = _stored(centre_rng.uniform([x0, y0, lo], [x1, y1, hi], size=(CENTRE_TRIES, 3)), like)
    inside = np.flatnonzero(region.contains(candidates))
    if not len(inside):
        raise ValueError(f"no place for a ghost cluster in the non-detection area (bounds x {x0:g}..{x1:g}, "
                         f"y {y0:g}..{y1:g}, z {lo:g}..{hi:g}): it is empty or covered by boxes")
    centre = candidates[inside[0]]
    offsets = offset_rng.normal(0.0, GHOST_SPREAD, size=(count, 3))
    ghosts = _stored(centre + offsets, like)
    outside = ~region.contains(ghosts)
    for _ in range(12):
        if not outside.any():
            break
        offsets[outside] *= 0.5
        ghosts[outside] = _stored(centre + offsets[outside], like)
        outside[outside] = ~region.contains(ghosts[outside])
    ghosts[outside] = centre
    return ghosts
