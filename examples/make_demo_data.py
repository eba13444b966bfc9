"""Write the generated L5-format scenes the demo scenarios use (fixtures/l5kit/generated.zarr).

Beside the zarr go its road as an L5 semantic map (semantic_map.pb) and
meta.json (the dataset's world-to-ECEF transform), as l5kit lays out its files.

    python examples/make_demo_data.py [--scenes 16] [--frames 150] [--seed 0]

Deterministic: the same arguments write the same arrays.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from pytest_driveeval.synth.scenegen import generate_zarr

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=ROOT / "fixtures" / "l5kit" / "generated.zarr")
    args = parser.parse_args()
    path = generate_zarr(args.out, args.scenes, num_frames=args.frames, seed=args.seed, overwrite=True)
    print(f"wrote {args.scenes} scenes x {args.frames} frames to {path}, "
          f"and semantic_map.pb, meta.json beside it")


if __name__ == "__main__":
    main()
