"""obstacle_segmentation robustness: perturb_cloud's properties, and the demo filter's search end to end
(its reported edge against direct evaluation, replay, reproducibility, errors, real data)."""
from __future__ import annotations

import html
import json
import re
import shlex
import sys

import numpy as np
import pytest
import yaml
from hypothesis import given, settings, strategies as st

from conftest import REPO_ROOT
from pytest_driveeval.metrics.pointcloud import Area, BoxSet, evaluate_cloud
from pytest_driveeval.strategies import CloudPerturbation
from pytest_driveeval.usecases.obstacle_segmentation.perturb import GhostRegion, example_rng, perturb_cloud

DEMO = REPO_ROOT / "scenario_tests" / "obstacle_segmentation" / "robustness"
CLEAN = REPO_ROOT / "fixtures" / "t4" / "clean"
EXAMPLES = REPO_ROOT / "examples"
ORIGIN = np.array([0.9, 0.0, 2.0])
CLOUD_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "u1"), ("index", "<u4")])
# The sample's non-detection area, clipped by a "lane" that leaves out its left edge, with a box in it.
AREA = Area(np.array([[10.0, 1.5], [10.0, -1.5], [0.0, -1.5], [0.0, 1.5]]), 0.0, 1.5,
            [np.array([[-5.0, -4.0], [30.0, -4.0], [30.0, 0.8], [-5.0, 0.8]])])
BOXES = BoxSet.from_ground_truth([[6.0, 0.0, 0.8]], [[1.0, 2.0, 1.6]], [0.3])


def cloud(n: int = 20000, seed: int = 0) -> np.ndarray:
    """Points 2-40 m from the sensor, all behind base_link (so none in AREA)."""
    rng = np.random.default_rng(seed)
    out = np.zeros(n, CLOUD_DTYPE)
    out["x"] = rng.uniform(-40, -2, n)
    out["y"] = rng.uniform(-20, 20, n)
    out["z"] = rng.uniform(-0.2, 3.0, n)
    out["intensity"] = rng.integers(0, 255, n)
    out["index"] = np.arange(n)
    return out


def xyz(points: np.ndarray) -> np.ndarray:
    return np.stack([points["x"], points["y"], points["z"]], axis=1).astype(np.float64)


# -- perturb_cloud ----------------------------------------------------------------------------------------
def test_no_change_is_the_cloud_itself_bit_for_bit():
    for points in (cloud(), xyz(cloud())):
        before = points.tobytes()
        out = perturb_cloud(points, CloudPerturbation(), example_rng(7, 0), origin=ORIGIN)
        assert out is points and out.tobytes() == before


@pytest.mark.parametrize("dropout", [0.05, 0.3, 0.7, 0.95])
def test_dropout_removes_that_fraction_and_a_larger_one_removes_more_of_the_same(dropout):
    points = cloud()
    n = len(points)
    for seed in range(4):
        out = perturb_cloud(points, CloudPerturbation(dropout=dropout), example_rng(seed, 3))
        # binomial: within 5 standard deviations of the expected count
        assert abs(len(out) - n * (1 - dropout)) <= 5 * np.sqrt(n * dropout * (1 - dropout))
        assert out.dtype == CLOUD_DTYPE
        np.testing.assert_array_equal(out, points[np.isin(points["index"], out["index"])])
        more = perturb_cloud(points, CloudPerturbation(dropout=min(1.0, dropout + 0.02)), example_rng(seed, 3))
        assert set(more["index"]) < set(out["index"])


@pytest.mark.parametrize("sigma", [0.01, 0.2])
def test_range_noise_moves_points_along_their_rays_only(sigma):
    points = cloud()
    out = perturb_cloud(points, CloudPerturbation(range_noise=sigma), example_rng(1, 0), origin=ORIGIN)
    assert out.dtype == CLOUD_DTYPE and len(out) == len(points)
    np.testing.assert_array_equal(out[["intensity", "index"]], points[["intensity", "index"]])
    before, after = xyz(points) - ORIGIN, xyz(out) - ORIGIN
    r0, r1 = np.linalg.norm(before, axis=1), np.linalg.norm(after, axis=1)
    # the direction is kept up to float32 rounding of the coordinates (~1e-6 m at 40 m)
    np.testing.assert_allclose(after / r1[:, None], before / r0[:, None], atol=1e-6)
    delta = r1 - r0
    assert abs(delta.mean()) < 5 * sigma / np.sqrt(len(delta))
    assert abs(delta.std() / sigma - 1) < 0.05


