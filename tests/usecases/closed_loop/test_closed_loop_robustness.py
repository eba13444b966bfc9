"""The closed-loop robustness search end to end: the demo's reported edge, replay, reproducibility, YAML errors."""
from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")

from conftest import REPO_ROOT  # noqa: E402

DEMO = REPO_ROOT / "scenario_tests" / "robustness" / "real_scene_lateral.scenario.yaml"
REAL = REPO_ROOT / "fixtures" / "l5kit" / "single_scene.zarr"
MODEL = REPO_ROOT / "fixtures" / "models" / "planning_model.pt2"


@pytest.fixture
def demo(pytester):
    """The demo scenario in a project of its own, naming the repository's data and model."""
    text = DEMO.read_text().replace("../../fixtures/l5kit/single_scene.zarr", str(REAL)).replace(
        "../../fixtures/models/planning_model.pt2", str(MODEL))
    assert str(REAL) in text and str(MODEL) in text
    (pytester.path / "scenarios").mkdir()
    (pytester.path / "scenarios" / DEMO.name).write_text(text)
    pytester.makeini("[pytest]\nmarkers =\n    demo\n    robustness\n")
    return pytester


def search_record(pytester, output="driveeval-results") -> dict:
    data = json.loads((pytester.path / output / "summary.json").read_text())
    (record,) = data["results"]
    return record


def lateral_fails(lateral: float) -> bool:
    """The demo's verdict on one lateral offset, from the Python API: an independent oracle."""
    from pytest_driveeval.closed_loop import judge_scene, unroll_scenes
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.policies.loading import load_model
    from pytest_driveeval.strategies import StartPerturbation
    from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConditions

    from pytest_driveeval.sim.torch_threads import one_torch_thread

    conditions = ClosedLoopConditions.model_validate(
        {"Collisions": {"Front": 0, "Side": 0, "Rear": 0, "AtFaultOnly": True},
         "Displacement": {"Max": 4.0, "Duration": 1.0}})
    with one_torch_thread():
        unroll = unroll_scenes(L5Dataset.open(REAL), load_model(str(MODEL)), [0], start_frame=10, steps=100,
                               drift_threshold=10.0, perturbation=StartPerturbation(lateral=lateral))
    return not judge_scene(unroll, 0, conditions).passed


def bisect_edge(passing: float, failing: float, tolerance: float = 0.01) -> float:
    while abs(failing - passing) > tolerance:
        middle = (passing + failing) / 2
        passing, failing = (passing, middle) if lateral_fails(middle) else (middle, failing)
    return failing


def test_the_demo_reports_the_nearest_edge_of_failure_that_bisection_finds(demo):
    demo.runpytest("--driveeval-search-profile=ci", "-p", "no:randomly").assert_outcomes(xfailed=1)
    record = search_record(demo)
    search = record["details"]["search"]
    reported = search["minimal"]["perturbation"]["lateral"]
    # Independent bisection from no change to each end of the range, one unroll at a time.
    edges = [bisect_edge(0.0, end) for end in (-6.0, 6.0) if lateral_fails(end)]
    nearest = min(edges, key=abs)
    assert abs(reported - nearest) <= 0.01 * 12.0, (reported, edges)  # Tolerance 1 % of the 12 m range
    assert lateral_fails(reported) and not lateral_fails(search["edge"]["lateral"])
    assert record["figures"]["minimal_lateral"] == reported
    assert search["where"]["scene"] == 0 and "Displacement" in search["reason"]
    assert "scene_0_gif" in record["artefacts"]  # the picture of the failing case
    assert search["examples"] <= 200 + 64 and search["failures"] >= 1


def test_the_replay_line_reproduces_the_failure_and_the_edge_next_to_it_passes(demo):
    demo.runpytest("--driveeval-search-profile=ci")
    search = search_record(demo)["details"]["search"]
    line = search["replay"]
    assert line.startswith("pytest ") and "--driveeval-replay" in line
    value = line.split("--driveeval-replay ", 1)[1]
    node = line.split(" ")[1].strip("'")
    result = demo.runpytest(node, "--driveeval-replay", value, "--driveeval-output", "replayed")
    result.assert_outcomes(xfailed=1)
    replayed = search_record(demo, "replayed")
    assert replayed["details"]["replay"] == value and replayed["details"]["perturbation"]["lateral"] == \
        search["minimal"]["perturbation"]["lateral"]
    assert replayed["figures"]["max_displacement"] > 4.0
    edge = search["edge"]["lateral"]
    demo.runpytest(node, "--driveeval-replay", f"scene=0,lateral={edge!r}", "--driveeval-output", "edge"
                   ).assert_outcomes(xpassed=0, failed=1)  # strict xfail: passing is reported as a failure
    assert search_record(demo, "edge")["verdict"] == "passed"


def test_serial_and_two_workers_give_the_same_search_and_a_stored_failure_comes_first(demo):
    runs = {}
    for name, extra in (("serial", []), ("xdist", ["-n", "2"])):
        # The default profile, also under CI=true (whose default is the ci profile, without the database).
        demo.runpytest_subprocess("--driveeval-output", name, "--driveeval-search-profile=default", *extra
                                  ).assert_outcomes(xfailed=1)
        runs[name] = search_record(demo, name)["details"]["search"]
    keys = ("examples", "failures", "generations", "evaluations", "shrunk", "minimal", "edge", "where")
    assert {k: runs["serial"][k] for k in keys} == {k: runs["xdist"][k] for k in keys}
    assert runs["serial"]["replayed_from_database"] == 0
    demo.runpytest_subprocess("--driveeval-output", "serial", "--driveeval-search-profile=default"
                              ).assert_outcomes(xfailed=1)
    again = search_record(demo, "serial")["details"]["search"]
    assert again["replayed_from_database"] >= 1 and again["generations"] == 1
    assert again["minimal"] == runs["serial"]["minimal"]


