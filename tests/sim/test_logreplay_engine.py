"""Closed-loop engine: oracle replay, collisions, freeze, drift resets, batching, failures."""
from __future__ import annotations

import io

import numpy as np
import pytest
torch = pytest.importorskip("torch")  # a Python without torch skips the file
from shapely.geometry import Polygon  # noqa: E402

from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset  # noqa: E402
from pytest_driveeval.metrics.collisions import FRONT  # noqa: E402
from pytest_driveeval.policies.baselines import ConstantVelocityPolicy, ReplayLogPolicy  # noqa: E402
from pytest_driveeval.sim.logreplay import (EGO_EXTENT, UnrollConfig, build_batch, scenes_from_arrays, stack_scenes,  # noqa: E402
                                            unroll)
from pytest_driveeval.synth.scenegen import generate_scenes  # noqa: E402

STOP_SCENE = 2  # of red_light_log(): CV runs into a car stopped at the red light


@pytest.fixture(scope="module")
def red_light_log():
    return stack_scenes(scenes_from_arrays(generate_scenes(6, 100, seed=0, red_light_fraction=1.0)))


@pytest.fixture(scope="module")
def mixed_log():
    """Scenes of different lengths in one batch."""
    short = scenes_from_arrays(generate_scenes(2, 60, seed=1))
    long = scenes_from_arrays(generate_scenes(2, 90, seed=2))
    return stack_scenes(short + long, scene_ids=[10, 11, 12, 13])


def _assert_oracle(result):
    assert result.errors == [None] * len(result.errors)
    v = result.valid
    assert np.all(v.sum(1) > 0)
    assert np.nanmax(result.displacement_error) < 1e-4
    assert not result.collision_kind[v].any()
    assert not result.reset.any() and not result.frozen.any()


def test_oracle_replay_on_real_sample(shared_data):
    scene = L5Dataset.open(shared_data / "l5kit" / "single_scene.zarr").scene(0)
    result = unroll([scene], ReplayLogPolicy())
    _assert_oracle(result)
    assert result.valid.sum() == scene.num_frames
    assert np.nanmax(np.abs(result.speed_difference)) < 1e-2


def test_oracle_replay_on_generated_scenes(mixed_log):
    result = unroll(mixed_log, ReplayLogPolicy())
    _assert_oracle(result)
    assert result.valid.sum(1).tolist() == [60, 60, 90, 90]


def _first_cv_overlap(log, s, start):
    """Independent expectation: constant velocity is a straight line; shapely per frame."""
    v = log.ego_xy[s, start] - log.ego_xy[s, start - 1]
    yaw = log.ego_yaw[s, start]
    c, sn = np.cos(yaw), np.sin(yaw)
    for t in range(start, int(log.num_frames[s])):
        xy = log.ego_xy[s, start] + (t - start) * v
        ego = Polygon(_corners(xy, c, sn, EGO_EXTENT))
        for a in np.flatnonzero(log.available[s, t]):
            ya = float(log.agent_yaw[s, t, a])
            box = Polygon(_corners(log.agent_xy[s, t, a], np.cos(ya), np.sin(ya), log.agent_extent[s, t, a]))
            if ego.intersects(box):
                return t, int(log.track_id[s, t, a]), a
    return None


def _corners(xy, c, s, ext):
    hl, hw = ext[0] / 2, ext[1] / 2
    return [(xy[0] + c * dx - s * dy, xy[1] + s * dx + c * dy) for dx, dy in ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))]


@pytest.mark.filterwarnings("ignore:`torch.jit.*` is deprecated:DeprecationWarning")  # TorchScript on purpose
def test_constant_velocity_runs_into_stopped_car(red_light_log):
    cfg = UnrollConfig(start_frame=5)
    result = unroll(red_light_log, torch.jit.script(ConstantVelocityPolicy()), cfg)
    expected_frame, expected_track, col = _first_cv_overlap(red_light_log, STOP_SCENE, 5)
    frames = np.flatnonzero(result.collision_kind[STOP_SCENE])
    assert frames[0] == expected_frame
    assert result.collision_kind[STOP_SCENE, expected_frame] == FRONT
    assert result.collision_at_fault[STOP_SCENE, expected_frame]
    assert result.collision_track_id[STOP_SCENE, expected_frame] == expected_track
    # ... and the car it hits is waiting at the light.
    assert np.linalg.norm(red_light_log.agent_velocity[STOP_SCENE, expected_frame, col]) < 0.5


def test_freeze_on_collision_holds_the_ego(red_light_log):
    result = unroll(red_light_log, ConstantVelocityPolicy(), UnrollConfig(start_frame=5, freeze_on_collision=True))
    s = STOP_SCENE
    hit = int(np.flatnonzero(result.collision_kind[s])[0])
    assert result.frozen[s, hit + 1]
    np.testing.assert_array_equal(result.driven_xy[s, hit + 1], result.driven_xy[s, hit])
    # Every frozen frame follows a collision frame, and every collision with a next frame freezes it.
    for k in range(len(result.errors)):
        v = np.flatnonzero(result.valid[k])
        coll = result.collision_kind[k, v[:-1]] != 0
        np.testing.assert_array_equal(result.frozen[k, v[1:]], coll)


def test_drift_reset_puts_the_ego_back_on_the_log(red_light_log):
    result = unroll(red_light_log, ConstantVelocityPolicy(), UnrollConfig(start_frame=5, drift_threshold=2.0))
    assert result.reset.any()
    s, t = np.nonzero(result.reset)
    np.testing.assert_array_equal(result.driven_xy[s, t], result.logged_xy[s, t])
    assert np.all(result.displacement_error[s, t] > 2.0)
    actual = np.linalg.norm(result.driven_xy - result.logged_xy, axis=-1)[result.valid]
    assert actual.max() <= 2.0 + 1e-9


