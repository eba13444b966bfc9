"""What the baseline session tests share: small scenarios of each use case built from fixtures/
data, a session run against a baseline folder, and readers of its summary and baseline files
(``from baseline_sessions import ...``; a test folder is on the path, as for ``from conftest import``)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any, Callable

from conftest import POLICY_BENCHMARK_HEAD, REPO_ROOT

from pytest_driveeval.baseline.store import relative_path
from pytest_driveeval.baseline.units import Units

FIXTURES = REPO_ROOT / "fixtures"
BASELINES = "baselines"

# No animation and no bar chart: rendering them (~0.3 s an item) is no claim of the baseline tests,
# which run these items a hundred times over; tests/report/ checks the artefacts.
CLOSED_LOOP = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - logs:
        Path: gen.zarr
  Model: {model}
  Unroll:
    Scenes: {scenes}
    Steps: {steps}
  Conditions:
    Collisions: {{Front: 0, Side: 0, Rear: 0, AtFaultOnly: true}}
    Displacement: {{Max: {max_displacement}}}
  Artefacts: {{Animations: none, Charts: false}}
{regression}"""


def closed_loop(name="drive", model="log_replay", scenes="[0, 1, 2, 3]", steps=40, max_displacement=5.0,
                regression="") -> str:
    return CLOSED_LOOP.format(name=name, model=model, scenes=scenes, steps=steps,
                              max_displacement=max_displacement, regression=regression)


def policy_benchmark(name="bench", policies="    mine: gnn.pt2\n    idm: idm_expert", episodes=12, first_seed=100,
                     extra="") -> str:
    return POLICY_BENCHMARK_HEAD.format(name=name) + (
        f"  Blueprint: {{Name: merging}}\n  Episodes: {episodes}\n  FirstSeed: {first_seed}\n  Strata: 4\n"
        f"  Policies:\n{policies}\n  Conditions:\n    CollisionRate: {{AtMost: 100}}\n"
        "  Artefacts: {Animations: none, ComparisonPlot: false}\n" + extra)


# The demo filter of examples/ground_filter.py under test; DROP_FRAMES (indices, comma separated)
# empties those frames' output, a filter that lost the lead car there.
OBSTACLE_CONFTEST = '''
import itertools
import os

import pytest
from ground_filter import ground_height_filter


@pytest.fixture
def driveeval_pointclouds():
    drop = {int(i) for i in os.environ.get("DROP_FRAMES", "").split(",") if i}
    calls = itertools.count()
    return lambda points: points[:0] if next(calls) in drop else ground_height_filter(points)
'''


def obstacle_scenario() -> str:
    demo = REPO_ROOT / "scenario_tests" / "obstacle_segmentation" / "robustness"
    return (demo / "filtered.scenario.yaml").read_text().replace("../../../fixtures/t4/clean", "t4")


def with_closed_loop_data(pytester) -> None:
    shutil.copytree(FIXTURES / "l5kit" / "generated.zarr", pytester.path / "gen.zarr")


def with_policy(pytester) -> None:
    shutil.copy(FIXTURES / "models" / "gnn_actor_merging.pt2", pytester.path / "gnn.pt2")


def with_obstacle_filter(pytester) -> None:
    shutil.copytree(FIXTURES / "t4" / "clean", pytester.path / "t4")
    shutil.copy(REPO_ROOT / "examples" / "ground_filter.py", pytester.path / "ground_filter.py")
    pytester.makeconftest(OBSTACLE_CONFTEST)
    pytester.syspathinsert()


def run(pytester, *args: str, folder: str = BASELINES):
    """A session compared with (or updating) the baseline folder."""
    return pytester.runpytest("-q", "-p", "no:randomly", "--driveeval-baseline", folder, *args)


def summary(pytester, output: str = "driveeval-results") -> dict[str, Any]:
    return json.loads((pytester.path / output / "summary.json").read_text())


def records(pytester, output: str = "driveeval-results") -> dict[str, dict[str, Any]]:
    return {r["nodeid"]: r for r in summary(pytester, output)["results"]}


def statuses(pytester, output: str = "driveeval-results") -> dict[str, str]:
    return {k: (r.get("comparison") or {}).get("status") for k, r in records(pytester, output).items()}


def baseline_path(pytester, nodeid: str, folder: str = BASELINES) -> Path:
    return pytester.path / folder / Path(*relative_path(nodeid).parts)


def read_baseline(pytester, nodeid: str) -> dict[str, Any]:
    return json.loads(baseline_path(pytester, nodeid).read_text())


def edit_baseline(pytester, nodeid: str, change: Callable[[dict[str, Any]], None]) -> None:
    """A hand edit of a baseline file, written back as the plugin writes it."""
    path = baseline_path(pytester, nodeid)
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")


def set_units(data: dict[str, Any], column: str, codes: str) -> None:
    units = Units.from_json(data["units"])
    units.columns[column] = codes
    data["units"] = units.to_json()


def changed_units(before: dict[str, Any], after: dict[str, Any], column: str) -> list[str]:
    """Ids of the units whose good / bad end differs between two payloads' units."""
    b, a = Units.from_json(before["units"]), Units.from_json(after["units"])
    assert b.ids == a.ids
    return [u for i, u in enumerate(a.ids) if b.is_good(column, i) != a.is_good(column, i)]
