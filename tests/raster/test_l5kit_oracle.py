"""Our rasters against l5kit 1.5.0's own, where its venv exists (benchmarks/l5kit_oracle/oracle_venv.py
makes it; without it these skip): the real L5 scene with box_debug, the real scene on a map laid along
its path, and generated scenes with their own map, with py_semantic."""
from __future__ import annotations

import pytest

from conftest import REPO_ROOT, module_at

ORACLE = REPO_ROOT / "benchmarks" / "l5kit_oracle"


def _load(name):
    return module_at(ORACLE / f"{name}.py", name)


@pytest.fixture(scope="module")
def oracle_python():
    python = _load("oracle_venv").existing_python()
    if python is None:
        pytest.skip("l5kit oracle venv absent (python benchmarks/l5kit_oracle/oracle_venv.py builds it)")
    return python


@pytest.mark.parametrize("case, least", [("real_box", 1.0), ("generated_semantic", 1.0),
                                         # 14 values of 1.9M differ, all in the map channels (2026-11-24).
                                         ("real_semantic", 0.99999)])
def test_pixel_agreement_with_l5kit(oracle_python, case, least):
    pytest.importorskip("torch")
    result = _load("compare_rasters").compare(case, oracle_python)
    assert result["frames"] >= 6 and result["pixels"] > 1_000_000
    assert result["box_differing"] == 0, result
    assert result["agreement"] >= least, result
