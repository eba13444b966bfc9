#!/usr/bin/env python3
"""The README's main job as CI runs it: the demo (``pytest scenario_tests -n 2``) with a given Python.

Its reports go to a folder of CI's (never into the clone), and its outcome must be the one the
README promises ("It ends `34 passed, 14 xfailed`"): a strict XFail that starts passing, an item
that is no longer collected, or pytest's exit 5 (nothing ran) fails CI as a failed item does.

Usage: ``python .ci/demo.py PYTHON OUTPUT``
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from ci_steps import ROOT, streamed  # noqa: E402

#: pytest's last line: "33 passed, 13 xfailed in 139.83s (0:02:19)"
COUNT = re.compile(r"(\d+) (passed|failed|xfailed|xpassed|skipped|errors?|deselected)\b")


def promised() -> dict[str, int]:
    """The outcome the README's set-up says the demo ends with."""
    found = re.search(r"It ends `([^`]+)`", (ROOT / "README.md").read_text())
    if found is None:
        raise SystemExit("demo: the README no longer says what the demo ends with (\"It ends `...`\")")
    return counts(found.group(1))


def counts(line: str) -> dict[str, int]:
    return {kind: int(n) for n, kind in COUNT.findall(line)}


def run_demo(python: str, output: Path) -> int:
    """Run the demo; 0 when it ends as the README says, else 1."""
    code, last = streamed([python, "-m", "pytest", "scenario_tests", "-n", "2", "-p", "no:cacheprovider",
                           "--driveeval-output", str(output)])
    got, want = counts(last), promised()
    if code == 5 or not got:
        print(f"demo: {python}: the demo ran no test (exit {code}); that is a failure", file=sys.stderr)
        return 1
    if got != want or code != 0:
        print(f"demo: {python}: the demo ended {got} (exit {code}), the README promises {want}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__.split("Usage: ")[1].strip())
    sys.exit(run_demo(sys.argv[1], Path(sys.argv[2]).resolve()))
