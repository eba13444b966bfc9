"""execute.reuse: what a process keeps from one chunk to the next, keyed by what the caller names
and the identity of the files it was read from.  The use cases' chunks on it:
tests/usecases/*/test_*_reuse.py."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from pytest_driveeval.execute import reuse
from reuse_items import nothing_kept, settle  # noqa: F401  (tests/reuse_items.py; the fixture by name)


def settled(path: Path, text: str, age: float = 60.0) -> Path:
    """``text`` in ``path``, modified ``age`` seconds ago (older than RACY_SECONDS)."""
    path.write_text(text)
    return settle(path, age)


class Loader:
    """Reads a file into a new object each time, counting the reads."""

    def __init__(self, path: Path):
        self.path = path
        self.calls = 0

    def __call__(self) -> list[str]:
        self.calls += 1
        return [self.path.read_text()]


def test_the_second_call_for_the_same_key_and_unchanged_file_gets_the_first_calls_object(tmp_path):
    path = settled(tmp_path / "m.pt2", "weights")
    load = Loader(path)
    first = reuse.reused("model", ("m.pt2", str(tmp_path)), [path], load)
    assert reuse.reused("model", ("m.pt2", str(tmp_path)), [path], load) is first
    assert load.calls == 1 and reuse.loads == {"model": 1}


@pytest.mark.parametrize("change", ["size", "mtime", "replaced"])
def test_a_changed_file_is_read_again(tmp_path, change):
    path = settled(tmp_path / "m.pt2", "weights")
    load = Loader(path)
    assert reuse.reused("model", "m", [path], load) == ["weights"]
    if change == "size":
        settled(path, "other weights")
    elif change == "mtime":  # same size, new content: only the mtime tells
        settled(path, "WEIGHTS", age=30.0)
    else:  # another file moved over it, same size and mtime: only the inode tells
        other = settled(tmp_path / "new.pt2", "WEIGHTS")
        os.utime(other, ns=(path.stat().st_atime_ns, path.stat().st_mtime_ns))
        os.replace(other, path)
    assert reuse.reused("model", "m", [path], load) == [path.read_text()]
    assert load.calls == 2
    # ... and the new version is kept in place of the old one
    assert reuse.reused("model", "m", [path], load) == [path.read_text()] and load.calls == 2
    assert reuse.held("model") == 1


def test_a_different_key_never_gets_anothers_object_even_from_the_same_file(tmp_path):
    path = settled(tmp_path / "m.pt2", "weights")
    load = Loader(path)
    a = reuse.reused("model", ("m.pt2", "/scenarios/a"), [path], load)
    b = reuse.reused("model", ("m.pt2", "/scenarios/b"), [path], load)
    c = reuse.reused("semantic map", ("m.pt2", "/scenarios/a"), [path], load)
    assert a is not b and a is not c and b is not c and load.calls == 3
    assert reuse.reused("model", ("m.pt2", "/scenarios/a"), [path], load) is a
    assert reuse.loads == {"model": 2, "semantic map": 1}


def test_a_file_modified_a_moment_ago_is_read_for_each_call(tmp_path):
    # Its next change may not show in size or mtime (a coarse clock): not trusted until it settles.
    path = tmp_path / "m.pt2"
    path.write_text("weights")
    load = Loader(path)
    reuse.reused("model", "m", [path], load)
    reuse.reused("model", "m", [path], load)
    assert load.calls == 2
    settled(path, "weights")
    reuse.reused("model", "m", [path], load)
    reuse.reused("model", "m", [path], load)
    assert load.calls == 3


def test_each_kind_keeps_its_last_entries_only(tmp_path):
    paths = [settled(tmp_path / f"m{i}.pt2", str(i)) for i in range(3)]
    loads = [Loader(p) for p in paths]
    for path, load in zip(paths, loads):
        reuse.reused("model", path.name, [path], load, keep=2)
    reuse.reused("model", paths[2].name, [paths[2]], loads[2], keep=2)   # kept
    reuse.reused("model", paths[0].name, [paths[0]], loads[0], keep=2)   # dropped as the oldest: read again
    assert [load.calls for load in loads] == [2, 1, 1]
    assert reuse.held("model") == 2


def test_a_missing_file_and_a_failed_load_are_left_to_the_loader_and_nothing_is_kept(tmp_path):
    missing = tmp_path / "none.pt2"

    def fails():
        raise FileNotFoundError(f"{missing}: no such file")

    for _ in range(2):
        with pytest.raises(FileNotFoundError, match="none.pt2: no such file"):
            reuse.reused("model", "none", [missing], fails)
    path = settled(tmp_path / "m.pt2", "weights")
    calls = []

    def flaky():
        calls.append(1)
        if len(calls) == 1:
            raise OSError("interrupted")
        return ["weights"]

    with pytest.raises(OSError):
        reuse.reused("model", "m", [path], flaky)
    assert reuse.reused("model", "m", [path], flaky) == ["weights"] == reuse.reused("model", "m", [path], flaky)
    assert len(calls) == 2


def test_the_environment_switch_turns_reuse_off(tmp_path, monkeypatch):
    path = settled(tmp_path / "m.pt2", "weights")
    load = Loader(path)
    monkeypatch.setenv(reuse.SWITCH, "0")
    assert reuse.reused("model", "m", [path], load) is not reuse.reused("model", "m", [path], load)
    assert load.calls == 2 and reuse.loads == {"model": 2}
