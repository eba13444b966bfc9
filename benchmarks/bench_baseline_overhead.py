"""What comparing a session's items with their baselines adds to the session's time (issue 22's
target: under 1 % for a session of 30 items).

A pytest session of ``--items`` policy_benchmark items (one per policy, two baseline policies per
scenario file, merging / highway / intersection in turn, ``--episodes`` seeded episodes each, the
default artefacts) runs ``--rounds`` times without baselines and as often with
``--driveeval-baseline DIR`` (after one ``--driveeval-baseline-update`` run), interleaved, each as
its own ``python -m pytest`` process, as a user runs it.  Printed: each session's time, the overhead
(median with / median without - 1), and the comparison's own cost measured in this process: for
each item, the time of ``make_payload`` (made in every session, baselines or not) and of
``Gate.compare`` (reading the item's baseline file, comparing), summed over the items, as a
fraction of the median session without baselines.  On a shared machine the sessions' times vary by
more than 1 % from run to run; the direct cost is the figure that noise does not blur.

    python benchmarks/bench_baseline_overhead.py [--items 30] [--episodes 64] [--rounds 3] [--smoke]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from pytest_driveeval.baseline.gate import BaselineOptions, Gate  # noqa: E402
from pytest_driveeval.baseline.payload import make_payload  # noqa: E402
from pytest_driveeval.outcome import Outcome  # noqa: E402
from pytest_driveeval.scenario import load_scenario  # noqa: E402
from pytest_driveeval.usecase import get_usecase  # noqa: E402

BLUEPRINTS = ("merging", "highway", "intersection")
POLICIES = ("constant", "random")
SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: overhead-{index}
Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint: {{Name: {blueprint}}}
  Episodes: {episodes}
  FirstSeed: {first_seed}
  Policies:
{policies}"""
#: in-process repetitions of each item's payload and comparison, for a time above the clock's grain
REPEATS = 20


def write_scenarios(folder: Path, items: int, episodes: int) -> None:
    files = -(-items // len(POLICIES))
    for index in range(files):
        names = POLICIES[:min(len(POLICIES), items - index * len(POLICIES))]
        text = SCENARIO.format(index=index, blueprint=BLUEPRINTS[index % len(BLUEPRINTS)], episodes=episodes,
                               first_seed=index * episodes,
                               policies="".join(f"    {name}: {name}\n" for name in names))
        (folder / f"overhead_{index:02d}.scenario.yaml").write_text(text)
    (folder / "pytest.ini").write_text("[pytest]\n")


def session(folder: Path, output: str, *options: str) -> tuple[float, float, dict]:
    """(the process's wall time, the session's own duration from summary.json, the summary)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    command = [sys.executable, "-m", "pytest", str(folder), "-q", "-p", "no:randomly", "-p", "no:cacheprovider",
               "--driveeval-output", str(folder / output), *options]
    started = time.perf_counter()
    done = subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed ({done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    summary = json.loads((folder / output / "summary.json").read_text())
    return wall, float(summary["duration"]), summary


def direct_cost(folder: Path, baselines: Path, summary: dict) -> tuple[float, float, int]:
    """(seconds of make_payload, seconds of Gate.compare) summed over the items, each an item's
    median over REPEATS; and how many items compared unchanged (all, or the figures mean nothing)."""
    gate = Gate(BaselineOptions(folder=baselines))
    made = compared = 0.0
    unchanged = 0
    for record in summary["results"]:
        file, _, item = record["nodeid"].partition("::")
        scenario = load_scenario(folder / file)
        outcome = Outcome(record["use_case"], record["verdict"], record["summary"], figures=record["figures"],
                          details=record["details"], scenario=f"{scenario.name} [{item}]")
        seed = record["baseline"]["fingerprint"]["seed"]
        use_case = get_usecase(record["use_case"])
        times_made, times_compared = [], []
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            payload = make_payload(outcome, record["nodeid"], use_case=use_case, scenario=scenario, dataset=None,
                                   seed=seed, item=item, file=file)
            t1 = time.perf_counter()
            comparison = gate.compare(record["nodeid"], payload)
            t2 = time.perf_counter()
            times_made.append(t1 - t0)
            times_compared.append(t2 - t1)
        made += statistics.median(times_made)
        compared += statistics.median(times_compared)
        unchanged += comparison.status == "unchanged"
    return made, compared, unchanged


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--items", type=int, default=30)
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--smoke", action="store_true", help="3 items of 4 episodes, one round: checks the script runs")
    args = parser.parse_args()
    if args.smoke:
        args.items, args.episodes, args.rounds = 3, 4, 1
        print("smoke run: 3 items of 4 episodes, one round; the figures mean nothing")
    with tempfile.TemporaryDirectory(prefix="driveeval-bench-baseline-") as tmp:
        folder = Path(tmp)
        write_scenarios(folder, args.items, args.episodes)
        baselines = folder / "baselines"
        session(folder, "out-update", "--driveeval-baseline", str(baselines), "--driveeval-baseline-update")
        print(f"{args.items} items, {args.episodes} episodes each; baselines written: "
              f"{len(list(baselines.rglob('*.json')))}")
        without, with_, last = {"wall": [], "own": []}, {"wall": [], "own": []}, None
        for round_ in range(args.rounds):
            for label, times, options in (("without", without, ()),
                                          ("with", with_, ("--driveeval-baseline", str(baselines)))):
                wall, own, summary = session(folder, f"out-{label}-{round_}", *options)
                times["wall"].append(wall)
                times["own"].append(own)
                if options:
                    last = summary
                    statuses = {(r.get("comparison") or {}).get("status") for r in summary["results"]}
                    assert statuses == {"unchanged"}, statuses
                print(f"  round {round_ + 1} {label:8} baselines: {wall:7.2f} s process, {own:7.2f} s session")
        made, compared, unchanged = direct_cost(folder, baselines, last)
    session_s = statistics.median(without["wall"])
    print(f"median session without baselines: {session_s:.2f} s process ({statistics.median(without['own']):.2f} s "
          f"session), with: {statistics.median(with_['wall']):.2f} s ({statistics.median(with_['own']):.2f} s)")
    for key, what in (("wall", "process"), ("own", "session")):
        ratio = statistics.median(with_[key]) / statistics.median(without[key]) - 1
        print(f"overhead, {what} time (median with / median without - 1): {100 * ratio:+.2f} %")
    print(f"in-process, summed over {args.items} items ({unchanged} unchanged): make_payload {1e3 * made:.2f} ms "
          f"(made with or without baselines), Gate.compare {1e3 * compared:.2f} ms")
    print(f"comparison's own cost: {100 * (made + compared) / session_s:.3f} % of the session "
          f"(target: under 1 %)")


if __name__ == "__main__":
    main()
