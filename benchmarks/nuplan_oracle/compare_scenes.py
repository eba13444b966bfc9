"""The harness's nuPlan score against nuplan-devkit's own metric code on real scenes: the nuScenes-mini
ScenarioNet scenes unrolled by the two baselines and the shipped planning model, on their real maps.

Run with the project's venv (it calls the oracle's venv through oracle_venv.run_metrics):

    DRIVEEVAL_SHARED_DATA=/work/shared/data python benchmarks/nuplan_oracle/compare_scenes.py \
        [--policies log_replay constant_velocity model] [--scenes 0 1 2 3 4 5] [--start-frame 10] [--steps 80] \
        [--jobs 2] [--cases-out cases.json] [--smoke]

Each (policy, scene) is unrolled as the closed loop does (unroll_scenes' defaults: the ego is put back
on the log when it asks for a pose more than 10 m off it, and holds its pose for a frame after it
overlaps an agent), its exact score inputs are exported as a case (case_from_inputs: the harness's map
as it scores it, its lanes, connectors, lane graph and roadblocks, its drivable outlines and which lane
surfaces count) and both sides score that case.  Printed: per case, a markdown table of the eight
terms and the score (ours, nuPlan's, ``**differs**`` where they do), each frame's time to collision
agreeing or not, and whether the harness's score of the exported case equals its score of the unrolled
scene itself (it must: otherwise the case would not be what the harness scores); then one summary table.
Exit status 1 when any term, score or frame's time to collision differs or nuPlan raised (not with --smoke).
The differences and why they arise: README.md, "Real scenes".
"""
from __future__ import annotations

import argparse
import functools
import importlib.util
import math
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO))

from pytest_driveeval.metrics.nuplan_score import score_scene  # noqa: E402
from pytest_driveeval.metrics.nuplan_score.case import answer, case_from_inputs  # noqa: E402
from pytest_driveeval.metrics.nuplan_score.term import TERMS  # noqa: E402

SMOKE_HELP = "one scene, one policy, 20 steps; the oracle skipped where its venv is absent: checks the script runs"
POLICIES = ("log_replay", "constant_velocity", "model", "raster_model")
#: the shipped models by policy name
MODELS = {"model": REPO / "fixtures" / "models" / "planning_model.pt2",
          "raster_model": REPO / "fixtures" / "models" / "raster_model.pt2"}
SHORT = {"no_ego_at_fault_collisions": "collisions", "drivable_area_compliance": "drivable area",
         "ego_is_making_progress": "making progress", "driving_direction_compliance": "driving direction",
         "ego_progress_along_expert_route": "progress", "time_to_collision_within_bound": "TTC",
         "speed_limit_compliance": "speed limit", "ego_is_comfortable": "comfort"}
#: a term or score "agrees" within this (both sides compute in float64; the oracle prints floats in full)
TOLERANCE = 1e-6


