"""Small hand-made logs and maps for the raster tests."""
from __future__ import annotations

import numpy as np

from pytest_driveeval.io.l5.l5_semantic_map import Polylines, SemanticMap
from pytest_driveeval.sim.logreplay.logarrays import LogArrays


def make_log(n_frames: int, agents: list[dict], ego_xy=(0.0, 0.0), ego_yaw=0.0) -> LogArrays:
    """One scene; each agent dict has ``frames`` (its frames), ``xy``, ``yaw``, ``extent`` (l, w)
    and optionally ``keep`` (its label is an agent class)."""
    shape = (1, n_frames, max(len(agents), 1))
    log = LogArrays(
        scene_ids=np.array([7]), num_frames=np.array([n_frames]),
        ego_xy=np.tile(np.asarray(ego_xy, np.float64), (1, n_frames, 1)), ego_yaw=np.full((1, n_frames), ego_yaw),
        agent_xy=np.zeros(shape + (2,)), agent_yaw=np.zeros(shape, np.float32),
        agent_extent=np.zeros(shape + (3,), np.float32), agent_velocity=np.zeros(shape + (2,), np.float32),
        available=np.zeros(shape, bool), track_id=np.full(shape, -1, np.int64), label=np.zeros(shape, np.int16),
        relevant=np.zeros(shape, bool), frame_row=np.full(shape, -1, np.int32))
    for c, agent in enumerate(agents):
        for f in agent["frames"]:
            log.agent_xy[0, f, c] = agent["xy"]
            log.agent_yaw[0, f, c] = agent.get("yaw", 0.0)
            log.agent_extent[0, f, c, :2] = agent["extent"]
            log.available[0, f, c] = True
            log.track_id[0, f, c] = c + 1
            log.label[0, f, c] = 3 if agent.get("keep", True) else 1
            log.relevant[0, f, c] = agent.get("keep", True)
            log.frame_row[0, f, c] = c
    return log


def make_map(*, lanes=(), crosswalks=(), faces=(), lane_faces=None) -> SemanticMap:
    """``lanes``: (left, right) point lists; ``faces``: (face id, colour code); ``lane_faces``:
    per lane, the face ids among its traffic controls."""
    lane_faces = lane_faces or [[] for _ in lanes]
    controls = [f for fs in lane_faces for f in fs]
    return SemanticMap(
        lane_ids=np.array([f"lane{i}" for i in range(len(lanes))]),
        lanes_left=Polylines.from_list([left for left, _ in lanes]),
        lanes_right=Polylines.from_list([right for _, right in lanes]),
        lane_control_offsets=np.concatenate([[0], np.cumsum([len(fs) for fs in lane_faces])]).astype(np.int64),
        lane_control_ids=np.array(controls, dtype="<U16"),
        crosswalk_ids=np.array([f"cw{i}" for i in range(len(crosswalks))]),
        crosswalks=Polylines.from_list(crosswalks),
        face_ids=np.array([f for f, _ in faces], dtype="<U16"),
        face_colours=np.array([c for _, c in faces], np.int8),
        world_to_ecef=np.eye(4))
