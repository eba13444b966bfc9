"""nuplan-devkit's own closed-loop metrics and per-scenario score for score cases (CASE_FORMAT.md).

Runs with the oracle venv's python (``oracle_venv.py`` makes it) and imports nothing from
pytest_driveeval.  It builds nuPlan's objects from each case (EgoState, Agent / StaticObject,
DetectionsTracks, SimulationHistory), a map implementing nuPlan's AbstractMap over the case's
polygons and a scenario that only answers ``get_expert_ego_trajectory``; then it instantiates the
metric classes of ``simulation_closed_loop_nonreactive_agents.yaml`` from the devkit's own yaml
files, runs them through nuPlan's MetricsEngine, and scores the results with the
WeightedAverageMetricAggregator's ``_compute_scenario_score`` (its config read from the devkit's
yaml).  Nothing of the metrics or the score is written here: only the inputs are built.

    python nuplan_metrics.py cases.json [--out results.jsonl] [--repeat N]
"""
from __future__ import annotations

import abc
import argparse
import importlib
import json
import math
import statistics
import sys
import tempfile
import time
import types
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple


def _stub_sensor_modules() -> None:
    # observation_type.py imports the camera image and lidar classes only to annotate its Sensors
    # observation; their modules pull in cv2, PIL, matplotlib, pyquaternion and pytest at import.
    # No metric reads sensors, so two empty classes stand in for them.
    for name, cls in (("nuplan.database.utils.image", "Image"),
                      ("nuplan.database.utils.pointclouds.lidar", "LidarPointCloud")):
        if name not in sys.modules:
            module = types.ModuleType(name)
            setattr(module, cls, type(cls, (), {}))
            sys.modules[name] = module


_stub_sensor_modules()

import numpy as np  # noqa: E402
import yaml  # noqa: E402
from shapely.geometry import LineString, Point, Polygon, box  # noqa: E402
from shapely.strtree import STRtree  # noqa: E402
from shapely.ops import unary_union  # noqa: E402

import nuplan  # noqa: E402
from nuplan.common.actor_state.agent import Agent  # noqa: E402
from nuplan.common.actor_state.ego_state import EgoState  # noqa: E402
from nuplan.common.actor_state.oriented_box import OrientedBox  # noqa: E402
from nuplan.common.actor_state.scene_object import SceneObjectMetadata  # noqa: E402
from nuplan.common.actor_state.state_representation import Point2D, StateSE2, StateVector2D, TimePoint  # noqa: E402
from nuplan.common.actor_state.static_object import StaticObject  # noqa: E402
from nuplan.common.actor_state.tracked_objects import TrackedObjects  # noqa: E402
from nuplan.common.actor_state.tracked_objects_types import TrackedObjectType  # noqa: E402
from nuplan.common.actor_state.vehicle_parameters import VehicleParameters, get_pacifica_parameters  # noqa: E402
from nuplan.common.maps.abstract_map import AbstractMap  # noqa: E402
from nuplan.common.maps.abstract_map_objects import (  # noqa: E402
    Intersection,
    Lane,
    LaneConnector,
    PolygonMapObject,
    PolylineMapObject,
    RoadBlockGraphEdgeMapObject,
)
from nuplan.common.maps.maps_datatypes import IntersectionType, SemanticMapLayer  # noqa: E402
from nuplan.planning.metrics.aggregator.weighted_average_metric_aggregator import (  # noqa: E402
    WeightedAverageMetricAggregator,
)
from nuplan.planning.metrics.metric_engine import MetricsEngine  # noqa: E402
from nuplan.planning.simulation.history.simulation_history import (  # noqa: E402
    SimulationHistory,
    SimulationHistorySample,
)
from nuplan.planning.simulation.observation.observation_type import DetectionsTracks  # noqa: E402
from nuplan.planning.simulation.simulation_time_controller.simulation_iteration import (  # noqa: E402
    SimulationIteration,
)

