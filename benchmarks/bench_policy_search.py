"""Robustness-search throughput on the policy benchmark, one core: examples per minute.

Ours: the use case's own search (:func:`pytest_driveeval.search.engine.search`
over :func:`~pytest_driveeval.usecases.policy_benchmark.robustness.policy_searchable`),
derandomised, on the merging blueprint's seeds 0..15: each hypothesis
generation of ``--batch`` examples is one batch of perturbed episodes.  The
rate is distinct examples evaluated over the whole search's wall time,
hypothesis's own work, shrinking and tightening included; the share of it
spent inside the engine is printed beside it.

Reference, in the same run: the very examples the search evaluated, each run
as an episode of its own (what a search that calls the simulator once per
example would cost).  Torch runs on one thread and the process on one core.
Target: >= 1,000 examples per minute per core.  Nothing is asserted.

    python benchmarks/bench_policy_search.py [--examples 200] [--batch 32] [--cases gnn random gnn-wide] [--smoke]
"""
from __future__ import annotations

import os

# One core, set before numpy or torch start a thread pool.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

import argparse
import sys
import time
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TARGET = 1000.0  # examples per minute per core
SMOKE_HELP = "every part at tiny sizes in seconds, reference venvs skipped: checks the script runs, measures nothing"
MODERATE = {"Lateral": [-0.3, 0.3], "Heading": [-0.03, 0.03], "SpeedScale": [0.9, 1.1],
            "AgentsSpeedScale": [0.9, 1.1], "GapScale": [0.85, 1.2]}
WIDE = {"Lateral": [-1.0, 1.0], "Heading": [-0.15, 0.15], "SpeedScale": [0.5, 1.5],
        "AgentsSpeedScale": [0.6, 1.4], "GapScale": [0.5, 2.0]}
# name: (policy spec, ranges); the GNN at the demo's ranges passes, at the wide ones it fails and is shrunk.
CASES = {"gnn": ("fixtures/models/gnn_actor_merging.pt2", MODERATE),
         "gnn-wide": ("fixtures/models/gnn_actor_merging.pt2", WIDE),
         "random": ("random", MODERATE),
         "constant": ("constant", MODERATE)}


class Timed:
    """``evaluate_many`` that remembers every example it was given and the time spent in it."""

    def __init__(self, evaluate_many):
        self.evaluate_many = evaluate_many
        self.examples = []
        self.calls: list[tuple[int, float]] = []  # (examples, seconds) per call

    def __call__(self, examples):
        start = time.perf_counter()
        try:
            return self.evaluate_many(examples)
        finally:
            self.calls.append((len(examples), time.perf_counter() - start))
            self.examples.extend(examples)

    @property
    def seconds(self) -> float:
        return sum(t for _, t in self.calls)

    def rate(self, keep) -> tuple[int, float]:
        """Examples, and examples per minute, over the calls whose size ``keep`` accepts."""
        n = sum(k for k, _ in self.calls if keep(k))
        t = sum(t for k, t in self.calls if keep(k))
        return n, 60.0 * n / t if t else float("nan")


def policy(spec: str):
    from pytest_driveeval.usecases.policy_benchmark import baseline
    from pytest_driveeval.usecases.policy_benchmark.config import BASELINES

    if spec in BASELINES:
        return baseline(spec)
    from pytest_driveeval.policies.loading import load_model

    return load_model(str(ROOT / spec))


def measure(name: str, examples: int, batch: int) -> dict:
    from hypothesis import strategies as st

    from pytest_driveeval.search.engine import SearchSettings, search
    from pytest_driveeval.sim.blueprints import make_blueprint
    from pytest_driveeval.usecases.policy_benchmark.config import PolicyBenchmarkConfig
    from pytest_driveeval.usecases.policy_benchmark.evaluate import seeds_for
    from pytest_driveeval.usecases.policy_benchmark.robustness import policy_searchable

    spec, ranges = CASES[name]
    config = PolicyBenchmarkConfig.model_validate({
        "Blueprint": {"Name": "merging"}, "Episodes": 16, "Policies": {name: spec},
        "Perturbation": {**ranges, "Examples": examples, "Batch": batch}, "Artefacts": {"Animations": "none"}})
    blueprint = make_blueprint("merging")
    seeds, _ = seeds_for(0, 16, 1)
    model = policy(spec)
    searchable = policy_searchable(config, blueprint, seeds, model, name, ctx=None)
    timed = Timed(searchable.evaluate_many)
    settings = SearchSettings(examples=examples, batch=batch, tolerance=config.Perturbation.Tolerance,
                              derandomize=True)
    result = search(st.integers(0, len(seeds) - 1), searchable.perturbations, timed, config.Perturbation.ranges(),
                    settings)

    # The reference: the same examples, one episode at a time.
    start = time.perf_counter()
    alone = [searchable.evaluate_many([example])[0] for example in timed.examples]
    single_seconds = time.perf_counter() - start
    # Episodes never see each other, so one batch of them all gives the verdicts the search saw.
    batched = searchable.evaluate_many(list(timed.examples))
    agree = all(a.failed == b.failed and a.where == b.where for a, b in zip(alone, batched))
    return {"name": name, "found": result.found, "examples": result.examples, "seconds": result.seconds,
            "engine_seconds": timed.seconds, "evaluations": result.evaluations, "single_seconds": single_seconds,
            "big_calls": timed.rate(lambda k: k >= 8), "small_calls": timed.rate(lambda k: k < 8),
            "single_examples": len(timed.examples), "agree": agree,
            "minimal": None if result.minimal is None else (int(seeds[result.minimal.case]),
                                                            result.minimal.perturbation)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--examples", type=int, default=200)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES), default=["gnn", "random", "gnn-wide"])
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.examples, args.batch, args.cases = 4, 2, ["gnn-wide"]
        print("smoke run: tiny sizes; the figures mean nothing")
    import torch

    torch.set_num_threads(1)
    print(f"policy-benchmark search, merging seeds 0..15, {args.examples} examples asked, batch {args.batch}, "
          f"torch threads {torch.get_num_threads()}, one core")
    header = (f"{'case':<10} {'outcome':<44} {'examples':>8} {'search s':>8} {'engine %':>8} "
              f"{'ex/min':>8} {'alone ex/min':>12} {'ratio':>6}  target")
    print(header)
    for name in args.cases:
        m = measure(name, args.examples, args.batch)
        rate = 60.0 * m["examples"] / m["seconds"]
        single = 60.0 * m["single_examples"] / m["single_seconds"]
        outcome = "passed" if not m["found"] else f"seed {m['minimal'][0]}: " + (", ".join(
            f"{k}={v:.3g}" for k, v in vars(m["minimal"][1]).items() if v != getattr(type(m["minimal"][1])(), k))
            or "no change")
        print(f"{name:<10} {outcome[:44]:<44} {m['examples']:>8} {m['seconds']:>8.2f} "
              f"{100 * m['engine_seconds'] / m['seconds']:>7.0f}% {rate:>8.0f} {single:>12.0f} "
              f"{rate / single:>6.1f}  {'meets' if rate >= TARGET else 'MISSES'} >= {TARGET:.0f}")
        (big, big_rate), (small, small_rate) = m["big_calls"], m["small_calls"]
        print(f"{'':<10} phases {m['evaluations']}; engine calls of >= 8 examples: {big} at {big_rate:.0f} ex/min, "
              f"smaller ones: {small} at {small_rate:.0f} ex/min; verdicts alone == batched: {m['agree']}")


if __name__ == "__main__":
    main()
