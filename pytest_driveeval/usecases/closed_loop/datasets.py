"""Which reader opens a closed-loop dataset: an l5kit zarr, or ScenarioNet's scenario files (one
file or a folder of them: nuPlan, Waymo, nuScenes, Argoverse 2, ... as ScenarioNet converts them).

Told by the files themselves, so that a Ray worker given only the path opens it the same way; a
dataset's ``Format:`` option, when given, must agree with them.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from pytest_driveeval.core.errors import DataError, display_path

FORMATS = ("l5kit", "scenarionet")


def format_of(path: Path) -> str:
    if path.suffix == ".pkl" and not path.is_dir():  # a link to a device or a FIFO too: its reader names it
        return "scenarionet"
    if path.is_dir() and not (path / ".zgroup").exists() and not (path / "scenes").exists() \
            and any(path.rglob("*.pkl")):
        return "scenarionet"
    return "l5kit"


def open_dataset(path: str | Path, declared: str | None = None) -> Any:
    path = Path(path)
    found = format_of(path)
    if declared is not None:
        if declared not in FORMATS:
            raise DataError(f"dataset {display_path(path)}: Format {declared!r} is not one of {', '.join(FORMATS)}")
        if declared != found:
            raise DataError(f"dataset {display_path(path)}: Format says {declared}, but the files are {found}'s")
    if found == "scenarionet":
        from pytest_driveeval.io.scenarionet.scenarionet_l5 import ScenarioNetDataset

        return ScenarioNetDataset.open(path)
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset

    return L5Dataset.open(path)
