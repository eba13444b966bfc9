"""Collisions with log replay vs reactive agents, on the closed-loop demo scenes.

The demo's closed-loop scenarios (scenario_tests/closed_loop/*.scenario.yaml)
are run with the shipped planning model and the constant-velocity baseline,
each once with ``Agents: log`` and once with ``Agents: reactive``, on the
scenario's own scenes and unroll settings.  For each run: collision frames of
each kind (front / side / rear), split into at fault and not at fault, how
many agents left their log (reactive only) and the harness time.  A
collision cell reads ``events (frames)``: an event is a run of consecutive
collision frames with one partner, judged (kind, blame) on its first frame.

The real scene is read from /work/shared/data/l5kit/single_scene.zarr (the
repository's fixture is a copy of it); its scenarios are skipped when that
file is absent.

    python examples/compare_reactive_agents.py [--threads 1]
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import torch

from pytest_driveeval import load_scenario
from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
from pytest_driveeval.policies.loading import load_model
from pytest_driveeval.usecases.closed_loop import baseline, replayed_agents
from pytest_driveeval.usecases.closed_loop.evaluate import KIND_CODE, unroll_scenes

REPO = Path(__file__).resolve().parents[1]
SCENARIOS = REPO / "scenario_tests" / "closed_loop"
MODEL = REPO / "fixtures" / "models" / "planning_model.pt2"
REAL_SCENE = Path("/work/shared/data/l5kit/single_scene.zarr")


def scene_sets() -> list[tuple[str, object, Path]]:
    """(name, unroll spec, dataset) of each scenario, one per distinct (dataset, unroll settings)."""
    seen, out = set(), []
    for path in sorted(SCENARIOS.glob("*.scenario.yaml")):
        scenario = load_scenario(path)
        dataset = Path(scenario.datasets[0].path)
        if dataset.name == REAL_SCENE.name:
            if not REAL_SCENE.exists():
                print(f"skipped {path.name}: {REAL_SCENE} is absent")
                continue
            dataset = REAL_SCENE
        spec = scenario.config.Unroll
        if spec.Inputs.Kind != "vector":
            # Both policies compared here read vector inputs; a raster scenario's set-up would only add rasters.
            print(f"skipped {path.name}: Inputs {spec.Inputs.Kind}")
            continue
        key = (dataset, spec.model_dump_json(exclude={"Agents": {"Mode"}}))
        if key not in seen:
            seen.add(key)
            out.append((path.name.removesuffix(".scenario.yaml"), scenario.config, dataset))
    return out


def events(r) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Collisions as events: (row, frame) where a run of consecutive collision
    frames with one partner starts.  A reactive agent that stopped inside a
    frozen ego stays there, so frame counts alone would weigh one crash by its
    aftermath."""
    hit = r.valid & (r.collision_kind > 0)
    before = np.zeros_like(hit)
    before[:, 1:] = hit[:, :-1] & (r.collision_track_id[:, 1:] == r.collision_track_id[:, :-1])
    return np.nonzero(hit & ~before)


def counts(unroll) -> dict[str, int]:
    r = unroll.result
    kind, fault = r.collision_kind[r.valid], r.collision_at_fault[r.valid]
    first = events(r)
    e_kind, e_fault = r.collision_kind[first], r.collision_at_fault[first]
    out = {}
    for name, code in KIND_CODE.items():
        out[f"{name} at fault"] = f"{((e_kind == code) & e_fault).sum()} ({((kind == code) & fault).sum()})"
        out[f"{name} not"] = f"{((e_kind == code) & ~e_fault).sum()} ({((kind == code) & ~fault).sum()})"
    if r.reacted is not None:
        agents = r.agents
        out["reacted"] = str(len({(s, int(agents.track_id[s, t, c])) for s, t, c in zip(*np.nonzero(r.reacted))}))
    else:
        out["reacted"] = "-"
    out["harness s"] = f"{r.harness_time:.2f}"
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    policies = {"planning_model": load_model(str(MODEL)), "constant_velocity": None}
    columns = ["front at fault", "front not", "side at fault", "side not", "rear at fault", "rear not", "reacted",
               "harness s"]
    rows = []
    for name, config, path in scene_sets():
        dataset = L5Dataset.open(path)
        spec = config.Unroll
        for policy_name, policy in policies.items():
            model = policy if policy is not None else baseline("constant_velocity", config)
            for mode in ("log", "reactive"):
                agents = spec.Agents.model_copy(update={"Mode": mode})
                options = spec.unroll_options() | {"reactive": agents.reactive()}
                unroll = unroll_scenes(dataset, model, **options, agents=replayed_agents(agents))
                rows.append((f"{name} ({dataset.num_scenes} scene{'s' * (dataset.num_scenes > 1)})", policy_name,
                             mode, counts(unroll)))
    head = f"| {'scenario':<34} | {'policy':<17} | {'agents':<8} | " + " | ".join(columns) + " |"
    print(head)
    print("|" + "|".join("-" * len(cell) for cell in head[1:-1].split("|")) + "|")
    for scene, policy, mode, c in rows:
        cells = [f"{c[k]:>{len(k)}}" for k in columns]
        print(f"| {scene:<34} | {policy:<17} | {mode:<8} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
