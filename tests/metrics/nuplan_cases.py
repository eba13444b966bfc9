"""Score cases (benchmarks/nuplan_oracle/CASE_FORMAT.md) of docs/nuplan_score.md §8's set-up: 151 frames
at 10 Hz, one straight lane along +x (4 m wide, x 0..500) in one roadblock and the drivable area, speed
limit 15 m/s, the ego's centre starting at x = 10 and the expert driving 10 m/s along the lane."""
from __future__ import annotations

import numpy as np

FRAMES, DT = 151, 0.1
LANE = [[0.0, -2.0], [500.0, -2.0], [500.0, 2.0], [0.0, 2.0]]


def lane_map(speed_limit: float | None = 15.0) -> dict:
    return {"lanes": [{"id": "l1", "polygon": LANE, "baseline": [[0.0, 0.0], [500.0, 0.0]],
                       "speed_limit": speed_limit, "roadblock": "rb1", "connector": False,
                       "incoming": [], "outgoing": []}],
            "roadblocks": [{"id": "rb1", "polygon": LANE, "connector": False}],
            "drivable_area": [LANE], "intersections": []}


def case(name: str, x: np.ndarray, *, y: np.ndarray | None = None, heading: np.ndarray | None = None,
         speed: np.ndarray | None = None, accel_x: np.ndarray | None = None,
         angular_velocity: np.ndarray | None = None, expert_speed: float = 10.0, agents: list | None = None,
         speed_limit: float | None = 15.0, with_map: bool = True) -> dict:
    t = np.arange(FRAMES) * DT
    zeros = np.zeros(FRAMES)
    y = zeros if y is None else y
    heading = zeros if heading is None else heading
    speed = np.gradient(x, DT) if speed is None else speed
    accel_x = zeros if accel_x is None else accel_x
    w = zeros if angular_velocity is None else angular_velocity
    expert_x = 10.0 + expert_speed * t
    return {"name": name, "timestamps": t.tolist(),
            "ego": {"length": 5.176, "width": 2.297, "rear_axle_to_center": 1.461,
                    "center": np.stack([x, y, heading], 1).tolist(),
                    "velocity": np.stack([speed, zeros], 1).tolist(),
                    "acceleration": np.stack([accel_x, zeros], 1).tolist(),
                    "angular_velocity": w.tolist(), "angular_acceleration": zeros.tolist()},
            "expert": {"center": np.stack([expert_x, zeros, zeros], 1).tolist()},
            "agents": agents or [],
            "map": lane_map(speed_limit) if with_map else None}


def agent(token: str, kind: str, xy: tuple[float, float], *, heading: float = 0.0, speed: float = 0.0,
          length: float = 0.5, width: float = 0.5) -> dict:
    """An agent present on every frame, moving at ``speed`` along ``heading`` from ``xy`` at t = 0."""
    t = np.arange(FRAMES) * DT
    x = xy[0] + speed * np.cos(heading) * t
    y = xy[1] + speed * np.sin(heading) * t
    return {"token": token, "type": kind, "length": length, "width": width, "frames": list(range(FRAMES)),
            "center": np.stack([x, y, np.full(FRAMES, heading)], 1).tolist(),
            "velocity": np.tile([speed * np.cos(heading), speed * np.sin(heading)], (FRAMES, 1)).tolist()}


def cruising(speed: float = 10.0) -> np.ndarray:
    return 10.0 + speed * np.arange(FRAMES) * DT