def test_a_structured_cloud_and_an_array_are_perturbed_alike():
    points = cloud(2000)
    p = CloudPerturbation(dropout=0.3, range_noise=0.05)
    structured = perturb_cloud(points, p, example_rng(5, 2), origin=ORIGIN)
    array = perturb_cloud(xyz(points), p, example_rng(5, 2), origin=ORIGIN)
    assert array.shape == (len(structured), 3) and array.dtype == np.float64
    np.testing.assert_allclose(array, xyz(structured), atol=1e-5)


def test_the_same_frame_and_seed_give_the_same_cloud_and_another_frame_another():
    points = cloud(3000)
    p = CloudPerturbation(dropout=0.2, range_noise=0.05, ghost_points=9)
    region = GhostRegion(AREA, BOXES)
    a = perturb_cloud(points, p, example_rng(11, 4), origin=ORIGIN, ghost=region)
    b = perturb_cloud(points, p, example_rng(11, 4), origin=ORIGIN, ghost=region)
    c = perturb_cloud(points, p, example_rng(11, 5), origin=ORIGIN, ghost=region)
    assert a.tobytes() == b.tobytes() and a.tobytes() != c.tobytes()


@settings(max_examples=25, deadline=None)
@given(count=st.integers(1, 80), seed=st.integers(0, 2**32))
def test_ghost_points_all_lie_in_the_non_detection_area_outside_every_box(count, seed):
    points = cloud(500)
    out = perturb_cloud(points, CloudPerturbation(ghost_points=count), example_rng(seed, 0), ghost=GhostRegion(
        AREA, BOXES))
    assert len(out) == len(points) + count and out.dtype == CLOUD_DTYPE
    # the judgement's own count: every ghost and nothing else is in the area
    counts = evaluate_cloud(out, BOXES, AREA)
    assert len(counts.area_points) == count and counts.counts[0] == 0
    ghosts = out[len(points):]
    assert set(ghosts["index"]) <= set(points["index"])   # other fields are copied from real returns
    assert np.all((ghosts["z"] > 0.0) & (ghosts["z"] < 1.5)) and np.all(ghosts["y"] <= 0.8)


def test_ghosts_go_to_the_cloud_frame_and_more_of_them_extend_the_same_cluster():
    base_to_lidar = np.eye(4)
    base_to_lidar[:3, 3] = -ORIGIN
    region = GhostRegion(AREA, BOXES, cloud_T_base=base_to_lidar)
    points = cloud(500)
    few = perturb_cloud(points, CloudPerturbation(ghost_points=5), example_rng(2, 0), ghost=region)
    many = perturb_cloud(points, CloudPerturbation(ghost_points=30), example_rng(2, 0), ghost=region)
    in_base = xyz(many[len(points):]) + ORIGIN
    assert len(evaluate_cloud(in_base, BOXES, AREA).area_points) == 30
    np.testing.assert_array_equal(few[len(points):], many[len(points):len(points) + 5])


def test_ghosts_without_an_area_and_an_area_without_room_are_errors():
    with pytest.raises(ValueError, match="need a GhostRegion"):
        perturb_cloud(cloud(10), CloudPerturbation(ghost_points=3), example_rng(0, 0))
    covered = BoxSet.from_ground_truth([[5.0, 0.0, 0.75]], [[4.0, 12.0, 1.6]], [0.0])
    with pytest.raises(ValueError, match="no place for a ghost cluster"):
        perturb_cloud(cloud(10), CloudPerturbation(ghost_points=3), example_rng(0, 0),
                      ghost=GhostRegion(AREA, covered))


# -- the demo search, end to end -----------------------------------------------------------------------
CONFTEST = f"""\
import sys
import pytest

sys.path.insert(0, {str(EXAMPLES)!r})
from ground_filter import ground_height_filter


@pytest.fixture
def driveeval_pointclouds():
    return ground_height_filter
"""
NODE = "scenarios/dropout.scenario.yaml::obstacle_segmentation[sample_dataset]"


