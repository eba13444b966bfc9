"""Take docs/report.png again: the pytest-html report of a failing closed-loop
scenario as headless Chromium shows it.

The picture is tests/report/test_report_in_browser.py's own screenshot (that
test runs the scenario, opens the report in /usr/bin/chromium through
playwright and checks the animation and chart are displayed), so the README
shows what the test checked.  The old picture is replaced only when the test
passed and took a new one.

    python docs/make_report_picture.py [--out docs/report.png]

Needs the `test` extra, Debian's chromium and the playwright package.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TEST = REPO / "tests" / "report" / "test_report_in_browser.py"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "report.png")
    args = parser.parse_args()
    out = args.out.resolve()
    with tempfile.TemporaryDirectory() as folder:
        shot = Path(folder) / "report.png"
        # Not CI=1 to turn a skip into a failure: pytest-html would list it in the picture's environment.
        env = os.environ | {"DRIVEEVAL_REPORT_SCREENSHOT": str(shot)}
        done = subprocess.run([sys.executable, "-m", "pytest", str(TEST), "-q",
                               "-p", "no:randomly", "-p", "no:xdist"], cwd=REPO, env=env)
        if done.returncode != 0 or not shot.is_file():
            print(f"{TEST.relative_to(REPO)} did not pass or was skipped (chromium or playwright missing?); "
                  f"{out} left as it was", file=sys.stderr)
            return 1
        out.parent.mkdir(parents=True, exist_ok=True)
        staged = out.with_name(f".{out.name}.new")
        staged.write_bytes(shot.read_bytes())
        os.replace(staged, out)  # the README never links a half-written picture
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