DEVKIT_ROOT = Path(nuplan.__file__).resolve().parent.parent
METRIC_CONFIG = DEVKIT_ROOT / "nuplan/planning/script/config/common/simulation_metric"
METRIC_SET = METRIC_CONFIG / "simulation_closed_loop_nonreactive_agents.yaml"
AGGREGATOR_CONFIG = (DEVKIT_ROOT / "nuplan/planning/script/config/simulation/metric_aggregator"
                     / "closed_loop_nonreactive_agents_weighted_average.yaml")
COMFORT = ("ego_lon_acceleration", "ego_lat_acceleration", "ego_lon_jerk", "ego_jerk",
           "ego_yaw_rate", "ego_yaw_acceleration")
AGENT_TYPES = {"vehicle", "pedestrian", "bicycle"}  # the rest become StaticObject, as in nuPlan's logs
AGENT_HEIGHT = 1.5  # no metric reads a height; OrientedBox wants one


# ---------------------------------------------------------------- map

def polygon_of(spec: Any) -> Polygon:
    """A case polygon: a list of points, or ``{"shell": points, "holes": [points, ...]}``."""
    if isinstance(spec, dict):
        return Polygon(spec["shell"], spec.get("holes") or [])
    return Polygon(spec)


def _unimplemented(name: str, is_property: bool) -> Any:
    def raiser(self: Any, *args: Any, **kwargs: Any) -> Any:
        raise NotImplementedError(f"{type(self).__name__}.{name}: not needed by the closed-loop metrics")
    return property(raiser) if is_property else raiser


def concrete(cls: type) -> type:
    """Make ``cls`` instantiable: every abstract member it leaves open raises when used.

    The metrics call only a few members of nuPlan's map interfaces; a call to any other one
    fails loudly instead of the oracle answering from a guess.
    """
    for name in list(getattr(cls, "__abstractmethods__", ())):
        base_attr = next(vars(base)[name] for base in cls.__mro__ if name in vars(base))
        setattr(cls, name, _unimplemented(name, isinstance(base_attr, property)))
    abc.update_abstractmethods(cls)
    return cls


@concrete
class Baseline(PolylineMapObject):
    def __init__(self, path_id: str, points: List[List[float]]):
        super().__init__(path_id)
        self._linestring = LineString(points)
        xy = np.asarray(points, dtype=np.float64)
        heading = np.arctan2(np.diff(xy[:, 1]), np.diff(xy[:, 0]))
        heading = np.append(heading, heading[-1])
        self._discrete_path = [StateSE2(float(x), float(y), float(h)) for (x, y), h in zip(xy, heading)]

    @property
    def linestring(self) -> LineString:
        return self._linestring

    @property
    def length(self) -> float:
        return float(self._linestring.length)

    @property
    def discrete_path(self) -> List[StateSE2]:
        return self._discrete_path

    def get_nearest_arc_length_from_position(self, point: Point2D) -> float:
        return float(self._linestring.project(Point(point.x, point.y)))


@concrete
class Roadblock(RoadBlockGraphEdgeMapObject):
    """A ROADBLOCK, or a ROADBLOCK_CONNECTOR when the case says ``connector: true``."""

    def __init__(self, block_id: str, polygon: Polygon):
        super().__init__(block_id)
        self._polygon = polygon
        self.lanes: List[Any] = []

    @property
    def polygon(self) -> Polygon:
        return self._polygon

    @property
    def interior_edges(self) -> List[Any]:
        return self.lanes


class _LaneFields:
    """What the route extractor, speed limit and progress metrics read of a lane or connector."""

    def _set(self, polygon: Polygon, baseline: Baseline, speed_limit: Optional[float], roadblock: Roadblock) -> None:
        self._polygon = polygon
        self._baseline = baseline
        self._speed_limit = speed_limit
        self._roadblock = roadblock
        self.incoming: List[Any] = []
        self.outgoing: List[Any] = []

    @property
    def polygon(self) -> Polygon:
        return self._polygon

    @property
    def baseline_path(self) -> Baseline:
        return self._baseline

    @property
    def speed_limit_mps(self) -> Optional[float]:
        return self._speed_limit

    @property
    def incoming_edges(self) -> List[Any]:
        return self.incoming

    @property
    def outgoing_edges(self) -> List[Any]:
        return self.outgoing

    @property
    def parallel_edges(self) -> List[Any]:
        return [lane for lane in self._roadblock.lanes if lane is not self]

    def get_roadblock_id(self) -> str:
        return self._roadblock.id

    @property
    def parent(self) -> Roadblock:
        return self._roadblock


