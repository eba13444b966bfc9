"""Files are written whole or not at all, with the user's umask."""
from __future__ import annotations

import os

import pytest

from pytest_driveeval.core.atomic import atomic_path, create_exclusive, write_text_atomic


def test_a_writer_that_fails_half_way_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "anim.gif"
    target.write_bytes(b"old, complete")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            assert tmp.parent == tmp_path and tmp.suffix == ".gif" and tmp != target
            tmp.write_bytes(b"half of a GI")
            raise RuntimeError("killed while encoding")
    assert target.read_bytes() == b"old, complete"
    assert [p.name for p in tmp_path.iterdir()] == ["anim.gif"]


def test_the_new_file_appears_only_when_complete(tmp_path):
    target = tmp_path / "sub" / "result.json"
    with atomic_path(target) as tmp:
        tmp.write_text("{}")
        assert not target.exists()
    assert target.read_text() == "{}"


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_files_get_the_mode_the_umask_gives(tmp_path, umask):
    old = os.umask(umask)
    try:
        write_text_atomic(tmp_path / "a.md", "x")
        assert create_exclusive(tmp_path / "b.json", "{}")
    finally:
        os.umask(old)
    for name in ("a.md", "b.json"):
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o666 & ~umask


def test_create_exclusive_never_replaces_an_existing_file(tmp_path):
    target = tmp_path / "run.json"
    assert create_exclusive(target, "first")
    assert not create_exclusive(target, "second")
    assert target.read_text() == "first"
    assert [p.name for p in tmp_path.iterdir()] == ["run.json"]
