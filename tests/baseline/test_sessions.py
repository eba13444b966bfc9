"""Baselines as users meet them: update, then compare; a changed model is a regression naming the
episodes, scenes and frames that changed; an improvement passes; -n 2 and two sessions at once."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest

pytest.importorskip("torch")
pytest.importorskip("scipy")

from baseline_sessions import (  # noqa: E402
    BASELINES,
    baseline_path,
    changed_units,
    closed_loop,
    edit_baseline,
    obstacle_scenario,
    policy_benchmark,
    read_baseline,
    records,
    run,
    set_units,
    statuses,
    with_closed_loop_data,
    with_obstacle_filter,
    with_policy,
)

DRIVE = "drive.scenario.yaml::closed_loop[logs]"
MINE, IDM = "bench.scenario.yaml::policy_benchmark[mine]", "bench.scenario.yaml::policy_benchmark[idm]"
FILTERED = "filtered.scenario.yaml::obstacle_segmentation[sample_dataset]"


@pytest.fixture
def project(pytester):
    with_closed_loop_data(pytester)
    with_policy(pytester)
    return pytester


def git_commit(pytester) -> str:
    def git(*args):
        return subprocess.run(["git", *args], cwd=pytester.path, check=True, capture_output=True, text=True).stdout
    git("init", "-q")
    git("add", "-A")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "scenarios")
    return git("rev-parse", "HEAD").strip()


def test_update_writes_one_sorted_indented_file_per_item_and_the_next_session_finds_nothing_changed(project):
    project.makefile(".scenario.yaml", drive=closed_loop(), bench=policy_benchmark(episodes=6))
    commit = git_commit(project)
    result = run(project, "--driveeval-baseline-update")
    result.assert_outcomes(passed=3)
    result.stdout.fnmatch_lines(["driveeval baselines (baselines): 3 missing",
                                 "driveeval baselines: wrote 3 in baselines"])
    run_id = json.loads((project.path / "driveeval-results" / "summary.json").read_text())["run"]["id"]
    for nodeid in (DRIVE, MINE, IDM):
        path = baseline_path(project, nodeid)
        assert path.parent == project.path / BASELINES / (nodeid.split("::")[0] + ".d")
        text = path.read_text()
        data = json.loads(text)
        assert text == json.dumps(data, indent=1, sort_keys=True, ensure_ascii=False) + "\n"  # diff-friendly
        assert data["key"]["nodeid"] == nodeid and data["run"]["id"] == run_id and data["run"]["commit"] == commit
        assert data["run"]["dirty"] is False
        assert set(data["fingerprint"]) >= {"dataset", "seed", "settings", "use_case"}
        assert "Conditions" not in data["fingerprint"]["settings"] and "rules" not in data
    drive, mine = read_baseline(project, DRIVE), read_baseline(project, MINE)
    assert drive["fingerprint"]["settings"]["Unroll"] == {"Scenes": [0, 1, 2, 3], "Steps": 40}
    assert drive["fingerprint"]["dataset"]["name"] == "logs" and len(drive["fingerprint"]["dataset"]["sha256"]) == 16
    assert set(drive["figures"]) == {"at_fault", "drift_resets", "max_displacement", "scenes_passed", "score"}
    assert drive["units"]["kind"] == "scene" and drive["units"]["columns"] == {"scene": ["pppp"]}
    assert mine["fingerprint"]["settings"]["Episodes"] == 6 and "Policies" not in mine["fingerprint"]["settings"]
    assert set(mine["figures"]) == {"goal_rate", "collision_rate", "off_road_rate"}
    assert mine["units"]["ids"] == {"from": 100, "count": 6} and len(mine["units"]["columns"]["outcome"][0]) == 6

    result = run(project)
    result.assert_outcomes(passed=3)
    result.stdout.fnmatch_lines(["driveeval baselines (baselines): 3 unchanged"])
    assert "wrote" not in result.stdout.str()
    for record in records(project).values():
        assert record["comparison"]["status"] == "unchanged"
        assert record["comparison"]["message"].startswith(f"no change against baseline `{commit[:12]}` (")
    assert baseline_path(project, DRIVE).read_text() == json.dumps(drive, indent=1, sort_keys=True) + "\n"


def test_a_worse_policy_fails_naming_the_episodes_that_changed_by_seed(project):
    project.makefile(".scenario.yaml", bench=policy_benchmark())
    run(project, "--driveeval-baseline-update").assert_outcomes(passed=2)
    result = run(project, "--driveeval-model", "random")
    # The baseline policy (idm) is not replaced by --driveeval-model; its comparison is unchanged.
    result.assert_outcomes(passed=1, failed=1)
    by_id = records(project)
    assert by_id[IDM]["comparison"]["status"] == "unchanged"
    mine = by_id[MINE]
    assert mine["status"] == "failed" and mine["comparison"]["status"] == "regressed"
    assert mine["verdict"] == "passed"  # its own verdict: CollisionRate at most 100 % holds
    goal = next(c for c in mine["comparison"]["changes"] if c["what"] == "goal_rate")
    assert goal["worse"] is True and goal["before"] > goal["after"]
    lost = changed_units(read_baseline(project, MINE), mine["baseline"], "outcome")
    assert lost and all(int(seed) >= 100 for seed in lost)  # seeds (FirstSeed 100), not episode indices
    named = re.search(r"episodes ([\d, ]+)(?: and (\d+) more)? no longer end in goal", goal["text"])
    assert named, goal["text"]
    shown = named.group(1).split(", ")
    assert shown == lost[:len(shown)] and len(shown) + int(named.group(2) or 0) == len(lost)
    assert re.search(r"\[paired 95 % interval of the difference -[\d.]+, -[\d.]+; McNemar exact p = ", goal["text"])
    result.stdout.fnmatch_lines(["*RegressionFailed: regression against baseline `no commit` (*):",
                                 "    goal_rate 100 % -> * %*no longer end in goal*",
                                 "  its own verdict: passed: *",
                                 "driveeval baselines (baselines): 1 regressed, 1 unchanged"])


def test_a_worse_planner_fails_naming_each_scene_that_passed_and_fails_now_with_condition_and_frame(project):
    project.makefile(".scenario.yaml", drive=closed_loop())
    run(project, "--driveeval-baseline-update").assert_outcomes(passed=1)
    result = run(project, "--driveeval-model", "constant_velocity")
    result.assert_outcomes(failed=1)
    (record,) = records(project).values()
    comparison = record["comparison"]
    assert comparison["status"] == "regressed"
    scenes = [c for c in comparison["changes"] if c["what"].startswith("scene ")]
    flipped = changed_units(read_baseline(project, DRIVE), record["baseline"], "scene")
    assert [c["what"] for c in scenes] == [f"scene {s}" for s in flipped] and flipped
    for change in scenes:
        assert change["worse"] is True
        assert re.match(r"scene \d+ passed before, failed now: (Displacement|front|side|rear) at frame \d+ \(",
                        change["text"]), change["text"]
        assert change["text"] in comparison["message"]
    at_fault = next(c for c in comparison["changes"] if c["what"] == "at_fault")
    assert at_fault["before"] == 0 and at_fault["after"] == record["figures"]["at_fault"] > 0
    result.stdout.fnmatch_lines(["*regression against baseline*", "    at_fault 0 -> * (lower is better; tolerance 0)",
                                 "*scene 2 passed before, failed now: front at frame * (scene 2 (gen.zarr): *"])


def test_a_filter_that_loses_the_car_in_two_frames_fails_naming_those_frames(pytester, monkeypatch):
    with_obstacle_filter(pytester)
    pytester.makefile(".scenario.yaml", filtered=obstacle_scenario())
    run(pytester, "--driveeval-baseline-update").assert_outcomes(passed=1)
    monkeypatch.setenv("DROP_FRAMES", "3,6")
    result = run(pytester)
    result.assert_outcomes(failed=1)
    (record,) = records(pytester).values()
    comparison = record["comparison"]
    assert comparison["status"] == "regressed"
    frames = [c for c in comparison["changes"] if c["what"].startswith("frame ")]
    assert [c["what"] for c in frames] == ["frame 3 detection", "frame 6 detection"]
    assert [c["text"] for c in frames] == [
        "frame 3 detection Success before, Fail now: stamp_ns 1700000000300000000",
        "frame 6 detection Success before, Fail now: stamp_ns 1700000000600000000"]
    rate = next(c for c in comparison["changes"] if c["what"] == "detection_rate")
    assert (rate["before"], rate["after"], rate["worse"]) == (100.0, 80.0, True)


def test_an_improvement_is_reported_and_passes(project):
    project.makefile(".scenario.yaml", drive=closed_loop(model="constant_velocity", max_displacement=50.0))
    run(project, "--driveeval-baseline-update").assert_outcomes(failed=1)  # its own verdict: a collision
    result = run(project, "--driveeval-model", "log_replay")
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["driveeval baselines (baselines): 1 improved"])
    comparison = records(project)[DRIVE]["comparison"]
    assert comparison["status"] == "improved" and comparison["message"].startswith("improvement against baseline")
    better = {c["what"] for c in comparison["changes"] if c["worse"] is False}
    assert {"at_fault", "max_displacement", "scene 2"} <= better
    assert not [c for c in comparison["changes"] if c["worse"]]
    assert "scene 2 failed before, passed now" in comparison["message"]


def test_two_workers_compare_like_one_process(project):
    project.makefile(".scenario.yaml", drive=closed_loop(model="constant_velocity", max_displacement=50.0),
                     steady=closed_loop(name="steady", scenes="[4, 5]", steps=10),
                     bench=policy_benchmark(episodes=6), fresh=closed_loop(name="fresh", scenes="[6]", steps=10),
                     old=closed_loop(name="old", scenes="[7]", steps=10),
                     cut=closed_loop(name="cut", scenes="[8]", steps=10))
    run(project, "--driveeval-baseline-update").assert_outcomes(passed=6, failed=1)
    baseline_path(project, "fresh.scenario.yaml::closed_loop[logs]").unlink()
    edit_baseline(project, "old.scenario.yaml::closed_loop[logs]", lambda data: data["fingerprint"].update(seed=1))
    cut = baseline_path(project, "cut.scenario.yaml::closed_loop[logs]")
    cut.write_text(cut.read_text()[:100])

    def better_before(data):  # scene 2 passed, no collision: the current run regresses
        data["figures"]["at_fault"] = 0
        set_units(data, "scene", "pppp")

    edit_baseline(project, DRIVE, better_before)
    edit_baseline(project, MINE, lambda data: set_units(data, "outcome", "c" * 6))  # an improvement

    def compared():
        return {k: (r["status"], r["comparison"]["status"], r["comparison"]["message"],
                    [(c["what"], c["worse"]) for c in r["comparison"]["changes"]]) for k, r in records(project).items()}

    run(project).assert_outcomes(passed=5, failed=2)
    serial = compared()
    assert {k: v[1] for k, v in serial.items()} == {
        DRIVE: "regressed", MINE: "improved", IDM: "unchanged", "steady.scenario.yaml::closed_loop[logs]": "unchanged",
        "fresh.scenario.yaml::closed_loop[logs]": "missing", "old.scenario.yaml::closed_loop[logs]": "stale",
        "cut.scenario.yaml::closed_loop[logs]": "error"}
    run(project, "-n", "2").assert_outcomes(passed=5, failed=2)
    assert compared() == serial


def test_two_sessions_updating_the_same_baselines_at_once_leave_every_file_whole(project):
    files = {f"s{i}": closed_loop(name=f"s{i}", scenes=f"[{i}]", steps=5) for i in range(8)}
    project.makefile(".scenario.yaml", **files)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(p) for p in sys.path if p])}
    sessions = [subprocess.Popen([sys.executable, "-m", "pytest", "-q", "-p", "no:randomly", "-p", "no:cacheprovider",
                                  "--driveeval-baseline", BASELINES, "--driveeval-baseline-update",
                                  "--driveeval-output", f"out{k}"], cwd=project.path, env=env,
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for k in (1, 2)]
    outputs = [s.communicate(timeout=300)[0] for s in sessions]
    assert [s.returncode for s in sessions] == [0, 0], outputs
    runs = {json.loads((project.path / f"out{k}" / "summary.json").read_text())["run"]["id"] for k in (1, 2)}
    written = sorted((project.path / BASELINES).rglob("*"))
    assert [p.name for p in written if p.is_file()] == ["closed_loop[logs].json"] * 8  # no temporary file left
    for name in files:
        data = read_baseline(project, f"{name}.scenario.yaml::closed_loop[logs]")
        assert data["run"]["id"] in runs and data["key"]["scenario"] == name
    # What they wrote is a baseline the next session compares with.
    run(project).assert_outcomes(passed=8)
    assert set(statuses(project).values()) == {"unchanged"}
