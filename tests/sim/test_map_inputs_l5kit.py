"""Our vectorised map keys against l5kit 1.5.0's ``Vectorizer``, where its venv exists
(benchmarks/l5kit_oracle/oracle_venv.py makes it; without it this skips): twelve frames of the real
L5 scene on a map laid along its path, with traffic lights."""
from __future__ import annotations

import pytest

from conftest import REPO_ROOT, module_at

ORACLE = REPO_ROOT / "benchmarks" / "l5kit_oracle"


def _load(name):
    return module_at(ORACLE / f"{name}.py", name)


def test_map_keys_equal_l5kits():
    python = _load("oracle_venv").existing_python()
    if python is None:
        pytest.skip("l5kit oracle venv absent (python benchmarks/l5kit_oracle/oracle_venv.py builds it)")
    result = _load("compare_vectors").compare(python)
    assert result["frames"] == 12
    for key, dtype in result["l5kit_dtypes"].items():
        entry = result[key]
        assert entry["dtype"] == dtype, (key, entry)
        assert entry["differing"] == 0, (key, entry)  # coordinates within 1e-4 m (the file's heights move them)
        assert entry.get("third_differing", 0) == 0, (key, entry)
    assert result["lanes_availabilities"]["available"] > 5000  # the comparison saw lanes, not empty slots
    assert result["crosswalks_availabilities"]["available"] > 0
    assert len(result["lanes_mid"]["third_values"]) >= 3  # lit, unlit and uncontrolled lanes all compared
