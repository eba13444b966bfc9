"""Which datasets a path holds, told by the files themselves (as the closed loop's dataset opener
tells an l5kit zarr from ScenarioNet files): a zarr group, a t4_dataset's ``annotation/``, a bag's
``metadata.yaml`` or storage file, a scenario pickle, a CommonRoad XML file.  A folder that is none
of these is searched; what it holds besides datasets is listed, not checked."""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator

from pytest_driveeval.core.errors import display_path
from pytest_driveeval.datacheck.result import FileCheck

#: a ScenarioNet folder's own index files: not scenarios (io.scenarionet.scenarionet.SUMMARY_FILES)
SCENARIONET_INDEX = ("dataset_summary.pkl", "dataset_mapping.pkl")
BAG_FILES = (".db3", ".mcap")


def kind_of(path: Path) -> str | None:
    """"l5", "t4", "bag", "scenarionet", "commonroad" or None (a plain folder, or another file)."""
    if path.is_dir():
        if (path / ".zgroup").is_file():
            return "l5"
        if (path / "annotation").is_dir():
            return "t4"
        if (path / "metadata.yaml").is_file():
            return "bag"
        return None
    if path.suffix == ".pkl" and path.name not in SCENARIONET_INDEX:
        return "scenarionet"
    if path.suffix.lower() == ".xml":
        return "commonroad"
    if path.suffix in BAG_FILES:
        return "bag"
    return None


def found_datasets(path: Path, ignored: list[Path] | None = None) -> Iterator[tuple[str, Path]]:
    """(kind, path) of each dataset at or under ``path``, in name order; ``ignored`` collects the
    other files met on the way (hidden files and folders are passed over)."""
    kind = kind_of(path)
    if kind is not None:
        yield kind, path
        if kind == "t4" and (path / "input_bag").is_dir():
            yield "bag", path / "input_bag"
        return
    if not path.is_dir():
        if ignored is not None:
            ignored.append(path)
        return
    for child in sorted(path.iterdir()):
        if not child.name.startswith("."):
            yield from found_datasets(child, ignored)


def _checkers() -> dict[str, Callable[[Path], FileCheck]]:
    from pytest_driveeval.datacheck import formats

    return {"l5": formats.check_l5, "scenarionet": formats.check_scenarionet,
            "commonroad": formats.check_commonroad, "bag": formats.check_bag, "t4": formats.check_t4}


def check_paths(paths: list[Path], on_check: Callable[[FileCheck], None] | None = None
                ) -> tuple[list[FileCheck], list[Path]]:
    """Every dataset at or under ``paths`` checked (``on_check`` sees each as it is done), and the
    files met that are of no format read here.  A path that does not exist, or a folder without a
    dataset, is a check that failed."""
    checkers = _checkers()
    checks: list[FileCheck] = []
    ignored: list[Path] = []

    def done(check: FileCheck) -> None:
        checks.append(check)
        if on_check is not None:
            on_check(check)

    for path in paths:
        if not path.exists() and not path.is_symlink():
            done(FileCheck(path, "not found", problems=[f"{display_path(path)}: no such file or folder"]))
            continue
        before = len(ignored)
        found = list(found_datasets(path, ignored))
        if not found:
            what = ("a folder without a dataset in it" if path.is_dir()
                    else "not a format check-data reads")
            seen = ignored[before:]
            done(FileCheck(path, "unknown", problems=[
                f"{display_path(path)}: {what} (an l5kit zarr, ScenarioNet *.pkl, CommonRoad *.xml, a ROS 2 bag "
                f"or a t4_dataset folder)" + (f"; it holds {len(seen)} other file(s)" if path.is_dir() and seen
                                               else "")]))
            del ignored[before:]
            continue
        for kind, where in found:
            done(checkers[kind](where))
    return checks, ignored
