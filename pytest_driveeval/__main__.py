"""``python -m pytest_driveeval COMMAND``: what people run besides pytest.

    python -m pytest_driveeval compare A B          two runs side by side (see baseline/cli.py)
    python -m pytest_driveeval check-data PATH...   can these datasets be evaluated (see datacheck/)
"""
from __future__ import annotations

import argparse
import sys

from .baseline.cli import add_compare_command
from .datacheck.cli import add_check_data_command

PROG = "python -m pytest_driveeval"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description="pytest-driveeval commands besides pytest itself")
    commands = parser.add_subparsers(metavar="COMMAND", required=True)
    add_compare_command(commands, PROG)
    add_check_data_command(commands, PROG)
    args = parser.parse_args(argv)
    # Names in a node id may be any text; a terminal that cannot show one gets an escape, not a crash.
    sys.stdout.reconfigure(errors="backslashreplace")  # type: ignore[union-attr]
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
