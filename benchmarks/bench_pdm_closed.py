"""``Model: pdm_closed`` on real scenes against issue 36's targets, beside log replay and the blind models.

Every model drives the same scenes in one batch as the demo's nuScenes items do (start frame 10, 150
steps, never put back on the log) and is scored by the harness's nuPlan score; pdm_closed once with the
agents replaying the log and once with ``Agents: reactive``.  Printed: each scene's score per model, the
means, the scenes where pdm_closed is more than 0.05 below log replay, and pdm_closed's planning time per
scene per step (the planner's calls only, batched over the scenes, one thread) as a share of nuPlan's 1 s
budget.  CPU seconds of the whole run are printed beside its wall time.

Targets (issue 36): mean >= 0.90 without reactive agents, >= 0.85 with them; per scene within 0.05 of log
replay where it does not beat it; <= 10 ms per scene per step.  Nothing is asserted: the figures are printed.

    python benchmarks/bench_pdm_closed.py [--shared DIR] [--steps 150] [--smoke]
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")  # before numpy and torch start their thread pools

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("DRIVEEVAL_SHARED_DATA", REPO.parent / "shared" / "data")) / "scenarionet" / "nuscenes"
FIXTURES = REPO / "fixtures" / "scenarionet" / "nuscenes"
VECTOR_MODEL = REPO / "fixtures" / "models" / "planning_model.pt2"
BUDGET_MS = 1000.0  # nuPlan's time per planner call


def drive(dataset, name: str, ids, steps: int, reactive: bool):
    import torch

    from pytest_driveeval.policies.loading import load_model
    from pytest_driveeval.sim.logreplay.reactive import ReactiveAgents
    from pytest_driveeval.usecases.closed_loop.baselines import BASELINES, baseline
    from pytest_driveeval.usecases.closed_loop.evaluate import unroll_scenes
    from pytest_driveeval.usecases.closed_loop.score import score_unroll

    torch.set_num_threads(1)
    model = baseline(name) if name in BASELINES else load_model(str(VECTOR_MODEL))
    cpu = [0.0]
    if hasattr(model, "plan"):  # the planner's own CPU time: the machine may be shared, wall time is not its
        plan = model.plan

        def timed(observation):
            start = time.process_time()
            try:
                return plan(observation)
            finally:
                cpu[0] += time.process_time() - start

        model.plan = timed
    unroll = unroll_scenes(dataset, model, ids, start_frame=10, steps=steps, drift_threshold=None,
                           reactive=ReactiveAgents() if reactive else None)
    r = unroll.result
    scores = score_unroll(unroll)
    steps_done = max(r.scene_steps, 1)
    return {s: scores[s].score for s in scores}, (1000.0 * r.model_time / steps_done, 1000.0 * cpu[0] / steps_done)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shared", type=Path, default=SHARED)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--smoke", action="store_true", help="one scene, 5 steps: checks the script runs")
    args = parser.parse_args()
    from pytest_driveeval.usecases.closed_loop.datasets import open_dataset

    folder = args.shared if args.shared.is_dir() else FIXTURES
    dataset = open_dataset(str(folder), None)
    ids = [0] if args.smoke else list(range(dataset.num_scenes))
    steps = 5 if args.smoke else args.steps
    if args.smoke:
        print("smoke run: one scene, 5 steps; the figures mean nothing")
    print(f"scenes: {folder} ({len(ids)}), start frame 10, {steps} steps")
    wall, cpu = time.perf_counter(), time.process_time()
    runs = {"log_replay": drive(dataset, "log_replay", ids, steps, False)}
    if not args.smoke:  # the smoke run keeps the two the figures need
        runs["constant_velocity"] = drive(dataset, "constant_velocity", ids, steps, False)
        if VECTOR_MODEL.is_file():
            runs["vector model (.pt2)"] = drive(dataset, "vector", ids, steps, False)
    runs["pdm_closed"] = drive(dataset, "pdm_closed", ids, steps, False)
    runs["pdm_closed, reactive"] = drive(dataset, "pdm_closed", ids, steps, True)
    if not args.smoke:
        runs["log_replay, reactive"] = drive(dataset, "log_replay", ids, steps, True)
    names = [dataset.files[i].stem.replace("sd_nuscenes_v1.0-mini_", "") for i in ids]
    print(f"{'model':24s}" + "".join(f"{n:>12s}" for n in names) + f"{'mean':>8s}")
    for model, (scores, _) in runs.items():
        row = [scores.get(i, float("nan")) for i in ids]
        print(f"{model:24s}" + "".join(f"{v:12.3f}" for v in row) + f"{np.nanmean(row):8.3f}")
    log, pdm = runs["log_replay"][0], runs["pdm_closed"][0]
    behind = [f"{names[k]} {pdm[i]:.3f} vs {log[i]:.3f}" for k, i in enumerate(ids) if pdm[i] < log[i] - 0.05]
    print("pdm_closed more than 0.05 below log replay: " + (", ".join(behind) if behind else "none"))
    mean_nr = np.mean([pdm[i] for i in ids])
    mean_r = np.mean([runs["pdm_closed, reactive"][0][i] for i in ids])
    print(f"pdm_closed mean nuPlan score: {mean_nr:.3f} (target 0.90), reactive agents {mean_r:.3f} (target 0.85)")
    wall_ms, cpu_ms = runs["pdm_closed"][1]
    print(f"pdm_closed: {cpu_ms:.2f} ms per scene per step (CPU time of its plan calls; {wall_ms:.2f} ms wall), "
          f"batched over {len(ids)} scene(s), one thread (target 10); {cpu_ms / BUDGET_MS:.4f} of nuPlan's 1 s budget")
    print(f"whole run: {time.perf_counter() - wall:.1f} s wall, {time.process_time() - cpu:.1f} s CPU")


if __name__ == "__main__":
    main()
