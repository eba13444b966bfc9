"""Log replay as l5kit does it, on scenes built by hand: the collision partner in
row order, which agents replay, a start past the end."""
from __future__ import annotations

import numpy as np

from pytest_driveeval.io.l5kit_zarr import (
    AGENT_DTYPE,
    FRAME_DTYPE,
    TL_FACE_DTYPE,
    L5Scene,
    label_index,
)
from pytest_driveeval.metrics.collisions import FRONT, REAR
from pytest_driveeval.policies.baselines import ReplayLogPolicy
from pytest_driveeval.sim.logreplay import UnrollConfig, stack_scenes, unroll

CAR, PEDESTRIAN = label_index("CAR"), label_index("PEDESTRIAN")


def tiny_scene(rows_per_frame, ego_xy=(0.0, 0.0)) -> L5Scene:
    """A parked ego at ``ego_xy`` (yaw 0) and, per frame, agent rows in the
    order given: (track id, x, y, label, probability); boxes 4 x 2 m."""
    frames = np.zeros(len(rows_per_frame), FRAME_DTYPE)
    frames["ego_translation"][:, :2] = ego_xy
    frames["ego_rotation"] = np.eye(3)
    counts = [len(rows) for rows in rows_per_frame]
    ends = np.cumsum(counts)
    frames["agent_index_interval"] = np.stack([ends - counts, ends], axis=1)
    agents = np.zeros(int(ends[-1]), AGENT_DTYPE)
    flat = [row for rows in rows_per_frame for row in rows]
    for agent, (track, x, y, label, prob) in zip(agents, flat):
        agent["track_id"], agent["centroid"], agent["extent"] = track, (x, y), (4.0, 2.0, 1.5)
        agent["label_probabilities"][label] = prob
    return L5Scene(index=0, host="tiny", start_time=0, end_time=0, frames=frames, agents=agents,
                   traffic_light_faces=np.zeros(0, TL_FACE_DTYPE))


FRONT_4 = (4, 3.6, 0.1, CAR, 0.9)
REAR_9 = (9, -3.6, 0.0, CAR, 0.9)


def test_partner_is_the_first_overlapping_agent_in_the_frames_row_order():
    # Frame 1 stores track 9 (behind) first, frame 2 track 4 (ahead) first.
    # Columns are packed by track id, so the lowest column is track 4 in both.
    scene = tiny_scene([[], [REAR_9, FRONT_4], [FRONT_4, REAR_9]])
    log = stack_scenes([scene])
    assert log.track_id[0, 1, log.frame_row[0, 1] == 0].tolist() == [9]
    r = unroll(log, ReplayLogPolicy(), UnrollConfig())
    assert r.collision_kind[0].tolist() == [0, REAR, FRONT]
    assert r.collision_track_id[0].tolist() == [-1, 9, 4]


def test_a_start_past_the_end_is_each_scenes_error_not_an_exception():
    log = stack_scenes([tiny_scene([[FRONT_4]] * 3)])
    r = unroll(log, ReplayLogPolicy(), UnrollConfig(start_frame=100_000))
    assert not r.valid.any()
    assert r.errors == ["scene 0: start_frame 100000 is not before its end (3 frames, num_steps None)"]
