"""Does the baseline gate catch a real regression, and how often does it cry wolf?

The shipped GNN actor (fixtures/models/gnn_actor_merging.pt2) drives seeded merging episodes, and
its runs are compared the way ``--driveeval-baseline`` compares an item with its baseline file:
each run becomes the policy_benchmark item's outcome (figures and per-episode ends), its payload
(``baseline.payload.make_payload``, written and read back as JSON) and a ``baseline.compare``
against the reference's.  The use case's rules test the goal, collision and off-road rates with
McNemar's exact paired test at 95 % (``baseline.paired``): an item "regressed" when the paired
interval of some rate's difference excludes zero on the worse side.

Three comparisons, all on the same episodes:

* a real regression: the GNN against a degraded copy of itself, Gaussian noise on its actions
  (``--noise``: the standard deviation as a fraction of the largest acceleration and the largest
  steering angle): the gate must flag it;
* a rerun of the deterministic GNN: no episode changes, the gate must never fire;
* ``--pairs`` pairs of equally good policies: the same noisy GNN with two different noise seeds.
  Any difference between the two is chance, so each pair the gate flags is a false alarm.  Each of
  the three rates is tested two-sided at 5 %, and only its worse side fails an item, so a rate's
  false alarms are at most 2.5 % of pairs (fewer: the exact test is conservative on few discordant
  episodes), and the item's at most about 1 in 20 with three correlated rates.

    python examples/regression_gate_study.py [--episodes 256] [--pairs 20] [--noise 0.2]
                                             [--confidence 95] [--smoke]
"""
from __future__ import annotations

import argparse
import json
import sys
from math import comb
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pytest_driveeval.baseline.compare import Comparison, compare  # noqa: E402
from pytest_driveeval.baseline.paired import PairedRate, paired_rate, two_sided_p  # noqa: E402
from pytest_driveeval.baseline.payload import make_payload  # noqa: E402
from pytest_driveeval.core.outcome import PASSED, Outcome  # noqa: E402
from pytest_driveeval.policies.loading import load_model  # noqa: E402
from pytest_driveeval.sim.blueprints import make_blueprint  # noqa: E402
from pytest_driveeval.core.usecase import get_usecase  # noqa: E402
from pytest_driveeval.usecases.policy_benchmark import regression  # noqa: E402
from pytest_driveeval.usecases.policy_benchmark.regression import FIGURES  # noqa: E402
from pytest_driveeval.usecases.policy_benchmark.evaluate import PolicyRun, run_policy, seeds_for  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "fixtures" / "models" / "gnn_actor_merging.pt2"
BLUEPRINT = "merging"
STRATA = 4
RATES = ("goal_rate", "collision_rate", "off_road_rate")


class NoisyPolicy:
    """The policy's actions plus Gaussian noise of standard deviation ``sd`` (per action), drawn
    from its own generator: the same seed gives the same noise on the same episodes."""

    def __init__(self, policy: Any, sd: np.ndarray, seed: int):
        self.policy, self.sd, self.rng = policy, np.asarray(sd, dtype=np.float64), np.random.default_rng(seed)

    def __call__(self, observation: Any) -> np.ndarray:
        actions = np.asarray(self.policy(observation), dtype=np.float64)
        return actions + self.rng.normal(size=actions.shape) * self.sd


def action_noise(blueprint: Any, noise: float) -> np.ndarray:
    """``noise`` as the standard deviation of (acceleration m/s^2, steering rad)."""
    params = blueprint.params
    return noise * np.array([max(abs(a) for a in params.ego_accel), params.ego_max_steer])


def payload_of(run: PolicyRun, confidence: float) -> dict[str, Any]:
    """The item's comparable record as the plugin keeps it: the policy_benchmark outcome's figures
    and per-episode ends, made into a payload and through a baseline file's JSON."""
    figures = run.figures()
    outcome = Outcome("policy_benchmark", PASSED, f"'{run.policy}': goal {figures['goal_rate']:.1f} %",
                      figures=figures,
                      details={"policy": run.policy,
                               "episode_outcomes": regression.episode_outcomes(run.seeds, run.outcome_names())})
    payload = make_payload(outcome, f"regression_gate_study::{run.policy}", use_case=get_usecase("policy_benchmark"))
    payload["rules"]["confidence"] = confidence  # what a scenario's Regression: Confidence sets
    return json.loads(json.dumps(payload))


@dataclass
class Row:
    """One comparison: the reference run, the run now, the gate's verdict, and each rate's test."""
    what: str
    before: PolicyRun
    now: PolicyRun
    comparison: Comparison
    tests: dict[str, PairedRate]

    @property
    def fired(self) -> bool:
        return self.comparison.regressed

    @property
    def any_change(self) -> bool:
        return any(t.significant() for t in self.tests.values())


def gate(before: PolicyRun, now: PolicyRun, what: str, confidence: float) -> Row:
    comparison = compare(payload_of(before, confidence), payload_of(now, confidence), against=before.policy)
    tests = {name: paired_rate(np.isin(before.outcome_names(), [event]), np.isin(now.outcome_names(), [event]),
                               confidence)
             for name, event in zip(RATES, ("goal", "collision", "off_road"))}
    return Row(what, before, now, comparison, tests)


