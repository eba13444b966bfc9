"""Hand-checkable score cases (docs/nuplan_score.md §8) as CASE_FORMAT.md JSON, with their expected values.

Imports nothing from pytest_driveeval; any python with numpy runs it.

    python cases.py --out cases.json                  # write every case (a JSON list)
    python cases.py --out cases.json --expected exp.json
    python cases.py --compare oracle.jsonl            # table: case, expected, what the oracle answered

Common set-up (§8): 151 frames at t = 0.0 ... 15.0 s; one straight lane along +x, baseline
x = 0 ... 500, 4 m wide, in one roadblock and inside the drivable area, speed limit 15 m/s; the
Pacifica's size; heading 0; no tracked objects; ego centre starting at x = 10; expert at 10 m/s.
The comfort terms read only the acceleration, heading and angular fields, so the comfort
profiles need not match the positions.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

DT = 0.1
N = 151
LENGTH, WIDTH, REAR_AXLE_TO_CENTER = 5.176, 2.297, 1.461
HALF_WIDTH = WIDTH / 2
LANE_HALF_WIDTH = 2.0
START_X = 10.0
SPEED_LIMIT = 15.0

Case = Dict[str, Any]


def times(n: int = N) -> np.ndarray:
    return np.round(np.arange(n) * DT, 10)


def rectangle(x0: float, x1: float, half_width: float) -> List[List[float]]:
    return [[x0, -half_width], [x1, -half_width], [x1, half_width], [x0, half_width]]


def straight_map(speed_limit: Optional[float] = SPEED_LIMIT, half_width: float = LANE_HALF_WIDTH) -> Dict[str, Any]:
    outline = rectangle(0.0, 500.0, half_width)
    return {"lanes": [{"id": "lane", "polygon": outline, "baseline": [[0.0, 0.0], [500.0, 0.0]],
                       "speed_limit": speed_limit, "roadblock": "block", "connector": False,
                       "incoming": [], "outgoing": []}],
            "roadblocks": [{"id": "block", "polygon": outline, "connector": False}],
            "drivable_area": [outline], "intersections": []}


def positions(speeds: np.ndarray, start: float = START_X) -> np.ndarray:
    """Centre x per frame for per-frame speeds along +x (each frame's speed carries it to the next)."""
    return start + np.concatenate([[0.0], np.cumsum(speeds[:-1] * DT)])


def make_case(name: str, x: np.ndarray, *, speed: Optional[np.ndarray] = None, y: Optional[np.ndarray] = None,
              heading: Optional[np.ndarray] = None, accel: Optional[np.ndarray] = None,
              angular_velocity: Optional[np.ndarray] = None, expert_x: Optional[np.ndarray] = None,
              agents: Optional[List[Dict[str, Any]]] = None, map_: Optional[Dict[str, Any]] = None) -> Case:
    """A case on the common set-up; ``speed`` is the rear axle's forward (body x) velocity, signed."""
    n = len(x)
    zeros = np.zeros(n)
    speed = np.zeros(n) if speed is None else speed
    y = zeros if y is None else y
    heading = zeros if heading is None else heading
    accel = zeros if accel is None else accel
    angular_velocity = zeros if angular_velocity is None else angular_velocity
    expert_x = START_X + 10.0 * times(n) if expert_x is None else expert_x
    return {
        "name": name,
        "timestamps": times(n).tolist(),
        "ego": {"length": LENGTH, "width": WIDTH, "rear_axle_to_center": REAR_AXLE_TO_CENTER,
                "center": np.column_stack([x, y, heading]).tolist(),
                "velocity": np.column_stack([speed, zeros]).tolist(),
                "acceleration": np.column_stack([accel, zeros]).tolist(),
                "angular_velocity": angular_velocity.tolist(),
                "angular_acceleration": zeros.tolist()},
        "expert": {"center": np.column_stack([expert_x, zeros, zeros]).tolist()},
        "agents": agents or [],
        "map": straight_map() if map_ is None else map_,
    }


def constant_speed(name: str, v: float, **kwargs: Any) -> Case:
    speed = np.full(N, v)
    return make_case(name, positions(speed), speed=speed, **kwargs)


def wrap(angle: np.ndarray) -> np.ndarray:
    # (-pi, pi], as a logged heading is
    return -((-angle + np.pi) % (2 * np.pi) - np.pi)


# ---------------------------------------------------------------- §8 cases

def case_1_constant_speed() -> Case:
    return constant_speed("1_straight_constant_speed", 10.0)


def case_2_stopped() -> Case:
    return make_case("2_ego_stopped", np.full(N, START_X))


def case_2b_stopped_expert_8m() -> Case:
    return make_case("2b_ego_stopped_expert_8m", np.full(N, START_X), expert_x=START_X + 8.0 * times() / 15.0)


def case_2c_stopped_expert_stopped() -> Case:
    return make_case("2c_ego_and_expert_stopped", np.full(N, START_X), expert_x=np.full(N, START_X))


def case_3_speeding_30_frames() -> Case:
    speed = np.full(N, SPEED_LIMIT)
    speed[:30] = SPEED_LIMIT + 2.23
    x = positions(speed)
    return make_case("3_speeding_2.23_on_30_frames", x, speed=speed, expert_x=x)


def case_3b_speeding_all_frames() -> Case:
    speed = np.full(N, SPEED_LIMIT + 1.115)
    x = positions(speed)
    return make_case("3b_speeding_1.115_all_frames", x, speed=speed, expert_x=x)


def case_3c_no_speed_limit() -> Case:
    speed = np.full(N, 20.0)
    x = positions(speed)
    return make_case("3c_no_speed_limit", x, speed=speed, expert_x=x, map_=straight_map(speed_limit=None))


def comfort_case(name: str, accel: np.ndarray, **kwargs: Any) -> Case:
    return constant_speed(name, 10.0, accel=accel, **kwargs)


def case_4a_accel_2_39() -> Case:
    return comfort_case("4a_lon_accel_2.39", np.full(N, 2.39))


def case_4a_accel_2_40() -> Case:
    return comfort_case("4a_lon_accel_2.40", np.full(N, 2.40))


def step(before: float, after: float) -> np.ndarray:
    return np.where(times() < 7.5, before, after)


def case_4b_step_to_minus_4() -> Case:
    return comfort_case("4b_step_0_to_-4.0", step(0.0, -4.0))


def case_4c_step_1_to_minus_3_2() -> Case:
    return comfort_case("4c_step_1_to_-3.2", step(1.0, -3.2))


def case_4c_step_1_to_minus_3() -> Case:
    return comfort_case("4c_step_1_to_-3.0", step(1.0, -3.0))


def spinning(name: str, yaw_rate: float) -> Case:
    # A heading turning at yaw_rate while the centre goes straight: a 20 m wide lane (and road)
    # keeps the spinning box inside one lane, so only the comfort terms see the turn.
    return constant_speed(name, 10.0, heading=wrap(yaw_rate * times()), map_=straight_map(half_width=10.0))


def case_4d_yaw_rate_0_9() -> Case:
    return spinning("4d_yaw_rate_0.9", 0.9)


def case_4d_yaw_rate_1_0() -> Case:
    return spinning("4d_yaw_rate_1.0", 1.0)


def case_4e_centre_shift() -> Case:
    return comfort_case("4e_centre_shift_quirk", np.full(N, 1.5), angular_velocity=np.full(N, 0.9))


def backwards(name: str, v: float) -> Case:
    # 5 s forward at 5 m/s, then 1.5 s backwards at v (15 steps > the 11-step window), then stopped.
    # The expert stays put, so progress is 1 whatever the ego does (P_ego >= -2).
    speed = np.zeros(N)
    speed[:50] = 5.0
    speed[50:65] = -v
    x = positions(speed)
    return make_case(name, x, speed=speed, expert_x=np.full(N, START_X))


def case_5_backwards_1_8() -> Case:
    return backwards("5_backwards_1.8", 1.8)


def case_5_backwards_1_9() -> Case:
    return backwards("5_backwards_1.9", 1.9)


def case_5_backwards_5_6() -> Case:
    return backwards("5_backwards_5.6", 5.6)


def agent(token: str, kind: str, x: np.ndarray, v: float = 0.0, length: float = 4.5, width: float = 2.0,
          y: float = 0.0, frames: Optional[List[int]] = None) -> Dict[str, Any]:
    frames = list(range(len(x))) if frames is None else frames
    return {"token": token, "type": kind, "length": length, "width": width, "frames": frames,
            "center": [[float(x[i]), y, 0.0] for i in frames], "velocity": [[v, 0.0] for _ in frames]}


def cone(token: str, x: float) -> Dict[str, Any]:
    return agent(token, "traffic_cone", np.full(N, x), length=0.5, width=0.5)


def case_6a_one_cone() -> Case:
    return constant_speed("6a_hits_one_cone", 5.0, expert_x=positions(np.full(N, 5.0)), agents=[cone("cone1", 50.0)])


def case_6b_two_cones() -> Case:
    return constant_speed("6b_hits_two_cones", 5.0, expert_x=positions(np.full(N, 5.0)),
                          agents=[cone("cone1", 50.0), cone("cone2", 70.0)])


def case_6c_parked_vehicle() -> Case:
    return constant_speed("6c_hits_parked_vehicle", 5.0, expert_x=positions(np.full(N, 5.0)),
                          agents=[agent("parked", "vehicle", np.full(N, 60.0))])


def case_6c_pedestrian() -> Case:
    # walking along the lane at 1 m/s, caught by the ego's front bumper
    return constant_speed("6c_hits_walking_pedestrian", 5.0, expert_x=positions(np.full(N, 5.0)),
                          agents=[agent("walker", "pedestrian", 40.0 + 1.0 * times(), v=1.0, length=0.6, width=0.6)])


def case_6d_stopped_ego_hit() -> Case:
    # ego and expert stopped at x = 10; a vehicle at 5 m/s drives into the ego from behind
    return make_case("6d_stopped_ego_hit_from_behind", np.full(N, START_X), expert_x=np.full(N, START_X),
                     agents=[agent("rammer", "vehicle", -20.0 + 5.0 * times(), v=5.0)])


def case_6e_rear_ended() -> Case:
    # ego at 5 m/s; a vehicle at 10 m/s from directly behind hits it
    return constant_speed("6e_rear_ended_while_moving", 5.0, expert_x=positions(np.full(N, 5.0)),
                          agents=[agent("tailgater", "vehicle", -20.0 + 10.0 * times(), v=10.0)])


def out_of_road(name: str, metres_out: float) -> Case:
    # the left corners stand metres_out beyond the lane (= road) edge all along
    y = np.full(N, LANE_HALF_WIDTH - HALF_WIDTH + metres_out)
    speed = np.full(N, 10.0)
    return make_case(name, positions(speed), speed=speed, y=y)


def case_7_half_metre_out() -> Case:
    return out_of_road("7_corner_0.5m_out_of_road", 0.5)


def case_7_fifth_metre_out() -> Case:
    return out_of_road("7_corner_0.2m_out_of_road", 0.2)


def following(name: str, final_gap: float) -> Case:
    # ego at 10 m/s behind a vehicle at 8 m/s in its lane; the bumper gap closes at 2 m/s to final_gap.
    # Gaps are off the 0.1 s grid by 0.05 m so no step of the TTC projection is a tie.
    speed = np.full(N, 10.0)
    x = positions(speed)
    closing = 2.0 * (N - 1) * DT
    lead_x = x + LENGTH / 2 + 4.5 / 2 + final_gap + closing - 2.0 * times()
    return make_case(name, x, speed=speed, expert_x=x, agents=[agent("lead", "vehicle", lead_x, v=8.0)])


def case_ttc_follow_safe() -> Case:
    return following("ttc_follow_gap_3.05", 3.05)


def case_ttc_follow_close() -> Case:
    return following("ttc_follow_gap_1.55", 1.55)


# (case function, expected values: score and the terms §8 names; "min_time_to_collision" in s, None = inf)
CASES: List[Tuple[Callable[[], Case], Dict[str, Any]]] = [
    (case_1_constant_speed, {"score": 1.0}),
    (case_2_stopped, {"score": 0.0, "ego_progress_along_expert_route": 2 / 150, "ego_is_making_progress": 0.0}),
    (case_2b_stopped_expert_8m, {"score": 0.765625, "ego_progress_along_expert_route": 0.25}),
    (case_2c_stopped_expert_stopped, {"score": 1.0}),
    (case_3_speeding_30_frames, {"score": 0.95, "speed_limit_compliance": 0.8}),
    (case_3b_speeding_all_frames, {"score": (5 + 5 + 4 * (1 - 151 * 1.115 * 0.1 / (2.23 * 15)) + 2) / 16,
                                   "speed_limit_compliance": 1 - 151 * 1.115 * 0.1 / (2.23 * 15)}),
    (case_3c_no_speed_limit, {"score": 1.0, "speed_limit_compliance": 1.0}),
    (case_4a_accel_2_39, {"score": 1.0, "ego_is_comfortable": 1.0}),
    (case_4a_accel_2_40, {"score": 0.875, "ego_is_comfortable": 0.0}),
    (case_4b_step_to_minus_4, {"score": 0.875, "ego_is_comfortable": 0.0, "ego_lon_acceleration_min": -4.375,
                               "ego_lon_jerk_absmax": 4.0179}),
    (case_4c_step_1_to_minus_3_2, {"score": 0.875, "ego_is_comfortable": 0.0, "ego_lon_acceleration_min": -3.594,
                                   "ego_lon_acceleration_max": 1.394, "ego_lon_jerk_absmax": 4.21875,
                                   "ego_jerk_absmax": 2.2098}),
    (case_4c_step_1_to_minus_3, {"score": 1.0, "ego_is_comfortable": 1.0, "ego_lon_acceleration_min": -3.375,
                                 "ego_lon_acceleration_max": 1.375, "ego_lon_jerk_absmax": 4.0179}),
    (case_4d_yaw_rate_0_9, {"score": 1.0, "ego_is_comfortable": 1.0, "ego_yaw_rate_absmax": 0.9}),
    (case_4d_yaw_rate_1_0, {"score": 0.875, "ego_is_comfortable": 0.0, "ego_yaw_rate_absmax": 1.0}),
    (case_4e_centre_shift, {"score": 0.875, "ego_is_comfortable": 0.0, "ego_lon_acceleration_max": 2.6834}),
    (case_5_backwards_1_8, {"score": 1.0, "driving_direction_compliance": 1.0}),
    (case_5_backwards_1_9, {"score": 0.5, "driving_direction_compliance": 0.5}),
    (case_5_backwards_5_6, {"score": 0.0, "driving_direction_compliance": 0.0}),
    (case_6a_one_cone, {"score": 0.34375, "no_ego_at_fault_collisions": 0.5, "time_to_collision_within_bound": 0.0}),
    (case_6b_two_cones, {"score": 0.0, "no_ego_at_fault_collisions": 0.0}),
    (case_6c_parked_vehicle, {"score": 0.0, "no_ego_at_fault_collisions": 0.0}),
    (case_6c_pedestrian, {"score": 0.0, "no_ego_at_fault_collisions": 0.0}),
    (case_6d_stopped_ego_hit, {"score": 1.0, "no_ego_at_fault_collisions": 1.0,
                               "time_to_collision_within_bound": 1.0}),
    (case_6e_rear_ended, {"score": 1.0, "no_ego_at_fault_collisions": 1.0, "time_to_collision_within_bound": 1.0}),
    (case_7_half_metre_out, {"score": 0.0, "drivable_area_compliance": 0.0}),
    (case_7_fifth_metre_out, {"score": 1.0, "drivable_area_compliance": 1.0}),
    (case_ttc_follow_safe, {"score": 1.0, "min_time_to_collision": 1.6}),
    (case_ttc_follow_close, {"score": 0.6875, "min_time_to_collision": 0.8, "time_to_collision_within_bound": 0.0}),
]


def all_cases() -> List[Case]:
    return [make() for make, _ in CASES]


def expected_values() -> Dict[str, Dict[str, Any]]:
    return {make()["name"]: expected for make, expected in CASES}


def answered(result: Dict[str, Any], key: str) -> Optional[float]:
    """The oracle's value for an expected-value key (a metric, the score, or a comfort min/max/absmax)."""
    if "error" in result:
        return None
    if key in ("score", "min_time_to_collision"):
        return result[key]
    if key in result["metrics"]:
        return result["metrics"][key]
    signal, _, which = key.rpartition("_")
    low, high = result["comfort"][signal]
    return {"min": low, "max": high, "absmax": max(abs(low), abs(high))}[which]


def compare(results: List[Dict[str, Any]], tolerance: float = 5e-4) -> Tuple[List[str], int]:
    expected = expected_values()
    rows = ["| case | term | expected | oracle | |", "| --- | --- | --- | --- | --- |"]
    mismatches = 0
    for result in results:
        for key, want in expected.get(result["name"], {}).items():
            got = answered(result, key)
            same = (got is None and want is None) or (got is not None and want is not None
                                                      and math.isclose(got, want, abs_tol=tolerance))
            mismatches += not same
            fmt = (lambda v: "inf/none" if v is None else f"{v:.6g}")
            rows.append(f"| {result['name']} | {key} | {fmt(want)} | "
                        f"{result.get('error', fmt(got))} | {'ok' if same else 'DIFFERS'} |")
    return rows, mismatches


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, help="write the cases here (a JSON list)")
    parser.add_argument("--expected", type=Path, help="write {case name: expected values} here")
    parser.add_argument("--compare", type=Path, help="oracle output (JSON lines) to set against the expected values")
    args = parser.parse_args(argv)
    if args.out:
        args.out.write_text(json.dumps(all_cases()))
        print(f"{len(CASES)} cases -> {args.out}")
    if args.expected:
        args.expected.write_text(json.dumps(expected_values(), indent=1))
    if args.compare:
        results = [json.loads(line) for line in args.compare.read_text().splitlines() if line.strip()]
        rows, mismatches = compare(results)
        print("\n".join(rows))
        print(f"{mismatches} differing of {len(rows) - 2}")
        return 1 if mismatches else 0
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