@pytest.fixture
def demo(pytester):
    """The demo's dropout scenario in a project of its own, on the repository's clean dataset."""
    pytest.importorskip("rosbags")      # the dataset's TF and diagnostics are in its bag
    matplotlib = pytest.importorskip("matplotlib")   # the failing frame's picture
    # Imported here, before any in-process run: pytester drops the modules a run imports, and a
    # second run's fresh pyplot would mix with the first one's classes.
    matplotlib.use("Agg")
    import matplotlib.pyplot  # noqa: F401
    (pytester.path / "scenarios").mkdir()
    text = (DEMO / "dropout.scenario.yaml").read_text().replace("../../../fixtures/t4/clean", str(CLEAN))
    assert str(CLEAN) in text
    (pytester.path / "scenarios" / "dropout.scenario.yaml").write_text(text)
    (pytester.path / "scenarios" / "conftest.py").write_text(CONFTEST)
    pytester.makeini("[pytest]\nmarkers =\n    demo\n    robustness\n")
    return pytester


def record_of(pytester, output="driveeval-results") -> dict:
    (record,) = json.loads((pytester.path / output / "summary.json").read_text())["results"]
    return record


def frame_fails(seed: int, frame: int, dropout: float) -> bool:
    """The demo's verdict on one frame under one dropout, from the Python API: the sweep perturbed
    with the item's random numbers, filtered, and judged alone."""
    sys.path.insert(0, str(EXAMPLES))
    from ground_filter import ground_height_filter

    from pytest_driveeval.io.t4.t4dataset import T4Dataset
    from pytest_driveeval.usecases.obstacle_segmentation.evaluate import evaluate_obstacle_segmentation
    from pytest_driveeval.usecases.obstacle_segmentation.sources import sweep_pointclouds

    config = yaml.safe_load((DEMO / "dropout.scenario.yaml").read_text())["Evaluation"]
    dataset = T4Dataset(CLEAN)
    stamp_ns, frame_id, raw = list(sweep_pointclouds(dataset))[frame]
    origin = dataset.lidar_to_base_link(dataset.sample_tokens[frame])[1]
    perturbed = perturb_cloud(raw, CloudPerturbation(dropout=dropout), example_rng(seed, frame), origin=origin)
    result = evaluate_obstacle_segmentation(dataset, [(stamp_ns, frame_id, ground_height_filter(perturbed))],
                                            config)
    return not result.success


def item_seed_of(nodeid: str) -> int:
    from pytest_driveeval.harness.settings import item_seed

    return item_seed(0, nodeid)


def test_the_demo_filter_fails_under_dropout_at_the_edge_that_direct_evaluation_finds(demo):
    demo.runpytest("--driveeval-search-profile=ci", "-p", "no:randomly").assert_outcomes(xfailed=1)
    record = record_of(demo)
    search = record["details"]["search"]
    frame, dropout = search["where"]["frame"], search["minimal"]["perturbation"]["dropout"]
    edge = search["edge"]["dropout"]
    seed = item_seed_of(NODE)
    assert frame_fails(seed, frame, dropout) and not frame_fails(seed, frame, edge)
    assert 0 < dropout - edge <= 0.01 * 0.6 + 1e-12          # Tolerance 1 % of the [0, 0.6] range
    # below the edge it keeps passing: a larger dropout only ever removes more of the same points
    assert not any(frame_fails(seed, frame, d) for d in np.linspace(0.0, edge, 4))
    assert re.fullmatch(r"box dcb2b352\.\. has \d of 10 point\(s\) needed", search["reason"])
    assert record["figures"]["minimal_dropout"] == dropout and search["failures"] >= 1
    # the picture of the failing case: that frame's filtered cloud
    png = [k for k in record["artefacts"] if k.startswith(f"frame_{frame}_")]
    assert len(png) == 1 and (demo.path / "driveeval-results" / record["artefacts"][png[0]]).stat().st_size > 5000
    assert record["details"]["failing_case"]["perturbation"]["dropout"] == dropout