@concrete
class CaseLane(_LaneFields, Lane):
    def __init__(self, lane_id: str, *fields: Any):
        Lane.__init__(self, lane_id)
        self._set(*fields)

    @property
    def index(self) -> int:
        return self._roadblock.lanes.index(self)


@concrete
class CaseLaneConnector(_LaneFields, LaneConnector):
    def __init__(self, lane_id: str, *fields: Any):
        LaneConnector.__init__(self, lane_id)
        self._set(*fields)


@concrete
class Area(PolygonMapObject):
    """A DRIVABLE_AREA polygon."""

    def __init__(self, area_id: str, polygon: Polygon):
        super().__init__(area_id)
        self._polygon = polygon

    @property
    def polygon(self) -> Polygon:
        return self._polygon


@concrete
class CaseIntersection(Intersection):
    def __init__(self, intersection_id: str, polygon: Polygon):
        super().__init__(intersection_id, IntersectionType.DEFAULT)
        self._polygon = polygon

    @property
    def polygon(self) -> Polygon:
        return self._polygon


@concrete
class CaseMap(AbstractMap):
    """nuPlan's map interface over the case's polygons, with NuPlanMap's semantics.

    Point queries use ``polygon.contains`` (NuPlanMap: geopandas ``contains``; a point on the
    outline is outside), ``get_one_map_object`` raises when more than one object holds the point,
    and ``get_distance_to_nearest_map_object`` answers (None, None) for a layer without polygons
    (NuPlanMap: a layer it cannot load), which the drivable-area metric treats as far.
    """

    def __init__(self, spec: Optional[Dict[str, Any]]):
        spec = spec or {}
        self.layers: Dict[SemanticMapLayer, Dict[str, Any]] = {layer: {} for layer in self.get_available_map_objects()}
        for block in spec.get("roadblocks", []):
            layer = SemanticMapLayer.ROADBLOCK_CONNECTOR if block.get("connector") else SemanticMapLayer.ROADBLOCK
            shape = (polygon_of(block["polygon"]) if "polygon" in block
                     else unary_union([polygon_of(p) for p in block["polygons"]]))
            self.layers[layer][str(block["id"])] = Roadblock(str(block["id"]), shape)
        lanes: Dict[str, Any] = {}
        for lane in spec.get("lanes", []):
            lane_id = str(lane["id"])
            connector = bool(lane.get("connector"))
            block_layer = SemanticMapLayer.ROADBLOCK_CONNECTOR if connector else SemanticMapLayer.ROADBLOCK
            roadblock = self.layers[block_layer].get(str(lane["roadblock"]))
            if roadblock is None:
                raise ValueError(f"lane {lane_id}: roadblock {lane['roadblock']!r} is not a "
                                 f"{'connector ' if connector else ''}roadblock of the case")
            cls = CaseLaneConnector if connector else CaseLane
            obj = cls(lane_id, polygon_of(lane["polygon"]), Baseline(lane_id, lane["baseline"]),
                      lane.get("speed_limit"), roadblock)
            roadblock.lanes.append(obj)
            lanes[lane_id] = obj
            self.layers[SemanticMapLayer.LANE_CONNECTOR if connector else SemanticMapLayer.LANE][lane_id] = obj
        for lane in spec.get("lanes", []):
            obj = lanes[str(lane["id"])]
            obj.incoming = [lanes[str(i)] for i in lane.get("incoming", [])]
            obj.outgoing = [lanes[str(i)] for i in lane.get("outgoing", [])]
        for i, outline in enumerate(spec.get("drivable_area", [])):
            self.layers[SemanticMapLayer.DRIVABLE_AREA][f"drivable_{i}"] = Area(f"drivable_{i}", polygon_of(outline))
        rings = [polygon_of(r) for r in spec.get("drivable_outlines", [])]
        if rings:  # one area read even-odd: the symmetric difference of its rings
            area = rings[0] if rings[0].is_valid else rings[0].buffer(0)
            for ring in rings[1:]:
                area = area.symmetric_difference(ring if ring.is_valid else ring.buffer(0))
            parts = list(area.geoms) if hasattr(area, "geoms") else [area]
            for i, part in enumerate(p for p in parts if isinstance(p, Polygon) and not p.is_empty):
                self.layers[SemanticMapLayer.DRIVABLE_AREA][f"outlined_{i}"] = Area(f"outlined_{i}", part)
        for i, outline in enumerate(spec.get("intersections", [])):
            self.layers[SemanticMapLayer.INTERSECTION][f"intersection_{i}"] = CaseIntersection(
                f"intersection_{i}", polygon_of(outline))
        self._trees: Dict[SemanticMapLayer, Tuple[List[Any], STRtree]] = {}

    def get_available_map_objects(self) -> List[SemanticMapLayer]:
        return [SemanticMapLayer.LANE, SemanticMapLayer.LANE_CONNECTOR, SemanticMapLayer.ROADBLOCK,
                SemanticMapLayer.ROADBLOCK_CONNECTOR, SemanticMapLayer.DRIVABLE_AREA, SemanticMapLayer.INTERSECTION]

    @property
    def map_name(self) -> str:
        return "score_case"

    def _layer(self, layer: SemanticMapLayer) -> Dict[str, Any]:
        if layer not in self.layers:
            raise ValueError(f"Object representation for layer: {layer.name} is unavailable")
        return self.layers[layer]

    def _candidates(self, layer: SemanticMapLayer, geometry: Any) -> List[Any]:
        """The layer's objects whose bounding boxes meet ``geometry``'s, in the layer's order (a real
        map has hundreds of lanes; the exact test follows on these only)."""
        if layer not in self._trees:
            objects = list(self._layer(layer).values())
            self._trees[layer] = (objects, STRtree([obj.polygon for obj in objects]))
        objects, tree = self._trees[layer]
        return [objects[i] for i in sorted(tree.query(geometry).tolist())] if objects else []

    def get_all_map_objects(self, point: Point2D, layer: SemanticMapLayer) -> List[Any]:
        query = Point(point.x, point.y)
        return [obj for obj in self._candidates(layer, query) if obj.polygon.contains(query)]

    def get_one_map_object(self, point: Point2D, layer: SemanticMapLayer) -> Optional[Any]:
        found = self.get_all_map_objects(point, layer)
        if len(found) > 1:
            raise AssertionError(f"{len(found)} map objects found. Expected only one. Try using get_all_map_objects()")
        return found[0] if found else None

    def is_in_layer(self, point: Point2D, layer: SemanticMapLayer) -> bool:
        return bool(self.get_all_map_objects(point, layer))

    def get_proximal_map_objects(self, point: Point2D, radius: float,
                                 layers: List[SemanticMapLayer]) -> Dict[SemanticMapLayer, List[Any]]:
        patch = box(point.x - radius, point.y - radius, point.x + radius, point.y + radius)
        return {layer: [obj for obj in self._candidates(layer, patch) if obj.polygon.intersects(patch)]
                for layer in layers}

    def get_map_object(self, object_id: str, layer: SemanticMapLayer) -> Optional[Any]:
        try:
            return self._layer(layer)[str(object_id)]
        except KeyError:
            raise ValueError(f"Object representation for layer: {layer.name} object: {object_id} is unavailable")

    def get_distance_to_nearest_map_object(self, point: Point2D,
                                           layer: SemanticMapLayer) -> Tuple[Optional[str], Optional[float]]:
        objects = self._layer(layer)
        if not objects:
            return None, None
        query = Point(point.x, point.y)
        nearest = min(objects.values(), key=lambda obj: obj.polygon.distance(query))
        return nearest.id, float(nearest.polygon.distance(query))

    def initialize_all_layers(self) -> None:
        pass


