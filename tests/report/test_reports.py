"""Each report kind carries every item's figures and artefacts, exactly once."""
from __future__ import annotations

import html
import json
import re
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

pytest.importorskip("torch")

from conftest import REPO_ROOT  # noqa: E402
from module_pytester import module_pytester  # noqa: E402

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
ScenarioDescription: replaying the log, for the reports
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - logs: {{Path: gen.zarr}}
  Model: {model}
  Unroll: {{Scenes: [0], StartFrame: 10, Steps: 20}}
  Conditions:
    Collisions: {{Front: 0, Side: 0, Rear: 0}}
  Artefacts: {{Animations: all}}
"""
ARTEFACTS = {"result", "chart", "scene_0_gif"}


def with_two_scenarios(pytester) -> None:
    shutil.copytree(REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr", pytester.path / "gen.zarr")
    pytester.makefile(".scenario.yaml", a=SCENARIO.format(name="a", model="log_replay"),
                      b=SCENARIO.format(name="b", model="log_replay"))


@pytest.fixture
def two(pytester):
    with_two_scenarios(pytester)
    return pytester


REPORTS = ("--html=report.html", "--self-contained-html", "--alluredir=allure", "--junitxml=junit.xml")


@pytest.fixture(scope="module")
def reported(request, tmp_path_factory):
    """The folder of one session of 'a' and 'b' with every report at once (serial or under ``-n 2``),
    run once per module: each report's test only reads its own file."""
    folders = {}

    def run(workers: list[str]) -> Path:
        key = tuple(workers)
        if key not in folders:
            with module_pytester(request, tmp_path_factory) as pytester:
                with_two_scenarios(pytester)
                pytester.runpytest("-q", *REPORTS, *workers).assert_outcomes(passed=2)
                folders[key] = pytester.path
        return folders[key]

    return run


def html_tests(path) -> dict:
    blob = re.search(r'data-jsonblob="([^"]*)"', path.read_text()).group(1)
    return json.loads(html.unescape(blob))["tests"]


@pytest.mark.parametrize("workers", [[], ["-n", "2"]])
def test_pytest_html_extras_inline_images_once_per_item(reported, workers):
    tests = html_tests(reported(workers) / "report.html")
    assert len(tests) == 2
    for phases in tests.values():
        extras = [e for phase in phases for e in phase["extras"]]
        names = [e["name"] for e in extras if e["format_type"] != "html"]
        assert sorted(names) == sorted(ARTEFACTS)
        by_name = {e["name"]: e for e in extras}
        assert by_name["scene_0_gif"]["content"].startswith("data:image/gif;base64,R0lGOD")
        assert by_name["chart"]["content"].startswith("data:image/png;base64,iVBOR")
        assert by_name["result"]["format_type"] == "json"
        figures, scores = [e["content"] for e in extras if e["format_type"] == "html"]
        assert "<td>front</td><td>0</td>" in figures
        # the scene's nuPlan score, term by term; the generated scene has no map: its map terms n/a
        assert "nuPlan score per scene" in scores and "<td>n/a</td>" in scores and "the scene has no map" in scores
        assert "<td>0 (gen.zarr)</td>" in scores  # the scene by its index and its zarr


@pytest.mark.parametrize("workers", [[], ["-n", "2"]])
def test_allure_results_have_typed_attachments_labels_and_figures(reported, workers):
    allure = reported(workers) / "allure"
    results = [json.loads(p.read_text()) for p in allure.glob("*-result.json")]
    assert sorted(r["name"] for r in results) == ["a [logs]", "b [logs]"]
    for r in results:
        types = sorted((a["name"], a["type"]) for a in r["attachments"])
        assert types == [("chart", "image/png"), ("nuPlan score per scene", "text/plain"),
                         ("result", "application/json"), ("scene_0_gif", "image/gif")]
        labels = {(label["name"], label["value"]) for label in r["labels"]}
        assert ("use_case", "closed_loop") in labels and ("feature", "closed_loop") in labels
        params = {p["name"]: p["value"] for p in r["parameters"]}
        assert params["dataset"] == "'logs'" and params["front"] == "0" and params["steps"] == "20"
        assert r["description"] == "replaying the log, for the reports"
        for attachment in r["attachments"]:
            assert (allure / attachment["source"]).stat().st_size > 100
        (scores,) = [a for a in r["attachments"] if a["name"] == "nuPlan score per scene"]
        assert "0 (gen.zarr)" in (allure / scores["source"]).read_text()  # the scene's zarr too


