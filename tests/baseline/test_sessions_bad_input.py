"""Issue 34: what is wrong in a baseline folder or a reference ends as a located error of the item
it belongs to, the other items run and the session writes its summary (section 2); an update, a
stale baseline and the figures' changes as a user meets them (section 3)."""
from __future__ import annotations

import json
import math

import pytest

pytest.importorskip("torch")

from baseline_sessions import (  # noqa: E402
    BASELINES,
    baseline_path,
    closed_loop,
    records,
    run,
    summary,
    with_closed_loop_data,
)

DRIVE, OTHER = "drive.scenario.yaml::closed_loop[logs]", "other.scenario.yaml::closed_loop[logs]"
BOMB = "[" * 100_000 + "]" * 100_000


@pytest.fixture
def cl(pytester):
    with_closed_loop_data(pytester)
    pytester.makefile(".scenario.yaml", drive=closed_loop(scenes="[0, 1]", steps=10),
                      other=closed_loop(name="other", scenes="[2]", steps=10))
    run(pytester, "--driveeval-baseline-update").assert_outcomes(passed=2)
    return pytester


def test_a_nesting_bomb_as_a_baseline_and_as_a_stray_file_is_located_and_the_session_ends_well(cl):
    baseline_path(cl, DRIVE).write_text('{"figures": ' + BOMB + "}")
    (cl.path / BASELINES / "stray.json").write_text(BOMB)
    result = run(cl)
    result.assert_outcomes(passed=1, failed=1)
    assert "RecursionError" not in result.stdout.str() + result.stderr.str()
    by_id = records(cl)
    assert by_id[OTHER]["comparison"]["status"] == "unchanged"
    assert by_id[DRIVE]["comparison"]["status"] == "error"
    assert by_id[DRIVE]["comparison"]["message"] == (
        f"baseline {BASELINES}/drive.scenario.yaml.d/closed_loop[logs].json of {DRIVE}: JSON nested 100001 levels "
        "deep, where the plugin's files are at most 64 levels deep: not one of them, or damaged; remove it or "
        "rewrite it with --driveeval-baseline-update")
    # The session's end (which lists the folder's files for pruning) went through: summary and all.
    result.stdout.fnmatch_lines(["driveeval baselines (baselines): 1 error, 1 unchanged"])


def test_a_nesting_bomb_as_the_compared_summary_fails_each_item_naming_it(cl):
    (cl.path / "bomb.json").write_text('{"results": ' + BOMB + "}")
    result = cl.runpytest("-q", "-p", "no:randomly", "--driveeval-compare", "bomb.json")
    result.assert_outcomes(failed=2)
    assert "RecursionError" not in result.stdout.str() + result.stderr.str()
    for record in records(cl).values():
        assert record["comparison"]["message"] == (
            "bomb.json is not a readable driveeval summary: JSON nested 100001 levels deep, where the plugin's "
            "files are at most 64 levels deep: not one of them, or damaged")


def test_a_nan_or_infinite_baseline_figure_is_located_and_the_summary_is_written(cl):
    for nodeid, value in ((DRIVE, math.nan), (OTHER, -math.inf)):
        path = baseline_path(cl, nodeid)
        data = json.loads(path.read_text())
        data["figures"]["max_displacement"] = value
        path.write_text(json.dumps(data, indent=1, sort_keys=True))  # Python writes NaN, -Infinity
    result = run(cl)
    result.assert_outcomes(failed=2)
    by_id = records(cl)  # summary.json was written, and is strict JSON
    for nodeid, said in ((DRIVE, "NaN"), (OTHER, "-Infinity")):
        where = f"{BASELINES}/{nodeid.split('::')[0]}.d/closed_loop[logs].json"
        assert by_id[nodeid]["comparison"]["message"] == (
            f"baseline {where} of {nodeid}: key 'figures.max_displacement' is {said}, not a finite number; "
            "rewrite it with --driveeval-baseline-update")
    json.loads((cl.path / "driveeval-results" / "summary.json").read_text(),
               parse_constant=lambda name: pytest.fail(f"summary.json holds {name}"))
    assert summary(cl)["counts"] == {"failed": 2}


def test_an_update_that_changes_nothing_but_the_run_leaves_every_file_as_it_was(cl):
    files = sorted((cl.path / BASELINES).rglob("*.json"))
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in files}
    result = run(cl, "--driveeval-baseline-update")
    result.assert_outcomes(passed=2)
    result.stdout.fnmatch_lines(["driveeval baselines: wrote 0 in baselines (2 unchanged but for the run, left as "
                                 "they were)"])
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in files} == before
    cl.makefile(".scenario.yaml", other=closed_loop(name="other", scenes="[2]", steps=12))
    result = run(cl, "--driveeval-baseline-update")
    result.stdout.fnmatch_lines(["driveeval baselines: wrote 1 in baselines (1 unchanged but for the run, left as "
                                 "they were)"])
    assert baseline_path(cl, DRIVE).read_bytes() == before[baseline_path(cl, DRIVE)][0]
    assert baseline_path(cl, OTHER).read_bytes() != before[baseline_path(cl, OTHER)][0]
