"""Synthetic t4_dataset for obstacle-segmentation evaluation, with known defects.

A curved three-lane road (constant curvature, Frenet coordinates s along /
d left of the centre line), the ego in the middle lane at 8-12 m/s, cars,
a truck, a cyclist and pedestrians, parked vehicles on the shoulders,
buildings and bushes off-road.  A 32-ring lidar is ray cast against all of
it each frame (``synth.lidar``), so visibility, occlusion and point counts in
the annotations come from the same geometry as the clouds.

The bag's obstacle cloud is what Autoware's obstacle_segmentation would
publish: every non-ground return plus a little misclassified ground, but
only far off-road, so a correct evaluation passes on the clean dataset and
fails exactly on the frames a ``defect`` touches.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry.boxes import points_in_boxes
from ..io.ros.pointcloud2 import XYZIRC_FIELDS, encode_pointcloud2, fields_dtype
from ..io.ros.rosbag import BagWriter, default_typestore, diagnostic_array, tf_message
from .lidar import scan
from .road import Road
from .t4tables import token, write_annotation, write_lanelet2_map

__all__ = ["T4Manifest", "generate_t4_dataset", "Road", "TARGET_TOKEN", "DIAG_NAME",
           "POINTCLOUD_TOPIC", "DEFECTS", "NON_DETECTION_AREA"]

POINTCLOUD_TOPIC = "/perception/obstacle_segmentation/pointcloud"
# The status driving_log_replayer's obstacle_segmentation evaluator watches
# on /diagnostics_agg to judge the topic rate.
DIAG_NAME = ("/autoware/perception/node_alive_monitoring/topic_status/"
             "topic_state_monitor_obstacle_segmentation_pointcloud: perception_topic_status")
# Instance token used by driving_log_replayer's sample obstacle_segmentation scenarios.
TARGET_TOKEN = "dcb2b352232fff50c4fad23718f31611"
DEFECTS = (None, "missed_object", "ghost_points")
# base_link box (x, y, z ranges) the clean obstacle cloud keeps free of non-object points.
NON_DETECTION_AREA = ((0.0, 10.0), (-1.5, 1.5), (0.0, 1.5))

LANE_WIDTH = 3.5
N_LANES = 3
LIDAR_XYZ = np.array([0.9, 0.0, 2.0])   # LIDAR_TOP in base_link (roof, slightly forward)
MAX_RANGE = 100.0
ANNOTATION_RANGE = 80.0
RANGE_NOISE = 0.015
FRAME_NS = 100_000_000                   # 10 Hz
START_NS = 1_700_000_000_000_000_000
OFFROAD_D = 11.5                         # |d| beyond which misclassified ground may survive


@dataclass
class T4Manifest:
    root: Path
    instance_tokens: dict[str, list[str]]
    frame_stamps_ns: list[int]
    pointcloud_topic: str
    annotated_frames: list[int]
    occluded_tokens: list[str]
    defect: str | None
    defect_frames: list[int]
    target_token: str = TARGET_TOKEN
    defect_token: str | None = None          # the object whose points went missing
    diag_name: str = DIAG_NAME
    storage: str = "sqlite3"
    seed: int = 0
    sample_tokens: list[str] = field(default_factory=list)
    occluded_frames: dict[str, list[int]] = field(default_factory=dict)  # token -> 0-point frames
    obstacle_points: list[int] = field(default_factory=list)             # cloud size per frame
    non_detection_area: tuple = NON_DETECTION_AREA

    @property
    def input_bag(self) -> Path:
        return self.root / "input_bag"

    @property
    def lanelet2_map(self) -> Path:
        return self.root / "map" / "lanelet2_map.osm"


def _scene_objects(rng: np.random.Generator, s_ego0: float, v_ego: float, s_mid: float):
    """Annotated actors as rows (name, category, attribute, s0, d, v_s, yaw_rel, w, l, h)."""
    j = lambda a: rng.uniform(-a, a)  # noqa: E731
    lane = LANE_WIDTH
    rows = [
        ("lead_car", "vehicle.car", "vehicle.moving", s_ego0 + 20 + j(2), j(0.2),
         v_ego + j(0.3), 0.0, 1.85, 4.6, 1.55),
        ("left_car", "vehicle.car", "vehicle.moving", s_ego0 + 6 + j(1.5), lane + j(0.2),
         v_ego + 1.0, 0.0, 1.8, 4.4, 1.5),
        ("left_car_far", "vehicle.car", "vehicle.moving", s_ego0 + 45 + j(3), lane + j(0.2),
         v_ego - 1.0, 0.0, 1.8, 4.5, 1.6),
        ("right_truck", "vehicle.truck", "vehicle.moving", s_ego0 + 35 + j(3), -lane + j(0.2),
         v_ego - 2.5, 0.0, 2.5, 9.0, 3.2),
        ("follow_car", "vehicle.car", "vehicle.moving", s_ego0 - 14 + j(1), j(0.2),
         v_ego, 0.0, 1.8, 4.5, 1.5),
        ("parked_truck", "vehicle.truck", "vehicle.parked", s_mid + 8 + j(1), 7.0,
         0.0, 0.0, 2.5, 8.5, 3.3),
        # stands right behind the parked truck: every ray to it crosses the truck
        ("hidden_ped", "human.pedestrian.adult", "pedestrian.standing", s_mid + 8 + j(1), 9.3,
         0.0, np.pi / 2, 0.6, 0.6, 1.75),
        ("parked_car", "vehicle.car", "vehicle.parked", s_ego0 + 30 + j(3), -7.0,
         0.0, np.pi, 1.8, 4.5, 1.5),
        ("cyclist", "vehicle.bicycle", "cycle.with_rider", s_ego0 + 12 + j(2), -6.3,
         4.5, 0.0, 0.7, 1.8, 1.7),
        ("ped_right_1", "human.pedestrian.adult", "pedestrian.moving", s_ego0 + 15 + j(3), -9.5,
         1.3, 0.0, 0.6, 0.6, 1.7),
        ("ped_right_2", "human.pedestrian.adult", "pedestrian.moving", s_ego0 + 42 + j(3), -9.8,
         -1.2, np.pi, 0.6, 0.6, 1.65),
        ("ped_left", "human.pedestrian.adult", "pedestrian.moving", s_ego0 + 26 + j(3), 10.0,
         1.0, 0.0, 0.6, 0.6, 1.8),
    ]
    return rows


def _static_boxes(rng, road: Road, s_lo: float, s_hi: float) -> np.ndarray:
    """Unannotated clutter (buildings, bushes) as (N, 8) rows x y z w l h yaw intensity."""
    rows = []
    for side in (-1, 1):
        s = s_lo
        while s < s_hi:  # buildings with gaps
            length = rng.uniform(12, 25)
            sc, dc = s + length / 2, side * rng.uniform(19, 22)
            x, y, yaw = road.pose(sc, dc)
            h = rng.uniform(6, 15)
            rows.append((x, y, h / 2, 10.0, length, h, yaw, rng.uniform(40, 90)))
            s += length + rng.uniform(3, 8)
        s = s_lo
        while s < s_hi:  # bushes/trees between sidewalk and buildings
            w, h = rng.uniform(0.8, 2.0), rng.uniform(0.8, 3.0)
            x, y, yaw = road.pose(s, side * rng.uniform(12.3, 14.0))
            rows.append((x, y, h / 2, w, w, h, yaw, rng.uniform(10, 35)))
            s += rng.uniform(8, 16)
    return np.array(rows, dtype=np.float64)


def _to_base_link(xy: np.ndarray, ego: tuple) -> np.ndarray:
    ex, ey, eyaw = ego
    c, s = np.cos(eyaw), np.sin(eyaw)
    dx, dy = xy[:, 0] - ex, xy[:, 1] - ey
    return np.stack([c * dx + s * dy, -s * dx + c * dy], -1)


def _visibility(hits: np.ndarray, alone: np.ndarray, npts: np.ndarray) -> list[str]:
    ratio = np.where(alone > 0, hits / np.maximum(alone, 1), 0.0)
    levels = np.select([ratio < 0.4, ratio < 0.6, ratio < 0.8], ["none", "partial", "most"], "full")
    return np.where(npts == 0, "none", levels).tolist()


def generate_t4_dataset(root, *, num_frames: int = 10, seed: int = 0, storage: str = "sqlite3",
                        points_per_frame: int = 30000, with_map: bool = True,
                        defect: str | None = None) -> T4Manifest:
    """Write a t4_dataset with input_bag into ``root``; see the module docstring.

    ``points_per_frame`` is the number of lidar rays per sweep; the sweep has
    fewer returns (rays into the sky), the obstacle cloud fewer still (no ground).
    """
    if defect not in DEFECTS:
        raise ValueError(f"defect must be one of {DEFECTS}, got {defect!r}")
    if num_frames < 1:
        raise ValueError("num_frames must be >= 1")
    root = Path(root)
    rng = np.random.default_rng(seed)
    road = Road(120.0 + rng.uniform(-20, 20), -35.0 + rng.uniform(-20, 20),
                rng.uniform(-np.pi, np.pi), rng.choice([-1, 1]) / rng.uniform(250, 600))
    v_ego, s_ego0 = rng.uniform(8, 12), 60.0
    dt = FRAME_NS / 1e9
    s_end = s_ego0 + v_ego * dt * (num_frames - 1)
    objs = _scene_objects(rng, s_ego0, v_ego, (s_ego0 + s_end) / 2)
    static = _static_boxes(rng, road, s_ego0 - MAX_RANGE - 20, s_end + MAX_RANGE + 20)
    names = [o[0] for o in objs]
    cats = [o[1] for o in objs]
    attrs = [o[2] for o in objs]
    s0, d, vs, yaw_rel = (np.array([o[k] for o in objs]) for k in range(3, 7))
    sizes = np.array([o[7:10] for o in objs])                      # w, l, h
    reflect = np.where(np.char.startswith(np.array(cats), "vehicle"),
                       rng.uniform(40, 120, len(objs)), rng.uniform(15, 60, len(objs)))
    tokens = [TARGET_TOKEN if n == "lead_car" else token(seed, "instance", n) for n in names]
    target = names.index("lead_car")
    cloud_dtype = fields_dtype(XYZIRC_FIELDS, 16)
    stamps = [START_NS + i * FRAME_NS for i in range(num_frames)]
    defect_frames = [i for i in range(num_frames) if i % 2 == 1] if defect else []
    # own stream: a defective dataset equals the clean one everywhere but its defect
    drng = np.random.default_rng([seed, 1])

    frames = []  # per frame: ego pose, obj centres/yaws (map), annotation rows, clouds
    for i in range(num_frames):
        t = i * dt
        ego = road.pose(s_ego0 + v_ego * t, 0.0)
        ox, oy, oyaw = road.pose(s0 + vs * t, d)
        oyaw = oyaw + yaw_rel
        centers_map = np.stack([ox, oy, sizes[:, 2] / 2], -1)
        bl_xy = _to_base_link(centers_map[:, :2], ego)
        centers_bl = np.column_stack([bl_xy, sizes[:, 2] / 2])
        yaws_bl = oyaw - ego[2]
        near = np.hypot(*(static[:, :2] - np.array(ego[:2])).T) < MAX_RANGE + 30
        st = static[near]
        st_bl = np.column_stack([_to_base_link(st[:, :2], ego), st[:, 2]])

        n_obj = len(objs)
        sc = scan(LIDAR_XYZ, points_per_frame, np.vstack([centers_bl, st_bl]),
                  np.vstack([sizes, st[:, 3:6]]), np.concatenate([yaws_bl, st[:, 6] - ego[2]]),
                  np.concatenate([reflect, st[:, 7]]), rng, max_range=MAX_RANGE,
                  range_noise=RANGE_NOISE)
        pts, inten, ring = sc.points, sc.intensity, sc.ring
        sweep = np.column_stack([pts - LIDAR_XYZ, inten, ring]).astype(np.float32)

        # obstacle segmentation: drop the ground, except a few far off-road misses
        d_road = road.frenet(*_from_base_link(pts[:, :2], ego).T)[1]
        keep = (sc.label >= 0) | ((np.abs(d_road) > OFFROAD_D) & (rng.random(len(pts)) < 0.02))
        spur = _spurious_points(rng, road, ego, s_ego0 + v_ego * t)
        obs_xyz = np.vstack([pts[keep], spur])
        obs_i = np.concatenate([inten[keep], rng.uniform(0, 10, len(spur))])
        obs_ring = np.concatenate([ring[keep], rng.integers(0, 32, len(spur))])

        # counted on float32 coordinates, as anyone reading the cloud back will
        inbox = points_in_boxes(obs_xyz.astype(np.float32).astype(np.float64), centers_bl, yaws_bl,
                                sizes[:, [1, 0, 2]]).mask
        npts = inbox.sum(0)
        vis = _visibility(sc.hits[:n_obj], sc.unoccluded[:n_obj], npts)
        annotated = np.hypot(*bl_xy.T) < ANNOTATION_RANGE

        if defect == "missed_object" and i in defect_frames:
            gone = points_in_boxes(obs_xyz, centers_bl[target:target + 1], yaws_bl[target:target + 1],
                                   sizes[target:target + 1, [1, 0, 2]], margin=0.15).mask[:, 0]
            obs_xyz, obs_i, obs_ring = obs_xyz[~gone], obs_i[~gone], obs_ring[~gone]
        elif defect == "ghost_points" and i in defect_frames:
            g = _ghost_cluster(drng)
            obs_xyz = np.vstack([obs_xyz, g])
            obs_i = np.concatenate([obs_i, drng.uniform(5, 40, len(g))])
            obs_ring = np.concatenate([obs_ring, drng.integers(8, 20, len(g))])

        cloud = np.zeros(len(obs_xyz), dtype=cloud_dtype)
        for k, c in enumerate("xyz"):
            cloud[c] = obs_xyz[:, k]
        cloud["intensity"] = np.clip(obs_i, 0, 255).astype(np.uint8)
        cloud["return_type"] = 1
        cloud["channel"] = obs_ring.astype(np.uint16)
        frames.append(dict(ego=ego, centers=centers_map, yaws=oyaw, npts=npts, vis=vis,
                           annotated=annotated, sweep=sweep, cloud=cloud))

    root.mkdir(parents=True, exist_ok=True)
    sample_tokens = write_annotation(
        root, seed, frames, stamps, tokens=tokens, cats=cats, attrs=attrs, sizes=sizes,
        with_map=with_map, lidar_xyz=LIDAR_XYZ)
    _write_bag(root / "input_bag", storage, frames, stamps)
    if with_map:
        write_lanelet2_map(root / "map" / "lanelet2_map.osm", road, s_ego0 - 60, s_end + 150,
                           LANE_WIDTH, N_LANES)

    occluded: dict[str, list[int]] = {}
    for i, fr in enumerate(frames):
        for b, tok in enumerate(tokens):
            if fr["annotated"][b] and fr["vis"][b] == "none":
                occluded.setdefault(tok, []).append(i)
    zero = {tok: [i for i in fs if frames[i]["npts"][tokens.index(tok)] == 0]
            for tok, fs in occluded.items()}
    by_cat: dict[str, list[str]] = {}
    for c, tok in zip(cats, tokens):
        by_cat.setdefault(c, []).append(tok)
    return T4Manifest(
        root=root, instance_tokens=by_cat, frame_stamps_ns=stamps,
        pointcloud_topic=POINTCLOUD_TOPIC, annotated_frames=list(range(num_frames)),
        occluded_tokens=sorted(occluded), defect=defect, defect_frames=defect_frames,
        defect_token=TARGET_TOKEN if defect == "missed_object" else None, storage=storage,
        seed=seed, sample_tokens=sample_tokens,
        occluded_frames={k: v for k, v in zero.items() if v},
        obstacle_points=[len(fr["cloud"]) for fr in frames])


def _from_base_link(xy: np.ndarray, ego: tuple) -> np.ndarray:
    ex, ey, eyaw = ego
    c, s = np.cos(eyaw), np.sin(eyaw)
    return np.stack([ex + c * xy[:, 0] - s * xy[:, 1], ey + s * xy[:, 0] + c * xy[:, 1]], -1)


def _spurious_points(rng, road: Road, ego: tuple, s_ego: float) -> np.ndarray:
    """A handful of isolated off-road returns (dust, rain, multipath), base_link."""
    n = int(rng.integers(5, 15))
    s = s_ego + rng.uniform(-40, 40, n)
    dd = rng.choice([-1, 1], n) * rng.uniform(OFFROAD_D + 1, 30, n)
    x, y, _ = road.pose(s, dd)
    return np.column_stack([_to_base_link(np.column_stack([x, y]), ego), rng.uniform(0.1, 3, n)])


def _ghost_cluster(rng) -> np.ndarray:
    """False obstacle points in the ego lane 3-8 m ahead, 0.2-1.2 m high."""
    n = int(rng.integers(25, 45))
    c = np.array([rng.uniform(4.0, 7.0), rng.uniform(-0.6, 0.6), rng.uniform(0.5, 0.9)])
    g = c + rng.normal(0, [0.3, 0.2, 0.15], (n, 3))
    return np.clip(g, [3.0, -1.2, 0.2], [8.0, 1.2, 1.2])


def _write_bag(path: Path, storage: str, frames: list, stamps: list[int]) -> None:
    import shutil
    if path.exists():
        shutil.rmtree(path)
    ts = default_typestore()
    qz = lambda yaw: (0.0, 0.0, float(np.sin(yaw / 2)), float(np.cos(yaw / 2)))  # noqa: E731
    with BagWriter(path, storage, typestore=ts) as bag:
        bag.write("/tf_static", tf_message([("base_link", "LIDAR_TOP", stamps[0], LIDAR_XYZ,
                                              (0.0, 0.0, 0.0, 1.0))], ts), stamps[0] - 1)
        for fr, stamp in zip(frames, stamps):
            ex, ey, eyaw = fr["ego"]
            bag.write("/tf", tf_message([("map", "base_link", stamp, (ex, ey, 0.0), qz(eyaw))], ts))
            # the monitor reports just before the cloud it vouches for is consumed
            bag.write("/diagnostics_agg", diagnostic_array(stamp - 1_000_000, [
                (DIAG_NAME, 0, "OK", {"topic": POINTCLOUD_TOPIC, "status": "OK",
                                      "warn_rate": "5.00", "error_rate": "1.00",
                                      "timeout": "1.00", "measured_rate": "10.00"},
                 "topic_state_monitor")], ts))
            bag.write(POINTCLOUD_TOPIC, encode_pointcloud2(fr["cloud"], "base_link", stamp, ts))
