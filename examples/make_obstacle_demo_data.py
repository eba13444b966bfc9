"""Write the obstacle-segmentation demo datasets into fixtures/t4/.

    python examples/make_obstacle_demo_data.py [--out fixtures/t4]

Deterministic (seed 0): rerunning rewrites identical annotation and bag
messages.  ``clean`` must pass detection and non-detection; ``missed_object``
drops the lead car's points (instance dcb2b352232fff50c4fad23718f31611) in
odd frames, so detection fails there.
"""
from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from pytest_driveeval.synth.t4gen import generate_t4_dataset

REPO = Path(__file__).resolve().parents[1]
# Fewer rays than the default 30k keep each dataset ~3 MB while every target
# still gets dozens of points.
DEMOS = {"clean": None, "missed_object": "missed_object"}
POINTS_PER_FRAME = 12000


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "fixtures" / "t4")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    for name, defect in DEMOS.items():
        root = args.out / name
        if root.exists():
            shutil.rmtree(root)  # stale frames of a longer run must not linger
        t0 = time.perf_counter()
        m = generate_t4_dataset(root, num_frames=10, seed=args.seed, storage="sqlite3",
                                points_per_frame=POINTS_PER_FRAME, defect=defect)
        size = sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
        print(f"{root}: {len(m.frame_stamps_ns)} frames, defect={defect}, "
              f"frames {m.defect_frames}, {size / 1e6:.1f} MB, "
              f"{time.perf_counter() - t0:.2f} s")


if __name__ == "__main__":
    main()
