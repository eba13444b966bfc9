"""Where references live (store.py): baseline files by node id, earlier runs' summaries, and which
summary --driveeval-compare names; no session."""
from __future__ import annotations

import json
import os
from pathlib import Path, PurePosixPath

import pytest

from pytest_driveeval.baseline.store import (BASELINE_FORMAT, MAX_NAME, BaselineError, BaselineStore, RunReference,
                                             check_baseline, relative_path, resolve_compare)

ODD_IDS = [
    "a/b.scenario.yaml::closed_loop[x]",
    "tests/test_x.py::TestClass::test_y[1-2]",
    "tests/test_x.py::TestClass::Inner::test_y",
    "s.yaml::closed_loop[town/one]",
    "s.yaml::closed_loop[town one]",
    "s.yaml::closed_loop[town_one]",
    "s.yaml::closed_loop[../../etc/passwd]",
    "../outside/s.yaml::closed_loop",
    "/abs/path/s.yaml::closed_loop",
    "./s.yaml::closed_loop",
    "s.yaml::..",
    "s.yaml::.",
    "s.yaml::...",
    "s.yaml::",
    "s.yaml::" + "p" * 400,
    "s.yaml::" + "p" * 399 + "q",
    "s.yaml::closed_loop[é ü 東京]",
    "s.yaml::closed_loop[\x00\n]",
    "x" * 300 + "/s.yaml::t",
]


@pytest.mark.parametrize("nodeid", ODD_IDS)
def test_relative_path_stays_inside_the_root_with_safe_short_parts(tmp_path, nodeid):
    rel = relative_path(nodeid)
    assert not rel.is_absolute()
    assert all(part not in ("", ".", "..") and len(part) <= MAX_NAME + len(".json") for part in rel.parts)
    assert rel.suffix == ".json"
    assert (tmp_path / rel).resolve().is_relative_to(tmp_path.resolve())
    assert relative_path(nodeid) == rel


def test_different_node_ids_never_share_a_file():
    paths = [relative_path(n) for n in ODD_IDS]
    assert len(set(paths)) == len(paths), [(n, str(p)) for n, p in zip(ODD_IDS, paths)]


def test_plain_node_ids_keep_readable_paths():
    assert relative_path("a/b.scenario.yaml::closed_loop[x]") == PurePosixPath("a/b.scenario.yaml.d/closed_loop[x].json")
    assert relative_path("t.py::C::test[1-2]") == PurePosixPath("t.py.d/C__test[1-2].json")


def test_a_long_name_is_cut_with_a_digest_of_all_of_it():
    a, b = relative_path("s.yaml::" + "p" * 400), relative_path("s.yaml::" + "p" * 399 + "q")
    assert a.name.startswith("p" * 100) and a != b


# --- write and read ---------------------------------------------------------------------------

PAYLOAD = {"version": 1, "rules": {"figures": {}}, "key": {"file": "s.yaml", "scenario": "S", "item": "t[a b]",
                                                        "nodeid": "s.yaml::t[a b]"},
           "verdict": "passed", "summary": "ok", "figures": {"at_fault": 0, "max_displacement": 0.25},
           "units": {"kind": "scene", "ids": {"from": 0, "count": 2}, "columns": {"scene": ["pf"]},
                     "legend": {"f": "failed", "p": "passed"}, "good": {"scene": "p"}, "reasons": {}},
           "search": None, "fingerprint": {"seed": 1}}
RUN = {"id": "r1", "started": "2026-01-01T00:00:00", "commit": "abc", "dirty": False, "other": "dropped"}


def test_write_then_read_round_trip(tmp_path):
    store = BaselineStore(tmp_path / "baselines")
    path = store.write("s.yaml::t[a b]", PAYLOAD, RUN)
    assert path == store.path_for("s.yaml::t[a b]") and path.is_relative_to(tmp_path / "baselines")
    text = path.read_text()
    assert text.endswith("\n") and '\n "figures": {' in text  # indented, one key a line
    back = store.read("s.yaml::t[a b]")
    assert back["run"] == {"id": "r1", "started": "2026-01-01T00:00:00", "commit": "abc", "dirty": False}
    assert back["driveeval_baseline"] == BASELINE_FORMAT
    assert "version" not in back and "rules" not in back
    assert {k: back[k] for k in ("key", "verdict", "figures", "units", "fingerprint")} == \
        {k: PAYLOAD[k] for k in ("key", "verdict", "figures", "units", "fingerprint")}
    assert store.files() == {path: "s.yaml::t[a b]"}
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temporary left


