"""Issue 22, point 5: ``python -m pytest_driveeval compare A B`` prints two real runs side by side,
with the plugin's own rules, without rerunning them; it names what it cannot read."""
from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import POLICY_BENCHMARK_HEAD, REPO_ROOT
from module_pytester import module_pytester

from pytest_driveeval.__main__ import main as compare_main

pytest.importorskip("torch")

BENCH = POLICY_BENCHMARK_HEAD + """\
  Blueprint: {{Name: merging}}
  Episodes: {episodes}
  Policies:
    mine: {policy}
  Judged: [mine]
"""
ITEM = "{}.scenario.yaml::policy_benchmark[mine]"
A_ITEM, SAME, GONE, NEW = (ITEM.format(n) for n in ("a", "same", "gone", "new"))


class Done:
    """What the tests read of a finished command: as subprocess.CompletedProcess."""

    def __init__(self, returncode: int, stdout: str, stderr: str):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def cli(cwd: Path, *args: str, columns: int = 200) -> Done:
    """``python -m pytest_driveeval compare ARGS`` run in this process: the same ``main`` the module's
    ``__main__`` calls, in ``cwd``, with COLUMNS as the terminal's width and utf-8 out, as the fresh
    process of ``cli_process`` has them; without paying the package's import (~1.5 s) per call.
    ``test_python_m_runs_the_same_command_in_a_process_of_its_own`` holds the two equal."""
    out, err = (io.TextIOWrapper(io.BytesIO(), encoding="utf-8", write_through=True) for _ in range(2))
    saved = os.getcwd(), os.environ.get("COLUMNS"), sys.stdout, sys.stderr
    os.chdir(cwd)
    os.environ["COLUMNS"] = str(columns)
    sys.stdout, sys.stderr = out, err
    try:
        code = compare_main(["compare", *args])
    except SystemExit as exc:  # argparse's usage errors exit with 2, as in a process of its own
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        os.chdir(saved[0])
        if saved[1] is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = saved[1]
        sys.stdout, sys.stderr = saved[2], saved[3]
    return Done(code, out.buffer.getvalue().decode("utf-8"), err.buffer.getvalue().decode("utf-8"))