def test_batched_equals_one_by_one(mixed_log):
    policy = ConstantVelocityPolicy()
    cfg = UnrollConfig(start_frame=3, drift_threshold=4.0, freeze_on_collision=True)
    together = unroll(mixed_log, policy, cfg)
    for i in range(len(mixed_log.scene_ids)):
        alone = unroll(mixed_log.take([i]), policy, cfg)
        for name in ("driven_xy", "driven_yaw", "valid", "collision_kind", "reset", "frozen"):
            np.testing.assert_array_equal(getattr(alone, name)[0], getattr(together, name)[i], err_msg=name)
        np.testing.assert_allclose(alone.distance_to_reference[0], together.distance_to_reference[i], atol=1e-9)


def test_unroll_is_deterministic(mixed_log):
    a = unroll(mixed_log, ConstantVelocityPolicy(), UnrollConfig(kinematic=True))
    b = unroll(mixed_log, ConstantVelocityPolicy(), UnrollConfig(kinematic=True))
    np.testing.assert_array_equal(a.driven_xy, b.driven_xy)
    np.testing.assert_array_equal(a.collision_kind, b.collision_kind)


class _Sabotage(torch.nn.Module):
    """Constant velocity, but broken at one forward in a chosen way."""

    def __init__(self, at: int, how: str, row: int = 1):
        super().__init__()
        self.inner, self.at, self.how, self.row, self.calls = ConstantVelocityPolicy(), at, how, row, 0

    def forward(self, data):
        out = self.inner(data)
        self.calls += 1
        if self.calls - 1 == self.at:
            if self.how == "nan":
                out["positions"][self.row, 0, 0] = float("nan")
            elif self.how == "shape":
                out["positions"] = out["positions"][..., :1]
            elif self.how == "raise":
                raise RuntimeError("boom in the model")
        return out


def test_nan_stops_only_that_scene(mixed_log):
    clean = unroll(mixed_log, ConstantVelocityPolicy())
    broken = unroll(mixed_log, _Sabotage(at=7, how="nan", row=1))
    assert broken.errors[1] == "scene 11: model returned NaN/inf in its first pose at frame 7"
    assert [e is None for e in broken.errors] == [True, False, True, True]
    assert np.flatnonzero(broken.valid[1]).max() == 7
    for i in (0, 2, 3):
        np.testing.assert_array_equal(broken.driven_xy[i], clean.driven_xy[i])
        np.testing.assert_array_equal(broken.valid[i], clean.valid[i])
    np.testing.assert_array_equal(broken.driven_xy[1, :8], clean.driven_xy[1, :8])


def test_wrong_shape_fails_every_scene_with_a_clear_message(mixed_log):
    result = unroll(mixed_log, _Sabotage(at=4, how="shape"))
    msg = result.errors[0]
    assert all(e == msg for e in result.errors)
    assert "frame 4" in msg and "[10, 11, 12, 13]" in msg
    assert "'positions'" in msg and "(B=4, T, 2)" in msg and "(4, 12, 1)" in msg
    assert result.valid.sum(1).tolist() == [5] * 4  # frames 0..4 kept


def test_policy_exception_fails_its_forward_only(mixed_log):
    result = unroll(mixed_log, _Sabotage(at=0, how="raise"))
    assert all("RuntimeError: boom in the model" in e and "frame 0" in e for e in result.errors)
    missing = unroll(mixed_log, lambda batch: {"positions": batch["target_positions"]})
    assert "no 'yaws' key" in missing.errors[0]


def test_scene_that_cannot_start_is_reported(mixed_log):
    result = unroll(mixed_log, ReplayLogPolicy(), UnrollConfig(start_frame=70))
    assert "start_frame 70" in result.errors[0] and result.errors[2] is None
    assert not result.valid[:2].any() and result.valid[2:].any()


def test_num_steps_and_timing(mixed_log):
    result = unroll(mixed_log, ReplayLogPolicy(), UnrollConfig(start_frame=2, num_steps=5))
    assert result.valid.sum(1).tolist() == [5] * 4
    assert result.forwards == 4 and result.scene_steps == 16
    assert 0 < result.model_time < result.total_time


@pytest.mark.filterwarnings("ignore:`torch.jit.*` is deprecated:DeprecationWarning")  # TorchScript on purpose
def test_baselines_torchscript_round_trip(mixed_log):
    batch = build_batch(mixed_log, np.arange(4), np.full(4, 10), mixed_log.ego_xy, mixed_log.ego_yaw)
    for module in (ConstantVelocityPolicy(), ReplayLogPolicy()):
        buf = io.BytesIO()
        torch.jit.save(torch.jit.script(module), buf)
        buf.seek(0)
        loaded = torch.jit.load(buf)
        eager, scripted = module(batch), loaded(batch)
        for key in ("positions", "yaws"):
            torch.testing.assert_close(eager[key], scripted[key])
        assert eager["positions"].shape == (4, 12, 2) and eager["yaws"].shape == (4, 12, 1)


def test_progress_counts_the_steps_all_scenes_take_together(mixed_log):
    seen = []
    cfg = UnrollConfig(start_frame=5)
    unroll(mixed_log, ConstantVelocityPolicy(), cfg, progress=lambda done, total: seen.append((done, total)))
    steps = int(mixed_log.num_frames.max()) - 5
    assert seen == [(done, steps) for done in range(steps + 1)]
