"""Every session keeps its results: a run folder each, a history, nothing of
the user's deleted, files whole and with the user's umask."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import GAIN_SCENARIO, NO_HYPOTHESIS_PLUGIN
from test_fixtures import summary

# With GATE set, the model waits (bounded) until that file exists: a test orders sessions by
# files it creates, not by how long a loaded machine takes to start them.
SLOW_MODEL = """import os, time

def double(x):
    time.sleep(float(os.environ['DELAY']))
    gate = os.environ.get('GATE')
    give_up = time.monotonic() + 120
    while gate and not os.path.exists(gate) and time.monotonic() < give_up:
        time.sleep(0.02)
    return 2 * x
"""


def run_ids(pytester, folder="driveeval-results") -> list[str]:
    return sorted(p.name for p in (pytester.path / folder / "runs").iterdir())


def history(pytester) -> list[dict]:
    text = (pytester.path / "driveeval-results" / "history.jsonl").read_text()
    return [json.loads(line) for line in text.splitlines()]


def test_each_session_keeps_its_own_run_and_the_latest_is_the_summary(gain):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"))
    gain.runpytest("-q", "--driveeval-output", "out").assert_outcomes(passed=1)
    first = summary(gain, "out")
    gain.runpytest("-q", "--driveeval-output", "out").assert_outcomes(passed=1)
    second = summary(gain, "out")
    assert first["run"]["id"] != second["run"]["id"]
    assert run_ids(gain, "out") == sorted([first["run"]["id"], second["run"]["id"]])
    for run in (first, second):
        (record,) = run["results"]
        assert record["artefacts"] == {"output": f"runs/{run['run']['id']}/items/a.scenario.yaml_gain/output.json"}
        assert (gain.path / "out" / record["artefacts"]["output"]).read_text() == "6.0"
        own = gain.path / "out" / "runs" / run["run"]["id"]
        assert json.loads((own / "summary.json").read_text()) == run
        marker = json.loads((own / "run.json").read_text())
        assert marker["state"] == "finished" and marker["run"] == run["run"]
        assert "items/a.scenario.yaml_gain/output.json" in marker["files"]
    assert second["run"]["started"] >= first["run"]["started"]
    assert second["run"]["commit"] is None  # not a git checkout


def test_the_run_names_its_git_commit(gain):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"))
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(gain.path)]
    subprocess.run([*git, "init", "-q"], check=True)
    subprocess.run([*git, "add", "a.scenario.yaml"], check=True)
    subprocess.run([*git, "commit", "-q", "-m", "x"], check=True)
    head = subprocess.run([*git, "rev-parse", "HEAD"], check=True, capture_output=True, text=True).stdout.strip()
    gain.runpytest("-q").assert_outcomes(passed=1)
    run = summary(gain)["run"]
    assert run["commit"] == head and run["dirty"] is False
    assert f"run `{run['id']}`, commit `{head[:12]}`" in (gain.path / "driveeval-results" / "summary.md").read_text()


def test_the_history_has_one_line_per_finished_session(gain):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"))
    ids = []
    for _ in range(3):
        gain.runpytest("-q")
        ids.append(summary(gain)["run"]["id"])
    lines = history(gain)
    assert [line["run"]["id"] for line in lines] == ids
    assert all(line["counts"] == {"passed": 1} and line["exit_status"] == 0 for line in lines)
    assert lines[-1]["summary"] == f"runs/{ids[-1]}/summary.json"


def test_a_run_without_scenarios_leaves_the_results_alone(gain):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"))
    gain.runpytest("-q").assert_outcomes(passed=1)
    before = summary(gain)
    (gain.path / "a.scenario.yaml").unlink()
    gain.makepyfile(test_plain="def test_x():\n    pass\n")
    gain.runpytest("-q").assert_outcomes(passed=1)
    assert summary(gain) == before
    assert run_ids(gain) == [before["run"]["id"]]


def test_files_the_plugin_did_not_write_are_never_deleted(gain):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"))
    gain.makeini("[pytest]\ndriveeval_keep_runs = 2\n")
    out = gain.path / "driveeval-results"
    precious = out / "items" / "my_precious" / "thesis.txt"
    precious.parent.mkdir(parents=True)
    precious.write_text("years of work")
    gain.runpytest("-q")
    first = summary(gain)["run"]["id"]
    added = out / "runs" / first / "items" / "a.scenario.yaml_gain" / "notes.txt"
    added.write_text("my notes on this run")
    for _ in range(3):
        gain.runpytest("-q").assert_outcomes(passed=1)
    assert precious.read_text() == "years of work"
    # The first run was pruned file by file: only what the user added is left.
    assert [p.relative_to(out / "runs" / first).as_posix() for p in (out / "runs" / first).rglob("*")
            if p.is_file()] == ["items/a.scenario.yaml_gain/notes.txt"]
    finished = [i for i in run_ids(gain) if (out / "runs" / i / "run.json").exists()]
    assert len(finished) == 2 and summary(gain)["run"]["id"] in finished


def _session(pytester, delay: float, gate: Path | None = None) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": ".", "DELAY": str(delay), "GATE": str(gate or "")}
    return subprocess.Popen([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *NO_HYPOTHESIS_PLUGIN,
                             "--driveeval-model", "slowmod:double"], cwd=pytester.path,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env)


def _wait_for_items(pytester, count: int, timeout: float = 60) -> None:
    deadline = time.time() + timeout
    while time.time() < deadline:
        runs = pytester.path / "driveeval-results" / "runs"
        if runs.is_dir() and sum(1 for _ in runs.glob("*/items/*")) >= count:
            return
        time.sleep(0.05)
    raise AssertionError("the sessions did not start")


def test_concurrent_sessions_each_keep_their_records_and_items(gain):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"), b=GAIN_SCENARIO.format(name="b"))
    gain.path.joinpath("slowmod.py").write_text(SLOW_MODEL)
    gate = gain.path / "second-finished"
    first = _session(gain, 0.0, gate=gate)
    _wait_for_items(gain, 1)
    second = _session(gain, 0.0)  # starts later, finishes first
    with first, second:  # their output pipes are closed on the way out
        assert second.wait(120) == 0, second.stdout.read().decode()
        gate.touch()
        assert first.wait(120) == 0, first.stdout.read().decode()
    lines = history(gain)
    assert len(lines) == 2
    for line in lines:
        own = json.loads((gain.path / "driveeval-results" / line["summary"]).read_text())
        assert own["counts"] == {"passed": 2}
        for record in own["results"]:
            assert (gain.path / "driveeval-results" / record["artefacts"]["output"]).read_text() == "6.0"
    started = sorted(lines, key=lambda line: line["run"]["started"])
    assert started[1]["run"]["started"] <= started[0]["finished"]  # they did overlap
    # The summary is the session that finished last.
    assert summary(gain)["run"]["id"] == lines[-1]["run"]["id"]


def test_a_killed_session_leaves_the_last_results_whole_and_says_it_never_finished(gain):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"), b=GAIN_SCENARIO.format(name="b"))
    gain.path.joinpath("slowmod.py").write_text(SLOW_MODEL)
    with _session(gain, 0.0) as done:
        assert done.wait(60) == 0
    before = summary(gain)
    killed = _session(gain, 30.0)
    _wait_for_items(gain, 3)
    killed.kill()
    killed.wait()
    killed.stdout.close()
    assert summary(gain) == before
    (newer,) = set(run_ids(gain)) - {before["run"]["id"]}
    marker = json.loads((gain.path / "driveeval-results" / "runs" / newer / "run.json").read_text())
    assert marker["state"] == "running" and marker["run"]["id"] > before["run"]["id"]
    assert len(history(gain)) == 1


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_results_get_the_users_umask(gain, umask):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"))
    old = os.umask(umask)
    try:
        gain.runpytest("-q").assert_outcomes(passed=1)
    finally:
        os.umask(old)
    out = gain.path / "driveeval-results"
    run = out / "runs" / summary(gain)["run"]["id"]
    for path in (out / "summary.json", out / "summary.md", run / "summary.json", run / "run.json"):
        assert path.stat().st_mode & 0o777 == 0o666 & ~umask, path
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]


def test_a_scenario_deep_in_folders_gets_a_short_item_folder(gain):
    deep = gain.path.joinpath(*[f"a_rather_long_folder_name_{i}" for i in range(12)])
    deep.mkdir(parents=True)
    (deep / "deep.scenario.yaml").write_text(GAIN_SCENARIO.format(name="deep"))
    gain.runpytest("-q").assert_outcomes(passed=1)
    (record,) = summary(gain)["results"]
    folder = (gain.path / "driveeval-results" / record["artefacts"]["output"]).parent
    assert folder.is_dir() and len(folder.name) <= 120
    assert folder.name.endswith("deep.scenario.yaml_gain")


@pytest.mark.parametrize("output, reason", [
    ("/dev/null", "driveeval output /dev/null is not a folder"),
    ("afile/sub", "driveeval output */afile/sub cannot be created: */afile is not a folder"),
])
def test_an_output_folder_that_cannot_be_written_is_a_usage_error_at_start(gain, output, reason):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"))
    gain.path.joinpath("afile").write_text("mine")
    result = gain.runpytest("-q", "--driveeval-output", output)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines([f"*{reason}*"])
    assert gain.path.joinpath("afile").read_text() == "mine"


def test_a_non_finite_value_costs_the_session_neither_its_summary_nor_the_history(tmp_path):
    from pytest_driveeval.harness.runs import RunIdentity, finish_run

    identity = RunIdentity(id="20260101T000000.000Z-abcdef", started="2026-01-01T00:00:00+00:00")
    record = {"nodeid": "a.scenario.yaml::x", "status": "passed", "figures": {"score": 1.0},
              "comparison": {"status": "unchanged", "reference_figures": {"score": float("nan"),
                                                                           "max": float("-inf")}}}
    summary = {"schema": 2, "run": identity.to_json(), "seed": 0, "exit_status": 0, "counts": {"passed": 1},
               "duration": 1.0, "results": [record]}
    warnings = finish_run(tmp_path, identity, summary, keep=0)
    assert warnings == ['summary.json: 2 value(s) that JSON cannot hold as numbers (NaN or infinite) written as the '
                        'strings "NaN", "Infinity" or "-Infinity": results[0].comparison.reference_figures.score, '
                        'results[0].comparison.reference_figures.max']
    for path in (tmp_path / "summary.json", tmp_path / "runs" / identity.id / "summary.json"):
        written = json.loads(path.read_text())  # strict JSON: no NaN literal in it
        assert written["results"][0]["comparison"]["reference_figures"] == {"score": "NaN", "max": "-Infinity"}
        assert written["results"][0]["figures"] == {"score": 1.0}
    assert len((tmp_path / "history.jsonl").read_text().splitlines()) == 1
