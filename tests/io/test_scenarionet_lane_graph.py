"""nuPlan's lane graph from what each ScenarioNet converter writes (io.scenarionet.scenarionet_lane_graph):
lanes and connectors by their outlines and types, the graph from exit lanes or shared end points, and
roadblocks from neighbours."""
import numpy as np

from pytest_driveeval.io.scenarionet.scenarionet_features import MapFeature
from pytest_driveeval.io.scenarionet.scenarionet_lane_graph import JOIN_TOLERANCE, lane_graph

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def feature(fid, kind="LANE_SURFACE_STREET", line=((0, 0), (10, 0)), polygon=SQUARE, **extra):
    return MapFeature(id=fid, type=kind, group="lane", polyline=np.array(line, dtype=float), polygon=polygon,
                      extra=extra)


def graph(features):
    ids = [f.id for f in features]
    return lane_graph(ids, {f.id: f for f in features}, [f.polyline for f in features])


def test_nuscenes_lanes_have_outlines_connectors_do_not_and_lanes_join_where_their_lines_meet():
    features = [feature("a", line=((0, 0), (10, 0))),
                feature("c", line=((10 + JOIN_TOLERANCE / 2, 0), (20, 5)), polygon=None),  # a lane_connector
                feature("b", line=((20, 5), (30, 5))),
                feature("far", line=((10 + 2 * JOIN_TOLERANCE, 0), (20, -5)))]
    connector, outgoing, roadblock, note = graph(features)
    assert connector.tolist() == [False, True, False, False]
    assert outgoing == [[1], [2], [], []]  # "far" starts beyond the tolerance: not joined
    assert roadblock.tolist() == [0, 1, 2, 3]  # no neighbours: each its own
    assert "2 joins" in note


def test_nuplan_connectors_are_typed_and_a_roadblock_is_a_lane_with_its_neighbours():
    features = [feature("l1", right_neighbor=["l2"], exit_lanes=["k"]),
                feature("l2", left_neighbor=["l1"], right_neighbor=["l3"]),
                feature("l3", left_neighbor=["l2"]),
                feature("k", kind="LANE_SURFACE_UNSTRUCTURE", exit_lanes=["m"], left_neighbor=["l1"]),
                feature("m")]
    connector, outgoing, roadblock, note = graph(features)
    assert connector.tolist() == [False, False, False, True, False]
    assert outgoing == [[3], [], [], [4], []] and note is None  # the file's own exits; no joins made
    assert roadblock.tolist() == [0, 0, 0, 3, 4]  # a connector never joins a roadblock of lanes


def test_waymo_lanes_without_outlines_are_all_connectors():
    features = [feature("1", polygon=None, exit_lanes=[2]), feature("2", polygon=None, line=((10, 0), (20, 0)))]
    connector, outgoing, _, _ = graph(features)
    assert connector.all() and outgoing == [[1], []]


def test_an_outline_of_fewer_than_three_points_is_no_outline():
    connector, *_ = graph([feature("a", polygon=SQUARE[:2])])
    assert connector.tolist() == [True]


def test_on_a_real_nuscenes_scene_the_graph_is_the_oracles(shared_data):
    """scene-0061: 476 joins, as benchmarks/nuplan_oracle/scenario_map.py (its own reading of the raw file)
    reports; the lane the logged ego starts on is a lane, the junction's connectors around it are not."""
    from pytest_driveeval.io.scenarionet.scenarionet_l5 import ScenarioNetDataset
    from pytest_driveeval.usecases.closed_loop.score import dataset_score_maps

    dataset = ScenarioNetDataset.open(shared_data / "scenarionet" / "nuscenes" / "sd_nuscenes_v1.0-mini_scene-0061.pkl")
    score_map = dataset_score_maps(dataset, [0])[0]
    index = {lane: n for n, lane in enumerate(score_map.lane_ids)}
    assert not score_map.connector[index["7b690728-97e7-4fe9-9116-a4a41ab39e41"]]
    assert score_map.connector[index["91da635c-b931-4517-89c9-ff90792d75f0"]]
    assert sum(len(out) for out in score_map.outgoing) == 476
    assert 0 < score_map.connector.sum() < len(score_map.connector)
