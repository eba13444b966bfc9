"""The closed-loop robustness search end to end: the demo's reported edge, replay, its reports, YAML errors
(reproducibility, the example database and chunks: test_closed_loop_search_reproducibility.py)."""
from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import pytest

pytest.importorskip("torch")

from robustness_demo import DEMO, MODEL, REAL, demo_project, search_record, session  # noqa: E402


@pytest.fixture
def demo(pytester):
    demo_project(pytester.path)
    return pytester


@pytest.fixture(scope="module")
def ci_search(tmp_path_factory) -> Path:
    """The demo's search under the ci profile, once for the tests that read it: its record, its
    replay line, its HTML, Allure and markdown reports (report options do not change the search)."""
    folder = demo_project(tmp_path_factory.mktemp("ci_search"))
    assert session(folder, "--driveeval-search-profile=ci", "-p", "no:randomly", "--html=report.html",
                   "--self-contained-html", "--alluredir=allure") == {"xfailed": 1}
    return folder


@lru_cache(maxsize=1)
def real_scene_and_model():
    """The demo's dataset and model, opened once for all the oracle's unrolls."""
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.policies.loading import load_model

    return L5Dataset.open(REAL), load_model(str(MODEL))


def demo_conditions():
    """The demo scenario's Conditions, as the oracle judges each unroll by them."""
    from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConditions

    return ClosedLoopConditions.model_validate(
        {"Collisions": {"Front": 0, "Side": 0, "Rear": 0, "AtFaultOnly": True},
         "Displacement": {"Max": 4.0, "Duration": 1.0}})


def laterals_fail(laterals: list[float]) -> list[bool]:
    """The demo's verdict on each lateral offset, from the Python API: an independent oracle.  One
    unroll of as many copies of the scene, each moved by its offset (as unroll_scenes stacks scenes)."""
    from pytest_driveeval.closed_loop import judge_scene
    from pytest_driveeval.sim.torch_threads import one_torch_thread
    from pytest_driveeval.strategies import StartPerturbation
    from pytest_driveeval.usecases.closed_loop.evaluate import stack_log, unroll_config, unroll_log
    from pytest_driveeval.usecases.closed_loop.score import SceneMaps

    dataset, model = real_scene_and_model()
    conditions = demo_conditions()
    config = unroll_config(start_frame=10, steps=100, drift_threshold=10.0, freeze_on_collision=True,
                           kinematic=False, history_frames=10, future_frames=12, max_agents=30)
    with one_torch_thread():
        unroll = unroll_log(stack_log(dataset, [0] * len(laterals), 10), model, config,
                            [StartPerturbation(lateral=float(x)) for x in laterals])
    unroll.maps = SceneMaps(dataset)
    return [not judge_scene(unroll, row, conditions).passed for row in range(len(laterals))]


def lateral_fails(lateral: float) -> bool:
    """The demo's verdict on one lateral offset, as unroll_scenes gives it for the scene alone."""
    from pytest_driveeval.closed_loop import judge_scene, unroll_scenes
    from pytest_driveeval.sim.torch_threads import one_torch_thread
    from pytest_driveeval.strategies import StartPerturbation

    dataset, model = real_scene_and_model()
    conditions = demo_conditions()
    with one_torch_thread():
        unroll = unroll_scenes(dataset, model, [0], start_frame=10, steps=100, drift_threshold=10.0,
                               perturbation=StartPerturbation(lateral=lateral))
    return not judge_scene(unroll, 0, conditions).passed


def bisect_edges(ends: tuple[float, ...], parts: int = 9, tolerance: float = 0.01) -> list[float]:
    """Per end of the range that fails: bisection from no change towards it, to a failing offset
    within ``tolerance`` of a passing one.  Each round splits every bracket into ``parts`` and keeps
    the part where failing starts, nearest no change; all brackets' points go through one unroll,
    the first round's together with the ends themselves (the bracket of an end that passes is
    dropped, its points unused).  Nine parts: three rounds reach 1 cm on a 6 m side (9**3 > 600),
    in three unrolls of 18 or 16 offsets (sixteen parts took four, the first for the ends alone)."""
    brackets = {end: (0.0, end) for end in ends}
    checked = False
    while any(abs(failing - passing) > tolerance for passing, failing in brackets.values()):
        points = {end: [passing + (failing - passing) * k / parts for k in range(1, parts)]
                  for end, (passing, failing) in brackets.items() if abs(failing - passing) > tolerance}
        verdicts = laterals_fail(([] if checked else list(ends)) + [x for xs in points.values() for x in xs])
        if not checked:
            checked, failing_ends = True, {end for end, fails in zip(ends, verdicts) if fails}
            brackets = {end: bracket for end, bracket in brackets.items() if end in failing_ends}
            verdicts = verdicts[len(ends):]
        verdicts = iter(verdicts)
        for end, xs in points.items():
            asked = [(x, next(verdicts)) for x in xs]
            if end not in brackets:
                continue
            passing, failing = brackets[end]
            for x, fails in asked:
                if fails:
                    failing = x
                    break
                passing = x
            brackets[end] = passing, failing
    return [failing for _, failing in brackets.values()]


def test_the_demo_reports_the_nearest_edge_of_failure_that_bisection_finds(ci_search):
    record = search_record(ci_search)
    search = record["details"]["search"]
    reported = search["minimal"]["perturbation"]["lateral"]
    # Independent bisection from no change to each end of the range.
    edges = bisect_edges((-6.0, 6.0))
    nearest = min(edges, key=abs)
    assert abs(reported - nearest) <= 0.01 * 12.0, (reported, edges)  # Tolerance 1 % of the 12 m range
    assert lateral_fails(reported) and not lateral_fails(search["edge"]["lateral"])
    assert record["figures"]["minimal_lateral"] == reported
    assert search["where"]["scene"] == 0 and "Displacement" in search["reason"]
    assert "scene_0_gif" in record["artefacts"]  # the picture of the failing case
    assert search["examples"] <= 200 + 64 and search["failures"] >= 1


def test_the_replay_line_reproduces_the_failure_and_the_edge_next_to_it_passes(demo, ci_search):
    search = search_record(ci_search)["details"]["search"]
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


def test_an_expected_failure_still_shows_its_search_in_html_allure_and_markdown(ci_search):
    import html

    search = search_record(ci_search)["details"]["search"]
    minimal = search["minimal_text"]
    assert minimal.startswith("lateral=")
    page = html.unescape(html.unescape((ci_search / "report.html").read_text()))  # extras are escaped twice
    assert f"smallest failing perturbation: {minimal}" in page and search["replay"] in page
    assert "data:image/gif;base64," in page  # the failing unroll's animation
    (result,) = [json.loads(p.read_text()) for p in (ci_search / "allure").glob("*-result.json")]
    kinds = {a["name"]: a["type"] for a in result["attachments"]}
    assert kinds["robustness search"] == "text/plain" and kinds["scene_0_gif"] == "image/gif"
    text = next((ci_search / "allure").glob(
        next(a["source"] for a in result["attachments"] if a["name"] == "robustness search"))).read_text()
    assert minimal in text and search["replay"] in text and f"{search['examples']} examples" in text
    markdown = (ci_search / "driveeval-results" / "summary.md").read_text()
    assert f"**{minimal}**" in markdown and "--driveeval-replay" in markdown