def test_read_of_an_item_without_a_baseline_is_none(tmp_path):
    assert BaselineStore(tmp_path / "nowhere").read("s.yaml::t") is None


def test_write_refuses_a_symlinked_folder_on_the_way(tmp_path):
    root, elsewhere = tmp_path / "baselines", tmp_path / "elsewhere"
    root.mkdir()
    elsewhere.mkdir()
    (root / "s.yaml.d").symlink_to(elsewhere, target_is_directory=True)
    (elsewhere / "t.json").write_text("not ours")
    store = BaselineStore(root)
    with pytest.raises(BaselineError, match="s.yaml.d is a symbolic link"):
        store.write("s.yaml::t", PAYLOAD, RUN)
    with pytest.raises(BaselineError, match="symbolic link"):
        store.read("s.yaml::t")
    assert [(p.name, p.read_text()) for p in elsewhere.iterdir()] == [("t.json", "not ours")]
    assert store.files() == {}


def test_write_refuses_a_symlink_file_and_leaves_its_target_alone(tmp_path):
    root = tmp_path / "baselines"
    store = BaselineStore(root)
    target = tmp_path / "precious.txt"
    target.write_text("keep")
    store.path_for("s.yaml::t").parent.mkdir(parents=True)
    store.path_for("s.yaml::t").symlink_to(target)
    with pytest.raises(BaselineError, match="symbolic link"):
        store.write("s.yaml::t", PAYLOAD, RUN)
    with pytest.raises(BaselineError, match="symbolic link"):
        store.read("s.yaml::t")
    assert target.read_text() == "keep"
    assert store.files() == {}


# --- check_baseline ----------------------------------------------------------------------------

def valid() -> dict:
    return {"driveeval_baseline": 1, "key": {"nodeid": "s.yaml::t"}, "run": {}, "verdict": "passed",
            "figures": {"a": 1}}


@pytest.mark.parametrize("text, match", [
    ("{not json", "is not valid JSON"),
    ('{"driveeval_baseline": 1, "key": {"nodeid": "s.y', r"is not valid JSON \(truncated\?\)"),
    ('{"driveeval_baseline": 1, "key": {', r"is not valid JSON \(truncated\?\)"),
    ("[1, 2]", "not a mapping at the top level"),
])
def test_unreadable_json_is_named_with_the_file(tmp_path, text, match):
    with pytest.raises(BaselineError, match=match) as info:
        check_baseline(text, tmp_path / "b" / "t.json", "s.yaml::t")
    assert "t.json" in str(info.value) and "s.yaml::t" in str(info.value)


@pytest.mark.parametrize("change, key", [
    ({"driveeval_baseline": "1"}, "driveeval_baseline"),
    ({"driveeval_baseline": True}, "driveeval_baseline"),
    ({"key": None}, "key"),
    ({"run": []}, "run"),
    ({"verdict": 1}, "verdict"),
    ({"figures": [1]}, "figures"),
    ({"figures": {"a": "1"}}, "figures.a"),
    ({"figures": {"a": True}}, "figures.a"),
    ({"units": "pf"}, "units"),
    ({"search": []}, "search"),
    ({"fingerprint": 3}, "fingerprint"),
    ({"units": {"kind": "scene"}}, "units.legend"),
    ({"key": {"nodeid": "other.yaml::t"}}, "key.nodeid"),
])
def test_wrong_types_name_the_file_and_the_key(tmp_path, change, key):
    with pytest.raises(BaselineError) as info:
        check_baseline(json.dumps(valid() | change), tmp_path / "t.json", "s.yaml::t")
    assert "t.json" in str(info.value) and f"'{key}" in str(info.value), str(info.value)


def test_a_missing_key_is_said_missing(tmp_path):
    data = valid()
    del data["verdict"]
    with pytest.raises(BaselineError, match="key 'verdict' is missing, not a str"):
        check_baseline(json.dumps(data), tmp_path / "t.json", "s.yaml::t")


