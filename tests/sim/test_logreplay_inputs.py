"""Policy input: l5kit keys and shapes, frames, agent selection, driven history."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")  # a Python without torch skips the file

from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset  # noqa: E402
from pytest_driveeval.sim.logreplay import build_batch, collate_training_samples, scenes_from_arrays, stack_scenes  # noqa: E402
from pytest_driveeval.synth.scenegen import generate_scenes  # noqa: E402

H, F, N = 10, 12, 30
SHAPES = {
    "history_positions": (H + 1, 2), "history_yaws": (H + 1, 1), "history_availabilities": (H + 1,),
    "target_positions": (F, 2), "target_yaws": (F, 1), "target_availabilities": (F,),
    "centroid": (2,), "yaw": (), "extent": (3,), "speed": (), "world_from_agent": (3, 3), "agent_from_world": (3, 3),
    "all_other_agents_history_positions": (N, H + 1, 2), "all_other_agents_history_yaws": (N, H + 1, 1),
    "all_other_agents_history_extents": (N, H + 1, 2), "all_other_agents_history_availability": (N, H + 1),
    "all_other_agents_types": (N,),
}


@pytest.fixture(scope="module")
def real_scene(shared_data):
    return L5Dataset.open(shared_data / "l5kit" / "single_scene.zarr").scene(0)


@pytest.fixture(scope="module")
def gen_log():
    return stack_scenes(scenes_from_arrays(generate_scenes(3, 60, seed=4)))


def test_keys_shapes_and_dtypes(gen_log):
    batch = collate_training_samples(gen_log, [0, 5, 59])
    assert set(batch) == set(SHAPES)
    for key, shape in SHAPES.items():
        assert tuple(batch[key].shape) == (3,) + shape, key
        assert batch[key].dtype.is_floating_point and batch[key].element_size() == 4, key


def test_frames_and_availability(gen_log):
    b = collate_training_samples(gen_log, [0, 5, 55])
    assert b["history_availabilities"][0].tolist() == [1] + [0] * H
    assert b["history_availabilities"][1].tolist() == [1] * 6 + [0] * 5
    assert b["target_availabilities"][2].tolist() == [1] * 4 + [0] * 8  # frames 56..59 exist
    assert float(b["history_positions"][:, 0].abs().max()) == 0.0  # index 0 is the current pose
    assert float(b["history_yaws"][:, 0].abs().max()) == 0.0
    # Target k is the logged pose at t+1+k, in the ego frame: back to world matches the log.
    w = b["world_from_agent"][1].double().numpy()
    tp = b["target_positions"][1].double().numpy()
    world = tp @ w[:2, :2].T + w[:2, 2]
    np.testing.assert_allclose(world, gen_log.ego_xy[0, 6:18], atol=1e-4)
    np.testing.assert_allclose(b["world_from_agent"][1].double().numpy() @ b["agent_from_world"][1].double().numpy(),
                               np.eye(3), atol=1e-5)


def test_closed_loop_history_is_the_driven_one(gen_log):
    driven_xy, driven_yaw = gen_log.ego_xy.copy(), gen_log.ego_yaw.copy()
    driven_xy[1, 20:31] += [0.0, 3.0]  # the ego drove 3 m to the left of the log
    b = build_batch(gen_log, np.array([1]), np.array([30]), driven_xy, driven_yaw)
    logged = collate_training_samples(gen_log, [30], row=1)
    np.testing.assert_allclose(b["history_positions"], logged["history_positions"], atol=1e-4)  # same shape of path
    np.testing.assert_allclose(b["centroid"][0].numpy(), gen_log.ego_xy[1, 30] + [0, 3], atol=1e-3)
    # ... but the logged future is now seen from 3 m off.
    assert not np.allclose(b["target_positions"].numpy(), logged["target_positions"].numpy(), atol=0.5)


def _agents_reference(scene, t, radius=35.0):
    """Brute force from the structured arrays: relevant agents in range now, sorted by distance."""
    rows = scene.agents_of_frame(t)
    keep = np.isin(rows["label_probabilities"].argmax(1), np.arange(3, 16))
    rows = rows[keep]
    centre = scene.ego_positions()[t]
    d = np.linalg.norm(rows["centroid"] - centre, axis=1)
    rows, d = rows[d < radius], d[d < radius]
    return rows[np.argsort(d, kind="stable")]


def test_other_agents_match_a_per_agent_reference(real_scene):
    t = 120
    b = collate_training_samples(real_scene, [t])
    expected = _agents_reference(real_scene, t)
    assert len(expected) > 3
    n = min(len(expected), N)
    got_now = b["all_other_agents_history_positions"][0, :n, 0].double().numpy()
    w = b["world_from_agent"][0].double().numpy()
    np.testing.assert_allclose(got_now @ w[:2, :2].T + w[:2, 2], expected["centroid"][:n], atol=1e-3)
    assert b["all_other_agents_history_availability"][0, :n, 0].all()
    # History of the nearest agent: per frame, the same track id looked up by hand.
    track = expected["track_id"][0]
    for k in range(H + 1):
        rows = real_scene.agents_of_frame(t - k)
        hit = rows[rows["track_id"] == track]
        assert bool(b["all_other_agents_history_availability"][0, 0, k]) == bool(len(hit))
        if len(hit):
            world = b["all_other_agents_history_positions"][0, 0, k].double().numpy() @ w[:2, :2].T + w[:2, 2]
            np.testing.assert_allclose(world, hit["centroid"][0], atol=1e-3)
            ext = b["all_other_agents_history_extents"][0, 0, k].numpy()
            np.testing.assert_allclose(ext, hit["extent"][0, :2], atol=1e-6)
    assert int(b["all_other_agents_types"][0, 0]) == int(expected["label_probabilities"][0].argmax())


def test_shared_columns_never_mix_tracks(real_scene):
    log = stack_scenes([real_scene])
    assert log.shape[2] < 400  # ~1650 tracks packed into a few hundred columns
    frames = np.arange(12, real_scene.num_frames, 31)
    b = collate_training_samples(log, frames)
    avail = b["all_other_agents_history_availability"].numpy().astype(bool)
    pos = b["all_other_agents_history_positions"].double().numpy()
    # One slot, one track: identify the track by its position in its latest
    # available frame, then every other available frame must be that track.
    for row, t in enumerate(frames):
        w = b["world_from_agent"][row].double().numpy()
        for slot in np.flatnonzero(avail[row].any(1)):
            ks = np.flatnonzero(avail[row, slot])
            tracks = set()
            for k in ks:
                rows = real_scene.agents_of_frame(t - k)
                world = pos[row, slot, k] @ w[:2, :2].T + w[:2, 2]
                d = np.linalg.norm(rows["centroid"] - world, axis=1)
                assert d.min() < 1e-3
                tracks.add(int(rows["track_id"][d.argmin()]))
            assert len(tracks) == 1, (t, slot, tracks)


def test_speed_is_the_backward_difference(gen_log):
    b = collate_training_samples(gen_log, [10])
    step = np.linalg.norm(gen_log.ego_xy[0, 10] - gen_log.ego_xy[0, 9])
    assert float(b["speed"][0]) == pytest.approx(step / 0.1, rel=1e-5)


def test_bad_frame_is_an_index_error(gen_log):
    with pytest.raises(IndexError, match="frame 60 outside"):
        collate_training_samples(gen_log, [60])
