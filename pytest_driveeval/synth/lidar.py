"""A spinning-lidar model: ring table, vectorised ray casting on ground + upright boxes.

Everything is cast in one frame (the vehicle's base_link, ground at z = 0):
rays leave one origin, and each return is the nearest of the ground plane and
every box, so objects occlude each other and the point density falls with
range exactly as the beam geometry dictates.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["RING_ELEVATIONS_DEG", "ray_directions", "cast_boxes", "cast_ground", "Scan", "scan"]

# 32 rings, denser near the horizon like a VLP-32C / Pandar: that is where the
# distant objects are, and what makes far objects get a handful of points only.
RING_ELEVATIONS_DEG = np.concatenate([
    np.linspace(-25.0, -8.0, 8, endpoint=False),
    np.linspace(-8.0, 2.0, 18, endpoint=False),
    np.linspace(2.0, 15.0, 6),
])


def ray_directions(num_rays: int, azimuth_offset: float = 0.0,
                   elevations_deg: np.ndarray = RING_ELEVATIONS_DEG
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(R, 3) unit directions and (R,) ring index for one full revolution.

    ``num_rays`` is rounded down to whole columns (one column fires every ring).
    """
    n_rings = len(elevations_deg)
    n_cols = max(num_rays // n_rings, 1)
    az = azimuth_offset + np.arange(n_cols) * (2 * np.pi / n_cols)
    el = np.deg2rad(np.asarray(elevations_deg, dtype=np.float64))
    # column-major like a real scan: all rings of one azimuth, then the next
    az_g, el_g = np.meshgrid(az, el, indexing="ij")
    ce = np.cos(el_g)
    dirs = np.stack([ce * np.cos(az_g), ce * np.sin(az_g), np.sin(el_g)], -1).reshape(-1, 3)
    ring = np.broadcast_to(np.arange(n_rings), (n_cols, n_rings)).reshape(-1)
    return dirs, ring.astype(np.int64)


def cast_ground(origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(R,) distance to the z = 0 plane along each ray; inf when the ray goes up."""
    dz = dirs[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dz < -1e-9, -origin[2] / dz, np.inf)
    return t


def cast_boxes(origin: np.ndarray, dirs: np.ndarray, centers: np.ndarray,
               sizes: np.ndarray, yaws: np.ndarray) -> np.ndarray:
    """(R, B) entry distance of each ray into each upright box; inf for a miss.

    Boxes are (center xyz, size = width, length, height, yaw); length lies
    along the box heading (nuScenes convention).  Slab test in each box's own
    frame, all rays x all boxes at once.  A ray starting inside a box misses
    it (the sensor never sits inside an obstacle).
    """
    n_rays, n_boxes = len(dirs), len(centers)
    if n_boxes == 0:
        return np.full((n_rays, 0), np.inf)
    c, s = np.cos(yaws), np.sin(yaws)
    rel = origin[None, :] - centers                       # (B, 3)
    ox = rel[:, 0] * c + rel[:, 1] * s                    # origin in box frames (B,)
    oy = -rel[:, 0] * s + rel[:, 1] * c
    dx = dirs[:, :1] * c + dirs[:, 1:2] * s               # (R, B)
    dy = -dirs[:, :1] * s + dirs[:, 1:2] * c
    half = sizes / 2.0
    t_near = np.zeros((n_rays, n_boxes))
    t_far = np.full((n_rays, n_boxes), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for o, d, h in ((ox, dx, half[:, 1]), (oy, dy, half[:, 0]),
                        (rel[:, 2], dirs[:, 2:3], half[:, 2])):
            inv = 1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d)
            t0 = (-h - o) * inv
            t1 = (h - o) * inv
            t_near = np.maximum(t_near, np.minimum(t0, t1))
            t_far = np.minimum(t_far, np.maximum(t0, t1))
    inside = (np.abs(ox) < half[:, 1]) & (np.abs(oy) < half[:, 0]) & (np.abs(rel[:, 2]) < half[:, 2])
    hit = (t_near <= t_far) & (t_near > 0) & ~inside[None, :]
    return np.where(hit, t_near, np.inf)


class Scan(NamedTuple):
    """One sweep's returns (rays without a return are dropped)."""

    points: np.ndarray      # (N, 3) in the casting frame
    intensity: np.ndarray   # (N,) 0..255
    ring: np.ndarray        # (N,) ring index
    label: np.ndarray       # (N,) -1 ground, else index of the box hit
    hits: np.ndarray        # (B,) returns per box in this scene
    unoccluded: np.ndarray  # (B,) returns each box would get were it alone on the ground


def scan(origin: np.ndarray, num_rays: int, centers: np.ndarray, sizes: np.ndarray,
         yaws: np.ndarray, reflectivity: np.ndarray, rng: np.random.Generator, *,
         max_range: float = 100.0, range_noise: float = 0.015,
         ground_reflectivity: tuple[float, float] = (3.0, 25.0)) -> Scan:
    """One revolution from ``origin``: first return of each ray, Gaussian range noise.

    ``hits / unoccluded`` is the visible fraction of each box, which is how
    annotators' visibility levels are derived.
    """
    dirs, ring = ray_directions(num_rays, rng.uniform(0, 2 * np.pi / max(num_rays, 1)))
    t_g = cast_ground(origin, dirs)
    t_b = cast_boxes(origin, dirs, centers, sizes, yaws)
    t_all = np.column_stack([t_g, t_b])
    first = np.argmin(t_all, axis=1)
    t_hit = t_all[np.arange(len(dirs)), first]
    ok = t_hit < max_range
    first, t_hit, dirs, ring = first[ok], t_hit[ok], dirs[ok], ring[ok]
    label = first - 1
    t_noisy = t_hit + rng.normal(0, range_noise, t_hit.shape)
    on_box = label >= 0
    inten = rng.uniform(*ground_reflectivity, label.shape)
    inten[on_box] = reflectivity[label[on_box]] * rng.uniform(0.8, 1.2, on_box.sum())
    n_boxes = len(centers)
    return Scan(points=origin + dirs * t_noisy[:, None], intensity=np.clip(inten, 0, 255),
                ring=ring, label=label,
                hits=np.bincount(label[on_box], minlength=n_boxes),
                unoccluded=(t_b < np.minimum(t_g, max_range)[:, None]).sum(0))
