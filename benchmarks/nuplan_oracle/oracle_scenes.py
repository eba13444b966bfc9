"""nuplan-devkit's score of the drives a closed-loop run reported, against the score that run wrote.

Runs with the oracle venv's python (oracle_venv.py makes it) and imports nothing from pytest_driveeval:

    ~/.cache/driveeval-bench/nuplan/bin/python benchmarks/nuplan_oracle/oracle_scenes.py \\
        driveeval-results/summary.json --data /work/shared/data/scenarionet/nuscenes \\
        [--tolerance 1e-6] [--ego-size file|driven] [--cases-out cases.json]

For every closed_loop item of the summary whose ``closed_loop.json`` holds the ego as driven, and for
every scene of it: the scene's raw ScenarioNet file (``--data``: the file or folder the item read;
scene n is the n-th scenario file in path order, as the harness numbers them, unless the scene's
record names its file) is read with the oracle's own restricted unpickler, nuPlan's map, agents,
expert and ego states are built from it and the driven poses (scenario_case.py), nuPlan's own
metrics and aggregator score it (nuplan_metrics.py), and each term and the score are compared with
what the harness wrote to summary.json in the same run (a term's ``used`` value: what the score
counted).  Printed: per scene, every term (harness, nuPlan, difference) and the oracle's notes; then
one table of all scenes.  Exit status 1 when any term or score differs by more than the tolerance,
when nuPlan raised on a scene, or when no scene was compared; 0 only when everything agrees.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import nuplan_metrics  # noqa: E402  (the devkit's metrics; its sensor stubs come first)
from scenario_case import case_from_scenario  # noqa: E402
from scenario_map import scenario_map  # noqa: E402
from scenario_pickle import load_scenario  # noqa: E402

SHORT = {"no_ego_at_fault_collisions": "collisions", "drivable_area_compliance": "drivable area",
         "ego_is_making_progress": "making progress", "driving_direction_compliance": "driving direction",
         "ego_progress_along_expert_route": "progress", "time_to_collision_within_bound": "TTC",
         "speed_limit_compliance": "speed limit", "ego_is_comfortable": "comfort"}
#: ScenarioNet's summary files beside the scenarios (not scenarios)
SUMMARY_FILES = {"dataset_summary.pkl", "dataset_mapping.pkl"}


def scenario_files(data: Path) -> List[Path]:
    if data.is_file():
        return [data]
    return sorted(p for p in data.rglob("*.pkl") if p.name not in SUMMARY_FILES and p.is_file())


def closed_loop_items(summary_path: Path) -> List[Tuple[Dict[str, Any], Dict[str, Any]]]:
    """(summary record, closed_loop.json) of each closed_loop item of the summary that left one."""
    summary = json.loads(summary_path.read_text())
    out = []
    for record in summary.get("results", []):
        if record.get("use_case") != "closed_loop":
            continue
        relative = (record.get("artefacts") or {}).get("result")
        # artefact paths are relative to the output folder: summary.json's folder, or two above runs/<id>/
        found = [base / relative for base in (summary_path.parent, summary_path.parent.parent.parent)
                 if relative and (base / relative).is_file()]
        if not found:
            print(f"{record.get('scenario')}: no closed_loop.json found ({relative!r}); not compared")
            continue
        out.append((record, json.loads(found[0].read_text())))
    return out


def scene_file(entry: Dict[str, Any], files: List[Path]) -> Optional[Path]:
    named = entry.get("file") or (entry.get("driven") or {}).get("file")
    if named:
        return Path(named)
    index = int(entry["scene"])
    return files[index] if 0 <= index < len(files) else None


def harness_values(record: Dict[str, Any], scene: int) -> Optional[Dict[str, Any]]:
    """{term: used, ..., "score": score} the harness wrote to summary.json for ``scene``, or None."""
    for entry in (record.get("details") or {}).get("scenes", []):
        if int(entry.get("scene", -1)) == scene:
            terms = entry.get("score_terms") or {}
            values = {name: (terms[name].get("used") if name in terms else None) for name in SHORT}
            values["score"] = entry.get("score")
            return values
    return None


def differs(ours: Any, theirs: Any, tolerance: float) -> bool:
    if ours is None or theirs is None:
        return not (ours is None and theirs is None)
    return not math.isclose(float(ours), float(theirs), rel_tol=0.0, abs_tol=tolerance)


def _cell(value: Any) -> str:
    return "n/a" if value is None else f"{float(value):.6g}"


def scene_report(name: str, ours: Dict[str, Any], theirs: Dict[str, Any], notes: List[str], tolerance: float
                 ) -> Tuple[str, List[str]]:
    lines = [f"#### {name}", "", "| term | harness | nuplan-devkit | difference |", "| --- | --- | --- | --- |"]
    off = []
    for key in [*SHORT, "score"]:
        a, b = ours.get(key), (theirs["score"] if key == "score" else theirs["metrics"].get(key))
        bad = differs(a, b, tolerance)
        gap = "" if a is None or b is None else f"{abs(float(a) - float(b)):.3g}"
        lines.append(f"| {key} | {_cell(a)} | {_cell(b)} | {('**' + (gap or 'missing') + '**') if bad else gap} |")
        if bad:
            off.append(key)
    lines += ["", *[f"- {note}" for note in notes]]
    return "\n".join(lines), off


def main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("summary", type=Path, help="the run's summary.json")
    parser.add_argument("--data", type=Path, required=True, help="the ScenarioNet file or folder the items read")
    parser.add_argument("--tolerance", type=float, default=1e-6)
    parser.add_argument("--ego-size", choices=("file", "driven"), default="file",
                        help="the ego box: the file's self-driving car (default) or the size closed_loop.json gives")
    parser.add_argument("--cases-out", type=Path, help="also write the cases the oracle built (JSON)")
    args = parser.parse_args(argv)
    files = scenario_files(args.data)
    configs = nuplan_metrics.metric_configs()
    rows: List[Tuple[str, Dict[str, Any], Dict[str, Any]]] = []
    disagreements: List[str] = []
    failures: List[str] = []
    cases = []
    # each file read and its map built once, however many items drove its scene (neither is changed by a case)
    read: Dict[Path, Tuple[Dict[str, Any], Dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        aggregator = nuplan_metrics.build_aggregator(Path(tmp) / "aggregator")
        for record, closed_loop in closed_loop_items(args.summary):
            for entry in closed_loop.get("scenes", []):
                name = f"{record.get('scenario')}/scene{entry['scene']}"
                driven = entry.get("driven")
                if not driven or not driven.get("frames"):
                    failures.append(f"{name}: closed_loop.json holds no driven poses (a run before they were written?)")
                    continue
                ours = harness_values(record, int(entry["scene"]))
                path = scene_file(entry, files)
                if ours is None or path is None:
                    failures.append(f"{name}: " + ("no scene record in summary.json" if ours is None
                                                   else f"no scenario file {entry['scene']} in {args.data}"))
                    continue
                try:
                    size = (driven["length"], driven["width"]) if args.ego_size == "driven" else None
                    if path not in read:
                        scenario = load_scenario(path)
                        read[path] = scenario, scenario_map(scenario)
                    case, notes = case_from_scenario(read[path][0], driven, name, size, read[path][1])
                    notes.insert(0, f"file {path}")
                    cases.append(case)
                    theirs = nuplan_metrics.evaluate(case, configs, aggregator, Path(tmp) / "metrics")
                except Exception as error:  # nuPlan drops a scenario a metric raises on: a failure here
                    failures.append(f"{name}: {type(error).__name__}: {error}")
                    continue
                text, off = scene_report(name, ours, theirs, notes, args.tolerance)
                print(text + "\n", flush=True)
                disagreements += [f"{name}: {key} harness {_cell(ours.get(key))}, nuplan-devkit "
                                  f"{_cell(theirs['score'] if key == 'score' else theirs['metrics'].get(key))}"
                                  for key in off]
                rows.append((name, ours, theirs))
    if args.cases_out:
        args.cases_out.write_text(json.dumps(cases))
    print(summary_table(rows, args.tolerance))
    terms = sum(len(SHORT) for _ in rows)
    agree = terms - sum(1 for d in disagreements if not d.split(": ", 1)[1].startswith("score "))
    scores = sum(not differs(o.get("score"), t["score"], args.tolerance) for _, o, t in rows)
    print(f"\n{len(rows)} scene(s) compared: {agree} of {terms} terms and {scores} of {len(rows)} scores agree "
          f"within {args.tolerance:g}; {len(failures)} scene(s) not compared")
    for line in disagreements:
        print(f"DISAGREES {line}")
    for line in failures:
        print(f"FAILED {line}")
    return 1 if disagreements or failures or not rows else 0


def summary_table(rows: List[Tuple[str, Dict[str, Any], Dict[str, Any]]], tolerance: float) -> str:
    head = ["scene", *SHORT.values(), "score"]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for name, ours, theirs in rows:
        cells = [name]
        for key in [*SHORT, "score"]:
            a, b = ours.get(key), (theirs["score"] if key == "score" else theirs["metrics"].get(key))
            cells.append(f"**{_cell(a)} / {_cell(b)}**" if differs(a, b, tolerance) else _cell(a))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