def test_the_replay_line_reproduces_the_failure_and_the_edge_next_to_it_passes(demo):
    demo.runpytest("--driveeval-search-profile=ci")
    search = record_of(demo)["details"]["search"]
    line = search["replay"]
    value = line.split("--driveeval-replay ", 1)[1]
    assert line == f"pytest {shlex.quote(NODE)} --driveeval-replay {shlex.quote(value)}"
    demo.runpytest(NODE, "--driveeval-replay", value, "--driveeval-output", "replayed").assert_outcomes(xfailed=1)
    replayed = record_of(demo, "replayed")
    assert replayed["details"]["replay"] == value
    assert replayed["details"]["perturbation"] == search["minimal"]["perturbation"]
    assert replayed["figures"]["detection_rate"] == 0.0 and replayed["figures"]["frames"] == 1
    frame = search["where"]["frame"]
    demo.runpytest(NODE, "--driveeval-replay", f"frame={frame},dropout={search['edge']['dropout']!r}",
                   "--driveeval-output", "edge").assert_outcomes(failed=1)   # strict xfail: a pass fails
    edge = record_of(demo, "edge")
    assert edge["verdict"] == "passed" and any(k.startswith(f"frame_{frame}_") for k in edge["artefacts"])


def test_the_ci_profile_gives_the_same_search_twice(demo):
    runs = []
    for output in ("first", "second"):
        demo.runpytest("--driveeval-search-profile=ci", "--driveeval-output", output).assert_outcomes(xfailed=1)
        search = record_of(demo, output)["details"]["search"]
        search.pop("seconds")
        runs.append(search)
    assert runs[0] == runs[1] and runs[0]["replayed_from_database"] == 0


def test_serial_and_two_workers_agree_and_a_stored_failure_comes_first(demo):
    runs = {}
    # Serially in this process (the search's draws do not depend on what it imported before: the
    # engine hides hypothesis's local constants), against two worker processes.
    for name, run, extra in (("serial", demo.runpytest, []), ("xdist", demo.runpytest_subprocess, ["-n", "2"])):
        # The default profile, also under CI=true (whose default is the ci profile, without the database).
        run("--driveeval-output", name, "--driveeval-search-profile=default", *extra).assert_outcomes(xfailed=1)
        runs[name] = record_of(demo, name)["details"]["search"]
    keys = ("examples", "failures", "generations", "evaluations", "shrunk", "minimal", "edge", "where", "reason")
    assert {k: runs["serial"][k] for k in keys} == {k: runs["xdist"][k] for k in keys}
    demo.runpytest("--driveeval-output", "serial", "--driveeval-search-profile=default").assert_outcomes(xfailed=1)
    again = record_of(demo, "serial")["details"]["search"]
    assert again["replayed_from_database"] >= 1 and again["generations"] == 1
    assert again["minimal"] == runs["serial"]["minimal"]


def test_the_shrunk_case_its_picture_and_the_replay_reach_the_html_and_allure_reports(demo):
    # Without the XFail envelope: an xfailed item's reports carry pytest's one-line reason only.
    path = demo.path / "scenarios" / "dropout.scenario.yaml"
    path.write_text(re.sub(r"XFail:\n(?: .*\n)+", "", path.read_text()))
    demo.runpytest("--driveeval-search-profile=ci", "--html=report.html", "--self-contained-html",
                   "--alluredir=allure").assert_outcomes(failed=1)
    page = html.unescape((demo.path / "report.html").read_text())
    assert "--driveeval-replay frame=" in page and "data:image/png;base64," in page
    (result,) = [json.loads(p.read_text()) for p in (demo.path / "allure").glob("*-result.json")]
    assert any(a["type"] == "image/png" and a["name"].startswith("frame_") for a in result["attachments"])
    assert "--driveeval-replay" in json.dumps(result)


def test_a_perturbation_section_without_a_filter_says_to_override_the_fixture(demo):
    (demo.path / "scenarios" / "conftest.py").unlink()
    result = demo.runpytest()
    out = result.stdout.str()
    assert "dropout.scenario.yaml:" in out and "Evaluation.Perturbation" in out
    assert "driveeval_pointclouds must be overridden in conftest.py to return a callable raw_points -> " \
           "obstacle_points" in out


@pytest.mark.parametrize("perturbation, message", [
    ("{Dropout: [0.0, 1.5]}", "Dropout: a fraction of the points, within [0, 1]"),
    ("{Dropout: [0.1, 0.5]}", "Dropout: the range [0.1, 0.5] must contain 0 (no change)"),
    ("{RangeNoise: [-0.1, 0.1]}", "RangeNoise: a standard deviation (m) cannot be negative"),
    ("{Frames: 10}", "give at least one range to search"),
])
def test_a_bad_perturbation_section_is_located(demo, perturbation, message):
    path = demo.path / "scenarios" / "dropout.scenario.yaml"
    text = path.read_text()
    path.write_text(text[:text.index("  Perturbation:")] + f"  Perturbation: {perturbation}\n")
    out = demo.runpytest().stdout.str()
    assert message in out and "dropout.scenario.yaml:" in out


