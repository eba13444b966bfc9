"""Log replay as l5kit does it, on scenes built by hand: the collision partner in
row order, which agents replay, a start past the end."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")  # a Python without torch skips the file

from pytest_driveeval.io.l5.l5kit_zarr import (  # noqa: E402
    AGENT_DTYPE,
    FRAME_DTYPE,
    TL_FACE_DTYPE,
    L5Scene,
    label_index,
)
from pytest_driveeval.metrics.collisions import FRONT, REAR  # noqa: E402
from pytest_driveeval.policies.baselines import ReplayLogPolicy  # noqa: E402
from pytest_driveeval.sim.logreplay import (  # noqa: E402
    ReplayedAgents,
    UnrollConfig,
    keep_agents,
    stack_scenes,
    unroll,
)

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


def test_label_filter_keeps_rows_above_the_threshold_one_by_one():
    scene = tiny_scene([[(1, 10.0, 0.0, CAR, 0.9), (2, 20.0, 0.0, PEDESTRIAN, 0.9), (3, 30.0, 0.0, CAR, 0.5)],
                        [(3, 30.0, 0.0, CAR, 0.6), (1, 10.0, 0.0, CAR, 0.4)]])
    kept = keep_agents(scene, ReplayedAgents(labels=["CAR"]))
    assert [kept.agents_of_frame(t)["track_id"].tolist() for t in (0, 1)] == [[1], [3]]
    both = keep_agents(scene, ReplayedAgents(labels=["PERCEPTION_LABEL_CAR", "PEDESTRIAN"], label_threshold=0.45))
    assert [both.agents_of_frame(t)["track_id"].tolist() for t in (0, 1)] == [[1, 2, 3], [3]]
    assert keep_agents(scene, ReplayedAgents()) is scene


def test_within_at_start_keeps_the_start_frames_near_cars_in_every_frame():
    # At the start frame (1): track 1 is a near car, 2 a near pedestrian, 3 a car
    # 60 m away; track 4 appears later.  Track 1 stays even where it is far and
    # barely a car, as l5kit's disable_new_agents allows by track id.
    scene = tiny_scene([[(2, 5.0, 0.0, PEDESTRIAN, 0.9), (1, 80.0, 0.0, CAR, 0.9)],
                        [(1, 49.0, 0.0, CAR, 0.9), (2, 5.0, 0.0, PEDESTRIAN, 0.9), (3, 60.0, 0.0, CAR, 0.9)],
                        [(4, 4.0, 0.0, CAR, 0.9), (3, 6.0, 0.0, CAR, 0.9), (1, 120.0, 0.0, CAR, 0.1)]])
    kept = keep_agents(scene, ReplayedAgents(labels=["CAR"], within_at_start=50.0), start_frame=1)
    assert [kept.agents_of_frame(t)["track_id"].tolist() for t in range(3)] == [[1], [1], [1]]
    assert kept.agents_of_frame(2)["centroid"].tolist() == [[120.0, 0.0]]
    anyone = keep_agents(scene, ReplayedAgents(within_at_start=50.0), start_frame=1)
    assert [anyone.agents_of_frame(t)["track_id"].tolist() for t in range(3)] == [[2, 1], [1, 2], [1]]


def test_dropped_agents_are_neither_seen_nor_hit():
    # Track 5, a pedestrian, stands on the ego; the cars are far.
    scene = tiny_scene([[(5, 0.5, 0.0, PEDESTRIAN, 0.9), (6, 20.0, 0.0, CAR, 0.9)]] * 3)
    hit = unroll([scene], ReplayLogPolicy(), UnrollConfig())
    assert hit.collision_track_id[0].tolist() == [5, 5, 5]
    log = stack_scenes([keep_agents(scene, ReplayedAgents(labels=["CAR"]))])
    assert log.track_id[log.available].tolist() == [6, 6, 6]
    assert not unroll(log, ReplayLogPolicy(), UnrollConfig()).collision_kind.any()


def test_an_unknown_label_is_named():
    with pytest.raises(ValueError, match="unknown perception label 'LORRY'; known: PERCEPTION_LABEL_NOT_SET"):
        ReplayedAgents(labels=["LORRY"])
