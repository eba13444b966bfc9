"""The synthetic t4_dataset's road: a constant-curvature centre line with Frenet coordinates.

Its own module because both the generator (t4gen) and the map writer (t4tables) use it.
"""
from __future__ import annotations

import numpy as np

__all__ = ["Road"]


class Road:
    """Constant-curvature centre line: Frenet (s, d) <-> map (x, y)."""

    def __init__(self, x0: float, y0: float, yaw0: float, curvature: float):
        if abs(curvature) < 1e-6:
            raise ValueError("curvature must be non-zero (use 1e-4 for almost straight)")
        self.p0, self.yaw0, self.k = np.array([x0, y0]), yaw0, curvature
        self.center = self.p0 + np.array([-np.sin(yaw0), np.cos(yaw0)]) / curvature
        self.phi0 = np.arctan2(*(self.p0 - self.center)[::-1])

    def heading(self, s):
        return self.yaw0 + self.k * np.asarray(s, dtype=np.float64)

    def pose(self, s, d):
        """Map x, y and heading of Frenet points (vectorised)."""
        yaw = self.heading(s)
        d = np.asarray(d, dtype=np.float64)
        x = self.p0[0] + (np.sin(yaw) - np.sin(self.yaw0)) / self.k - d * np.sin(yaw)
        y = self.p0[1] - (np.cos(yaw) - np.cos(self.yaw0)) / self.k + d * np.cos(yaw)
        return x, y, yaw

    def frenet(self, x, y):
        vx, vy = np.asarray(x) - self.center[0], np.asarray(y) - self.center[1]
        dphi = (np.arctan2(vy, vx) - self.phi0 + np.pi) % (2 * np.pi) - np.pi
        return dphi / self.k, np.sign(self.k) * (1 / abs(self.k) - np.hypot(vx, vy))