def cli_process(cwd: Path, *args: str, columns: int = 200) -> subprocess.CompletedProcess:
    """``python -m pytest_driveeval compare ARGS`` in a process of its own, as a user runs it."""
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT), "COLUMNS": str(columns), "PYTHONIOENCODING": "utf-8"}
    return subprocess.run([sys.executable, "-m", "pytest_driveeval", "compare", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def make_runs(pytester) -> tuple[str, str]:
    """Two sessions of the same seeds: the first (with its baselines written) drives 'a' with the IDM
    expert, which reaches the goal in every episode, the second with the constant policy, which
    does not; 'same' is the same in both, 'gone' only in the first, 'new' only in the second."""
    pytester.makefile(".scenario.yaml", a=BENCH.format(name="a", episodes=16, policy="idm_expert"),
                      same=BENCH.format(name="same", episodes=4, policy="constant"),
                      gone=BENCH.format(name="gone", episodes=4, policy="constant"))
    pytester.runpytest("-p", "no:randomly", "--driveeval-baseline", "baselines",
                       "--driveeval-baseline-update").assert_outcomes(passed=3)
    (pytester.path / "gone.scenario.yaml").unlink()
    pytester.makefile(".scenario.yaml", a=BENCH.format(name="a", episodes=16, policy="constant"),
                      new=BENCH.format(name="new", episodes=4, policy="constant"))
    pytester.runpytest("-p", "no:randomly").assert_outcomes(passed=3)
    history = (pytester.path / "driveeval-results" / "history.jsonl").read_text().splitlines()
    first, second = (json.loads(line)["run"]["id"] for line in history)
    return first, second


@pytest.fixture(scope="module")
def two_runs(request, tmp_path_factory) -> tuple[Path, str, str]:
    """make_runs once per module: its folder and the two run ids. Each test works in a copy (one adds
    a third run, one a broken baseline folder), so neither sees the other's."""
    with module_pytester(request, tmp_path_factory) as pytester:
        first, second = make_runs(pytester)
        return pytester.path, first, second


def copy_of(two_runs, folder: Path) -> tuple[str, str]:
    made, first, second = two_runs
    shutil.copytree(made, folder, dirs_exist_ok=True)
    return first, second


def rows(result: Done) -> dict[str, dict]:
    return {row["nodeid"]: row for row in json.loads(result.stdout)["rows"]}


def test_the_later_run_against_the_earlier_names_the_regression_and_exits_1(pytester, two_runs):
    first, second = copy_of(two_runs, pytester.path)
    result = cli(pytester.path, "last~1", "last")
    assert result.returncode == 1, result.stderr
    out = result.stdout.splitlines()
    assert out[0].startswith(f"A: run {first} (`") and out[1].startswith(f"B: run {second} (`")
    line = {status: next(x for x in out if x.startswith(status)) for status in
            ("regressed", "unchanged", "only in A", "only in B")}
    assert A_ITEM in line["regressed"] and "goal_rate 100 -> 0 (-100 ↓ worse)" in line["regressed"]
    assert "off_road_rate 0 -> 75 (+75 ↑ worse)" in line["regressed"]
    # 4 of 16 episodes now collide: not enough for the paired test to call it worse.
    assert "collision_rate 0 -> 25 (+25 ↑);" in line["regressed"]
    assert SAME in line["unchanged"] and "goal_rate 0 -> 0 (=)" in line["unchanged"]
    assert GONE in line["only in A"] and NEW in line["only in B"]
    assert "goal_rate 100 % -> 0 % [paired 95 % interval of the difference" in result.stdout
    assert "episodes 0, 1, 2, 3, 4, 5, 6, 7 and 8 more no longer end in goal" in result.stdout
    assert out[-1] == "1 regressed, 1 unchanged, 1 only in A, 1 only in B"

    back = cli(pytester.path, "last", "last~1", "--only-changed")
    assert back.returncode == 0, back.stderr
    assert "goal_rate 0 -> 100 (+100 ↑ better)" in next(x for x in back.stdout.splitlines()
                                                        if x.startswith("improved"))
    assert SAME not in back.stdout and "(1 unchanged not shown)" in back.stdout
    assert "only in A" in back.stdout and "only in B" in back.stdout

    markdown = cli(pytester.path, "last~1", "last", "--format", "markdown")
    assert markdown.returncode == 1
    assert f"| **regressed** | `{A_ITEM}` | passed | goal_rate 100 -> 0 (-100 ↓ worse)<br>" in markdown.stdout

    # A narrow terminal wraps the rows instead of cutting them.
    narrow = cli(pytester.path, "last~1", "last", columns=50)
    assert narrow.returncode == 1
    assert all(len(x) <= 50 or " " not in x.strip() for x in narrow.stdout.splitlines())
    assert any(x.strip() == "goal_rate 100 -> 0 (-100 ↓ worse)" for x in narrow.stdout.splitlines())
    assert "no longer end in goal" in " ".join(x.strip() for x in narrow.stdout.splitlines())

    beyond = cli(pytester.path, "last~2", "last")
    assert beyond.returncode == 2 and beyond.stdout == ""
    assert "'last~2' is the run 2 before the last, and driveeval-results/history.jsonl has 2 finished run(s)" \
        in beyond.stderr


def test_every_way_of_naming_a_run_gives_the_same_rows(pytester, two_runs):
    first, second = copy_of(two_runs, pytester.path)
    runs = pytester.path / "driveeval-results" / "runs"
    expected = rows(cli(pytester.path, "last~1", "last", "--format", "json"))
    assert {n: r["status"] for n, r in expected.items()} == {
        A_ITEM: "regressed", SAME: "unchanged", GONE: "only in A", NEW: "only in B"}
    assert expected[A_ITEM]["figures"]["goal_rate"] == {"a": 100.0, "b": 0.0, "delta": -100.0, "worse": True,
                                                        "within_tolerance": False}
    for names in ((first, str(runs / second / "summary.json")),
                  (str(runs / first), f"driveeval-results/runs/{second}"),
                  ("baselines", "last")):
        result = cli(pytester.path, *names, "--format", "json")
        assert result.returncode == 1, (names, result.stderr)
        assert {n: (r["status"], r["figures"]) for n, r in rows(result).items()} == \
            {n: (r["status"], r["figures"]) for n, r in expected.items()}, names
    header = json.loads(cli(pytester.path, "baselines", "last", "--format", "json").stdout)["a"]
    assert header["title"].startswith(f"baselines baselines: 3 file(s) from run {first} (`")

    # A baseline folder as B: baseline files keep no rules, so A's judge it.
    result = cli(pytester.path, "last", "baselines", "--format", "json")
    assert result.returncode == 0, result.stderr
    assert rows(result)[A_ITEM]["status"] == "improved" and rows(result)[NEW]["status"] == "only in A"

    # Another output folder, named by --output: the same runs, found from elsewhere.
    elsewhere = pytester.path / "elsewhere"
    elsewhere.mkdir()
    result = cli(elsewhere, "last~1", "last", "--output", "../driveeval-results", "--format", "json")
    assert result.returncode == 1 and rows(result).keys() == expected.keys()

    # One unreadable baseline file is named; the rest of the folder still compares.
    broken = pytester.path / "broken"
    shutil.copytree(pytester.path / "baselines", broken)
    same = next(broken.rglob("same.scenario.yaml.d/*.json"))
    same.write_text(same.read_text()[:40])
    result = cli(pytester.path, "broken", "last")
    assert result.returncode == 2
    assert f"error: baseline broken/same.scenario.yaml.d/{same.name} of (unknown item) is not valid JSON (truncated?)" \
        in result.stderr
    assert next(x for x in result.stdout.splitlines() if A_ITEM in x).startswith("regressed")

    # An item that errored in B kept no comparable record: not compared, and why.
    (pytester.path / "same.scenario.yaml").write_text(BENCH.format(name="same", episodes=4, policy="absent.pt2"))
    pytester.runpytest("-p", "no:randomly").assert_outcomes(passed=2, errors=1)
    result = cli(pytester.path, "last~1", "last", "--format", "json")
    assert result.returncode == 0, result.stderr
    assert rows(result)[SAME]["status"] == "not compared"
    assert rows(result)[SAME]["details"] == ["B: error: kept no comparable record"]


def test_python_m_runs_the_same_command_in_a_process_of_its_own(pytester, two_runs):
    """The other tests call ``cli`` in this process; ``python -m pytest_driveeval`` in a fresh one
    prints the same, byte for byte, and exits with the same status: a regression (1), a usage error (2)."""
    copy_of(two_runs, pytester.path)
    for args in (("last~1", "last"), ("last", "last", "--format", "yaml")):
        fresh, here = cli_process(pytester.path, *args), cli(pytester.path, *args)
        assert (fresh.returncode, fresh.stdout, fresh.stderr) == (here.returncode, here.stdout, here.stderr), args
    assert fresh.returncode == 2 and "invalid choice: 'yaml'" in fresh.stderr


def test_what_cannot_be_read_is_named_with_exit_status_2(tmp_path):
    nothing = cli(tmp_path, "last", "last")
    assert nothing.returncode == 2 and nothing.stdout == ""
    assert "no finished run in driveeval-results/history.jsonl to compare with" in nothing.stderr

    unknown = cli(tmp_path, "20260101T000000.000Z-abcdef", "last")
    assert unknown.returncode == 2
    assert "'20260101T000000.000Z-abcdef' is neither 'last', 'last~N', a run id under driveeval-results/runs, nor " \
           "a summary.json, nor a run folder or a baseline folder" in unknown.stderr

    (tmp_path / "cut").mkdir()
    (tmp_path / "cut" / "summary.json").write_text('{"run": {"id": "x"}, "results": [{"nodeid": ')
    corrupt = cli(tmp_path, "cut/summary.json", "cut")
    assert corrupt.returncode == 2 and corrupt.stdout == ""
    assert "error: cut/summary.json is not a readable driveeval summary: Expecting value" in corrupt.stderr

    killed = tmp_path / "driveeval-results" / "runs" / "killed"
    killed.mkdir(parents=True)
    (killed / "run.json").write_text('{"run": {"id": "killed"}, "state": "running"}')
    result = cli(tmp_path, str(killed), "last")
    assert result.returncode == 2
    assert "holds neither a summary.json nor baseline files (a run folder without its summary: that session " \
           "did not finish)" in result.stderr

    usage = cli(tmp_path, "last", "last", "--format", "yaml")
    assert usage.returncode == 2 and "invalid choice: 'yaml'" in usage.stderr


def test_a_nesting_bomb_as_either_side_exits_2_naming_the_file(tmp_path):
    bomb = "[" * 100_000 + "]" * 100_000
    (tmp_path / "bomb.json").write_text('{"results": ' + bomb + "}")
    (tmp_path / "baselines" / "s.yaml.d").mkdir(parents=True)
    (tmp_path / "baselines" / "stray.json").write_text(bomb)
    (tmp_path / "baselines" / "s.yaml.d" / "t.json").write_text(json.dumps(
        {"driveeval_baseline": 1, "key": {"nodeid": "s.yaml::t"}, "run": {}, "verdict": "passed", "figures": {}}))
    for args, file in ((("bomb.json", "baselines"), "bomb.json"), (("baselines", "baselines"), "baselines/stray.json")):
        result = cli(tmp_path, *args)
        assert result.returncode == 2, result.stderr
        assert "RecursionError" not in result.stderr and "Traceback" not in result.stderr
        assert f"error: {'baseline ' if file != 'bomb.json' else ''}{file}" in result.stderr
        assert "JSON nested 10000" in result.stderr
