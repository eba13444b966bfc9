"""``python -m pytest_driveeval check-data PATH...``: read a dataset before writing scenarios for it.

Each PATH is a file or folder of a supported format (an l5kit zarr, ScenarioNet scenario files, a
CommonRoad XML file, a ROS 2 bag, a t4_dataset), or a folder holding such: it is searched, and
each dataset found is checked with the reader the evaluation uses (:mod:`.formats`).  For each it
says what was read, what was skipped and why, and, when it cannot be evaluated, why (the file and
the element).  Exit status: 0 every file can be evaluated, 1 some cannot (a path that does not
exist, or a folder with nothing to read, counts as one), 2 the command line is wrong.
"""
from __future__ import annotations

from pytest_driveeval.datacheck.find import check_paths, found_datasets
from pytest_driveeval.datacheck.result import SKIPPED_ATTRIBUTES, FileCheck, skipped_entries

__all__ = ["SKIPPED_ATTRIBUTES", "FileCheck", "check_paths", "found_datasets", "skipped_entries"]
