"""The output folder's own files damaged or replaced by links: the session
refuses up front or warns in one line and writes everything else; nothing
outside the output folder is written or deleted."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from conftest import speed_project, speed_scenario
from module_pytester import module_pytester

GOOD = speed_scenario("good")
INI = "[pytest]\nmarkers =\n    smoke: quick scenarios\ndriveeval_keep_runs = 1\n"


def snapshot(folder: Path) -> dict[str, object]:
    """Every entry under ``folder`` without following links: file bytes, link targets, folders."""
    seen: dict[str, object] = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            path = Path(root) / name
            key = path.relative_to(folder).as_posix()
            seen[key] = (("link", os.readlink(path)) if path.is_symlink()
                         else "folder" if path.is_dir() else path.read_bytes())
    return seen


def summary(project, folder="driveeval-results") -> dict:
    return json.loads((project.path / folder / "summary.json").read_text())


def test_pruning_never_follows_a_run_folder_linked_out_of_the_output_folder(project):
    project.makefile(".scenario.yaml", good=GOOD)
    project.runpytest("-q", "--driveeval-output", "other").assert_outcomes(passed=1)
    other = project.path / "other"
    (theirs,) = (other / "runs").iterdir()
    before = snapshot(other)
    assert f"runs/{theirs.name}/summary.json" in before
    runs = project.path / "driveeval-results" / "runs"
    runs.mkdir(parents=True)
    # Sorts before any real run id: the oldest "finished run", first to be pruned.
    (runs / "00000000T000000.000Z-000000").symlink_to(theirs)
    project.makeini(INI)
    for _ in range(2):
        project.runpytest("-q").assert_outcomes(passed=1)
    assert snapshot(other) == before
    assert (runs / "00000000T000000.000Z-000000").is_symlink()
    # Pruning itself still works: of our two real runs the older one is gone.
    assert [p.name for p in runs.iterdir() if not p.is_symlink()] == [summary(project)["run"]["id"]]


def test_pruning_never_follows_a_linked_folder_inside_an_old_run(project):
    project.makefile(".scenario.yaml", good=GOOD)
    project.makeini(INI)
    project.runpytest("-q").assert_outcomes(passed=1)
    old = project.path / "driveeval-results" / "runs" / summary(project)["run"]["id"]
    elsewhere = project.path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "summary.json").write_text("theirs")
    # An old manifest naming a file under a folder that is now a link out.
    (old / "sub").symlink_to(elsewhere)
    marker = json.loads((old / "run.json").read_text())
    (old / "run.json").write_text(json.dumps({**marker, "files": [*marker["files"], "sub/summary.json"]}))
    project.runpytest("-q").assert_outcomes(passed=1)
    assert (elsewhere / "summary.json").read_text() == "theirs"
    assert not (old / "summary.json").exists() and not (old / "run.json").exists()


@pytest.mark.parametrize("damage, message", [
    ("history link", "*driveeval-results/history.jsonl is a symbolic link (to ../theirs.jsonl); "
                     "the plugin writes nothing through a link: remove it*"),
    ("history loop", "*driveeval-results/history.jsonl is a symbolic link (to history.jsonl)*"),
    ("history folder", "*driveeval-results/history.jsonl is a folder, where the plugin keeps its own file: "
                       "move it away (set --driveeval-output or driveeval_output)"),
    ("summary folder", "*driveeval-results/summary.json is a folder, where the plugin keeps its own file*"),
    ("runs file", "*driveeval-results/runs is a file, where the plugin keeps the folder of its runs: move it away*"),
    ("runs link", "*driveeval-results/runs is a symbolic link (to ../theirs)*"),
    ("history hardlink", "*driveeval-results/history.jsonl has 1 other hard link(s); the plugin appends to it only "
                         "when it is the file's one name: copy it*"),
])
@pytest.mark.parametrize("xdist", [(), ("-n", "2")], ids=["plain", "xdist"])
def test_damaged_output_files_are_a_usage_error_before_anything_runs(project, damage, message, xdist):
    project.makefile(".scenario.yaml", good=GOOD)
    out = project.path / "driveeval-results"
    out.mkdir()
    (project.path / "theirs.jsonl").write_text('{"theirs": 1}\n')
    (project.path / "theirs").mkdir()
    name = {"history": "history.jsonl", "summary": "summary.json", "runs": "runs"}[damage.split()[0]]
    kind = damage.split()[1]
    if kind == "link":
        (out / name).symlink_to(f"../theirs{'.jsonl' if name == 'history.jsonl' else ''}")
    elif kind == "hardlink":
        os.link(project.path / "theirs.jsonl", out / name)
    elif kind == "loop":
        (out / name).symlink_to(name)
    elif kind == "folder":
        (out / name).mkdir()
    else:
        (out / name).write_text("mine")
    before = snapshot(project.path)
    result = project.runpytest("-q", "-p", "no:cacheprovider", *xdist)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines([f"ERROR: driveeval output {message}"])
    assert snapshot(project.path) == before


@pytest.mark.parametrize("output", ["/proc/x", "/proc/self/x", "/sys/x"])
def test_an_output_folder_in_a_kernel_view_is_a_usage_error(project, output):
    project.makefile(".scenario.yaml", good=GOOD)
    result = project.runpytest("-q", "--driveeval-output", output)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines([f"ERROR: driveeval output /{output.split('/')[1]}/* is in /{output.split('/')[1]}, "
                                 "a view of the kernel, not a place for files*"])


def test_the_writability_check_leaves_no_folder_behind(project):
    project.makepyfile(test_plain="def test_x():\n    pass\n")
    project.runpytest("-q", "--driveeval-output", "new/deeper/out").assert_outcomes(passed=1)
    assert not (project.path / "new").exists()


BROKEN_MANIFESTS = {"null": None, "string": "run.json", "number": [1], "dotdot": ["../../../victim.txt"],
                    "absolute": ["/etc/hostname"], "empty": [""]}


@pytest.fixture(scope="module")
def broken_old_runs(request, tmp_path_factory):
    """One old run per kind of broken manifest (each run's ``files`` replaced right after it ran), then
    one ``-n 2`` session, which must keep them all: its folder, each old run's id and snapshot, and the
    session's result. One xdist session for the six kinds, not six: each test reads its own kind's part."""
    with module_pytester(request, tmp_path_factory) as project:
        speed_project(project)
        project.makefile(".scenario.yaml", good=GOOD)
        project.makeini(INI)
        (project.path / "victim.txt").write_text("mine")
        olds, before = {}, {}
        for kind, files in BROKEN_MANIFESTS.items():
            project.runpytest("-q").assert_outcomes(passed=1)
            old = project.path / "driveeval-results" / "runs" / summary(project)["run"]["id"]
            marker = json.loads((old / "run.json").read_text())
            (old / "run.json").write_text(json.dumps({**marker, "files": files}))
            olds[kind] = old
        for kind, old in olds.items():
            before[kind] = snapshot(old)
        result = project.runpytest("-q", "-n", "2")
        return project, olds, before, result


@pytest.mark.parametrize("kind", list(BROKEN_MANIFESTS))
def test_an_old_run_with_a_broken_manifest_is_kept_with_a_warning(broken_old_runs, kind):
    project, olds, before, result = broken_old_runs
    old = olds[kind]
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines([f"driveeval warning: */runs/{old.name}/run.json: 'files' is not a list of paths "
                                 "inside the run's folder; that run is kept, delete it by hand"])
    assert snapshot(old) == before[kind]
    assert (project.path / "victim.txt").read_text() == "mine"
    # Everything else written: the new run is the summary, finished, in the history.
    new = summary(project)["run"]["id"]
    assert new != old.name and summary(project)["counts"] == {"passed": 1}
    new_marker = json.loads((project.path / "driveeval-results" / "runs" / new / "run.json").read_text())
    assert new_marker["state"] == "finished"
    history = (project.path / "driveeval-results" / "history.jsonl").read_text().splitlines()
    assert [json.loads(line)["run"]["id"] for line in history] == [o.name for o in olds.values()] + [new]


@pytest.mark.parametrize("damage, warning", [
    ("Path('driveeval-results/summary.json').mkdir(parents=True)",
     "cannot write the latest summary: Is a directory (*driveeval-results/summary.json)"),
    ("Path('driveeval-results').mkdir(); Path('driveeval-results/history.jsonl').symlink_to('../theirs.jsonl')",
     "cannot add this session to history.jsonl: Too many levels of symbolic links "
     "(*driveeval-results/history.jsonl)"),
], ids=["summary folder", "history link"])
def test_the_output_damaged_while_the_session_runs_is_a_warning_and_the_rest_is_written(project, damage, warning):
    (project.path / "theirs.jsonl").write_text('{"theirs": 1}\n')
    # Collected first (files by name), so it runs before the scenario item.
    project.makepyfile(test_damage=f"from pathlib import Path\n\ndef test_damage():\n    {damage}\n")
    project.makefile(".scenario.yaml", zgood=GOOD)
    result = project.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(passed=2)
    result.stdout.fnmatch_lines([f"driveeval warning: {warning}"])
    assert (project.path / "theirs.jsonl").read_text() == '{"theirs": 1}\n'
    out = project.path / "driveeval-results"
    (run,) = (out / "runs").iterdir()
    own = json.loads((run / "summary.json").read_text())
    assert own["counts"] == {"passed": 1} and own["results"][0]["nodeid"] == "zgood.scenario.yaml::speed_limit[slow.csv]"
    assert json.loads((run / "run.json").read_text())["state"] == "finished"
    assert (out / "summary.md").is_file()
    if "history" in warning:
        assert json.loads((out / "summary.json").read_text()) == own
    else:
        (line,) = [json.loads(text) for text in (out / "history.jsonl").read_text().splitlines()]
        assert line["run"]["id"] == run.name


def test_a_history_whose_last_line_lacks_its_newline_keeps_every_session_on_a_line_of_its_own(project):
    project.makefile(".scenario.yaml", good=GOOD)
    out = project.path / "driveeval-results"
    out.mkdir()
    (out / "history.jsonl").write_text('{"old": 1}\n{not json')
    ids = []
    for _ in range(2):
        project.runpytest("-q").assert_outcomes(passed=1)
        ids.append(summary(project)["run"]["id"])
    lines = (out / "history.jsonl").read_text().split("\n")
    assert lines[:2] == ['{"old": 1}', "{not json"] and lines[-1] == ""
    assert [json.loads(line)["run"]["id"] for line in lines[2:-1]] == ids


def test_a_folder_that_refuses_a_file_is_a_usage_error_whatever_its_permission_bits_say(tmp_path, monkeypatch):
    # Root, or a read-only mount, passes os.access; only creating a file tells.
    import tempfile

    from pytest_driveeval.harness.settings import check_output_dir

    def refuse(dir, **kw):
        raise PermissionError(13, "Permission denied", str(dir))

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(pytest.UsageError, match=r"driveeval output .*ro/out cannot be written: Permission denied "
                                                r"\(.*ro/out\)"):
        check_output_dir(tmp_path / "ro" / "out")
    assert list(tmp_path.iterdir()) == []  # the folders made for the trial are gone
