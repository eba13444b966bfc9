"""A closed_loop scenario written from a few YAML lines, and the problems loading it reports:
what the closed-loop key tests share (``from closed_loop_yaml import load, problems``; tests/
is on the path, as for ``from conftest import REPO_ROOT``)."""
from __future__ import annotations

import pytest

from pytest_driveeval import load_scenario
from pytest_driveeval.core.errors import ScenarioError

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: keys
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Model: {model}
{extra}"""


def load(tmp_path, extra, model="constant_velocity"):
    """The scenario with ``extra`` (lines under ``Evaluation``, from line 7 on) after its Model."""
    path = tmp_path / "k.scenario.yaml"
    path.write_text(SCENARIO.format(model=model, extra=extra))
    return load_scenario(path)


def problems(tmp_path, extra, model="constant_velocity") -> list[str]:
    with pytest.raises(ScenarioError) as failed:
        load(tmp_path, extra, model)
    return [p.render("k") for p in failed.value.problems]