@pytest.mark.parametrize("workers", [[], ["-n", "2"]])
def test_junit_properties_carry_key_figures(reported, workers):
    cases = list(ET.parse(reported(workers) / "junit.xml").getroot().iter("testcase"))
    assert len(cases) == 2
    for case in cases:
        props = [(p.get("name"), p.get("value")) for p in case.iter("property")]
        names = [n for n, _ in props]
        assert len(names) == len(set(names)), "a property appears twice"
        assert ("driveeval.verdict", "passed") in props and ("driveeval.front", "0") in props
        assert ("driveeval.use_case", "closed_loop") in props


@pytest.fixture(scope="module")
def plain(request, tmp_path_factory):
    """One ``-n 2`` session of 'a', 'b' and a failing 'c', without pytest-html and allure, in a CI
    step whose summary file holds an earlier step's text: the markdown test and the test without the
    report plugins read it (two inner ``-n 2`` sessions were the most of this module's time)."""
    with module_pytester(request, tmp_path_factory) as pytester:
        with_two_scenarios(pytester)
        step = pytester.path / "step_summary.md"
        step.write_text("earlier step\n")
        pytester.makefile(".scenario.yaml", c=SCENARIO.format(name="c", model="constant_velocity").replace(
            "Steps: 20", "Steps: 140").replace("Rear: 0}", "Rear: 0}\n    MaxResets: 0"))
        with pytest.MonkeyPatch.context() as monkeypatch:
            monkeypatch.setenv("GITHUB_STEP_SUMMARY", str(step))
            result = pytester.runpytest("-q", "-p", "no:html", "-p", "no:allure_pytest", "-n", "2")
        return pytester.path, result


def test_markdown_summary_and_ci_step_summary(plain):
    folder, _ = plain
    markdown = (folder / "driveeval-results" / "summary.md").read_text()
    assert markdown.startswith("## pytest-driveeval: 1 failed, 2 passed (run `")
    assert "| ✅ passed | `a.scenario.yaml::closed_loop[logs]` | closed_loop |" in markdown
    assert "| ❌ failed | `c.scenario.yaml::closed_loop[logs]` | closed_loop |" in markdown
    assert (folder / "step_summary.md").read_text() == "earlier step\n" + markdown


def test_without_the_report_plugins_nothing_breaks(plain):
    folder, result = plain
    result.assert_outcomes(passed=2, failed=1)  # 'c' fails by its own conditions (a collision), as it should
    summary = json.loads((folder / "driveeval-results" / "summary.json").read_text())
    assert {r["nodeid"].split(".")[0]: r["status"] for r in summary["results"]} == {
        "a": "passed", "b": "passed", "c": "failed"}


def test_markdown_compares_policies_on_the_same_data(two):
    two.makefile(".scenario.yaml", cv=SCENARIO.format(name="cv", model="constant_velocity"))
    two.runpytest("-q")
    markdown = (two.path / "driveeval-results" / "summary.md").read_text()
    table = markdown.split("### Policies by scenario")[1].strip().splitlines()
    assert table[0] == "| use case | data | `constant_velocity` | `log_replay` |"
    assert table[2].startswith("| closed_loop | logs | ✅ front=0") and table[2].count("✅") == 2


def test_numpy_scalars_reach_the_reports_as_plain_python():
    import numpy as np

    from pytest_driveeval.core.outcome import Outcome
    from pytest_driveeval.report.attachments import junit_properties, scalar_figures

    outcome = Outcome("u", "passed", "s", figures={"rate": np.float64(100.0), "n": np.int64(3), "ok": np.bool_(True),
                                                   "curve": np.arange(3.0)})
    figures = scalar_figures(outcome)
    # An np.int64 (no int subclass) was left out, an np.float64 kept its type into allure's repr.
    assert figures == {"rate": 100.0, "n": 3, "ok": True}
    assert [type(v) for v in figures.values()] == [float, int, bool]
    assert junit_properties(outcome)[2:] == [("driveeval.rate", "100"), ("driveeval.n", "3"), ("driveeval.ok", "true")]
