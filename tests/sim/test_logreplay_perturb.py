"""A perturbed closed-loop start: the offset is reached at the start frame, blended in smoothly before it."""
from __future__ import annotations

import numpy as np
import pytest

from pytest_driveeval.sim.logreplay.perturb import perturb_history


def straight(scenes=2, frames=30, speed=10.0, dt=0.1, yaw=0.3):
    t = np.arange(frames) * dt
    xy = np.stack([speed * t * np.cos(yaw), speed * t * np.sin(yaw)], axis=-1)
    return np.broadcast_to(xy, (scenes, frames, 2)).copy(), np.full((scenes, frames), yaw)


def test_no_change_gives_back_the_log_bit_for_bit():
    xy, yaw = straight()
    out_xy, out_yaw = perturb_history(xy, yaw, start=15, history=10, perturbation=np.tile([0, 0, 0, 1.0], (2, 1)))
    assert np.array_equal(out_xy, xy) and np.array_equal(out_yaw, yaw)


def test_the_offset_is_in_the_egos_frame_at_the_start_and_blends_in_smoothly():
    xy, yaw = straight(yaw=0.3)
    p = np.array([[1.5, 0.0, 0.1, 1.0], [0.0, -2.0, 0.0, 1.0]])
    out_xy, out_yaw = perturb_history(xy, yaw, start=15, history=10, perturbation=p)
    left = np.array([-np.sin(0.3), np.cos(0.3)])
    assert np.allclose(out_xy[0, 15] - xy[0, 15], 1.5 * left)
    assert np.allclose(out_xy[1, 15] - xy[1, 15], -2.0 * np.array([np.cos(0.3), np.sin(0.3)]))
    assert out_yaw[0, 15] == pytest.approx(0.4) and out_yaw[1, 15] == pytest.approx(0.3)
    # Before the window and after the start the log is untouched; the first frame of the window too.
    for frames in (slice(0, 6), slice(16, None)):
        assert np.array_equal(out_xy[:, frames], xy[:, frames])
    assert np.allclose(out_xy[:, 5], xy[:, 5])
    # No jump: the lateral offset grows monotonically, by at most 1.5 * 1.5 / 10 per frame (smoothstep's peak slope).
    lateral = (out_xy[0, 5:16] - xy[0, 5:16]) @ left
    assert np.all(np.diff(lateral) >= 0) and np.diff(lateral).max() <= 1.5 * 1.5 / 10 + 1e-9


def test_speed_scale_stretches_the_past_so_the_inferred_speed_scales():
    xy, yaw = straight(speed=10.0)
    out_xy, _ = perturb_history(xy, yaw, start=15, history=10, perturbation=np.tile([0, 0, 0, 1.3], (2, 1)))
    steps = np.linalg.norm(np.diff(out_xy[0, 5:16], axis=0), axis=1) / 0.1
    assert np.allclose(steps, 13.0) and np.array_equal(out_xy[:, 15], xy[:, 15])


def test_bad_shapes_and_frames_are_refused():
    xy, yaw = straight()
    with pytest.raises(ValueError, match=r"perturbation must be \(2, 4\)"):
        perturb_history(xy, yaw, 15, 10, np.zeros((3, 4)))
    with pytest.raises(ValueError, match="start frame 40 is outside the 30 frames"):
        perturb_history(xy, yaw, 40, 10, np.zeros((2, 4)))