# ---------------------------------------------------------------- ego, agents, history

def vehicle_parameters(length: float, width: float, rear_axle_to_center: float) -> VehicleParameters:
    """The Pacifica's parameters, resized so that nuPlan's half_length - rear_length is the case's value."""
    pacifica = get_pacifica_parameters()
    scale = length / pacifica.length
    rear_length = length / 2.0 - rear_axle_to_center
    return VehicleParameters(width=width, front_length=length - rear_length, rear_length=rear_length,
                             cog_position_from_rear_axle=pacifica.cog_position_from_rear_axle * scale,
                             wheel_base=pacifica.wheel_base * scale, vehicle_name="score_case",
                             vehicle_type=pacifica.vehicle_type, height=pacifica.height)


def rear_axle_pose(center: List[float], rear_axle_to_center: float) -> StateSE2:
    x, y, heading = center
    return StateSE2(x - rear_axle_to_center * math.cos(heading), y - rear_axle_to_center * math.sin(heading), heading)


def time_points(case: Dict[str, Any]) -> List[TimePoint]:
    return [TimePoint(int(round(t * 1e6))) for t in case["timestamps"]]


def ego_states(case: Dict[str, Any]) -> List[EgoState]:
    ego = case["ego"]
    params = vehicle_parameters(ego["length"], ego["width"], ego["rear_axle_to_center"])
    n = len(case["timestamps"])
    for key in ("center", "velocity", "acceleration", "angular_velocity", "angular_acceleration"):
        if len(ego[key]) != n:
            raise ValueError(f"ego.{key} has {len(ego[key])} rows for {n} timestamps")
    return [EgoState.build_from_rear_axle(
        rear_axle_pose=rear_axle_pose(ego["center"][i], ego["rear_axle_to_center"]),
        rear_axle_velocity_2d=StateVector2D(*ego["velocity"][i]),
        rear_axle_acceleration_2d=StateVector2D(*ego["acceleration"][i]),
        tire_steering_angle=0.0, time_point=tp, vehicle_parameters=params,
        angular_vel=float(ego["angular_velocity"][i]), angular_accel=float(ego["angular_acceleration"][i]),
    ) for i, tp in enumerate(time_points(case))]