def test_a_newer_format_asks_for_an_upgrade(tmp_path):
    with pytest.raises(BaselineError, match=rf"t\.json: format {BASELINE_FORMAT + 1} \(key 'driveeval_baseline'\) "
                                            "is newer .* upgrade"):
        check_baseline(json.dumps(valid() | {"driveeval_baseline": BASELINE_FORMAT + 1}), tmp_path / "t.json",
                       "s.yaml::t")


def test_a_newer_format_is_said_before_its_reshaped_keys(tmp_path):
    data = {"driveeval_baseline": BASELINE_FORMAT + 1, "figures": [["a", 1]], "identity": {"nodeid": "s.yaml::t"}}
    with pytest.raises(BaselineError, match="is newer than this pytest-driveeval reads"):
        check_baseline(json.dumps(data), tmp_path / "t.json", "s.yaml::t")


def test_a_valid_baseline_with_extra_keys_and_null_figures_reads(tmp_path):
    data = valid() | {"figures": {"a": None, "b": 1.5}, "new_key": [1]}
    assert check_baseline(json.dumps(data), tmp_path / "t.json", "s.yaml::t") == data


def test_a_corrupt_file_read_through_the_store_names_it(tmp_path):
    store = BaselineStore(tmp_path)
    path = store.write("s.yaml::t", PAYLOAD | {"key": {"nodeid": "s.yaml::t"}}, RUN)
    path.write_text(path.read_text()[:40])
    with pytest.raises(BaselineError, match=r"t\.json of s\.yaml::t is not valid JSON \(truncated\?\)"):
        store.read("s.yaml::t")
    assert store.files() == {path: None}


BOMB = "[" * 100_000 + "]" * 100_000


def test_a_nesting_bomb_is_a_baseline_error_naming_the_file_not_a_recursion_error(tmp_path):
    store = BaselineStore(tmp_path)
    path = store.path_for("s.yaml::t")
    path.parent.mkdir(parents=True)
    path.write_text('{"figures": ' + BOMB + "}")
    with pytest.raises(BaselineError) as info:
        store.read("s.yaml::t")
    assert str(info.value).startswith(f"baseline {path} of s.yaml::t: JSON nested 100001 levels deep")
    assert str(info.value).endswith("remove it or rewrite it with --driveeval-baseline-update")


def test_a_stray_nesting_bomb_in_the_folder_is_listed_as_unreadable(tmp_path):
    store = BaselineStore(tmp_path)
    good = store.write("s.yaml::t", PAYLOAD | {"key": {"nodeid": "s.yaml::t"}}, RUN)
    (tmp_path / "stray.json").write_text(BOMB)
    assert store.files() == {good: "s.yaml::t", tmp_path / "stray.json": None}


def test_a_baseline_file_that_is_a_fifo_is_refused_without_waiting_for_a_writer(tmp_path):
    store = BaselineStore(tmp_path)
    path = store.path_for("s.yaml::t")
    path.parent.mkdir(parents=True)
    os.mkfifo(path)
    with pytest.raises(BaselineError, match=r"t\.json is not a regular file: remove it"):
        store.read("s.yaml::t")
    assert store.files() == {}


@pytest.mark.parametrize("value, said", [("NaN", "NaN"), ("Infinity", "Infinity"), ("-Infinity", "-Infinity")])
@pytest.mark.parametrize("group", ["figures", "search.minimal"])
def test_a_non_finite_figure_is_a_located_error(tmp_path, value, said, group):
    outer, _, inner = group.partition(".")
    data = valid()
    if inner:
        data["search"] = {"broke": True, "minimal": {"offset": 1.0}}
    text = json.dumps(data).replace('"a": 1' if not inner else '"offset": 1.0', f'"{"a" if not inner else "offset"}": {value}')
    with pytest.raises(BaselineError) as info:
        check_baseline(text, tmp_path / "t.json", "s.yaml::t")
    name = "a" if not inner else "offset"
    assert str(info.value) == (f"baseline {tmp_path / 't.json'} of s.yaml::t: key '{group}.{name}' is {said}, not a "
                               "finite number; rewrite it with --driveeval-baseline-update")


# --- earlier runs ------------------------------------------------------------------------------

def write_summary(folder: Path, records: list, run_id: str = "r1") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "summary.json"
    path.write_text(json.dumps({"run": {"id": run_id, "commit": "c0ffee"}, "results": records}))
    return path


