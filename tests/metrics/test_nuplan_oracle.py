"""The harness's nuPlan score against the hand-checkable cases' expected values (always), and against
nuplan-devkit's own metric code where its venv exists (benchmarks/nuplan_oracle/oracle_venv.py builds
it): every term, each frame's time to collision, the comfort signals' ranges and the score."""
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


def test_every_hand_checkable_case_has_its_expected_values():
    rows, mismatches = cases.compare([answer(case) for case in cases.all_cases()])
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
        ours, theirs = answer(case), oracle[case["name"]]
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