def expert_states(case: Dict[str, Any]) -> List[EgoState]:
    # The progress metric reads only the expert's box centre; the dynamic fields are left at rest.
    ego = case["ego"]
    params = vehicle_parameters(ego["length"], ego["width"], ego["rear_axle_to_center"])
    centers = case["expert"]["center"]
    if len(centers) != len(case["timestamps"]):
        raise ValueError(f"expert.center has {len(centers)} rows for {len(case['timestamps'])} timestamps")
    return [EgoState.build_from_rear_axle(
        rear_axle_pose=rear_axle_pose(c, ego["rear_axle_to_center"]), rear_axle_velocity_2d=StateVector2D(0.0, 0.0),
        rear_axle_acceleration_2d=StateVector2D(0.0, 0.0), tire_steering_angle=0.0, time_point=tp,
        vehicle_parameters=params) for c, tp in zip(centers, time_points(case))]


def observations(case: Dict[str, Any]) -> List[DetectionsTracks]:
    stamps = time_points(case)
    per_frame: List[List[Any]] = [[] for _ in stamps]
    for track_id, agent in enumerate(case.get("agents", [])):
        kind = TrackedObjectType[agent["type"].upper()]
        rows = len(agent["frames"])
        if len(agent["center"]) != rows or (agent["type"] in AGENT_TYPES and len(agent["velocity"]) != rows):
            raise ValueError(f"agent {agent['token']}: center/velocity rows differ from its frames")
        for row, frame in enumerate(agent["frames"]):
            metadata = SceneObjectMetadata(timestamp_us=stamps[frame].time_us, token=f"{agent['token']}_{frame}",
                                           track_id=track_id, track_token=str(agent["token"]))
            oriented_box = OrientedBox(StateSE2(*agent["center"][row]), agent["length"], agent["width"], AGENT_HEIGHT)
            if agent["type"] in AGENT_TYPES:
                obj = Agent(tracked_object_type=kind, oriented_box=oriented_box,
                            velocity=StateVector2D(*agent["velocity"][row]), metadata=metadata)
            else:
                obj = StaticObject(tracked_object_type=kind, oriented_box=oriented_box, metadata=metadata)
            per_frame[frame].append(obj)
    return [DetectionsTracks(TrackedObjects(objects)) for objects in per_frame]


