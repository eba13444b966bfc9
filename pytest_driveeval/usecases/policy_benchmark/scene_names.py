"""Which CommonRoad scene a policy_benchmark item drove, said in its findings, ``summary.json``
(``details["scene"]``), ``episodes.json`` and its GIFs' names: the benchmark id, the planning
problem and the file (a file's name need not be its benchmark id: ZAM_Loading_Bay-1_1_T.xml holds
ZAM_Tutorial-1_1_T-1).  A blueprint's episodes are named by the blueprint and their seeds, as before."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from pytest_driveeval.core.filenames import safe_name_part
from pytest_driveeval.core.outcome import Outcome

__all__ = ["gif_part", "name_outcome", "scene_identity", "scene_label"]


def scene_identity(scene: Any) -> dict[str, Any] | None:
    """``{"benchmark_id", "planning_problem", "file"}`` of a CommonRoad scene (sim.commonroad_scene),
    None for a blueprint."""
    scenario, problem = getattr(scene, "scenario", None), getattr(scene, "problem", None)
    if scenario is None or problem is None or not hasattr(scenario, "benchmark_id"):
        return None
    return {"benchmark_id": scenario.benchmark_id or Path(scenario.path).stem,
            "planning_problem": int(problem.id), "file": Path(scenario.path).name}


def scene_label(identity: dict[str, Any] | None) -> str:
    """"benchmark B, planning problem P (file.xml)", or "" for a blueprint."""
    if not identity:
        return ""
    return (f"benchmark {identity['benchmark_id']}, planning problem {identity['planning_problem']} "
            f"({identity['file']})")


def gif_part(identity: dict[str, Any] | None) -> str:
    """What a GIF's name adds after its seed: ``_<benchmark id>_problem<P>``, or nothing for a blueprint."""
    if not identity:
        return ""
    return f"_{safe_name_part(str(identity['benchmark_id']))}_problem{identity['planning_problem']}"


def name_outcome(outcome: Outcome, identity: dict[str, Any] | None) -> Outcome:
    """The item's outcome with its scene's identity in ``details`` and before each finding (in place)."""
    if not identity:
        return outcome
    label = scene_label(identity)
    outcome.details["scene"] = {**identity, "name": label}
    for finding in outcome.findings:
        if label not in finding.message:
            finding.message = f"{label}: {finding.message}"
    return outcome
