"""Episodes in a CommonRoad scene: the ego at the planning problem's initial state, the obstacles at
their recorded states, CommonRoad's goal, the lanelets' road, seeded start offsets."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import REPO_ROOT

from pytest_driveeval.geometry.polygons import outline_distance
from pytest_driveeval.io.commonroad.commonroad import CommonRoadError
from pytest_driveeval.io.commonroad.commonroad_geometry import on_road
from pytest_driveeval.metrics.episode_outcomes import COLLISION, GOAL, OFF_ROAD, STEP_LIMIT
from pytest_driveeval.sim.blueprints import ParameterError
from pytest_driveeval.sim.commonroad_episodes import start_offsets
from pytest_driveeval.sim.commonroad_scene import commonroad_scene, read_cached
from pytest_driveeval.sim.episodes import reset

TUTORIAL = REPO_ROOT / "fixtures" / "commonroad" / "ZAM_Tutorial-1_2_T-1.xml"
SHARED = ("FRA_Anglet-1_1_T-1", "USA_Lanker-1_1_T-1", "USA_US101-3_3_T-1", "ZAM_Tutorial-1_2_T-1")


def zero_offsets(**params):
    return dict(start_lateral=(0, 0), start_longitudinal=(0, 0), start_heading=(0, 0), start_speed=(0, 0), **params)


def scene_of(path, **params):
    return commonroad_scene(path, next(iter(read_cached(path).planning_problems)), **params)


def run(episodes, actions):
    frames = []
    while not episodes.done.all():
        episodes.step(actions(episodes))
        frames.append((episodes.xy.copy(), episodes.yaw.copy(), episodes.valid.copy(), episodes.outcome.copy()))
    return frames


def keep_speed(episodes):
    return np.zeros((episodes.num_episodes, 2))


def check_replay(scene, seeds):
    """Ego exactly at the initial state at the start (seed 0); every obstacle at its recorded state at
    every step, present exactly within its recorded time steps."""
    episodes = reset(scene, seeds, 12)
    init = scene.problem.initial
    assert episodes.xy[0, 0].tolist() == [init.x, init.y]
    assert episodes.yaw[0, 0] == init.orientation and episodes.speed[0, 0] == init.velocity
    k = 0
    while True:
        for j, ident in enumerate(scene.obstacle_ids, start=1):
            obstacle = scene.scenario.obstacles[int(ident)]
            traj, t = obstacle.trajectory, scene.t0 + k
            present = obstacle.role == "static" or traj.t[0] <= t <= traj.t[-1]
            assert episodes.valid[:, j].tolist() == [present] * len(seeds), (ident, t)
            if present and obstacle.role == "dynamic":
                state = traj.at(t)
                # The files' rectangles sit on their state (centre 0, 0).
                np.testing.assert_allclose(episodes.xy[:, j], [[state.x, state.y]] * len(seeds), atol=1e-12)
                np.testing.assert_allclose(episodes.yaw[:, j], state.orientation, atol=1e-12)
        if episodes.done.all():
            break
        episodes.step(keep_speed(episodes))
        k += 1
    return episodes


def test_seed_0_starts_at_the_initial_state_and_obstacles_replay_the_recording():
    scene = scene_of(TUTORIAL)
    episodes = check_replay(scene, np.array([0]))
    assert scene.dt == 0.1 and scene.max_steps == 40  # the goal's time interval ends at step 40
    # Keeping its 22 m/s straight along lanelet 1, the ego is there when the goal's time interval opens.
    assert episodes.outcome.tolist() == [GOAL] and episodes.steps.tolist() == [35]


@pytest.mark.parametrize("name", SHARED)
def test_the_shared_scenarios_replay_their_recording(shared_data, name):
    check_replay(scene_of(shared_data / "commonroad" / f"{name}.xml"), np.array([0, 3]))


def test_seeds_draw_start_offsets_within_the_ranges_and_seed_0_draws_none():
    scene = scene_of(TUTORIAL, start_lateral=(-0.5, 0.5), start_speed=(-2.0, 1.0))
    offsets = start_offsets(scene.params, np.arange(64))
    assert offsets[0].tolist() == [0, 0, 0, 0]
    assert np.all(offsets[1:, 0] >= -0.5) and np.all(offsets[1:, 0] <= 0.5) and np.ptp(offsets[1:, 0]) > 0.5
    assert np.all(offsets[1:, 3] >= -2.0) and np.all(offsets[1:, 3] <= 1.0)
    assert np.all(np.abs(offsets[1:, 2]) <= 0.01)
    episodes = reset(scene, np.arange(64), 12)
    init = scene.problem.initial
    # The tutorial's ego heads along +x: the lateral offset is a y offset, the longitudinal one an x offset.
    np.testing.assert_allclose(episodes.xy[:, 0, 1] - init.y, offsets[:, 0], atol=1e-12)
    np.testing.assert_allclose(episodes.xy[:, 0, 0] - init.x, offsets[:, 1], atol=1e-12)
    np.testing.assert_allclose(episodes.speed[:, 0], init.velocity + offsets[:, 3])


def test_an_episode_depends_on_its_seed_only():
    scene = scene_of(TUTORIAL)

    def weave(episodes):
        steer = 0.05 * np.sin(0.3 * episodes.steps + episodes.seeds)
        return np.stack([np.full(episodes.num_episodes, 1.0), steer], axis=1)

    alone = run(reset(scene, np.array([9]), 12), weave)
    mixed = run(reset(scene, np.array([4, 9, 0, 17]), 12), weave)
    for a, m in zip(alone, mixed):
        for x, y in zip(a, m):
            np.testing.assert_array_equal(x[0], y[1])


def judged(scene, xy, yaw, speed, k):
    episodes = reset(scene, np.array([0]), 12)
    goal, collision, left = episodes.judge(np.array([xy], float), np.array([yaw], float), np.array([speed], float),
                                           np.array([k]))
    return bool(goal[0]), bool(collision[0]), bool(left[0])


def test_constructed_states_reach_the_goal_leave_the_road_and_collide():
    scene = scene_of(TUTORIAL, max_steps=60)
    # The goal: lanelet 1 (y in [-1.75, 1.75]), heading within [-1.05, 0.95], time steps 35..40.
    assert judged(scene, (120.0, 0.0), 0.0, 20.0, 35) == (True, False, False)
    assert judged(scene, (120.0, 0.0), 0.0, 20.0, 34) == (False, False, False)  # too early
    assert judged(scene, (120.0, 0.0), 0.0, 20.0, 41) == (False, False, False)  # too late
    assert judged(scene, (120.0, 3.5), 0.0, 20.0, 36) == (False, False, False)  # lanelet 2, not the goal's
    assert judged(scene, (120.0, 0.0), 1.2, 20.0, 36)[0] is False  # heading outside the interval
    # Off the road: a corner beyond lanelet 1's right edge (-1.75) or past the road's end.
    assert judged(scene, (120.0, -1.0), 0.0, 20.0, 10)[2] is True
    assert judged(scene, (198.0, 0.0), 0.0, 20.0, 10)[2] is True
    # Into obstacle 44 where the recording has it at step 20 (4.3 m x 1.8 m, along x at y = 0).
    j = list(scene.obstacle_ids).index(44)
    at = scene.xy[20, j]
    assert judged(scene, at + (4.3, 0.0), 0.0, 20.0, 20)[1] is True  # 4.3 < (4.3 + 4.508) / 2 apart: touching
    assert judged(scene, at + (4.5, 0.0), 0.0, 20.0, 20)[1] is False
    # After its last recorded step (40) it is gone: no collision where it was.
    last = scene.xy[40, j]
    assert judged(scene, last, 0.0, 20.0, 40)[1] is True
    assert judged(scene, last, 0.0, 20.0, 41)[1] is False
    # The parked vehicle (static) is there at every step.
    parked = scene.xy[0, list(scene.obstacle_ids).index(43)]
    assert judged(scene, parked, 0.0, 0.0, 0)[1] and judged(scene, parked, 0.0, 0.0, 60)[1]


def test_episodes_end_off_road_by_collision_and_at_the_step_limit():
    scene = scene_of(TUTORIAL)
    right = run(reset(scene, np.array([0]), 12), lambda e: np.array([[0.0, -0.2]]))
    assert right[-1][3].tolist() == [OFF_ROAD]
    # Braking hard: the car cutting in behind (obstacle 42) drives into the ego.
    brake = run(reset(scene, np.array([0]), 12), lambda e: np.array([[-5.0, 0.0]]))
    assert brake[-1][3].tolist() == [COLLISION]
    slow = run(reset(commonroad_scene(TUTORIAL, 100, max_steps=20), np.array([0]), 12), keep_speed)
    assert slow[-1][3].tolist() == [STEP_LIMIT] and len(slow) == 20


@pytest.mark.parametrize("name", SHARED)
def test_the_raster_agrees_with_the_exact_road_test_but_within_a_cell_of_an_edge(shared_data, name):
    path = shared_data / "commonroad" / f"{name}.xml"
    scenario, scene = read_cached(path), scene_of(path)
    lo, hi = scene.road.bounds[:2] - 3.0, scene.road.bounds[2:] + 3.0
    points = np.random.default_rng(0).uniform(lo, hi, (20000, 2))
    exact = on_road(scenario, points[:, 0], points[:, 1])
    assert 0.02 < exact.mean() < 0.98
    differ = points[exact != scene.road.drivable.contains(points)]
    if len(differ):
        near = np.min([outline_distance(differ, ll.polygon) for ll in scenario.lanelets.values()], axis=0)
        cell = np.sqrt(2) * scene.params.resolution
        assert np.all(near <= cell), differ[near > cell]


def test_bad_scenes_are_refused_naming_what():
    with pytest.raises(CommonRoadError, match=r"no planning problem with id 7 .*the file has: 100"):
        commonroad_scene(TUTORIAL, 7)
    with pytest.raises(ParameterError, match="timeStepSize"):
        commonroad_scene(TUTORIAL, 100, dt=0.2)
    with pytest.raises(ParameterError, match="gap.*does not apply"):
        commonroad_scene(TUTORIAL, 100, gap=(1, 2))
    with pytest.raises(ParameterError, match="start_heading"):
        commonroad_scene(TUTORIAL, 100, start_heading=(0.1, -0.1))
    with pytest.raises(OSError):
        commonroad_scene(TUTORIAL.with_name("absent.xml"), 100)


def test_reactive_traffic_drives_the_recorded_paths_and_brakes_for_the_ego():
    replay, reactive = scene_of(TUTORIAL), scene_of(TUTORIAL, traffic="reactive")
    brake = lambda e: np.tile([-5.0, 0.0], (e.num_episodes, 1))  # noqa: E731
    assert run(reset(replay, np.array([0, 5]), 12), brake)[-1][3].tolist() == [COLLISION] * 2
    # The car cutting in behind (42) now brakes for the ego; the ego is on its goal lanelet in time.
    assert run(reset(reactive, np.array([0, 5]), 12), brake)[-1][3].tolist() == [GOAL] * 2
    # With nothing ahead of it, obstacle 44 (22 m/s, its fastest recorded speed) drives its recording.
    frames = run(reset(reactive, np.array([0]), 12), keep_speed)
    j = list(reactive.obstacle_ids).index(44)
    np.testing.assert_allclose(np.array([f[0][0, 1 + j] for f in frames]), reactive.xy[1:len(frames) + 1, j],
                               atol=1e-9)


def test_reactive_episodes_depend_on_their_seed_only():
    scene = scene_of(TUTORIAL, traffic="reactive")

    def brake_some(episodes):
        return np.stack([np.where(episodes.seeds % 2 == 1, -5.0, 0.5), np.zeros(episodes.num_episodes)], axis=1)

    alone = run(reset(scene, np.array([9]), 12), brake_some)
    mixed = run(reset(scene, np.array([4, 9, 0]), 12), brake_some)
    for a, m in zip(alone, mixed):
        for x, y in zip(a, m):
            np.testing.assert_array_equal(x[0], y[1])


@pytest.mark.parametrize("name", SHARED)
def test_reactive_obstacles_appear_at_their_first_recorded_step_where_recorded(shared_data, name):
    scene = scene_of(shared_data / "commonroad" / f"{name}.xml", traffic="reactive")
    episodes = reset(scene, np.array([0]), 12)
    seen = np.zeros(len(scene.obstacle_ids), bool)
    for k in range(scene.max_steps + 1):
        for j, ident in enumerate(scene.obstacle_ids):
            obstacle = scene.scenario.obstacles[int(ident)]
            first = int(obstacle.trajectory.t[0]) - scene.t0
            if obstacle.role == "dynamic" and not seen[j]:
                assert episodes.valid[0, 1 + j] == (k >= first), (ident, k)
                if episodes.valid[0, 1 + j]:
                    seen[j] = True
                    np.testing.assert_allclose(episodes.xy[0, 1 + j], scene.xy[max(k, 0), j], atol=1e-6)
        if episodes.done.all():
            break
        episodes.step(np.array([[0.0, 0.0]]))


@pytest.mark.parametrize("name", SHARED)
def test_constructed_goal_states_of_the_shared_scenarios_reach_the_goal(shared_data, name):
    scene = scene_of(shared_data / "commonroad" / f"{name}.xml")
    goal = scene.problem.goals[0]
    centre, heading = scene.goal_centre, scene.goal_heading  # a goal position's centre (the first)
    speed = scene.goal_speed
    k = (int(np.ceil(goal.time.start)) if goal.time is not None else 0) - scene.t0
    assert judged(scene, centre, heading, speed, k)[0] is True
    if goal.time is not None and goal.time.start > scene.t0:
        assert judged(scene, centre, heading, speed, k - 1)[0] is False
    if goal.velocity is not None:
        assert judged(scene, centre, heading, goal.velocity.end + 1.0, k)[0] is False
    far = scene.road.bounds[2:] + 50.0
    assert judged(scene, far, heading, speed, k)[2] is True


def test_a_raster_too_fine_for_the_lanelets_is_a_parameter_error_on_resolution():
    with pytest.raises(ParameterError, match=r"ZAM_Tutorial-1_2_T-1\.xml's lanelets: the road's drivable area "
                                             r"\(209 m x 20\.5 m\) would be a raster of 4\.28e\+15 cells at 1e-06 m, "
                                             r"above the limit .*; give a coarser resolution") as raised:
        scene_of(TUTORIAL, resolution=1e-6)
    assert raised.value.parameter == "resolution"


def test_scene_bytes_grow_with_steps_and_obstacles_and_cover_the_arrays():
    from pytest_driveeval.sim.commonroad_scene import scene_bytes

    scene = scene_of(TUTORIAL, max_steps=1000)
    held = sum(a.nbytes for a in (scene.xy, scene.yaw, scene.speed, scene.valid))
    assert scene_bytes(1000, len(scene.obstacle_ids)) > 2 * held
    assert scene_bytes(10 ** 9, 0) > 2 ** 36 and scene_bytes(10, 3) > scene_bytes(10, 2)