class CaseScenario:
    """The one thing the standard metrics ask of a scenario: the logged (expert) ego trajectory."""

    scenario_name = scenario_type = log_name = "score_case"

    def __init__(self, expert: List[EgoState]):
        self._expert = expert

    def get_expert_ego_trajectory(self) -> List[EgoState]:
        return self._expert


def build_history(case: Dict[str, Any]) -> Tuple[SimulationHistory, CaseScenario]:
    if any(b <= a for a, b in zip(case["timestamps"], case["timestamps"][1:])):
        raise ValueError("timestamps must be strictly increasing")
    history = SimulationHistory(CaseMap(case.get("map")), mission_goal=None)
    for index, (ego, observation) in enumerate(zip(ego_states(case), observations(case))):
        history.add_sample(SimulationHistorySample(
            iteration=SimulationIteration(ego.time_point, index), ego_state=ego,
            trajectory=None,  # read only by the open-loop metrics, not part of this set
            observation=observation, traffic_light_status=[]))
    return history, CaseScenario(expert_states(case))


# ---------------------------------------------------------------- metrics and score, from the devkit's config

def _load_yaml(path: Path) -> Dict[str, Any]:
    with open(path) as handle:
        return yaml.safe_load(handle)


def _instantiate(cfg: Dict[str, Any], **extra: Any) -> Any:
    module_name, _, class_name = cfg["_target_"].rpartition(".")
    kwargs = {k: v for k, v in cfg.items() if not k.startswith("_") and k != "required_metrics"}
    return getattr(importlib.import_module(module_name), class_name)(**kwargs, **extra)


def metric_configs() -> List[Tuple[str, Dict[str, Any]]]:
    """(config key, config) of the closed-loop metric set, low level first, in the yaml's order."""
    groups: Dict[str, List[str]] = {}
    for entry in _load_yaml(METRIC_SET)["defaults"]:
        if isinstance(entry, dict):
            groups.update(entry)
    configs = []
    for group in ("low_level", "high_level"):
        for file_stem in groups.get(group, []):
            configs.extend(_load_yaml(METRIC_CONFIG / group / f"{file_stem}.yaml").items())
    return configs


def build_engine(configs: List[Tuple[str, Dict[str, Any]]], save_dir: Path) -> MetricsEngine:
    """Fresh metric objects (they keep per-scenario results for the high-level ones), as metric_builder wires them."""
    engine = MetricsEngine(main_save_path=save_dir)
    built: Dict[str, Any] = {}
    for key, cfg in configs:
        required = {param: built[name] for param, name in cfg.get("required_metrics", {}).items()}
        built[key] = _instantiate(cfg, **required)
        engine.add_metric(built[key])
    return engine


def build_aggregator(save_dir: Path) -> WeightedAverageMetricAggregator:
    (cfg,) = _load_yaml(AGGREGATOR_CONFIG).values()
    # file_name holds a hydra ${now:...} interpolation; no file is written here.
    return WeightedAverageMetricAggregator(name=cfg["name"], metric_weights=dict(cfg["metric_weights"]),
                                           file_name="oracle", aggregator_save_path=save_dir,
                                           multiple_metrics=list(cfg["multiple_metrics"]),
                                           challenge_name=cfg.get("challenge_name"))


def scored_metric_names() -> List[str]:
    (cfg,) = _load_yaml(AGGREGATOR_CONFIG).values()
    return list(cfg["multiple_metrics"]) + [name for name in cfg["metric_weights"] if name != "default"]


def _finite(value: Any) -> Optional[float]:
    value = float(value)
    return value if math.isfinite(value) else None


