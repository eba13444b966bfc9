"""Loading a shipped ``.pt2`` through the harness's loader (``policies.pt2_archive``: no pickle, every
name checked) against ``torch.export.load`` (the reference, which unpickles the sample inputs),
both measured in the same run, each followed by ``.module()`` as ``load_model`` does.

Per model: the median of ``--repeats`` loads of each after one warm-up of each (torch's first
deserialisation imports and registers its operator libraries), alternated so that load on the
machine falls on both alike.  Prints each model's ratio (ours / torch.export.load) and the median
over the models.  Nothing is asserted; issue 34 named no target, only that safety may cost little.

    python benchmarks/bench_pt2_loading.py [--repeats 5] [--smoke]
"""
from __future__ import annotations

import argparse
import statistics
import time
import warnings
from pathlib import Path

import torch

from pytest_driveeval.policies.pt2_archive import load_exported_program

MODELS = Path(__file__).resolve().parents[1] / "fixtures" / "models"


def timed(load) -> float:
    start = time.perf_counter()
    load().module()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--smoke", action="store_true", help="one model, one repeat: checks the script runs")
    args = parser.parse_args()
    models = sorted(MODELS.glob("*.pt2"))
    if args.smoke:
        print("smoke run: one model, one repeat; the figures mean nothing")
        models, args.repeats = models[:1], 1
    warnings.filterwarnings("ignore")
    ratios = []
    for path in models:
        ours_load = lambda: load_exported_program(path)  # noqa: E731
        torch_load = lambda: torch.export.load(str(path))  # noqa: E731
        timed(ours_load), timed(torch_load)  # warm-up
        ours, theirs = [], []
        for _ in range(args.repeats):
            ours.append(timed(ours_load))
            theirs.append(timed(torch_load))
        a, b = statistics.median(ours), statistics.median(theirs)
        ratios.append(a / b)
        print(f"{path.name:28s} ours {a * 1000:8.1f} ms   torch.export.load {b * 1000:8.1f} ms   ratio {a / b:.2f}")
    print(f"median ours / torch.export.load over {len(ratios)} model(s): {statistics.median(ratios):.2f}x")


if __name__ == "__main__":
    main()
