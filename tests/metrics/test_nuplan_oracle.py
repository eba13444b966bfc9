"""The harness's nuPlan score against the hand-checkable cases' expected values (always), and against
nuplan-devkit's own metric code where its venv exists (benchmarks/nuplan_oracle/oracle_venv.py builds
it): every term, each frame's time to collision, the comfort signals' ranges and the score."""
import functools
import importlib.util
import math

import pytest

from conftest import REPO_ROOT
from pytest_driveeval.metrics.nuplan_score.case import answer

ORACLE = REPO_ROOT / "benchmarks" / "nuplan_oracle"


def _load(name):
    spec = importlib.util.spec_from_file_location(f"nuplan_oracle_{name}", ORACLE / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


cases = _load("cases")


@functools.cache
def hand_answers() -> dict:
    """The harness's answer to each hand-checkable case, by name: scored once for the two tests that read them."""
    return {case["name"]: answer(case) for case in cases.all_cases()}


def test_every_hand_checkable_case_has_its_expected_values():
    rows, mismatches = cases.compare(list(hand_answers().values()))
    assert mismatches == 0, "\n".join(r for r in rows if "DIFFERS" in r)
    assert len(rows) - 2 >= 60  # the table's rows: every expected value was looked at


def same(a, b, tolerance=5e-4):
    return (a is None and b is None) or (a is not None and b is not None and math.isclose(a, b, abs_tol=tolerance))


def test_the_harness_agrees_with_nuplan_devkit_on_every_term():
    python = _load("oracle_venv").existing_python()
    if python is None:
        pytest.skip("nuplan-devkit oracle venv absent (python benchmarks/nuplan_oracle/oracle_venv.py builds it)")
    oracle = {r["name"]: r for r in _load("oracle_venv").run_metrics(cases.all_cases(), python)}
    differences = []
    for case in cases.all_cases():
        ours, theirs = hand_answers()[case["name"]], oracle[case["name"]]
        assert "error" not in theirs, theirs
        for name, value in theirs["metrics"].items():
            if name in ours["metrics"] and not same(ours["metrics"][name], value):
                differences.append(f"{case['name']}: {name} ours {ours['metrics'][name]} nuplan {value}")
        if not same(ours["score"], theirs["score"]):
            differences.append(f"{case['name']}: score ours {ours['score']} nuplan {theirs['score']}")
        for frame, (a, b) in enumerate(zip(ours["time_to_collision"], theirs["time_to_collision"])):
            if not same(a, b):
                differences.append(f"{case['name']}: time to collision at frame {frame} ours {a} nuplan {b}")
        for signal, (low, high) in theirs["comfort"].items():
            if not (same(ours["comfort"][signal][0], low, 1e-6) and same(ours["comfort"][signal][1], high, 1e-6)):
                differences.append(f"{case['name']}: {signal} ours {ours['comfort'][signal]} nuplan {[low, high]}")
    assert not differences, "\n".join(differences[:40])


# Real scenes: the six nuScenes-mini scenes driven by log replay, constant velocity and both shipped models
# (compare_scenes.py), with nuPlan's protocol (80 steps from frame 10) and whole (to each scene's end).  Every
# term, the score, each frame's time to collision and the comfort signals' ranges agree within 1e-6.
EXACT = 1e-6
PROTOCOLS = {"80 steps": 80, "whole scenes": None}


@pytest.fixture(scope="module")
def real_runs(shared_data):
    """Both protocols' (records, nuplan-devkit's answers), by protocol.  One dataset serves both (each
    scenario read and each scene's score map built once, not once per protocol) and one oracle call
    answers all their cases (its two processes start once: each imports the devkit, pandas and geopandas)."""
    python = _load("oracle_venv").existing_python()
    if python is None:
        pytest.skip("nuplan-devkit oracle venv absent (python benchmarks/nuplan_oracle/oracle_venv.py builds it)")
    from pytest_driveeval.usecases.closed_loop.datasets import open_dataset

    compare = _load("compare_scenes")
    folder = shared_data / "scenarionet" / "nuscenes"
    dataset = open_dataset(folder, None)
    records = {name: compare.scene_cases(folder, steps=steps, dataset=dataset) for name, steps in PROTOCOLS.items()}
    # the oracle answers by case name, which both protocols share: each case goes in under its protocol's
    every = [{**r["case"], "name": f"{name}: {r['name']}"} for name in PROTOCOLS for r in records[name]]
    answers = iter(compare.run_oracle(every, python))
    return {name: (records[name], [next(answers) for _ in records[name]]) for name in PROTOCOLS}


@pytest.fixture(params=list(PROTOCOLS))
def real_scenes(request, real_runs):
    records, answers = real_runs[request.param]
    assert [a.get("error") for a in answers] == [None] * len(records)
    return records, answers


def test_on_real_scenes_the_case_is_what_the_harness_scores(real_scenes):
    records, _ = real_scenes
    assert len(records) == 24
    for record in records:
        assert same(record["ours"]["score"], record["direct"]["score"], 1e-9), record["name"]
        assert record["ours"]["metrics"] == pytest.approx(record["direct"]["metrics"], abs=1e-9), record["name"]


def test_on_real_scenes_every_term_and_the_score_agree_with_nuplan_devkit(real_scenes):
    differences = []
    for record, theirs in zip(*real_scenes):
        ours = record["ours"]
        for name, value in theirs["metrics"].items():
            if name in ours["metrics"] and not same(ours["metrics"][name], value, EXACT):
                differences.append(f"{record['name']}: {name} ours {ours['metrics'][name]} nuplan {value}")
        if not same(ours["score"], theirs["score"], EXACT):
            differences.append(f"{record['name']}: score ours {ours['score']} nuplan {theirs['score']}")
    assert not differences, "\n".join(differences)


def test_on_real_scenes_each_frames_time_to_collision_and_the_comfort_signals_agree(real_scenes):
    differences = []
    for record, theirs in zip(*real_scenes):
        ours = record["ours"]
        _, off = _load("compare_scenes").ttc_agreement(ours, theirs)
        if off:
            differences.append(f"{record['name']}: time to collision differs at rows {off}")
        for signal, (low, high) in theirs["comfort"].items():
            if not (same(ours["comfort"][signal][0], low, EXACT) and same(ours["comfort"][signal][1], high, EXACT)):
                differences.append(f"{record['name']}: {signal} ours {ours['comfort'][signal]} nuplan {[low, high]}")
    assert not differences, "\n".join(differences)
