"""The planner API's inputs on a real nuScenes scene (map query, route, goal), and PDM-Closed's choice
on a hand-made road where the answer is known."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")

from pytest_driveeval.metrics.nuplan_score import ScoreMap  # noqa: E402
from pytest_driveeval.metrics.nuplan_score.progress import route_pairs, simplified  # noqa: E402
from pytest_driveeval.metrics.nuplan_score.route import centre_route  # noqa: E402
from pytest_driveeval.policies.pdm_closed import PDMClosed  # noqa: E402
from pytest_driveeval.policies.planner_api import Goal, Observation, PlannerContext, SceneContext  # noqa: E402
from pytest_driveeval.sim.map_query import MapQuery, Route  # noqa: E402

SCENE = 1  # scene-0103 among the shared six


@pytest.fixture(scope="module")
def real(shared_data):
    from pytest_driveeval.sim.logreplay import UnrollConfig
    from pytest_driveeval.usecases.closed_loop.datasets import open_dataset
    from pytest_driveeval.usecases.closed_loop.evaluate import stack_log
    from pytest_driveeval.usecases.closed_loop.planner_inputs import planner_context
    from pytest_driveeval.usecases.closed_loop.score import SceneMaps

    dataset = open_dataset(str(shared_data / "scenarionet" / "nuscenes"), None)
    log = stack_log(dataset, [SCENE], 10)
    maps = SceneMaps(dataset)
    context = planner_context(log, UnrollConfig(start_frame=10), dataset, maps)
    return dataset, log, maps.get(SCENE), context.scenes[0]


def test_map_query_answers_from_the_files_own_lanes(real):
    dataset, _, score_map, scene = real
    query = scene.map
    features = {f.id: f for f in dataset.source(SCENE).map_features}
    lane = next(n for n, i in enumerate(score_map.lane_ids) if features[i].polyline is not None
                and len(features[i].polyline) > 4 and query.successors(n))
    line = features[query.lane_id(lane)].polyline[:, :2]
    middle = line[len(line) // 2]
    assert lane in query.lanes_at(middle)
    assert query.lanes_near(middle, 0.0)[:len(query.lanes_at(middle))] == sorted(query.lanes_at(middle))
    assert query.lanes_near(middle + 1e4, 50.0) == []
    # the baseline is the file's centre line, and each successor starts where the lane ends (nuScenes'
    # lanes join where their centre lines meet), read from the file's own polylines
    assert np.abs(query.centre_line(lane)[[0, -1]] - line[[0, -1]]).max() < 0.5
    for nxt in query.successors(lane):
        assert np.hypot(*(features[query.lane_id(nxt)].polyline[0, :2] - line[-1])) < 1.0
        assert lane in query.predecessors(nxt)
    for other in query.neighbours(lane):
        assert query.roadblock(other) == query.roadblock(lane)
    assert query.speed_limit(lane) is None and "placeholder" in query.no_limits_reason
    assert query.in_drivable_area(middle[None]).tolist() == [True]
    assert query.lights(10) == {}  # nuScenes' ScenarioNet files carry no light states


def test_route_is_the_scores_expert_route_and_goal_the_last_logged_pose(real):
    dataset, log, score_map, scene = real
    n = int(log.num_frames[0])
    xy, yaw = log.ego_xy[0, :n], log.ego_yaw[0, :n]
    expert = simplified(centre_route(score_map, xy, yaw))
    assert scene.route.lanes == tuple(lanes[0] for lanes in expert)
    assert scene.route.roadblocks == tuple(block for block, _ in route_pairs(score_map, expert))
    assert len(scene.route.lanes) >= 2
    source = dataset.source(SCENE)
    track = source.tracks
    last = np.flatnonzero(track.valid[source.sdc])[-1]
    assert scene.goal.frame == n - 1
    assert np.allclose(scene.goal.xy, track.position[source.sdc, last, :2], atol=1e-6)
    assert scene.goal.yaw == pytest.approx(float(track.heading[source.sdc, last]), abs=1e-6)


def _road() -> MapQuery:
    """One straight lane, 3.6 m wide, x from -20 to 400 m along y = 0."""
    polygon = np.array([[-20.0, -1.8], [400.0, -1.8], [400.0, 1.8], [-20.0, 1.8]])
    line = np.stack([np.linspace(-20, 400, 421), np.zeros(421)], axis=1)
    return MapQuery(ScoreMap(lane_ids=["road"], polygons=[polygon], baselines=[line], speed_limits=[10.0],
                             connector=[False], outgoing=[[]], drivable=[polygon]))


def _drive(obstacle_x: float | None, steps: int = 80) -> tuple[np.ndarray, PDMClosed]:
    """PDM-Closed driving the road from x=0 at 8 m/s, a car stopped in the lane at ``obstacle_x``; the ego
    moved to each plan's first pose as the engine does.  Returns the ego's x per step."""
    query = _road()
    planner = PDMClosed()
    planner.initialize(PlannerContext([SceneContext(0, query, Route((0,), (0,), (0,), np.zeros((1, 2))),
                                                    Goal(np.array([380.0, 0.0]), 0.0, 400), 0)],
                                      0.1, (4.869, 1.852, 1.476), 12))
    xy, yaw, speed = np.zeros(2), 0.0, 8.0
    xs = []
    agents = np.array([[[obstacle_x if obstacle_x is not None else 0.0, 0.0]]])
    for t in range(steps):
        obs = Observation(rows=np.array([0]), frame=t, ego_xy=xy[None].copy(), ego_yaw=np.array([yaw]),
                          ego_speed=np.array([speed]), history_xy=np.repeat(xy[None, None], 11, 1),
                          history_yaw=np.full((1, 11), yaw), agents_xy=agents, agents_yaw=np.zeros((1, 1)),
                          agents_extent=np.array([[[4.5, 1.9, 1.5]]]), agents_velocity=np.zeros((1, 1, 2)),
                          agents_available=np.array([[obstacle_x is not None]]),
                          agents_track_id=np.array([[7]]), lights=[{}])
        out = planner.plan(obs)
        step = out["positions"][0, 0].astype(np.float64)
        c, s = np.cos(yaw), np.sin(yaw)
        new = xy + np.array([c * step[0] - s * step[1], s * step[0] + c * step[1]])
        speed = float(np.hypot(*(new - xy))) / 0.1
        xy, yaw = new, yaw + float(out["yaws"][0, 0, 0])
        xs.append(xy[0])
    return np.array(xs), planner


def test_pdm_keeps_the_centre_line_at_the_limit_on_a_free_road():
    xs, planner = _drive(None, steps=40)
    assert int(planner.last_choice[0]) == 0  # offset 0 at the full limit: the first proposal
    assert xs[-1] > 4.0 * 8.0 - 1.0  # it did not slow down
    assert np.all(np.diff(xs) > 0)


def test_pdm_stops_behind_a_stopped_car_instead_of_hitting_it():
    xs, planner = _drive(40.0)
    rear_of_car, front_of_ego = 40.0 - 4.5 / 2, xs + 4.869 / 2
    assert front_of_ego.max() < rear_of_car  # never touched it
    assert rear_of_car - front_of_ego[-1] < 6.0  # and stopped close behind (IDM's gap), not far back
    assert xs[-1] - xs[-2] < 0.05  # all but at rest (under 0.5 m/s, creeping up to IDM's gap)
