"""The synthetic scene generator: determinism and plausibility."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset, label_index
from pytest_driveeval.synth.scenegen import EGO_EXTENT, generate_scenes, generate_zarr, road_layout

NUM_SCENES, NUM_FRAMES = 8, 100


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("gen") / "synthetic.zarr"
    generate_zarr(path, NUM_SCENES, NUM_FRAMES, seed=11)
    return L5Dataset.open(path)


def _corners(centre, yaw, length, width):
    u = np.array([np.cos(yaw), np.sin(yaw)])
    w = np.array([-np.sin(yaw), np.cos(yaw)])
    return np.array([centre + sx * length / 2 * u + sy * width / 2 * w for sx in (-1, 1) for sy in (-1, 1)])


def _overlap(box_a, box_b) -> bool:
    """Plain separating-axis test on corner sets (independent of the generator's own test)."""
    for corners in (box_a, box_b):
        for i in (0, 1):
            edge = corners[[1, 2][i]] - corners[0]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = box_a @ axis, box_b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


def test_overlap_helper_sanity():
    a = _corners(np.zeros(2), 0.0, 4.0, 2.0)
    assert _overlap(a, _corners(np.array([3.9, 0.0]), 0.0, 4.0, 2.0))
    assert not _overlap(a, _corners(np.array([4.1, 0.0]), 0.0, 4.0, 2.0))
    assert not _overlap(a, _corners(np.array([3.0, 2.1]), np.pi / 2, 4.0, 0.1))
    assert _overlap(a, _corners(np.array([2.5, 0.0]), np.pi / 4, 2.0, 1.0))


def test_same_seed_same_bytes_different_seed_differs():
    a = generate_scenes(3, 40, seed=7)
    b = generate_scenes(3, 40, seed=7)
    c = generate_scenes(3, 40, seed=8)
    assert all(x.tobytes() == y.tobytes() for x, y in zip(a, b))
    assert a.agents.tobytes() != c.agents.tobytes()
    assert a.frames["ego_translation"].tobytes() != c.frames["ego_translation"].tobytes()


def test_timestamps_and_shapes(store):
    assert store.num_scenes == NUM_SCENES
    for scene in store:
        ts = scene.frames["timestamp"]
        assert len(ts) == NUM_FRAMES
        assert np.all(np.diff(ts) == 100_000_000)  # 10 Hz in nanoseconds
        assert scene.start_time == ts[0] and scene.end_time == ts[-1]
        assert scene.host.startswith("host-synth")


def test_speeds_within_bounds(store):
    for scene in store:
        ego_speed = np.linalg.norm(np.diff(scene.ego_positions(), axis=0), axis=1) / 0.1
        assert ego_speed.min() >= 0 and ego_speed.max() <= 20
        agent_speed = np.linalg.norm(scene.agents["velocity"], axis=1)
        assert agent_speed.min() >= 0 and agent_speed.max() <= 20


def test_some_scenes_stop_and_accelerate(store):
    stops = accelerations = 0
    for scene in store:
        v = np.linalg.norm(np.diff(scene.ego_positions(), axis=0), axis=1) / 0.1
        stops += bool(np.any(v < 0.05))
        accelerations += bool(np.any(np.diff(v) > 0.05))
    assert stops >= 1 and accelerations >= NUM_SCENES // 2


def test_no_ego_agent_overlap(store):
    checked = 0
    for scene in store:
        ego, ego_yaw = scene.ego_positions(), scene.ego_yaws()
        for t in range(scene.num_frames):
            agents = scene.agents_of_frame(t)
            near = np.linalg.norm(agents["centroid"] - ego[t], axis=1) < 8.0
            ego_box = _corners(ego[t], ego_yaw[t], EGO_EXTENT[0], EGO_EXTENT[1])
            for a in agents[near]:
                checked += 1
                assert not _overlap(ego_box, _corners(a["centroid"], a["yaw"], a["extent"][0], a["extent"][1])), \
                    f"scene {scene.index} frame {t} track {a['track_id']}"
    assert checked > 0  # the test must actually look at close encounters


def test_heading_matches_motion_and_velocity(store):
    for scene in store:
        tensor = scene.agent_tensor()
        both = tensor.available[1:] & tensor.available[:-1]
        step = tensor.centroid[1:] - tensor.centroid[:-1]
        moving = both & (np.linalg.norm(step, axis=-1) > 0.05)
        travel = np.arctan2(step[..., 1], step[..., 0])[moving]
        heading = tensor.yaw[:-1][moving]
        assert np.abs(np.angle(np.exp(1j * (travel - heading)))).max() < 0.1
        fast = np.linalg.norm(scene.agents["velocity"], axis=1) > 0.1
        vel_dir = np.arctan2(scene.agents["velocity"][fast, 1], scene.agents["velocity"][fast, 0])
        assert np.abs(np.angle(np.exp(1j * (vel_dir - scene.agents["yaw"][fast])))).max() < 1e-3


def test_agents_stay_near_lane_centerlines(store):
    lanes = road_layout(NUM_FRAMES)["lanes"]
    points = np.concatenate(list(lanes.values()))
    centroids = np.concatenate([scene.agents["centroid"] for scene in store])
    sample = centroids[:: max(1, len(centroids) // 2000)]
    dist = np.sqrt(((sample[:, None, :] - points[None, :, :]) ** 2).sum(-1)).min(1)
    assert dist.max() < 0.3  # centerlines are sampled every 0.5 m


def test_agents_in_range_and_tracks_unique(store):
    for scene in store:
        ego = scene.ego_positions()
        for t in (0, scene.num_frames // 2, scene.num_frames - 1):
            rows = scene.agents_of_frame(t)
            assert np.all(np.linalg.norm(rows["centroid"] - ego[t], axis=1) < 50.0)
            assert np.unique(rows["track_id"]).size == len(rows)
        tensor = scene.agent_tensor()  # raises if a track id repeats within a frame
        assert tensor.track_id.min() >= 1
        # Agents come and go as the ego moves: some tracks are not visible in every frame.
        assert not tensor.available.all(axis=0).all()


def test_labels_and_extents(store):
    agents = np.concatenate([scene.agents for scene in store])
    probs = agents["label_probabilities"]
    assert np.all(probs.sum(1) == 1) and np.all(probs.max(1) == 1)
    label = probs.argmax(1)
    car, ped, cyc = label_index("CAR"), label_index("PEDESTRIAN"), label_index("CYCLIST")
    assert set(np.unique(label)) <= {car, ped, cyc}
    assert (label == car).any() and (label == ped).any()
    length = agents["extent"][:, 0]
    assert np.all((length[label == car] > 3.5) & (length[label == car] < 5.5))
    assert np.all(length[label == ped] < 1.0)


def test_traffic_light_faces(store):
    scene = store.scene(0)
    faces = scene.traffic_light_faces
    if len(faces):
        status = faces["traffic_light_face_status"]
        assert np.all(status.sum(1) == 1)
        for t in range(scene.num_frames):
            per = scene.tl_faces_of_frame(t)
            for light in np.unique(per["traffic_light_id"]):
                assert per["traffic_light_face_status"][per["traffic_light_id"] == light][:, 0].sum() == 1


def test_layout_in_attrs(store):
    layout = store.attrs["driveeval_layout"]
    assert set(layout["lanes"]) == set(road_layout(NUM_FRAMES)["lanes"])
    assert layout["generator"]["seed"] == 11


def test_long_scene_and_knobs():
    arrays = generate_scenes(1, 248, seed=2, red_light_fraction=1.0, car_density=0.05)
    assert len(arrays.frames) == 248
    with pytest.raises(TypeError, match="unknown scene generator knob"):
        generate_scenes(1, 10, seed=0, nonsense=1)
