"""docs/reference/scenario-keys.md is made from the models that validate the keys: the committed page
must be what the models make now, and every key must say what it means."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from pydantic import BaseModel, Field

from conftest import REPO_ROOT
from pytest_driveeval.scenario import reference


def test_the_committed_page_is_what_the_models_make():
    made = reference.page()
    committed = reference.PAGE.read_text() if reference.PAGE.exists() else ""
    assert committed == made, (f"{reference.PAGE.relative_to(REPO_ROOT)} is stale or missing: run "
                               f"`{reference.COMMAND}` and commit the page")


def test_the_page_is_the_manuals():
    assert reference.PAGE == REPO_ROOT / "docs" / "reference" / "scenario-keys.md"
    assert "reference/scenario-keys.md" in (REPO_ROOT / "mkdocs.yml").read_text()


def test_every_shipped_use_case_is_on_the_page():
    shipped = sorted(p.parent.name for p in (REPO_ROOT / "pytest_driveeval" / "usecases").glob("*/config.py"))
    assert sorted(reference.USECASES) == shipped
    page = reference.page()
    assert all(f"## {name}\n" in page for name in shipped)


def test_the_commonroad_keys_are_on_the_page():
    page = reference.page()
    for key in ("Blueprint.CommonRoad", "Blueprint.PlanningProblem", "Blueprint.Traffic", "Blueprint.Params",
                "Blueprint.Params.start_lateral", "Blueprint.Params.resolution"):
        assert f"`Evaluation.{key}`" in page, key


def test_every_row_has_a_type_a_default_and_a_meaning():
    rows = [line for line in reference.page().splitlines() if line.startswith("| `")]
    assert len(rows) > 150
    for row in rows:
        cells = [cell.strip() for cell in row.strip("|").split(" | ")]
        assert len(cells) == 4 and all(cells), row


def _keys(mapping: dict, prefix: str = "") -> set[str]:
    """The key paths of a scenario file as the page spells them."""
    out = set()
    for key, value in mapping.items():
        path = f"{prefix}{key}"
        out.add(path)
        if isinstance(value, dict) and key not in ("Params", "Policies", "Figures", "Replay", "RuntimeEnv", "Terms"):
            out |= _keys(value, path + ".")
        elif isinstance(value, list) and key in ("Datasets", "Beats"):
            for entry in value:
                if key == "Datasets":
                    for options in entry.values():
                        out |= _keys(options or {}, path + "[].<name>.")
                else:
                    out |= _keys(entry, path + "[].")
    return out


@pytest.mark.parametrize("scenario", sorted((REPO_ROOT / "scenario_tests").rglob("*scenario*.yaml")),
                         ids=lambda p: p.relative_to(REPO_ROOT / "scenario_tests").as_posix())
def test_every_key_the_demo_scenarios_use_is_on_the_page(scenario: Path):
    page = reference.page()
    documented = {line.split("`")[1] for line in page.splitlines() if line.startswith("| `")}
    data = yaml.safe_load(scenario.read_text())
    if data["Evaluation"]["UseCaseName"] not in reference.USECASES:
        pytest.skip("a use case of the examples (examples/custom_usecase), which documents its own keys")
    used = _keys(data)
    assert sorted(used - documented) == []


def test_a_key_without_a_meaning_stops_the_page_naming_it():
    class Undocumented(BaseModel):
        Said: int = Field(1, description="a key that says what it is")
        Silent: int = 2

    with pytest.raises(reference.MissingDescription, match=r"Undocumented\.Silent"):
        list(reference.rows(Undocumented))


def test_the_check_command_fails_on_a_stale_page_and_says_how_to_remake_it(tmp_path, monkeypatch, capsys):
    stale = tmp_path / "scenario-keys.md"
    stale.write_text(reference.page().replace("required", "optional", 1))
    monkeypatch.setattr(reference, "PAGE", stale)
    assert reference.main(["--check"]) == 1
    assert reference.COMMAND in capsys.readouterr().err
    stale.write_text(reference.page())
    assert reference.main(["--check"]) == 0


def test_the_commonroad_params_table_lists_what_a_commonroad_scene_accepts():
    from pytest_driveeval.sim.blueprints import ParameterError
    from pytest_driveeval.sim.commonroad_scene import CommonRoadParams, check_params

    table = reference.page().split("of a `CommonRoad` scene", 1)[1]
    listed = [line.split("`")[1].rsplit(".", 1)[1] for line in table.splitlines() if line.startswith("| `")]
    assert "start_lateral" in listed and "dt" not in listed
    defaults = CommonRoadParams()
    for name in listed:
        check_params({name: getattr(defaults, name)})  # accepted: a listed key means something there
    with pytest.raises(ParameterError):
        check_params({"lane_width": 3.5})  # and one the blueprints know but the table leaves out does not