def test_ghost_points_need_a_non_detection_area(demo):
    path = demo.path / "scenarios" / "dropout.scenario.yaml"
    text = path.read_text()
    start, end = text.index("    NonDetection:"), text.index("  SensingEvaluationConfig:")
    text = text[:start] + "    NonDetection: null\n" + text[end:]
    path.write_text(text[:text.index("  Perturbation:")] + "  Perturbation: {GhostPoints: [0, 10]}\n")
    out = demo.runpytest().stdout.str()
    assert "Perturbation.GhostPoints needs a NonDetection condition" in out


def test_the_search_runs_on_the_real_nuscenes_sweep(pytester, shared_data):
    """The real sweep's one annotated box (a pedestrian 63 m away) holds one return: a filter that
    keeps what is above the ground detects it, and a dropout that drops that return fails."""
    (pytester.path / "conftest.py").write_text(
        "import pytest\n\n@pytest.fixture\ndef driveeval_pointclouds():\n"
        "    return lambda points: points[points[:, 2] > 0.3]\n")
    (pytester.path / "real.scenario.yaml").write_text(
        "ScenarioFormatVersion: 3.0.0\nScenarioName: real-sweep-dropout\nEvaluation:\n"
        "  UseCaseName: obstacle_segmentation\n  UseCaseFormatVersion: 0.1.0\n  Datasets:\n"
        f"    - t4_sample:\n        Path: {shared_data / 't4_sample'}\n"
        "  Conditions:\n    ObstacleDetection: {PassRate: 100.0}\n    NonDetection: null\n"
        "  SensingEvaluationConfig:\n    evaluation_config_dict: {target_uuids: null, min_points_threshold: 1}\n"
        "  Perturbation: {Dropout: [0.0, 1.0], Examples: 40, Batch: 8}\n")
    pytester.runpytest("-q", "--driveeval-search-profile=ci").assert_outcomes(failed=1)
    record = record_of(pytester)
    search = record["details"]["search"]
    assert record["details"]["search_frames"] == {"searched": 1, "skipped_before": 0, "more_not_searched": False}
    assert search["where"]["frame"] == 0 and search["reason"].endswith("has 0 of 1 point(s) needed")
    assert 0 < search["edge"]["dropout"] < search["minimal"]["perturbation"]["dropout"] <= 1.0
    assert search["examples"] >= 2 and "--driveeval-replay frame=0,dropout=" in search["replay"]


def test_without_a_perturbation_section_the_filter_passes_the_clean_sweeps(demo):
    text = (DEMO / "filtered.scenario.yaml").read_text().replace("../../../fixtures/t4/clean", str(CLEAN))
    (demo.path / "scenarios" / "filtered.scenario.yaml").write_text(text)
    demo.runpytest("scenarios/filtered.scenario.yaml").assert_outcomes(passed=1)
    record = record_of(demo)
    assert record["figures"]["frames"] == 10 and record["figures"]["detection_rate"] == 100.0
    assert record["figures"]["non_detection_rate"] == 100.0 and "search" not in record["details"]


def test_frames_bounds_the_search_and_a_bag_topic_is_searched_as_structured_clouds(demo):
    path = demo.path / "scenarios" / "dropout.scenario.yaml"
    text = path.read_text().replace(
        "PointCloud: {RawTopic: null}", "PointCloud: {RawTopic: /perception/obstacle_segmentation/pointcloud}")
    path.write_text(text.replace("    Examples: 100\n", "    Examples: 40\n    Frames: 3\n"))
    demo.runpytest("--driveeval-search-profile=ci").assert_outcomes(xfailed=1)
    record = record_of(demo)
    assert record["details"]["search_frames"] == {"searched": 3, "skipped_before": 0, "more_not_searched": True}
    assert "the first 3 frames only" in record["summary"]
    search = record["details"]["search"]
    assert search["where"]["frame"] in (0, 1, 2) and "of 10 point(s) needed" in search["reason"]
