"""One check per format: read the file with the reader the evaluation uses, say what it holds, and go
as far as the evaluation would before its first step (a ScenarioNet scenario into the closed loop's
scene and its map, a CommonRoad planning problem into the policy benchmark's scene), so that a file
that passes here does not fail there for its data.

Each check returns its :class:`~.result.FileCheck`; the reader's own error (it names the file and
the element) becomes the reason the file cannot be evaluated.
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from pytest_driveeval.core.errors import DataError, display_path
from pytest_driveeval.datacheck.result import FileCheck, counted, plural, reader_notes, skipped_entries

#: what a reader raises for a file it did not foresee, besides its own DataError: still that file's
#: problem, named, never the end of the check of the others
UNFORESEEN = (ValueError, TypeError, IndexError, KeyError, AttributeError, OverflowError, RecursionError,
              MemoryError, EOFError, UnicodeError)


def failed(check: FileCheck, exc: BaseException) -> FileCheck:
    """``check`` with the reader's error as its reason (ours name the file; others get it named)."""
    if isinstance(exc, (DataError, OSError)) and display_path(check.path) in str(exc) \
            or isinstance(exc, DataError) and str(check.path) in str(exc):
        check.problems.append(str(exc))
    elif isinstance(exc, OSError):
        check.problems.append(f"{display_path(check.path)}: {exc.strerror or exc}")
    elif isinstance(exc, DataError):
        check.problems.append(f"{display_path(check.path)}: {exc}")
    else:
        check.problems.append(f"{display_path(check.path)}: could not be read as {check.format} "
                              f"({type(exc).__name__}: {str(exc)[:200]}); if its dataset wrote it so, please report it")
    return check


def check_l5(path: Path) -> FileCheck:
    """An l5kit zarr: its scenes (each read, as the closed loop reads it), and the semantic map
    (``semantic_map.pb`` and ``meta.json`` beside the zarr, where l5kit keeps them)."""
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset

    check = FileCheck(path, "l5kit zarr")
    try:
        dataset = L5Dataset.open(path)
        frames = agents = faces = 0
        for index in range(dataset.num_scenes):
            scene = dataset.scene(index)
            frames += scene.num_frames
            agents += len(scene.agents)
            faces += len(scene.traffic_light_faces)
    except (DataError, OSError, *UNFORESEEN) as exc:
        return failed(check, exc)
    if dataset.num_scenes == 0:
        check.problems.append(f"{display_path(path)}: the store has no scenes")
    check.read.append(f"{plural(dataset.num_scenes, 'scene')}, {plural(frames, 'frame')}, "
                      f"{plural(agents, 'agent row')}, {plural(faces, 'traffic-light face')}")
    check.skipped.extend(skipped_entries(dataset))
    _l5_map(check, path)
    return check


def _l5_map(check: FileCheck, path: Path) -> None:
    from pytest_driveeval.io.l5.l5_semantic_map import read_semantic_map

    pb, meta = path.parent / "semantic_map.pb", path.parent / "meta.json"
    if not pb.is_file() or not meta.is_file():
        absent = " and ".join(p.name for p in (pb, meta) if not p.is_file())
        check.skipped.append(f"the semantic map: no {absent} beside the zarr (in {display_path(path.parent)}); "
                             "scenes run without it, rasters of MapType py_semantic need it")
        return
    try:
        semantic = read_semantic_map(pb, meta)
    except (DataError, OSError, *UNFORESEEN) as exc:
        failed(FileCheck(pb, "l5kit semantic map"), exc)
        check.problems.append(f"{display_path(pb)}: the semantic map cannot be read: {exc}")
        return
    check.read.append(f"semantic map {pb.name}: {plural(len(semantic.lane_ids), 'lane')}, "
                      f"{plural(len(semantic.crosswalk_ids), 'crosswalk')}, "
                      f"{plural(len(semantic.face_ids), 'traffic-light face')}")
    if len(semantic.lane_ids) == 0 and len(semantic.crosswalk_ids) == 0:
        check.problems.append(f"{display_path(pb)}: the semantic map holds no lanes and no crosswalks")


