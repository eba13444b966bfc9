"""The ``check-data`` command of ``python -m pytest_driveeval``."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pytest_driveeval.core.errors import display_path

#: exit status: every file can be evaluated / some file cannot / the command line is wrong (argparse)
ALL_FINE, SOME_CANNOT, USAGE = 0, 1, 2


def add_check_data_command(commands, prog: str) -> None:
    parser = commands.add_parser(
        "check-data", help="read datasets and say what can be evaluated",
        description="Read each dataset with the reader the evaluation uses (l5kit zarr with its semantic map, "
                    "ScenarioNet files or folders, CommonRoad XML, ROS 2 bags, t4_datasets; a folder is "
                    "searched for them) and say, per file, what was read, what was skipped and why, and why a "
                    "file cannot be evaluated.",
        epilog=f"exit status: {ALL_FINE} every file can be evaluated, {SOME_CANNOT} some file cannot (a path "
               f"that does not exist or a folder without a dataset counts), {USAGE} wrong command line. "
               f"Example: {prog} check-data data/scenarionet data/maps/*.xml")
    parser.add_argument("paths", nargs="+", type=Path, metavar="PATH", help="a dataset file or folder")
    parser.add_argument("--json", action="store_true", help="one JSON document on stdout instead of text")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from pytest_driveeval.datacheck.find import check_paths

    def show(check) -> None:
        if not args.json:
            print("\n".join(check.lines()), flush=True)

    checks, ignored = check_paths(list(args.paths), show)
    bad = [c for c in checks if not c.ok]
    if args.json:
        json.dump({"checks": [c.to_json() for c in checks], "not_read": [str(p) for p in ignored],
                   "ok": not bad}, sys.stdout, indent=1)
        print()
    else:
        if ignored:
            shown = ", ".join(display_path(p) for p in ignored[:5]) + (", ..." if len(ignored) > 5 else "")
            print(f"not read ({len(ignored)} file(s) of no format check-data reads): {shown}")
        print(f"checked {len(checks)} dataset file(s): {len(checks) - len(bad)} can be evaluated, "
              f"{len(bad)} cannot" + (": " + ", ".join(display_path(c.path) for c in bad) if bad else ""))
    return SOME_CANNOT if bad else ALL_FINE
