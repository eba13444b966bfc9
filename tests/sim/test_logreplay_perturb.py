"""A perturbed closed-loop start: the past moves rigidly with it (so it stays drivable), agents replay faster or slower."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")  # a Python without torch skips the file

from pytest_driveeval.policies.baselines import ConstantVelocityPolicy  # noqa: E402
from pytest_driveeval.sim.logreplay import (UnrollConfig, perturb_history, scale_agent_time, scenes_from_arrays,  # noqa: E402
                                            stack_scenes, unroll)
from pytest_driveeval.synth.scenegen import generate_scenes  # noqa: E402

NO_CHANGE = [0.0, 0.0, 0.0, 1.0]


def curve(scenes=2, frames=30, speed=10.0, dt=0.1, yaw0=0.3, turn=0.02):
    """A path that turns ``turn`` rad per frame, yaw along the path."""
    yaw = yaw0 + turn * np.arange(frames)
    steps = speed * dt * np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)
    xy = np.cumsum(steps, axis=0) - steps[0]
    return np.broadcast_to(xy, (scenes, frames, 2)).copy(), np.broadcast_to(yaw, (scenes, frames)).copy()


def headings(xy):
    d = np.diff(xy, axis=-2)
    return np.arctan2(d[..., 1], d[..., 0])


def test_no_change_gives_back_the_log_bit_for_bit():
    xy, yaw = curve()
    out_xy, out_yaw = perturb_history(xy, yaw, start=15, perturbation=np.tile(NO_CHANGE, (2, 1)))
    assert np.array_equal(out_xy, xy) and np.array_equal(out_yaw, yaw)


def test_the_offset_is_in_the_egos_frame_at_the_start_and_the_future_is_the_logs():
    xy, yaw = curve()
    p = np.array([[1.5, 0.0, 0.0, 1.0], [0.0, -2.0, 0.0, 1.0]])
    out_xy, out_yaw = perturb_history(xy, yaw, start=15, perturbation=p)
    left = np.array([-np.sin(yaw[0, 15]), np.cos(yaw[0, 15])])
    ahead = np.array([np.cos(yaw[0, 15]), np.sin(yaw[0, 15])])
    assert np.allclose(out_xy[0, 15] - xy[0, 15], 1.5 * left)
    assert np.allclose(out_xy[1, 15] - xy[1, 15], -2.0 * ahead)
    assert np.array_equal(out_xy[:, 16:], xy[:, 16:]) and np.array_equal(out_yaw[:, 16:], yaw[:, 16:])


@pytest.mark.parametrize("heading", [0.15, -0.3])
def test_the_past_is_the_logged_motion_moved_rigidly_so_it_is_as_drivable(heading):
    xy, yaw = curve(turn=0.02)
    out_xy, out_yaw = perturb_history(xy, yaw, start=15, perturbation=np.array([[0.8, -0.5, heading, 1.0]] * 2))
    # Same speeds, same turning per frame: nothing harder for the car than the log was.
    np.testing.assert_allclose(np.linalg.norm(np.diff(out_xy[0, :16], axis=0), axis=1),
                               np.linalg.norm(np.diff(xy[0, :16], axis=0), axis=1), atol=1e-12)
    np.testing.assert_allclose(np.diff(headings(out_xy[0, :16])), np.diff(headings(xy[0, :16])), atol=1e-12)
    # It arrives at the start along the perturbed heading: no sideways jump into the start pose.
    arrival = headings(out_xy[0, 14:16])[0]
    assert np.angle(np.exp(1j * (arrival - headings(xy[0, 14:16])[0] - heading))) == pytest.approx(0, abs=1e-12)
    assert out_yaw[0, 15] == pytest.approx(yaw[0, 15] + heading)


def test_speed_scale_scales_the_speeds_of_the_past_and_keeps_the_start():
    xy, yaw = curve(speed=10.0)
    out_xy, _ = perturb_history(xy, yaw, start=15, perturbation=np.tile([0, 0, 0, 1.3], (2, 1)))
    steps = np.linalg.norm(np.diff(out_xy[0, :16], axis=0), axis=1) / 0.1
    assert np.allclose(steps, 13.0) and np.array_equal(out_xy[:, 15], xy[:, 15])


def test_bad_shapes_and_frames_are_refused():
    xy, yaw = curve()
    with pytest.raises(ValueError, match=r"perturbation must be \(2, 4\)"):
        perturb_history(xy, yaw, 15, np.zeros((3, 4)))
    with pytest.raises(ValueError, match="start frame 40 is outside the 30 frames"):
        perturb_history(xy, yaw, 40, np.zeros((2, 4)))


@pytest.fixture(scope="module")
def log():
    return stack_scenes(scenes_from_arrays(generate_scenes(2, 80, seed=3)), scene_ids=[0, 1])


def test_agents_replayed_twice_as_fast_are_where_the_log_had_them_twice_as_far_from_the_start(log):
    start = 20
    fast = scale_agent_time(log, start, np.array([2.0, 1.0]))
    assert fast.agent_xy[1] is not log.agent_xy[1] and np.array_equal(fast.agent_xy[1], log.agent_xy[1])
    for t in (10, 25, 40):
        logged = 2 * t - start
        cells = log.available[0, logged] & fast.available[0, t]
        assert cells.any()
        np.testing.assert_array_equal(fast.track_id[0, t][cells], log.track_id[0, logged][cells])
        np.testing.assert_allclose(fast.agent_xy[0, t][cells], log.agent_xy[0, logged][cells])
        np.testing.assert_allclose(fast.agent_velocity[0, t][cells], 2 * log.agent_velocity[0, logged][cells])
    # Past the end of the log there is nothing left to replay.
    assert not fast.available[0, (log.num_frames[0] - 1 + start) // 2 + 1:].any()


def test_agents_between_logged_frames_are_interpolated(log):
    slow = scale_agent_time(log, 20, np.array([0.5, 0.5]))
    t = 31  # logged time 25.5
    both = log.available[0, 25] & log.available[0, 26] & (log.track_id[0, 25] == log.track_id[0, 26])
    assert both.any()
    np.testing.assert_allclose(slow.agent_xy[0, t][both], (log.agent_xy[0, 25][both] + log.agent_xy[0, 26][both]) / 2)


def test_no_scale_is_the_log_itself(log):
    assert scale_agent_time(log, 20, np.ones(2)) is log
    with pytest.raises(ValueError, match="finite and > 0"):
        scale_agent_time(log, 20, np.array([0.0, 1.0]))


def test_unroll_with_no_change_is_bit_identical_and_rows_do_not_see_each_other(log):
    policy, cfg = ConstantVelocityPolicy(), UnrollConfig(start_frame=10, drift_threshold=5.0, freeze_on_collision=True)
    plain = unroll(log, policy, cfg)
    same = unroll(log, policy, cfg, start_perturbation=np.tile(NO_CHANGE, (2, 1)))
    for name in ("driven_xy", "driven_yaw", "collision_kind", "displacement_error", "speed_difference", "reset"):
        np.testing.assert_array_equal(getattr(same, name), getattr(plain, name), err_msg=name)
    p = np.array([[1.0, 0.0, 0.1, 1.1], NO_CHANGE])
    both = unroll(log, policy, cfg, start_perturbation=p)
    alone = unroll(log.take([0]), policy, cfg, start_perturbation=p[:1])
    np.testing.assert_array_equal(both.driven_xy[0], alone.driven_xy[0])
    np.testing.assert_array_equal(both.driven_xy[1], plain.driven_xy[1])
    # The perturbed ego starts off the log, and the drift is measured against the log.
    assert both.displacement_error[0, 10] == pytest.approx(1.0)


def test_cells_and_window_columns_computed_once_and_shared_by_copies_unroll_bit_identically(log):
    from pytest_driveeval.sim.logreplay import window_columns
    from pytest_driveeval.sim.logreplay.agents import LogCells

    policy, cfg = ConstantVelocityPolicy(), UnrollConfig(start_frame=10, drift_threshold=5.0, freeze_on_collision=True)
    rows = np.array([1, 0, 1, 1])
    p = np.array([[0.5, 0.0, 0.05, 1.0], NO_CHANGE, [-1.0, 0.5, 0.0, 0.9], NO_CHANGE])
    own = unroll(log.take(rows), policy, cfg, start_perturbation=p)
    columns, ok = window_columns(log, cfg.history_frames)
    shared = unroll(log.take(rows), policy, cfg, start_perturbation=p, cells=LogCells(log).rows_of(rows),
                    candidates=(columns[rows], ok[rows]))
    for name in ("driven_xy", "driven_yaw", "collision_kind", "collision_track_id", "displacement_error", "reset"):
        np.testing.assert_array_equal(getattr(shared, name), getattr(own, name), err_msg=name)
    # Shared, not copied: the copies read the packing of the two scenes.
    cells = LogCells(log)
    assert cells.rows_of(rows).sel is cells.sel and cells.rows_of(rows).rows_of([2, 0]).row_of.tolist() == [1, 1]
