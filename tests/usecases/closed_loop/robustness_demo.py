"""The demo's closed-loop robustness scenario (scenario_tests/robustness/real_scene_lateral.scenario.yaml) in
a project of its own, run in a fresh pytest, and its search record: what the robustness tests
(test_closed_loop_robustness.py, test_closed_loop_search_reproducibility.py) share."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

import pytest

from conftest import REPO_ROOT, fresh_pytest_run

DEMO = REPO_ROOT / "scenario_tests" / "robustness" / "real_scene_lateral.scenario.yaml"
REAL = REPO_ROOT / "fixtures" / "l5kit" / "single_scene.zarr"
MODEL = REPO_ROOT / "fixtures" / "models" / "planning_model.pt2"
INI = "[pytest]\nmarkers =\n    demo\n    robustness\n"
ANOTHER = "another.scenario.yaml"   # the demo under another ScenarioName, on the same data


def demo_text(name: str = "real-scene-planning-model-lateral-offset") -> str:
    """The demo scenario naming the repository's data and model (wherever it is copied to)."""
    text = DEMO.read_text().replace("../../fixtures/l5kit/single_scene.zarr", str(REAL)).replace(
        "../../fixtures/models/planning_model.pt2", str(MODEL))
    assert str(REAL) in text and str(MODEL) in text
    return text.replace("ScenarioName: real-scene-planning-model-lateral-offset", f"ScenarioName: {name}")


def demo_project(folder: Path, another: bool = False, text: Callable[..., str] = demo_text) -> Path:
    """The demo scenario in a project of its own; ``another``: with a second scenario on the same data;
    ``text(name)``: the scenario's text (the demo's own by default)."""
    (folder / "scenarios").mkdir()
    (folder / "scenarios" / DEMO.name).write_text(text())
    if another:
        (folder / "scenarios" / ANOTHER).write_text(text("another-search"))
    (folder / "tox.ini").write_text(INI)   # what pytester.makeini writes
    return folder


def session(folder: Path, *args: str) -> dict[str, int]:
    """The outcome counts of pytest run in ``folder`` in a fresh process: the module fixtures' runs,
    which several tests read (pytester's folder lives for one test only)."""
    done = fresh_pytest_run(folder, "-p", "no:cacheprovider", *args, timeout=3600)
    print(done.stdout[-3000:], done.stderr[-3000:])   # shown when a test of the run fails
    outcomes = pytest.RunResult.parse_summary_nouns(done.stdout.splitlines())
    return {k: v for k, v in outcomes.items() if k not in ("warning", "warnings")}


def search_record(folder, output="driveeval-results") -> dict:
    path = folder if isinstance(folder, Path) else folder.path
    data = json.loads((path / output / "summary.json").read_text())
    (record,) = data["results"]
    return record
