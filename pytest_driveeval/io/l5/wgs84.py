"""WGS84 geodetic, ECEF and local east-north-up coordinates (vectorised, degrees in, metres out).

l5kit's map stores each element in an east-north-up frame at a latitude and
longitude (altitude 0) and goes ENU -> ECEF -> the dataset's world frame.
"""
from __future__ import annotations

import numpy as np

A = 6378137.0  # semi-major axis, m
F = 1 / 298.257223563  # flattening
E2 = F * (2 - F)  # first eccentricity squared


def enu_axes(lat_deg, lng_deg) -> np.ndarray:
    """(..., 3, 3): rows are the east, north and up unit vectors in ECEF."""
    lat, lng = np.radians(lat_deg), np.radians(lng_deg)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lng), np.cos(lng)
    zero = np.zeros_like(sl)
    return np.stack([np.stack([-so, co, zero], -1),
                     np.stack([-sl * co, -sl * so, cl], -1),
                     np.stack([cl * co, cl * so, sl], -1)], -2)


def geodetic_to_ecef(lat_deg, lng_deg, alt=0.0) -> np.ndarray:
    lat, lng = np.radians(lat_deg), np.radians(lng_deg)
    n = A / np.sqrt(1 - E2 * np.sin(lat) ** 2)  # prime vertical radius of curvature
    return np.stack([(n + alt) * np.cos(lat) * np.cos(lng), (n + alt) * np.cos(lat) * np.sin(lng),
                     (n * (1 - E2) + alt) * np.sin(lat)], -1)


def ecef_to_geodetic(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lat, lng) in degrees; a few fixed-point steps are sub-millimetre near the surface."""
    x, y, z = np.moveaxis(np.asarray(xyz, np.float64), -1, 0)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1 - E2))
    for _ in range(5):
        n = A / np.sqrt(1 - E2 * np.sin(lat) ** 2)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1 - E2 * n / (n + h)))
    return np.degrees(lat), np.degrees(np.arctan2(y, x))


def ecef_to_enu(xyz: np.ndarray, lat_deg, lng_deg) -> np.ndarray:
    axes = enu_axes(lat_deg, lng_deg)
    return np.einsum("...ij,...j->...i", axes, xyz - geodetic_to_ecef(lat_deg, lng_deg))