def check_scenarionet(path: Path) -> FileCheck:
    """One ScenarioNet scenario file: its tracks, map features and lights as read, then the closed
    loop's scene (steps, agents) and the score's map made from it."""
    from pytest_driveeval.io.scenarionet.scenarionet import read_scenario
    from pytest_driveeval.io.scenarionet.scenarionet_l5 import l5_scene
    from pytest_driveeval.io.scenarionet.scenarionet_map import scenario_map

    check = FileCheck(path, "ScenarioNet")
    try:
        scene = read_scenario(path)
    except (DataError, OSError, *UNFORESEEN) as exc:
        return failed(check, exc)
    tracks = scene.tracks
    check.read.append(f"scenario {scene.id} ({scene.dataset or 'dataset not named'}, map "
                      f"{scene.metadata.get('map', 'not named')}): {plural(scene.steps, 'step')} every "
                      f"{scene.sample_rate:g} s")
    check.read.append(f"{plural(len(tracks.ids), 'track')}: {counted(Counter(tracks.types))}; the self-driving "
                      f"car is track {tracks.ids[scene.sdc]}")
    groups = Counter(f.group for f in scene.map_features)
    check.read.append(f"{plural(len(scene.map_features), 'map feature')}: {counted(groups)}; "
                      f"{plural(len(scene.lights), 'traffic light')}")
    other = Counter(f.type for f in scene.map_features if f.group == "other")
    if other:
        check.skipped.append(f"map features of types the map does not use: {counted(other)}")
    try:
        l5 = l5_scene(scene)
        semantic = scenario_map(scene)
    except (DataError, *UNFORESEEN) as exc:
        check.skipped.extend(skipped_entries(scene))
        return failed(check, exc)
    check.read.append(f"closed-loop scene: {plural(l5.num_frames, 'frame')} while the self-driving car is "
                      f"valid, {plural(len(l5.agents), 'agent row')}; map: "
                      f"{plural(len(semantic.semantic.lane_ids), 'lane')}, "
                      f"{plural(len(semantic.surfaces), 'drivable surface')}")
    if l5.num_frames < scene.steps:
        check.skipped.append(f"steps {l5.num_frames}..{scene.steps - 1}: the self-driving car's track is not "
                             "valid from there on (the closed loop drives its first valid run)")
    if len(semantic.semantic.lane_ids) == 0:
        check.skipped.append("the map: no lanes, so the score's map terms are not available")
    check.skipped.extend(skipped_entries(scene, semantic))
    read, skipped = reader_notes(scene)  # after l5_scene, which notes the timestamps' jitter
    check.read.extend(read)
    check.skipped.extend(skipped)
    return check


def check_commonroad(path: Path) -> FileCheck:
    """A CommonRoad XML file: lanelets, obstacles and planning problems as read, then each planning
    problem as the policy benchmark's scene."""
    from pytest_driveeval.io.commonroad.commonroad import read_commonroad

    check = FileCheck(path, "CommonRoad")
    try:
        scenario = read_commonroad(path)
    except (DataError, OSError, *UNFORESEEN) as exc:
        return failed(check, exc)
    roles = Counter(o.role for o in scenario.obstacles.values())
    kinds = Counter(o.type for o in scenario.obstacles.values())
    check.read.append(f"benchmark {scenario.benchmark_id or '(no benchmarkID)'}, format {scenario.version}, "
                      f"a step every {scenario.dt:g} s")
    check.read.append(f"{plural(len(scenario.lanelets), 'lanelet')}; {plural(len(scenario.obstacles), 'obstacle')}"
                      + (f" ({counted(roles)}: {counted(kinds)})" if scenario.obstacles else ""))
    check.read.append(f"planning problems: {', '.join(map(str, sorted(scenario.planning_problems))) or 'none'}")
    check.skipped.extend(skipped_entries(scenario))
    read, skipped = reader_notes(scenario)
    check.read.extend(read)
    check.skipped.extend(skipped)
    if not scenario.planning_problems:
        check.problems.append(f"{display_path(path)}: no <planningProblem>: the policy benchmark drives a planning "
                              "problem's ego (the file's lanelets and obstacles alone are not a scene)")
        return check
    _commonroad_scenes(check, path, scenario)
    return check