def timed_per_metric(engine: MetricsEngine, history: SimulationHistory, scenario: CaseScenario,
                     per_metric: Dict[str, List[float]]) -> Dict[str, Any]:
    """What MetricsEngine.compute_metric_results does (each metric in order), timing each metric."""
    results = {}
    for metric in engine.metrics:
        start = time.perf_counter()
        results[metric.name] = metric.compute(history, scenario=scenario)
        per_metric.setdefault(metric.name, []).append(time.perf_counter() - start)
    return results


def evaluate(case: Dict[str, Any], configs: List[Tuple[str, Dict[str, Any]]],
             aggregator: WeightedAverageMetricAggregator, save_dir: Path, repeat: int = 1,
             per_metric: bool = False) -> Dict[str, Any]:
    start = time.perf_counter()
    history, scenario = build_history(case)
    build_seconds = time.perf_counter() - start
    seconds: List[float] = []
    metric_seconds: Dict[str, List[float]] = {}
    for _ in range(max(1, repeat)):
        engine = build_engine(configs, save_dir)
        start = time.perf_counter()
        if per_metric:
            results = timed_per_metric(engine, history, scenario, metric_seconds)
        else:
            results = engine.compute_metric_results(history=history, scenario=scenario)
        seconds.append(time.perf_counter() - start)
    by_name = {stat.name: stat for stats in results.values() for stat in stats}
    # One column per metric-statistics name, its metric_score as value: what _group_scenario_metrics builds.
    columns: Dict[str, Dict[str, Any]] = {case["name"]: {name: stat.metric_score for name, stat in by_name.items()}}
    aggregator._compute_scenario_score(columns)
    metrics = {name: (None if name not in by_name or by_name[name].metric_score is None
                      else float(by_name[name].metric_score)) for name in scored_metric_names()}
    comfort = {name: [float(np.min(by_name[name].time_series.values)), float(np.max(by_name[name].time_series.values))]
               for name in COMFORT}
    ttc = by_name["time_to_collision_within_bound"]
    min_ttc = next(s.value for s in ttc.statistics if s.name == "min_time_to_collision")
    out = {"name": case["name"], "metrics": metrics, "comfort": comfort,
           "min_time_to_collision": _finite(min_ttc),
           "time_to_collision": [_finite(v) for v in ttc.time_series.values], "score": float(columns[case["name"]]["score"]),
           "seconds": statistics.median(seconds), "build_seconds": build_seconds}
    if repeat > 1:
        out["repeats"] = len(seconds)
    if per_metric:
        out["metric_seconds"] = {name: statistics.median(runs) for name, runs in metric_seconds.items()}
    return out


def load_cases(path: Path) -> List[Dict[str, Any]]:
    data = json.loads(path.read_text())
    return data if isinstance(data, list) else [data]


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("cases", type=Path, help="JSON file: one case or a list of cases (CASE_FORMAT.md)")
    parser.add_argument("--out", type=Path, help="write the JSON lines here instead of stdout")
    parser.add_argument("--repeat", type=int, default=1,
                        help="compute each case's metrics N times; 'seconds' is the median wall time")
    parser.add_argument("--only", nargs="*", help="case names to run (default: all)")
    parser.add_argument("--per-metric", action="store_true",
                        help="also time each metric ('metric_seconds', medians over the repeats)")
    args = parser.parse_args(argv)
    cases = load_cases(args.cases)
    if args.only:
        cases = [c for c in cases if c["name"] in set(args.only)]
    configs = metric_configs()
    lines = []
    failed = 0
    with tempfile.TemporaryDirectory() as tmp:
        aggregator = build_aggregator(Path(tmp) / "aggregator")
        for case in cases:
            try:
                out = evaluate(case, configs, aggregator, Path(tmp) / "metrics", args.repeat, args.per_metric)
            except Exception as error:  # a metric that raises makes nuPlan drop the scenario: report it, go on
                failed += 1
                out = {"name": case.get("name"), "error": f"{type(error).__name__}: {error}"}
            line = json.dumps(out)
            lines.append(line)
            if args.out is None:
                print(line, flush=True)
    if args.out is not None:
        args.out.write_text("\n".join(lines) + "\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