def test_run_reference_reads_the_payload_of_a_record(tmp_path):
    summary = write_summary(tmp_path, [{"nodeid": "s.yaml::t", "baseline": {"verdict": "passed", "figures": {}}}])
    reference = RunReference(summary)
    assert reference.read("s.yaml::t") == {"verdict": "passed", "figures": {}, "run": {"id": "r1", "commit": "c0ffee"}}
    assert reference.read("s.yaml::other") is None


def test_a_non_finite_figure_of_an_earlier_run_is_located(tmp_path):
    summary = write_summary(tmp_path, [{"nodeid": "s.yaml::t", "baseline": {"verdict": "passed",
                                                                              "figures": {"a": float("nan")}}}])
    with pytest.raises(BaselineError, match=r"run r1 \(.*summary.json\): the record of s.yaml::t cannot be compared: "
                                            r"key 'figures.a' is NaN, not a finite number"):
        RunReference(summary).read("s.yaml::t")


def test_run_reference_without_payloads_says_so(tmp_path):
    summary = write_summary(tmp_path, [{"nodeid": "s.yaml::t", "outcome": {}}])
    with pytest.raises(BaselineError, match=r"run r1 \(.*summary.json\) kept no comparable record of s.yaml::t"):
        RunReference(summary).read("s.yaml::t")


@pytest.mark.parametrize("text", ["", "{", "[]", '{"run": {}}', '{"results": {}}', '{"results": [], "run": 3}',
                                  '{"results": ' + BOMB + "}"])
def test_an_unreadable_summary_is_a_baseline_error(tmp_path, text):
    (tmp_path / "summary.json").write_text(text)
    with pytest.raises(BaselineError, match="is not a readable driveeval summary"):
        RunReference(tmp_path / "summary.json")


def history(output: Path, *lines: str) -> None:
    output.mkdir(exist_ok=True)
    (output / "history.jsonl").write_text("".join(line + "\n" for line in lines))


def line(run_id: str) -> str:
    return json.dumps({"run": {"id": run_id}, "summary": f"runs/{run_id}/summary.json"})


def test_last_is_the_newest_finished_run_but_this_one(tmp_path):
    out = tmp_path / "out"
    for run_id in ("r1", "r2", "r3"):
        write_summary(out / "runs" / run_id, [], run_id)
    history(out, line("r1"), line("r2"), line("r3"))
    assert resolve_compare("last", out) == out / "runs/r3/summary.json"
    assert resolve_compare("last", out, current_run="r3") == out / "runs/r2/summary.json"


def test_last_skips_corrupt_lines_and_pruned_runs(tmp_path):
    out = tmp_path / "out"
    write_summary(out / "runs" / "r1", [], "r1")
    history(out, line("r1"), line("r2-pruned"), "{torn", "[]", '"text"', '{"run": "r9", "summary": "x"}',
            '{"run": {"id": "r8"}, "summary": 5}', '{"run": {"id": "r7"}}')
    assert resolve_compare("last", out) == out / "runs/r1/summary.json"


def test_last_without_a_finished_run_is_an_error(tmp_path):
    with pytest.raises(ValueError, match="no finished run in .*history.jsonl"):
        resolve_compare("last", tmp_path)
    history(tmp_path, line("r1"))
    write_summary(tmp_path / "runs" / "r1", [], "r1")
    with pytest.raises(ValueError, match="no finished run"):
        resolve_compare("last", tmp_path, current_run="r1")


def test_a_run_id_a_summary_path_and_a_run_folder(tmp_path, monkeypatch):
    out = tmp_path / "out"
    summary = write_summary(out / "runs" / "r1", [], "r1")
    other = write_summary(tmp_path / "saved", [], "r0")
    assert resolve_compare("r1", out) == summary
    assert resolve_compare(str(other), out) == other
    assert resolve_compare(str(tmp_path / "saved"), out) == other
    monkeypatch.chdir(tmp_path)
    assert resolve_compare("saved/summary.json", out) == Path("saved/summary.json")


@pytest.mark.parametrize("spec", ["r2", "nowhere/summary.json", "saved"])
def test_anything_else_is_an_error_naming_the_choices(tmp_path, monkeypatch, spec):
    (tmp_path / "saved").mkdir()  # a folder without a summary
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=rf"'{spec}' is neither 'last', 'last~N', a run id under .*runs, nor a summary.json"):
        resolve_compare(spec, tmp_path / "out")