def chance_of_firing(row: Row, confidence: float) -> float:
    """How likely the gate is to fire on this pair's discordant counts if the two policies are
    equally good (each discordant episode as likely to go either way): per rate, the exact test's
    chance of rejecting on its worse side; summed over the rates (a bound: they can fire together)."""
    alpha = 1.0 - confidence / 100.0
    total = 0.0
    for name, test in row.tests.items():
        d = test.worse + test.better
        # k counts the discordant episodes that gained the event: few is worse for goals, many for crashes
        worse_side = range(d // 2 + 1) if FIGURES[name].better == "higher" else range(d - d // 2, d + 1)
        total += sum(comb(d, k) for k in worse_side if 2 * k != d and two_sided_p(min(k, d - k), d) < alpha) / 2 ** d
    return total


@dataclass
class Study:
    episodes: int
    noise: float
    confidence: float
    regression: Row
    rerun: Row
    pairs: list[Row]
    seconds: float

    @property
    def false_alarms(self) -> int:
        return sum(row.fired for row in self.pairs)


def study(episodes: int = 256, pairs: int = 20, noise: float = 0.2, confidence: float = 95.0, first_seed: int = 0,
          model: Any = None, say=lambda text: None) -> Study:
    """Run the three comparisons; ``model`` defaults to the shipped GNN."""
    started = time.perf_counter()
    model = load_model(str(MODEL)) if model is None else model
    blueprint = make_blueprint(BLUEPRINT)
    seeds, strata = seeds_for(first_seed, episodes, STRATA)
    sd = action_noise(blueprint, noise)

    def run(policy: Any, name: str) -> PolicyRun:
        say(f"  running {name} on {episodes} episodes")
        return run_policy(blueprint, seeds, policy, name, strata=strata)

    reference = run(model, "gnn")
    degraded = gate(reference, run(NoisyPolicy(model, sd, 0), "gnn+noise[0]"), "gnn -> gnn+noise[0]", confidence)
    rerun = gate(reference, run(model, "gnn rerun"), "gnn -> gnn (rerun)", confidence)
    rows = []
    for i in range(pairs):
        a, b = 2 * i + 1, 2 * i + 2
        rows.append(gate(run(NoisyPolicy(model, sd, a), f"gnn+noise[{a}]"),
                         run(NoisyPolicy(model, sd, b), f"gnn+noise[{b}]"),
                         f"gnn+noise[{a}] -> gnn+noise[{b}]", confidence))
    return Study(episodes, noise, confidence, degraded, rerun, rows, time.perf_counter() - started)


def _rates(run: PolicyRun) -> str:
    f = run.figures()
    return f"{f['goal_rate']:5.1f} {f['collision_rate']:5.1f} {f['off_road_rate']:5.1f}"


def table(result: Study) -> str:
    head = (f"{'comparison':36} {'before g/c/o %':17} {'now g/c/o %':17} {'goal -/+':>8} {'p goal':>8} "
            f"{'p coll':>8} {'p off':>8}  gate")
    lines = [head, "-" * len(head)]
    for row in [result.regression, result.rerun, *result.pairs]:
        goal = row.tests["goal_rate"]
        p = "".join(f" {row.tests[name].p_value:8.2g}" for name in RATES)
        # For the goal rate the counted event is a goal: 'worse' counts goals gained.
        lines.append(f"{row.what:36} {_rates(row.before):17} {_rates(row.now):17} {goal.better:>4}/{goal.worse:<3}"
                     f"{p}  {row.comparison.status}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=256)
    parser.add_argument("--pairs", type=int, default=20)
    parser.add_argument("--noise", type=float, default=0.2,
                        help="action noise's standard deviation, as a fraction of the largest acceleration "
                             "and steering angle")
    parser.add_argument("--confidence", type=float, default=95.0)
    parser.add_argument("--smoke", action="store_true", help="16 episodes, 2 pairs: checks the script runs")
    args = parser.parse_args()
    if args.smoke:
        args.episodes, args.pairs = 16, 2
        print("smoke run: 16 episodes, 2 pairs; the figures mean nothing")
    result = study(args.episodes, args.pairs, args.noise, args.confidence, say=print)
    print()
    print(table(result))
    print()
    reg = result.regression
    drop = reg.before.figures()["goal_rate"] - reg.now.figures()["goal_rate"]
    print(f"real regression (noise {args.noise:g}, goal rate {drop:+.1f} points down): "
          f"{'flagged' if reg.fired else 'NOT flagged'} at {args.confidence:g} %")
    print(f"deterministic rerun: {'FLAGGED' if result.rerun.fired else 'not flagged'} "
          f"({result.rerun.tests['goal_rate'].worse + result.rerun.tests['goal_rate'].better} goal ends changed)")
    changed = sum(row.any_change for row in result.pairs)
    discordant = [row.tests["goal_rate"].worse + row.tests["goal_rate"].better for row in result.pairs]
    print(f"equally good pairs: the gate fired on {result.false_alarms} of {len(result.pairs)} "
          f"(some rate significantly different either way: {changed} of {len(result.pairs)}); "
          f"discordant goal episodes per pair: median {np.median(discordant) if discordant else 0:g}, "
          f"range {min(discordant, default=0)}-{max(discordant, default=0)}")
    expected = sum(chance_of_firing(row, args.confidence) for row in result.pairs)
    print(f"expected false alarms if the pairs are equally good, given their discordant counts (exact): "
          f"{expected:.2f} of {len(result.pairs)} ({100 * expected / max(1, len(result.pairs)):.1f} % per pair)")
    print(f"{result.seconds:.0f} s")


if __name__ == "__main__":
    main()