def test_two_scenarios_on_the_same_data_never_share_examples(demo):
    other = (demo.path / "scenarios" / DEMO.name).read_text().replace(
        "ScenarioName: real-scene-planning-model-lateral-offset", "ScenarioName: another-search")
    (demo.path / "scenarios" / "another.scenario.yaml").write_text(other)
    demo.runpytest("scenarios/" + DEMO.name, "--driveeval-search-profile=default")
    assert search_record(demo)["details"]["search"]["replayed_from_database"] == 0
    demo.runpytest("scenarios/" + DEMO.name, "--driveeval-search-profile=default")
    assert search_record(demo)["details"]["search"]["replayed_from_database"] >= 1
    demo.runpytest("scenarios/another.scenario.yaml", "--driveeval-output", "second", "--driveeval-search-profile=default")
    assert search_record(demo, "second")["details"]["search"]["replayed_from_database"] == 0


@pytest.mark.parametrize("perturbation, message", [
    ("{Lateral: [1.0, 3.0]}", "Lateral: the range [1, 3] must contain 0 (no change)"),
    ("{SpeedScale: [0.0, 1.5]}", "SpeedScale: a speed scale must stay above 0"),
    ("{Lateal: [-1, 1]}", "Lateal"),
    ("{Examples: 50}", "give at least one range to search"),
])
def test_a_bad_perturbation_section_is_located(demo, perturbation, message):
    path = demo.path / "scenarios" / DEMO.name
    text = path.read_text()
    start = text.index("  Perturbation:")
    path.write_text(text[:start] + f"  Perturbation: {perturbation}\n")
    result = demo.runpytest()
    result.assert_outcomes(errors=1) if "errors" in result.parseoutcomes() else result.assert_outcomes(failed=1)
    out = result.stdout.str()
    assert message in out and f"{DEMO.name}:" in out


def test_a_replay_of_an_unknown_field_or_scene_says_what_is_known(demo):
    result = demo.runpytest("--driveeval-replay", "scene=0,latteral=1.0")
    assert "latteral not a perturbation of closed_loop" in result.stdout.str()
    assert "Lateral" in result.stdout.str()
    result = demo.runpytest("--driveeval-replay", "scene=4,lateral=1.0")
    assert "scene 4 is not one of this item's (0)" in result.stdout.str()


def test_an_expected_failure_still_shows_its_search_in_html_allure_and_markdown(demo):
    import html

    demo.runpytest("--driveeval-search-profile=ci", "--html=report.html", "--self-contained-html",
                   "--alluredir=allure").assert_outcomes(xfailed=1)
    search = search_record(demo)["details"]["search"]
    minimal = search["minimal_text"]
    assert minimal.startswith("lateral=")
    page = html.unescape(html.unescape((demo.path / "report.html").read_text()))  # extras are escaped twice
    assert f"smallest failing perturbation: {minimal}" in page and search["replay"] in page
    assert "data:image/gif;base64," in page  # the failing unroll's animation
    (result,) = [json.loads(p.read_text()) for p in (demo.path / "allure").glob("*-result.json")]
    kinds = {a["name"]: a["type"] for a in result["attachments"]}
    assert kinds["robustness search"] == "text/plain" and kinds["scene_0_gif"] == "image/gif"
    text = next((demo.path / "allure").glob(
        next(a["source"] for a in result["attachments"] if a["name"] == "robustness search"))).read_text()
    assert minimal in text and search["replay"] in text and f"{search['examples']} examples" in text
    markdown = (demo.path / "driveeval-results" / "summary.md").read_text()
    assert f"**{minimal}**" in markdown and "--driveeval-replay" in markdown


def test_the_replay_line_repeats_a_session_seed_that_is_not_the_default(demo):
    demo.runpytest("--driveeval-search-profile=ci", "--driveeval-seed", "7")
    assert search_record(demo)["details"]["search"]["replay"].endswith(" --driveeval-seed 7")


def test_a_search_in_local_chunks_finds_what_the_one_process_search_finds(demo):
    """Executor Kind: local with a ChunkSize judges each generation in chunks, as a Ray run would
    (each chunk on its own stacking of the scene): the same search, and the report says where."""
    demo.runpytest("-p", "no:randomly", "--driveeval-search-profile", "ci", "--driveeval-output", "plain")
    demo.runpytest("-p", "no:randomly", "--driveeval-search-profile", "ci", "--driveeval-output", "chunked",
                   "--driveeval-executor", "{Kind: local, ChunkSize: 16}")
    plain, chunked = search_record(demo, "plain"), search_record(demo, "chunked")
    assert chunked["details"]["search"]["minimal"] == plain["details"]["search"]["minimal"]
    assert chunked["details"]["search"]["examples"] == plain["details"]["search"]["examples"]
    assert "executor" not in plain["details"]
    assert chunked["details"]["executor"]["chunks_per_node"], chunked["details"]["executor"]
