"""Robustness-search throughput in closed loop: batched generations vs one example at a time.

The demo's search (scenario_tests/robustness/real_scene_lateral.scenario.yaml:
the shipped planning model on the real L5 scene, 100 steps from frame 10,
lateral offsets within +-6 m), run derandomised through the use case's own
``evaluate_many``.  Three rates, in examples per second, on one core with
torch on one thread:

* batched: the examples of the search's generations (``--batch`` at a time,
  one unroll each), the way the search evaluates them;
* one at a time, the reference: the same examples, each unrolled alone (what
  a search that runs the simulator once per example would cost), with the
  scene stacked and packed once, as the search has it;
* one at a time through the Python API (``unroll_scenes`` per example, the
  scene read and stacked each time, as a replay or a ``@given`` test does);
* the whole search: distinct examples over its wall time, hypothesis,
  shrinking and tightening (whose steps are partly one example at a time)
  included.

Target: batched >= 10x one at a time.  Nothing is asserted; figures are printed.
On a 2-core machine (2026-11-24): 3.6-3.7x with the shipped model, whose
arithmetic per example hardly shrinks with the batch (model time 2.5x; the
harness's own time 9.3-9.7x), 4.1-4.3x against ``unroll_scenes``; with
``--model constant_velocity`` 12.3x and 17.6-18.4x.

    python benchmarks/bench_closed_loop_search.py [--batch 32] [--generations 4] [--smoke]
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy and torch start their thread pools
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset  # noqa: E402
from pytest_driveeval.policies.loading import load_model  # noqa: E402
from pytest_driveeval.scenario import load_scenario  # noqa: E402
from pytest_driveeval.search.engine import Example, SearchSettings, search  # noqa: E402
from pytest_driveeval.strategies import StartPerturbation  # noqa: E402
from pytest_driveeval.usecases.closed_loop import replayed_agents  # noqa: E402
from pytest_driveeval.usecases.closed_loop.evaluate import judge_scene, unroll_scenes  # noqa: E402
from pytest_driveeval.usecases.closed_loop.robustness import closed_loop_searchable  # noqa: E402

SCENARIO = ROOT / "scenario_tests" / "robustness" / "real_scene_lateral.scenario.yaml"
TARGET = 10.0
SMOKE_HELP = "every part at tiny sizes in seconds, reference venvs skipped: checks the script runs, measures nothing"


class Timed:
    """The model, with the time spent in it."""

    def __init__(self, model):
        self.model, self.seconds = model, 0.0

    def __call__(self, batch):
        tic = time.perf_counter()
        try:
            return self.model(batch)
        finally:
            self.seconds += time.perf_counter() - tic


class Recorded:
    """``evaluate_many`` that keeps the batches it was given and the time spent in it."""

    def __init__(self, evaluate_many):
        self.evaluate_many, self.batches, self.seconds = evaluate_many, [], 0.0

    def __call__(self, examples):
        tic = time.perf_counter()
        try:
            return self.evaluate_many(examples)
        finally:
            self.seconds += time.perf_counter() - tic
            self.batches.append(list(examples))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--generations", type=int, default=4, help="generations of random examples timed")
    parser.add_argument("--model", default=None, help="instead of the scenario's model: a model file or "
                                                      "constant_velocity (the harness alone, nearly)")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    torch.set_num_threads(1)

    scenario = load_scenario(SCENARIO)
    config = scenario.config
    if args.smoke:
        args.batch, args.generations = 2, 1
        config.Unroll.Steps, config.Perturbation.Examples = 5, 4
        print("smoke run: tiny sizes, 5 steps per example; the figures mean nothing")
    dataset = L5Dataset.open(scenario.datasets[0].path)
    if args.model == "constant_velocity":
        from pytest_driveeval.policies.baselines import ConstantVelocityPolicy

        model = ConstantVelocityPolicy().eval()
    else:
        model = load_model(args.model or str((SCENARIO.parent / config.Model).resolve()))
    model = Timed(model)
    print(f"model: {args.model or config.Model}")
    searchable = closed_loop_searchable(config, dataset, model, [0], replayed_agents(config.Unroll.Agents),
                                        show=lambda scene, perturbation: None)
    print(f"scenario: {SCENARIO.relative_to(ROOT)}; {config.Unroll.Steps} steps per example; "
          f"torch threads {torch.get_num_threads()}, one core")

    # The same random examples, batched and one at a time: uniform over the scenario's ranges.
    rng = np.random.default_rng(0)
    ranges = config.Perturbation.ranges()
    examples = [Example(0, StartPerturbation(**{name: float(rng.uniform(low, high))
                                                for name, (low, high) in ranges.items()}))
                for _ in range(args.batch * args.generations)]
    searchable.evaluate_many(examples[:2])  # warm up the model and the caches
    model.seconds = 0.0
    tic = time.perf_counter()
    batched = []
    for i in range(0, len(examples), args.batch):
        batched += searchable.evaluate_many(examples[i:i + args.batch])
    t_batched, m_batched = time.perf_counter() - tic, model.seconds
    model.seconds = 0.0
    tic = time.perf_counter()
    alone = [searchable.evaluate_many([e])[0] for e in examples]
    t_alone, m_alone = time.perf_counter() - tic, model.seconds
    # The same examples as a user would run them without the search: one unroll_scenes call each
    # (the Python API, and what --driveeval-replay does), the scene read and stacked every time.
    spec = config.Unroll
    model.seconds = 0.0
    tic = time.perf_counter()
    api = [judge_scene(unroll_scenes(dataset, model, [0], start_frame=spec.StartFrame, steps=spec.Steps,
                                     drift_threshold=spec.DriftThreshold, agents=replayed_agents(spec.Agents),
                                     perturbation=e.perturbation), 0, config.Conditions).passed for e in examples]
    t_api, m_api = time.perf_counter() - tic, model.seconds
    same = [v.failed for v in batched] == [v.failed for v in alone] == [not ok for ok in api]
    rate_batched, rate_alone = len(examples) / t_batched, len(examples) / t_alone
    print(f"{len(examples)} examples ({sum(v.failed for v in batched)} failing), verdicts identical batched and "
          f"alone: {same}")
    print(f"batched by {args.batch}: {rate_batched:8.1f} examples/s ({t_batched:.2f} s, model {m_batched:.2f} s)")
    print(f"one at a time:  {rate_alone:8.1f} examples/s ({t_alone:.2f} s, model {m_alone:.2f} s)  <- reference")
    rate_api = len(examples) / t_api
    print(f"one at a time through unroll_scenes: {rate_api:8.1f} examples/s ({t_api:.2f} s, model {m_api:.2f} s): "
          f"batched is {rate_batched / rate_api:.1f}x")
    print(f"ratio: {rate_batched / rate_alone:.1f}x (target >= {TARGET:g}x: "
          f"{'met' if rate_batched / rate_alone >= TARGET else 'NOT met'}); model time alone "
          f"{m_alone / m_batched:.1f}x, harness time alone {(t_alone - m_alone) / (t_batched - m_batched):.1f}x")

    recorded = Recorded(searchable.evaluate_many)
    tic = time.perf_counter()
    result = search(st.integers(0, 0), searchable.perturbations, recorded, config.Perturbation.ranges(),
                    SearchSettings(examples=config.Perturbation.Examples, batch=args.batch, derandomize=True,
                                   tolerance=config.Perturbation.Tolerance))
    t_search = time.perf_counter() - tic
    sizes = [len(b) for b in recorded.batches]
    print(f"whole search: {result.examples} examples in {t_search:.2f} s = {result.examples / t_search:.1f} "
          f"examples/s ({result.examples / t_search / rate_alone:.1f}x one at a time); engine share "
          f"{100 * recorded.seconds / t_search:.0f} %; {len(sizes)} engine calls, {sizes.count(1)} of one example; "
          f"phases {result.evaluations}; " + (f"minimal lateral {result.minimal.perturbation.lateral:.4f} m"
                                             if result.minimal is not None else "no failing example found"))


if __name__ == "__main__":
    main()