def oracle_venv():
    spec = importlib.util.spec_from_file_location("nuplan_oracle_venv", HERE / "oracle_venv.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def nuscenes_folder(data: Path | None = None) -> Path:
    """Where the ScenarioNet nuScenes-mini scenes are: ``data`` (the shared data folder), else
    $DRIVEEVAL_SHARED_DATA, else ../shared/data beside the repository (as the tests' shared_data)."""
    root = data or Path(os.environ.get("DRIVEEVAL_SHARED_DATA", REPO.parent / "shared" / "data"))
    return root / "scenarionet" / "nuscenes"


def policy(name: str):
    if name in MODELS:
        return _model(name)
    from pytest_driveeval.usecases.closed_loop.baselines import baseline
    from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig

    return baseline(name, ClosedLoopConfig(Model=name))


@functools.cache
def _model(name: str):
    """A shipped model, loaded once per process (1-2 s each): the raster model drives each scene in an
    unroll of its own, and the tests run both protocols; a loaded model keeps no state between calls."""
    from pytest_driveeval.policies.loading import load_model

    return load_model(str(MODELS[name]))


def raster_options(name: str, dataset, scenes: list[int]) -> dict:
    """The raster model's inputs (its json's raster, the scenes' own map), as a scenario's Unroll.Inputs gives
    them; nothing for the other policies."""
    if name != "raster_model":
        return {}
    import json

    from pytest_driveeval.raster import RasterParams

    spec = json.loads(MODELS[name].with_suffix(".json").read_text())["raster"]
    params = RasterParams(map_type=spec["map_type"], raster_size=spec["raster_size"], pixel_size=spec["pixel_size"],
                          ego_center=spec["ego_center"], history_num_frames=spec["history_num_frames"],
                          filter_agents_threshold=spec["filter_agents_threshold"])
    return {"raster": params, "semantic_map": dataset.semantic_map(scenes),
            "history_frames": spec["history_num_frames"]}


def scene_cases(folder: Path, policies=POLICIES, scenes=range(6), start_frame: int = 10, steps: int | None = 80,
                dataset=None) -> list[dict]:
    """Per (policy, scene): ``case`` (CASE_FORMAT), ``ours`` (the harness's answer on the case),
    ``direct`` (its score of the unrolled scene, not through the case), the rows of ``resets`` (the ego
    put back on the log) and ``frozen`` (held after an overlap), and ``collisions`` (row, at fault).
    ``dataset``: the folder's dataset already opened (open_dataset), so that a caller scoring it under two
    protocols reads each scenario and builds each scene's score map once (the dataset keeps them)."""
    from pytest_driveeval.closed_loop import unroll_scenes
    from pytest_driveeval.usecases.closed_loop.datasets import open_dataset

    dataset = dataset if dataset is not None else open_dataset(folder, None)
    out = []
    for name in policies:
        # a raster draws one map: the raster model drives each scene in an unroll of its own
        batches = [[s] for s in scenes] if name == "raster_model" else [list(scenes)]
        for batch in batches:
            out += _cases_of(name, unroll_scenes(dataset, policy(name), batch, start_frame=start_frame, steps=steps,
                                                 **raster_options(name, dataset, batch)))
    return out


def _cases_of(name: str, unroll) -> list[dict]:
    from pytest_driveeval.usecases.closed_loop.score import score_inputs

    out = []
    for row, scene in enumerate(unroll.result.scene_ids):
        inputs = score_inputs(unroll, row, unroll.maps.get(int(scene)))
        keep = unroll.result.valid[row]
        case = case_from_inputs(inputs, f"{name}/scene{int(scene)}")
        direct = score_scene(inputs)
        out.append({"name": case["name"], "case": case, "ours": answer(case),
                    "direct": {"score": direct.score, "metrics": {n: t.used for n, t in direct.terms.items()}},
                    "resets": np.flatnonzero(unroll.result.reset[row][keep]).tolist(),
                    "frozen": np.flatnonzero(unroll.result.frozen[row][keep]).tolist(),
                    "collisions": [(c.frame, c.at_fault) for c in inputs.collisions]})
    return out


def run_oracle(cases: list[dict], python: Path, jobs: int = 2) -> list[dict]:
    """nuplan-devkit's answers, in ``cases``' order, ``jobs`` oracle processes at once."""
    run = oracle_venv().run_metrics
    chunks = [cases[i::jobs] for i in range(jobs) if cases[i::jobs]]
    with ThreadPoolExecutor(len(chunks)) as pool:
        answers = [a for chunk in pool.map(lambda c: run(c, python), chunks) for a in chunk]
    by_name = {a["name"]: a for a in answers}
    return [by_name[c["name"]] for c in cases]


def same(a, b, tolerance: float = TOLERANCE) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and math.isclose(a, b, abs_tol=tolerance))


def ttc_agreement(ours: dict, theirs: dict) -> tuple[int, list[int]]:
    """(frames whose time to collision agrees, rows of those that do not)."""
    pairs = list(zip(ours["time_to_collision"], theirs["time_to_collision"]))
    off = [k for k, (a, b) in enumerate(pairs) if not same(a, b, 1e-6)]
    return len(pairs) - len(off), off


def differing_terms(ours: dict, theirs: dict) -> list[str]:
    return [n for n in TERMS if not same(ours["metrics"][n], theirs["metrics"][n])]


def _number(value) -> str:
    return "n/a" if value is None else f"{value:.4f}".rstrip("0").rstrip(".") if value not in (0, 1) else f"{value:g}"


def case_table(record: dict, theirs: dict) -> str:
    ours = record["ours"]
    lines = [f"#### {record['name']}", "", "| term | ours | nuPlan | |", "| --- | --- | --- | --- |"]
    for name in TERMS:
        a, b = ours["metrics"][name], theirs["metrics"][name]
        lines.append(f"| {name} | {_number(a)} | {_number(b)} | {'' if same(a, b) else '**differs**'} |")
    lines.append(f"| **score** | {_number(ours['score'])} | {_number(theirs['score'])} | "
                 f"{'' if same(ours['score'], theirs['score']) else '**differs**'} |")
    agree, off = ttc_agreement(ours, theirs)
    frames = len(ours["time_to_collision"])
    lines += ["", f"time to collision: {agree} of {frames} frames agree"
              + (f" (not at rows {off}: ours {[ours['time_to_collision'][k] for k in off]}, nuPlan "
                 f"{[theirs['time_to_collision'][k] for k in off]})" if off else "")]
    comfort = [s for s, (lo, hi) in theirs["comfort"].items()
               if not (same(ours["comfort"][s][0], lo, 1e-6) and same(ours["comfort"][s][1], hi, 1e-6))]
    lines.append(f"comfort signals' ranges: {6 - len(comfort)} of 6 agree" + (f" (not {comfort})" if comfort else ""))
    lines.append(f"engine: collisions (row, at fault) {record['collisions']}; ego put back on the log at rows "
                 f"{record['resets'] or 'none'}; held after an overlap at rows {record['frozen'] or 'none'}")
    return "\n".join(lines)


