"""The files of a synthetic t4_dataset, written from ``t4gen``'s frames: the nuScenes/t4
annotation tables (linked by token, as perception_eval reads them) and an
Autoware-style Lanelet2 map of the road.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from ..geometry.quaternions import quat_wxyz_from_yaw
from .road import Road


def token(seed: int, *key) -> str:
    """Stable 32-hex token: the same seed names the same things identically."""
    return hashlib.md5(":".join(map(str, ("t4gen", seed) + key)).encode()).hexdigest()


# -- annotation tables --------------------------------------------------------
_VISIBILITY = [("none", "v0-40", 0, 40), ("partial", "v40-60", 40, 60),
               ("most", "v60-80", 60, 80), ("full", "v80-100", 80, 100)]
_ATTRIBUTES = ("vehicle.moving", "vehicle.parked", "cycle.with_rider",
               "pedestrian.moving", "pedestrian.standing")


def _r(v) -> list[float]:
    # full precision: rounding would move box faces across points and change counts
    return [float(x) for x in v]


def _link(rows: list[dict]) -> None:
    for a, b in zip(rows, rows[1:]):
        a["next"], b["prev"] = b["token"], a["token"]


def write_annotation(root: Path, seed: int, frames: list, stamps: list[int], *, tokens, cats,
                     attrs, sizes, with_map: bool, lidar_xyz) -> list[str]:
    """All nuScenes/t4 tables the reader and perception_eval expect, linked by token."""
    tk = lambda *k: token(seed, *k)  # noqa: E731
    log_tok, scene_tok, sensor_tok, calib_tok = tk("log"), tk("scene"), tk("sensor"), tk("calib")
    us = [s // 1000 for s in stamps]
    samples = [dict(token=tk("sample", i), timestamp=us[i], scene_token=scene_tok, next="",
                    prev="") for i in range(len(frames))]
    _link(samples)
    sample_data, ego_poses = [], []
    for i, fr in enumerate(frames):
        ex, ey, eyaw = fr["ego"]
        sd_tok = tk("sample_data", i)
        ego_poses.append(dict(token=sd_tok, timestamp=us[i], translation=_r([ex, ey, 0.0]),
                              rotation=quat_wxyz_from_yaw(eyaw)))
        fname = f"data/LIDAR_TOP/{i:05d}.pcd.bin"
        (root / fname).parent.mkdir(parents=True, exist_ok=True)
        (root / fname).write_bytes(fr["sweep"].tobytes())
        sample_data.append(dict(token=sd_tok, sample_token=samples[i]["token"],
                                ego_pose_token=sd_tok, calibrated_sensor_token=calib_tok,
                                timestamp=us[i], fileformat="pcd.bin", is_key_frame=True,
                                height=0, width=0, filename=fname, prev="", next=""))
    _link(sample_data)
    cat_rows = [dict(token=tk("category", c), name=c, description="") for c in sorted(set(cats))]
    attr_rows = [dict(token=tk("attribute", a), name=a, description="") for a in _ATTRIBUTES]
    per_inst: dict[int, list[dict]] = {}
    for i, fr in enumerate(frames):
        for b in np.flatnonzero(fr["annotated"]):
            per_inst.setdefault(int(b), []).append(dict(
                token=tk("ann", i, b), sample_token=samples[i]["token"],
                instance_token=tokens[b], visibility_token=fr["vis"][b],
                attribute_tokens=[tk("attribute", attrs[b])],
                translation=_r(fr["centers"][b]), size=_r(sizes[b]),
                rotation=quat_wxyz_from_yaw(fr["yaws"][b]), num_lidar_pts=int(fr["npts"][b]),
                num_radar_pts=0, prev="", next="", category_name=cats[b]))
    anns, instances = [], []
    for b in sorted(per_inst):
        rows = per_inst[b]
        _link(rows)
        anns += rows
        instances.append(dict(token=tokens[b], category_token=tk("category", cats[b]),
                              instance_name="", nbr_annotations=len(rows),
                              first_annotation_token=rows[0]["token"],
                              last_annotation_token=rows[-1]["token"]))
    tables = {
        "sample": samples, "sample_data": sample_data, "ego_pose": ego_poses,
        "sample_annotation": anns, "instance": instances, "category": cat_rows,
        "attribute": attr_rows,
        "visibility": [dict(token=t, level=lv, description=f"visibility of whole object is "
                            f"between {lo} and {hi}%") for t, lv, lo, hi in _VISIBILITY],
        "calibrated_sensor": [dict(token=calib_tok, sensor_token=sensor_tok,
                                   translation=_r(lidar_xyz), rotation=[1.0, 0.0, 0.0, 0.0],
                                   camera_intrinsic=[], camera_distortion=[])],
        "sensor": [dict(token=sensor_tok, channel="LIDAR_TOP", modality="lidar")],
        "scene": [dict(token=scene_tok, name=f"t4gen_seed{seed}", description="synthetic: "
                       "curved 3-lane road, traffic, parked vehicles, pedestrians",
                       log_token=log_tok, nbr_samples=len(samples),
                       first_sample_token=samples[0]["token"],
                       last_sample_token=samples[-1]["token"])],
        "log": [dict(token=log_tok, logfile="", vehicle="t4gen", data_captured="2023-11-14",
                     location="synthetic")],
        "map": [dict(token=tk("map"), log_tokens=[log_tok], category="lanelet2",
                     filename="map/lanelet2_map.osm" if with_map else "")],
        "object_ann": [], "surface_ann": [],
    }
    ann_dir = root / "annotation"
    ann_dir.mkdir(parents=True, exist_ok=True)
    for name, rows in tables.items():
        (ann_dir / f"{name}.json").write_text(json.dumps(rows, indent=2), encoding="utf-8")
    return [s["token"] for s in samples]


# -- lanelet2 map -------------------------------------------------------------
_LAT0, _LON0 = 35.0, 139.0  # lat/lon only approximate the local frame (equirectangular)


def write_lanelet2_map(path: Path, road: Road, s_lo: float, s_hi: float, lane_width: float,
                       n_lanes: int, segment: float = 50.0, step: float = 5.0) -> None:
    """Autoware-style Lanelet2 OSM: nodes carry local_x/local_y/ele (what Autoware reads)
    plus lat/lon; each lane segment is a type=lanelet relation whose left/right bounds are
    line ways shared with the neighbouring lanes and the next segment."""
    offsets = (np.arange(n_lanes + 1) - n_lanes / 2) * lane_width  # boundary d, right to left
    cuts = np.append(np.arange(s_lo, s_hi, segment), s_hi)
    nodes, ways, rels, next_id = [], [], [], 1
    bound_ids = {}
    for j, (a, b) in enumerate(zip(cuts, cuts[1:])):
        s = np.linspace(a, b, max(int(np.ceil((b - a) / step)), 1) + 1)
        for k, off in enumerate(offsets):
            x, y, _ = road.pose(s, np.full_like(s, off))
            ids = []
            for m, (xi, yi) in enumerate(zip(x, y)):
                if m == 0 and j > 0:  # share the end node of the previous segment
                    ids.append(bound_ids[(j - 1, k)][1][-1])
                    continue
                lat = _LAT0 + yi / 111_320.0
                lon = _LON0 + xi / (111_320.0 * np.cos(np.deg2rad(_LAT0)))
                nodes.append(f'  <node id="{next_id}" lat="{lat:.10f}" lon="{lon:.10f}">\n'
                             f'    <tag k="local_x" v="{xi:.4f}"/>\n'
                             f'    <tag k="local_y" v="{yi:.4f}"/>\n'
                             f'    <tag k="ele" v="0.0"/>\n  </node>')
                ids.append(next_id)
                next_id += 1
            outer = k in (0, len(offsets) - 1)
            refs = "".join(f'\n    <nd ref="{n}"/>' for n in ids)
            ways.append(f'  <way id="{next_id}">{refs}\n    <tag k="type" v="line_thin"/>\n'
                        f'    <tag k="subtype" v="{"solid" if outer else "dashed"}"/>\n  </way>')
            bound_ids[(j, k)] = (next_id, ids)
            next_id += 1
        for lane in range(n_lanes):
            right, left = bound_ids[(j, lane)][0], bound_ids[(j, lane + 1)][0]
            rels.append(f'  <relation id="{next_id}">\n'
                        f'    <member type="way" role="left" ref="{left}"/>\n'
                        f'    <member type="way" role="right" ref="{right}"/>\n'
                        '    <tag k="type" v="lanelet"/>\n    <tag k="subtype" v="road"/>\n'
                        '    <tag k="location" v="urban"/>\n    <tag k="one_way" v="yes"/>\n'
                        '    <tag k="speed_limit" v="50"/>\n    <tag k="participant:vehicle" '
                        'v="yes"/>\n  </relation>')
            next_id += 1
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text('<?xml version="1.0" encoding="UTF-8"?>\n'
                    '<osm generator="pytest_driveeval.sim.t4gen" version="0.6">\n'
                    + "\n".join(nodes + ways + rels) + "\n</osm>\n", encoding="utf-8")
