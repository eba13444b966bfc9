"""A session compared with its baseline, as people read it: the terminal table (coloured),
summary.md, pytest-html (delta cells and the trend plot) and allure (the trend plot)."""
from __future__ import annotations

import base64
import html
import json
import re
import shutil

import pytest

pytest.importorskip("torch")

from conftest import POLICY_BENCHMARK_HEAD, REPO_ROOT  # noqa: E402
from module_pytester import module_pytester  # noqa: E402

SCENARIO = POLICY_BENCHMARK_HEAD.format(name="merge") + """\
  Blueprint: {Name: merging}
  Episodes: 24
  Policies:
    gnn: gnn_actor_merging.pt2
  Conditions:
    GoalRate: {AtLeast: 10}
"""
ITEM = "merge.scenario.yaml::policy_benchmark[gnn]"
RED = "\x1b[31m\x1b[1m"


@pytest.fixture
def merge_bench(pytester):
    """The merging benchmark with the shipped GNN (not named `benchmark`: pytest-benchmark, where installed,
    owns that fixture name and fails every test that takes another one)."""
    shutil.copy(REPO_ROOT / "fixtures" / "models" / "gnn_actor_merging.pt2", pytester.path)
    pytester.makefile(".scenario.yaml", merge=SCENARIO)
    return pytester


def html_tests(path) -> list[dict]:
    blob = json.loads(html.unescape(re.search(r'data-jsonblob="([^"]*)"', path.read_text()).group(1)))
    return [phase for phases in blob["tests"].values() for phase in phases]


def html_extras(path) -> list[dict]:
    return [e for phase in html_tests(path) for e in phase["extras"]]


@pytest.fixture(scope="module")
def updated(request, tmp_path_factory):
    """The benchmark's folder after its baseline update, made once for both runs of the test below."""
    with module_pytester(request, tmp_path_factory) as pytester:
        shutil.copy(REPO_ROOT / "fixtures" / "models" / "gnn_actor_merging.pt2", pytester.path)
        pytester.makefile(".scenario.yaml", merge=SCENARIO)
        pytester.runpytest("-q", "--driveeval-baseline", "bl", "--driveeval-baseline-update").assert_outcomes(passed=1)
        return pytester.path


@pytest.mark.parametrize("workers", [[], ["-n", "2"]])
def test_a_regression_in_every_report(pytester, updated, monkeypatch, workers):
    merge_bench = pytester
    shutil.copytree(updated, merge_bench.path, dirs_exist_ok=True)
    monkeypatch.setenv("COLUMNS", "250")
    # The shipped GNN reaches its goal in every episode; a constant policy in none.
    result = merge_bench.runpytest("-q", "--driveeval-baseline", "bl", "--driveeval-model", "constant", "--color=yes",
                                 "--html=report.html", "--self-contained-html", "--alluredir=allure", *workers)
    result.assert_outcomes(failed=1)

    table = result.stdout.str().split("scenario item(s)")[1].split("results:")[0]
    assert f"{RED}baseline: regressed" in table
    assert f"{RED}goal_rate=0 (100, ▼100)" in table

    markdown = (merge_bench.path / "driveeval-results" / "summary.md").read_text()
    assert "🔴 goal_rate=0 (100, ▼100)" in markdown and "| 🔴 regressed |" in markdown
    section = markdown.split("### Compared with baseline `")[1]
    assert f"- 🔴 regressed: `{ITEM}`" in section and "  - goal_rate 100 % -> 0 % [paired 95 %" in section

    extras = html_extras(merge_bench.path / "report.html")
    table = next(e["content"] for e in extras if e["format_type"] == "html")
    assert "<th>baseline</th><th>change</th>" in table
    assert re.search(r"<td>goal_rate</td><td>0</td><td class='driveeval-baseline-value'>100</td>"
                     r"<td class='driveeval-change driveeval-worse' style='color:#c62828[^']*'>▼100</td>", table)
    assert "baseline: regressed</span>: regression against baseline" in table
    [row] = [phase["resultsTableRow"] for phase in html_tests(merge_bench.path / "report.html")]
    assert re.fullmatch(r'<td class="col-driveeval-baseline"><span style="color:#c62828[^"]*">regressed</span>: '
                        r"<span style='color:#c62828[^']*'>goal_rate ▼100</span>, .*</td>", row[-1])
    assert "<th class=\"col-driveeval-baseline\">baseline</th>" in (merge_bench.path / "report.html").read_text()
    trend = next(e for e in extras if e["name"] == "trend")
    png = base64.b64decode(trend["content"].split(",", 1)[1])
    assert png.startswith(b"\x89PNG") and len(png) > 2000

    [allure] = [json.loads(p.read_text()) for p in (merge_bench.path / "allure").glob("*-result.json")]
    [attachment] = [a for a in allure["attachments"] if a["name"] == "trend"]
    assert attachment["type"] == "image/png"
    assert (merge_bench.path / "allure" / attachment["source"]).read_bytes().startswith(b"\x89PNG")


def test_no_trend_before_an_earlier_run_and_no_delta_without_a_baseline(merge_bench):
    merge_bench.runpytest("-q", "--html=report.html", "--self-contained-html").assert_outcomes(passed=1)
    extras = html_extras(merge_bench.path / "report.html")
    assert "trend" not in [e["name"] for e in extras]
    assert "driveeval-change" not in next(e["content"] for e in extras if e["format_type"] == "html")
    assert "col-driveeval-baseline" not in (merge_bench.path / "report.html").read_text()