def _commonroad_scenes(check: FileCheck, path: Path, scenario) -> None:
    from pytest_driveeval.sim.blueprints import ParameterError
    from pytest_driveeval.sim.commonroad_scene import commonroad_scene

    for problem in sorted(scenario.planning_problems):
        try:
            scene = commonroad_scene(path, problem)
        except (DataError, ParameterError, *UNFORESEEN) as exc:
            check.problems.append(f"{display_path(path)}: planning problem {problem}: {exc}"
                                  if str(path) not in str(exc) and display_path(path) not in str(exc) else str(exc))
            continue
        steps = scene.params.max_steps
        check.read.append(f"planning problem {problem}: a scene of {plural(steps, 'step')} from time step "
                          f"{scene.t0}, {plural(len(scene.obstacle_ids), 'obstacle')} replayed")
        check.skipped.extend(f"planning problem {problem}: {entry}" for entry in skipped_entries(scene))


def check_bag(path: Path) -> FileCheck:
    """A ROS 2 bag (a folder with metadata.yaml, or one .db3 / .mcap file): its topics, their types
    and message counts, and the time it spans."""
    from pytest_driveeval.io.ros.rosbag import Bag

    check = FileCheck(path, "ROS 2 bag")
    try:
        with Bag(path) as bag:
            topics = {topic: (kind, bag.message_count(topic)) for topic, kind in sorted(bag.topics.items())}
            span = (bag.end_time_ns - bag.start_time_ns) / 1e9 if topics else 0.0
    except (DataError, OSError, *UNFORESEEN) as exc:
        return failed(check, exc)
    total = sum(n for _, n in topics.values())
    check.read.append(f"{plural(len(topics), 'topic')}, {plural(total, 'message')} over {span:.1f} s")
    check.read.extend(f"{topic} ({kind}): {plural(n, 'message')}" for topic, (kind, n) in topics.items())
    empty = [topic for topic, (_, n) in topics.items() if n == 0]
    if empty:
        check.skipped.append(f"topics without messages: {', '.join(empty)}")
    if total == 0:
        check.problems.append(f"{display_path(path)}: the bag holds no messages")
    return check


def check_t4(path: Path) -> FileCheck:
    """A t4_dataset folder: its samples, annotations, lidar sweeps, input bag and map."""
    from pytest_driveeval.io.t4.t4dataset import T4Dataset

    check = FileCheck(path, "t4_dataset")
    try:
        dataset = T4Dataset(path)
        tokens = dataset.sample_tokens
        boxes = [len(dataset.ground_truth(token)) for token in tokens]
        categories = Counter(str(c.get("name", "?")) for c in dataset.table("category"))
        lidar = [dataset.lidar_path(token) for token in tokens]
    except (DataError, OSError, *UNFORESEEN) as exc:
        return failed(check, exc)
    present = sum(p.is_file() for p in lidar)
    annotated = plural(int(np.sum(boxes)), "annotated box", "annotated boxes")
    check.read.append(f"{plural(len(tokens), 'sample')}, {annotated} (of "
                      f"{plural(len(categories), 'category', 'categories')}), lidar sweeps: {present} of "
                      f"{len(lidar)} present")
    if present < len(lidar):
        missing = [display_path(p) for p in lidar if not p.is_file()]
        check.skipped.append(f"lidar sweeps not there ({', '.join(missing[:3])}{', ...' if len(missing) > 3 else ''}): "
                             "point clouds then come from the input bag or the scenario's own source")
    check.read.append(f"input bag: {'input_bag/' if dataset.input_bag else 'none'}; lanelet2 map: "
                      f"{'map/lanelet2_map.osm' if dataset.lanelet2_map else 'none'}")
    if not tokens:
        check.problems.append(f"{display_path(path)}: annotation/sample.json lists no sample")
    check.skipped.extend(skipped_entries(dataset))
    return check
