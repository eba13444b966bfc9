"""Issue 34: what is wrong in a baseline folder or a reference ends as a located error of the item
it belongs to, the other items run and the session writes its summary (section 2); an update, a
stale baseline and the figures' changes as a user meets them (section 3)."""
from __future__ import annotations

import json
import math
import shutil

import pytest

pytest.importorskip("torch")

from module_pytester import module_pytester  # noqa: E402
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


def with_two_scenarios_updated(pytester) -> None:
    with_closed_loop_data(pytester)
    pytester.makefile(".scenario.yaml", drive=closed_loop(scenes="[0, 1]", steps=10),
                      other=closed_loop(name="other", scenes="[2]", steps=10))
    run(pytester, "--driveeval-baseline-update").assert_outcomes(passed=2)


@pytest.fixture(scope="module")
def updated(request, tmp_path_factory):
    """The folder after the update every test here starts from, made once per module."""
    with module_pytester(request, tmp_path_factory) as pytester:
        with_two_scenarios_updated(pytester)
        return pytester.path


@pytest.fixture
def cl(pytester, updated):
    """A copy of the updated folder (copytree keeps the files' times, which one test compares)."""
    shutil.copytree(updated, pytester.path, dirs_exist_ok=True)
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


def test_a_baseline_folder_outside_that_moves_the_rootdir_is_named_as_the_reason_and_nothing_is_pruned(pytester,
                                                                                                      monkeypatch):
    project = pytester.path / "project"
    project.mkdir()
    with_closed_loop_data(pytester)
    (pytester.path / "gen.zarr").rename(project / "gen.zarr")
    (project / "drive.scenario.yaml").write_text(closed_loop(scenes="[0]", steps=5))
    monkeypatch.chdir(project)
    # The folder does not exist yet: pytest's rootdir is the project, and the update writes there.
    run(pytester, "--driveeval-baseline-update", folder="../shared-baselines").assert_outcomes(passed=1)
    written = sorted(p.relative_to(pytester.path) for p in (pytester.path / "shared-baselines").rglob("*.json"))
    assert [str(p) for p in written] == ["shared-baselines/drive.scenario.yaml.d/closed_loop[logs].json"]
    # It exists now: pytest takes it for a test path, and its rootdir moves up to their common parent.
    result = run(pytester, "--driveeval-baseline-update", "--driveeval-baseline-prune", folder="../shared-baselines")
    result.assert_outcomes(passed=1)
    text = " ".join(line.strip() for line in result.stdout.lines)
    assert f"pytest's rootdir is {pytester.path}, not {project}: pytest chose it before it knew pytest-driveeval's " \
           "options, and took `--driveeval-baseline ../shared-baselines` for a test path because that path exists " \
           "now." in text
    assert "Write `--driveeval-baseline=../shared-baselines`, or fix the rootdir" in text
    assert "none written or removed in" in text
    assert sorted(p.relative_to(pytester.path) for p in (pytester.path / "shared-baselines").rglob("*.json")) == \
        written  # neither pruned as an item gone nor written twice under the moved node id
    # Written with '=', the value is no test path: the rootdir stays, and the baseline is found.
    result = pytester.runpytest("-q", "-p", "no:randomly", "--driveeval-baseline=../shared-baselines")
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["driveeval baselines (*shared-baselines): 1 unchanged"])
    assert "pytest's rootdir is" not in result.stdout.str()
