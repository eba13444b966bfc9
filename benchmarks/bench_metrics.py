"""Time the closed-loop metrics on synthetic scenes, against the l5kit way.

Run: ``python benchmarks/bench_metrics.py [--scenes 16] [--repeat 50] [--smoke]``.

"Ours" is every per-frame metric for a scene (collision kind / partner /
blame, displacement, yaw error, distance to the reference polyline, driven
distance, speed difference).  The reference follows l5kit's closed-loop
evaluator: loop over frames, range pre-filter, one shapely polygon test per
agent in range, edge-intersection lengths for the type.  Both run in this
process on the same arrays and the ratio is printed.  shapely comes with the
``test`` extra only; without it the reference is skipped and said so.

:func:`l5kit_style_collision` is also the oracle of
``tests/test_collision_metrics.py``.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pytest_driveeval.metrics.collisions import FRONT, NONE, REAR, SIDE, detect_collisions  # noqa: E402
from pytest_driveeval.metrics.drift import (  # noqa: E402
    displacement_error,
    distance_to_reference,
    driven_distance,
    speed_difference,
    yaw_error,
)

EGO_EXTENT = np.array([4.87, 1.85])  # l5kit's EGO_EXTENT_LENGTH / _WIDTH
FRAMES, AGENTS, DT = 248, 80, 0.1
SMOKE_HELP = "every part at tiny sizes in seconds, reference venvs skipped: checks the script runs, measures nothing"


def l5kit_style_collision(ego_xy, ego_yaw, ego_extent, agent_xy, agent_yaw, agent_extent, available=None):
    """One frame, the way l5kit does it: returns (kind code, agent index or -1)."""
    from shapely.geometry import LineString, Polygon

    def polygon(xy, yaw, ext):
        # Corners front-left, front-right, rear-right, rear-left (l5kit order).
        c, s = np.cos(yaw), np.sin(yaw)
        hl, hw = ext[0] / 2, ext[1] / 2
        pts = [(xy[0] + c * u - s * v, xy[1] + s * u + c * v) for u, v in ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))]
        return Polygon(pts), pts

    ego_poly, (p1, p2, p3, p4) = polygon(ego_xy, ego_yaw, ego_extent)
    edges = [LineString([p1, p2]), LineString([p3, p4]), LineString([p1, p4]), LineString([p2, p3])]
    reach = 0.5 * (np.linalg.norm(ego_extent[:2]) + np.linalg.norm(agent_extent[:, :2], axis=-1))
    near = np.linalg.norm(agent_xy - ego_xy, axis=-1) < reach
    if available is not None:
        near &= available
    for i in np.flatnonzero(near):
        poly, _ = polygon(agent_xy[i], agent_yaw[i], agent_extent[i])
        if ego_poly.intersects(poly):
            lengths = [poly.intersection(e).length for e in edges]
            return (FRONT, REAR, SIDE, SIDE)[int(np.argmax(lengths))], int(i)
    return NONE, -1


def synthetic_scenes(num_scenes: int, seed: int = 0, near_sigma: float = 5.0) -> dict[str, np.ndarray]:
    """Ego on a gentle curve at ~10 m/s; agents scattered around it, three
    hovering ``near_sigma`` metres around it so that every collision kind
    occurs (5 m: collisions in most frames, a worst case; 12 m: ~1/5)."""
    rng = np.random.default_rng(seed)
    s, t, a = num_scenes, FRAMES, AGENTS
    time_s = np.arange(t) * DT
    speed = 10.0 + rng.normal(0, 1, (s, 1))
    curvature = rng.normal(0, 0.01, (s, 1))
    yaw0 = rng.uniform(-np.pi, np.pi, (s, 1))
    log_yaw = yaw0 + curvature * speed * time_s
    step = speed[..., None] * DT * np.stack([np.cos(log_yaw), np.sin(log_yaw)], -1)
    log_xy = np.cumsum(step, axis=1) + rng.uniform(-2000, 2000, (s, 1, 2))  # l5kit-sized world coords
    # The "driven" ego drifts laterally and lags the log a little.
    lateral = np.stack([-np.sin(log_yaw), np.cos(log_yaw)], -1)
    drift = np.cumsum(rng.normal(0, 0.02, (s, t)), axis=1)[..., None]
    ego_xy = log_xy + drift * lateral - 0.02 * time_s[None, :, None] * step / DT
    ego_yaw = log_yaw + rng.normal(0, 0.01, (s, t))
    ego_speed = np.full((s, t), 1.0) * speed

    agent_xy = ego_xy[:, :, None] + rng.uniform(-50, 50, (s, t, a, 2))
    agent_xy[:, :, :3] = ego_xy[:, :, None] + rng.normal(0, near_sigma, (s, t, 3, 2))
    agent_yaw = rng.uniform(-np.pi, np.pi, (s, t, a))
    agent_extent = np.stack([rng.uniform(3.5, 6, (s, t, a)), rng.uniform(1.6, 2.2, (s, t, a))], -1)
    agent_velocity = rng.normal(0, 5, (s, t, a, 2))
    available = rng.random((s, t, a)) > 0.05
    return dict(
        ego_xy=ego_xy, ego_yaw=ego_yaw, ego_speed=ego_speed, log_xy=log_xy, log_yaw=log_yaw,
        log_speed=np.broadcast_to(speed, (s, t)), agent_xy=agent_xy, agent_yaw=agent_yaw,
        agent_extent=agent_extent, agent_velocity=agent_velocity, available=available,
        track_ids=np.broadcast_to(np.arange(1, a + 1), (s, t, a)),
    )


def all_metrics(d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    col = detect_collisions(
        d["ego_xy"], d["ego_yaw"], EGO_EXTENT, d["agent_xy"], d["agent_yaw"], d["agent_extent"],
        d["available"], d["agent_velocity"], track_ids=d["track_ids"], ego_speed=d["ego_speed"],
    )
    return dict(
        kind=col.kind, at_fault=col.at_fault,
        displacement=displacement_error(d["ego_xy"], d["log_xy"]),
        yaw_error=yaw_error(d["ego_yaw"], d["log_yaw"]),
        distance_to_reference=distance_to_reference(d["ego_xy"], d["log_xy"]),
        driven=driven_distance(d["ego_xy"]),
        speed_diff=speed_difference(d["ego_speed"], d["log_speed"]),
    )


def reference_metrics(d: dict[str, np.ndarray], scene: int) -> dict[str, np.ndarray]:
    kinds = np.zeros(FRAMES, np.int8)
    for f in range(FRAMES):
        kinds[f], _ = l5kit_style_collision(
            d["ego_xy"][scene, f], d["ego_yaw"][scene, f], EGO_EXTENT, d["agent_xy"][scene, f],
            d["agent_yaw"][scene, f], d["agent_extent"][scene, f], d["available"][scene, f],
        )
    ego, log = d["ego_xy"][scene], d["log_xy"][scene]
    return dict(
        kind=kinds,
        displacement=np.linalg.norm(ego - log, axis=-1),
        # l5kit: nearest logged centroid, per frame
        distance_to_reference=np.linalg.norm(ego[:, None] - log[None], axis=-1).min(axis=1),
    )


def have_shapely() -> bool:
    try:
        import shapely.geometry  # noqa: F401
    except ImportError:
        return False
    return True


def _time(fn, repeat: int) -> float:
    """Median wall time; the median rather than the min because CI machines
    are shared and we want the typical figure."""
    fn()  # warm-up
    samples = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t0)
    return statistics.median(samples)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--repeat", type=int, default=50)
    parser.add_argument("--ref-scenes", type=int, default=2)
    parser.add_argument("--near-sigma", type=float, default=5.0, help="spread (m) of the 3 agents around the ego")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.scenes, args.repeat, args.ref_scenes = 2, 3, 1
        print("smoke run: tiny sizes; the figures mean nothing")

    data = synthetic_scenes(args.scenes, near_sigma=args.near_sigma)
    one = {k: v[:1] for k, v in data.items()}
    t_one = _time(lambda: all_metrics(one), args.repeat)
    t_batch = _time(lambda: all_metrics(data), max(3, args.repeat // 5)) / args.scenes
    ours = all_metrics(data)
    kinds = (("front", FRONT), ("side", SIDE), ("rear", REAR))
    counts = {name: int((ours["kind"] == code).sum()) for name, code in kinds}
    print(f"scene: {FRAMES} frames x {AGENTS} agents; collision frames over {args.scenes} scenes: {counts}, "
          f"at fault: {int(ours['at_fault'].sum())}")
    o = one
    t_col = _time(lambda: detect_collisions(
        o["ego_xy"], o["ego_yaw"], EGO_EXTENT, o["agent_xy"], o["agent_yaw"], o["agent_extent"], o["available"],
        o["agent_velocity"], track_ids=o["track_ids"], ego_speed=o["ego_speed"]), args.repeat)
    t_ref_dist = _time(lambda: distance_to_reference(o["ego_xy"], o["log_xy"]), args.repeat)
    print(f"ours, one scene per call     : {t_one * 1e3:8.3f} ms/scene "
          f"(collisions {t_col * 1e3:.3f}, distance to reference {t_ref_dist * 1e3:.3f})")
    print(f"ours, {args.scenes:3d} scenes per call  : {t_batch * 1e3:8.3f} ms/scene")
    if have_shapely():
        ref_scenes = min(args.ref_scenes, args.scenes)
        t_ref = _time(lambda: [reference_metrics(data, i) for i in range(ref_scenes)], 2) / ref_scenes
        agree = all(np.array_equal(ours["kind"][i], reference_metrics(data, i)["kind"]) for i in range(ref_scenes))
        print(f"shapely per-agent reference  : {t_ref * 1e3:8.3f} ms/scene")
        print(f"speed-up (one scene per call): {t_ref / t_one:8.1f}x ; batched: {t_ref / t_batch:.1f}x")
        print(f"collision kinds identical to reference on {ref_scenes} scenes: {agree}")
    else:
        print("shapely per-agent reference  : skipped, shapely is not installed (pip install -e \".[test]\")")
    print(f"target <= 1.2 ms/scene: {'met' if t_one <= 1.2e-3 else 'NOT met'} (one scene per call)")


if __name__ == "__main__":
    main()
