"""Which storage a ROS 2 bag path stands for, checked before ``rosbags`` opens it.

A bag is a folder with metadata.yaml and its .db3/.mcap files, but recorders
that are stopped hard (and many tools) leave a folder with one storage file and
no metadata.yaml; ``rosbags`` reads such a file on its own, so we hand it that.
What cannot be read (a ROS 1 bag, a split bag without metadata.yaml, an MCAP
file whose chunks do not match its index) is a :class:`BagError` that says how
to fix it, rather than a bag that silently is not there.
"""
from __future__ import annotations

from pathlib import Path

from ...core.errors import DataError
from .mcap_index import chunk_problem

__all__ = ["STORAGE_SUFFIXES", "BagError", "storage_files", "storage_for"]

STORAGE_SUFFIXES = (".db3", ".mcap")
ROS1_MAGIC = b"#ROSBAG V2.0"


class BagError(DataError, ValueError):
    """Bag missing, corrupt, or lacking the requested topic/type."""


def storage_files(path: Path) -> str:
    """The storage files of a bag, for error messages."""
    if path.is_dir():
        files = sorted(p.name for p in path.iterdir() if p.suffix in STORAGE_SUFFIXES)
        return "storage files " + (", ".join(files) or "none")
    return f"storage file {path.name}"


def storage_for(path: Path) -> Path:
    """What rosbags should open for ``path``: the folder when it has metadata.yaml, else
    its single storage file; MCAP files are checked against their chunk index first."""
    storage = _resolve(path)
    mcaps = sorted(storage.glob("*.mcap")) if storage.is_dir() else [storage] * (storage.suffix == ".mcap")
    for mcap in mcaps:
        problem = chunk_problem(mcap)
        if problem:
            raise BagError(f"{path}: {problem}")
    return storage


def _resolve(path: Path) -> Path:
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    if not path.is_dir():
        if path.suffix == ".bag" or _magic(path) == ROS1_MAGIC:
            raise BagError(_ros1_message(path, path.with_suffix("")))
        return path
    if (path / "metadata.yaml").is_file():
        return path
    found = sorted(p.name for p in path.iterdir())
    storage = [path / n for n in found if Path(n).suffix in STORAGE_SUFFIXES]
    if len(storage) == 1:
        return storage[0]
    ros1 = [path / n for n in found if n.endswith(".bag")]
    if not storage and ros1:
        raise BagError(_ros1_message(ros1[0], Path(f"{path}_ros2"), folder=path))
    if not storage:
        raise BagError(f"{path}: not a ROS 2 bag: no metadata.yaml and no .db3 or .mcap file "
                       f"(found: {', '.join(found) or 'nothing'})")
    # Without metadata.yaml the order of a split bag's files is unknown.
    raise BagError(f"{path}: no metadata.yaml, and {len(storage)} storage files "
                   f"({', '.join(p.name for p in storage)}); a bag split over several files is read "
                   f"through its metadata.yaml: recreate it with `ros2 bag reindex {path}`")


def _magic(path: Path) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(len(ROS1_MAGIC))
    except OSError:
        return b""


def _ros1_message(bag: Path, dst: Path, folder: Path | None = None) -> str:
    where = f"{folder}: holds a ROS 1 bag ({bag.name})" if folder else f"{bag}: a ROS 1 bag"
    then = f"put that folder in place of {folder}" if folder else "read that folder instead"
    return (f"{where}, and only ROS 2 bags (.db3 or .mcap storage) can be read; convert it with "
            f"`rosbags-convert --src {bag} --dst {dst}` (from the rosbags package) and {then}")