def summary_table(records: list[dict], answers: list[dict]) -> str:
    """One row per case: each term's value where both agree, ``ours / nuPlan`` in bold where not."""
    head = ["case", *[SHORT[n] for n in TERMS], "score", "TTC frames"]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for record, theirs in zip(records, answers):
        ours = record["ours"]
        cells = [record["name"]]
        for a, b in [(ours["metrics"][n], theirs["metrics"][n]) for n in TERMS] + [(ours["score"], theirs["score"])]:
            cells.append(_number(a) if same(a, b) else f"**{_number(a)} / {_number(b)}**")
        agree, _ = ttc_agreement(ours, theirs)
        cells.append(f"{agree}/{len(ours['time_to_collision'])}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, help="the shared data folder (default: $DRIVEEVAL_SHARED_DATA)")
    parser.add_argument("--policies", nargs="*", default=list(POLICIES), choices=POLICIES)
    parser.add_argument("--scenes", nargs="*", type=int, default=list(range(6)))
    parser.add_argument("--start-frame", type=int, default=10)
    parser.add_argument("--steps", type=int, default=80, help="frames per scene (0: to the scene's end)")
    parser.add_argument("--jobs", type=int, default=2, help="oracle processes at once")
    parser.add_argument("--cases-out", type=Path, help="also write the exported cases (JSON) here")
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args(argv)
    if args.smoke:
        print("smoke run: one scene, one policy, 20 steps; the figures mean nothing")
        args.policies, args.scenes, args.steps = ["log_replay"], [0], 20
    folder = nuscenes_folder(args.data)
    if not folder.is_dir():
        print(f"{folder} absent: nothing to compare (set DRIVEEVAL_SHARED_DATA or --data)")
        print("terms agreeing with nuplan-devkit: 0 of 0")
        return 0 if args.smoke else 1
    start = time.perf_counter()
    records = scene_cases(folder, args.policies, args.scenes, args.start_frame, args.steps or None)
    print(f"unrolled and scored {len(records)} case(s) in {time.perf_counter() - start:.1f} s "
          f"(StartFrame {args.start_frame}, {args.steps or 'all'} steps)")
    if args.cases_out:
        import json

        args.cases_out.write_text(json.dumps([r["case"] for r in records]))
    direct = sum(same(r["ours"]["score"], r["direct"]["score"], 1e-9)
                 and all(same(r["ours"]["metrics"][n], r["direct"]["metrics"][n], 1e-9) for n in TERMS)
                 for r in records)
    print(f"harness on the exported case = harness on the unrolled scene: {direct} of {len(records)}")
    python = oracle_venv().existing_python()
    if python is None:
        print("nuplan-devkit's venv is absent (python3.11 benchmarks/nuplan_oracle/oracle_venv.py builds it): "
              "oracle skipped")
        print("terms agreeing with nuplan-devkit: 0 of 0")
        return 0 if args.smoke else 1
    start = time.perf_counter()
    answers = run_oracle([r["case"] for r in records], python, args.jobs)
    print(f"nuplan-devkit answered in {time.perf_counter() - start:.1f} s ({args.jobs} process(es))\n")
    failed = [a for a in answers if "error" in a]
    for record, theirs in zip(records, answers):
        print(f"{record['name']}: nuPlan raised {theirs['error']}\n" if "error" in theirs
              else case_table(record, theirs) + "\n")
    pairs = [(r, a) for r, a in zip(records, answers) if "error" not in a]
    print("### Summary (ours / nuPlan's where they differ)\n")
    print(summary_table(*zip(*pairs)) if pairs else "(no case answered)")
    agreeing = sum(len(TERMS) - len(differing_terms(r["ours"], a)) for r, a in pairs)
    frames = sum(len(r["ours"]["time_to_collision"]) for r, _ in pairs)
    ttc = sum(ttc_agreement(r["ours"], a)[0] for r, a in pairs)
    scores = sum(same(r["ours"]["score"], a["score"]) for r, a in pairs)
    print(f"\nterms agreeing with nuplan-devkit: {agreeing} of {len(TERMS) * len(pairs)}; scores {scores} of "
          f"{len(pairs)}; time to collision {ttc} of {frames} frames; {len(failed)} case(s) nuPlan raised on")
    # Any difference fails the run (a smoke run's figures mean nothing: it checks that the script runs)
    differs = agreeing < len(TERMS) * len(pairs) or scores < len(pairs) or ttc < frames
    return 1 if failed or (differs and not args.smoke) else 0


if __name__ == "__main__":
    sys.exit(main())
