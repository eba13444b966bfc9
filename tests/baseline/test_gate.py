"""The session's side of baselines without a session (gate.py): when an item fails, which baseline
files are unused, what a prune deletes, what an update writes."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from pytest_driveeval.baseline.compare import ERROR, IMPROVED, MISSING, REGRESSED, STALE, UNCHANGED, Comparison
from pytest_driveeval.baseline.gate import (NO_BASELINE, BaselineOptions, Gate, prune, unused_baselines,
                                            update_baselines)
from pytest_driveeval.baseline.store import BaselineStore

ALL = (REGRESSED, IMPROVED, UNCHANGED, MISSING, STALE, ERROR)


@pytest.mark.parametrize("update, strict, failing", [
    (False, False, {REGRESSED, ERROR}),
    (False, True, {REGRESSED, ERROR, MISSING, STALE}),
    (True, False, set()),
    (True, True, set()),
])
def test_must_fail(tmp_path, update, strict, failing):
    gate = Gate(BaselineOptions(tmp_path, update=update, strict=strict))
    assert {status for status in ALL if gate.must_fail(Comparison(status))} == failing


def payload(nodeid: str, at_fault: int = 0) -> dict:
    return {"version": 1, "key": {"nodeid": nodeid}, "verdict": "passed", "summary": "ok",
            "figures": {"at_fault": at_fault}, "units": None, "search": None, "fingerprint": None,
            "rules": {"figures": {"at_fault": {"better": "lower", "atol": 0, "rtol": 0}}}}


def test_gate_compares_with_the_baseline_file(tmp_path):
    BaselineStore(tmp_path).write("s.yaml::t", payload("s.yaml::t"), {"id": "r1", "commit": "abcdef"})
    gate = Gate(BaselineOptions(tmp_path))
    result = gate.compare("s.yaml::t", payload("s.yaml::t", at_fault=2))
    assert result.status == REGRESSED and result.against.startswith("baseline `abcdef`")
    assert result.source.endswith("s.yaml.d/t.json")
    missing = gate.compare("s.yaml::u", payload("s.yaml::u"))
    assert (missing.status, missing.note) == (MISSING, NO_BASELINE)


def test_gate_turns_a_corrupt_baseline_into_an_error_comparison(tmp_path):
    path = BaselineStore(tmp_path).write("s.yaml::t", payload("s.yaml::t"), {})
    path.write_text("{")
    result = Gate(BaselineOptions(tmp_path)).compare("s.yaml::t", payload("s.yaml::t"))
    assert result.status == ERROR and "t.json" in result.message() and "not valid JSON" in result.message()


def test_gate_compares_with_an_earlier_run(tmp_path):
    summary = tmp_path / "summary.json"
    summary.write_text(json.dumps({"run": {"id": "r7", "commit": "abc"},
                                   "results": [{"nodeid": "s.yaml::t", "baseline": payload("s.yaml::t", 3)}]}))
    gate = Gate(BaselineOptions(compare_with=summary))
    assert gate.compare("s.yaml::t", payload("s.yaml::t", 1)).status == IMPROVED
    missing = gate.compare("s.yaml::u", payload("s.yaml::u"))
    assert missing.status == MISSING and missing.note.startswith("run r7 (`abc`")


# --- unused baselines and prune --------------------------------------------------------------

def baselines(tmp_path: Path, nodeids: list[str]) -> tuple[Path, Path, BaselineStore]:
    root, folder = tmp_path / "project", tmp_path / "project" / "baselines"
    store = BaselineStore(folder)
    for nodeid in nodeids:
        store.write(nodeid, payload(nodeid), {})
    return root, folder, store


def test_unused_baselines_are_those_of_gone_files_and_gone_items(tmp_path):
    root, folder, store = baselines(tmp_path, ["a.yaml::x", "a.yaml::y", "gone.yaml::x", "sub/b.yaml::z",
                                               "unknown.yaml::x"])
    (root / "sub").mkdir()
    for name in ("a.yaml", "sub/b.yaml", "unknown.yaml"):
        (root / name).write_text("")
    asked = []

    def items_of(path: Path):
        asked.append(path)
        return {root / "a.yaml": {"x"}, root / "sub" / "b.yaml": {"z"}}.get(path)  # unknown.yaml: None

    unused = unused_baselines(folder, root, items_of)
    assert unused == [store.path_for("a.yaml::y"), store.path_for("gone.yaml::x")]
    assert sorted(asked) == sorted({root / "a.yaml", root / "sub" / "b.yaml", root / "unknown.yaml"})  # once each


def test_files_the_plugin_did_not_write_there_are_never_unused(tmp_path):
    root, folder, store = baselines(tmp_path, ["gone.yaml::x"])
    moved = folder / "gone.yaml.d" / "elsewhere.json"
    store.path_for("gone.yaml::x").rename(moved)            # its content names another place
    (folder / "notes.json").write_text("[1]")               # not ours
    (folder / "broken.json").write_text("{")
    assert unused_baselines(folder, root, lambda p: set()) == []


def test_prune_removes_the_files_and_the_folders_they_leave_empty_and_nothing_else(tmp_path):
    root, folder, store = baselines(tmp_path, ["gone/deep/a.yaml::x", "gone/deep/a.yaml::y", "kept/b.yaml::x",
                                               "kept/b.yaml::y"])
    foreign = folder / "kept" / "b.yaml.d" / "README.txt"
    foreign.write_text("mine")
    paths = [store.path_for(n) for n in ("gone/deep/a.yaml::x", "gone/deep/a.yaml::y", "kept/b.yaml::x")]
    assert prune(paths, folder) == []
    assert not (folder / "gone").exists()
    assert folder.is_dir()
    assert sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*")) == [
        "kept", "kept/b.yaml.d", "kept/b.yaml.d/README.txt", "kept/b.yaml.d/y.json"]
    assert foreign.read_text() == "mine"


def test_prune_keeps_the_folder_itself_and_reports_what_it_cannot_remove(tmp_path):
    root, folder, store = baselines(tmp_path, ["a.yaml::x"])
    path = store.path_for("a.yaml::x")
    assert prune([path], folder) == []
    assert folder.is_dir() and list(folder.iterdir()) == []
    (problem,) = prune([path], folder)
    assert problem.startswith("cannot remove ") and "x.json" in problem


# --- update ------------------------------------------------------------------------------------

def test_update_writes_the_records_that_ran_and_keeps_the_old_baseline_of_an_errored_one(tmp_path):
    store = BaselineStore(tmp_path)
    store.write("s.yaml::err", payload("s.yaml::err", 1), {"id": "old"})
    records = [
        {"nodeid": "s.yaml::ok", "status": "passed", "baseline": payload("s.yaml::ok", 0)},
        {"nodeid": "s.yaml::bad", "status": "failed", "baseline": payload("s.yaml::bad", 4)},
        {"nodeid": "s.yaml::err", "status": "error", "baseline": payload("s.yaml::err", 9)},
        {"nodeid": "s.yaml::skip", "status": "skipped", "baseline": payload("s.yaml::skip")},
        {"nodeid": "s.yaml::none", "status": "passed", "baseline": None},
        {"nodeid": "s.yaml::nostatus", "baseline": payload("s.yaml::nostatus")},
    ]
    updated = update_baselines(tmp_path, records, {"id": "new"})
    assert (updated.written, updated.kept, updated.problems) == (2, 0, [])
    assert sorted(store.files().values()) == ["s.yaml::bad", "s.yaml::err", "s.yaml::ok"]
    kept = store.read("s.yaml::err")
    assert kept["figures"] == {"at_fault": 1} and kept["run"]["id"] == "old"
    assert store.read("s.yaml::bad")["figures"] == {"at_fault": 4}


def test_update_reports_a_file_it_cannot_write_and_goes_on(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "link.yaml.d").symlink_to(elsewhere, target_is_directory=True)
    records = [{"nodeid": "link.yaml::t", "status": "passed", "baseline": payload("link.yaml::t")},
               {"nodeid": "ok.yaml::t", "status": "passed", "baseline": payload("ok.yaml::t")}]
    updated = update_baselines(tmp_path / "b", records, {})
    problems = updated.problems
    assert updated.written == 1
    assert len(problems) == 1 and problems[0].startswith("cannot write the baseline of link.yaml::t: ")
    assert list(elsewhere.iterdir()) == []


def test_update_leaves_a_file_byte_for_byte_when_only_the_run_would_change(tmp_path):
    store = BaselineStore(tmp_path)
    first = {"id": "r1", "started": "2026-01-01T00:00:00+00:00", "commit": "a" * 40, "dirty": False}
    path = store.write("s.yaml::same", payload("s.yaml::same", 1), first)
    store.write("s.yaml::moved", payload("s.yaml::moved", 1), first)
    before, stat = path.read_bytes(), path.stat()
    records = [{"nodeid": "s.yaml::same", "status": "passed", "baseline": payload("s.yaml::same", 1)},
               {"nodeid": "s.yaml::moved", "status": "passed", "baseline": payload("s.yaml::moved", 2)}]
    second = {"id": "r2", "started": "2026-02-02T00:00:00+00:00", "commit": "b" * 40, "dirty": True, "host": "h"}
    updated = update_baselines(tmp_path, records, second)
    assert (updated.written, updated.kept, updated.problems) == (1, 1, [])
    assert path.read_bytes() == before and path.stat().st_mtime_ns == stat.st_mtime_ns
    assert store.read("s.yaml::moved")["run"]["id"] == "r2" and store.read("s.yaml::moved")["figures"] == {"at_fault": 2}
    assert updated.line(tmp_path / "x").endswith(" (1 unchanged but for the run, left as they were)")


@pytest.mark.parametrize("change, key", [
    ({"units": {"kind": "scene", "ids": [], "columns": {}, "legend": {}, "good": {}, "reasons": 3}}, "units.reasons"),
    ({"units": ["p"]}, "units"),
    ({"search": ["broke"]}, "search"),
    ({"fingerprint": "abc"}, "fingerprint"),
])
def test_a_damaged_record_of_an_earlier_run_is_an_error_naming_the_key(tmp_path, change, key):
    summary = tmp_path / "summary.json"
    summary.write_text(json.dumps({"run": {"id": "r7"}, "results": [
        {"nodeid": "s.yaml::t", "baseline": payload("s.yaml::t") | change}]}))
    result = Gate(BaselineOptions(compare_with=summary)).compare("s.yaml::t", payload("s.yaml::t"))
    assert result.status == ERROR
    assert f"key '{key}" in result.note and "summary.json" in result.note and "s.yaml::t" in result.note
