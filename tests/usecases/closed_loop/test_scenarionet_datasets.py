"""ScenarioNet scenario folders as closed-loop datasets in a scenario file: recognised from their
files or declared with Format, the real nuScenes-mini scenes driven by the shipped planning model."""
import json

import numpy as np
import pytest

from conftest import REPO_ROOT
from pytest_driveeval.errors import DataError
from pytest_driveeval.usecases.closed_loop.datasets import format_of, open_dataset

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - nuscenes_mini:
        Path: {data}
{format}  Model: {model}
  Unroll:
{unroll}    StartFrame: 10
    Steps: {steps}
  Conditions:
    Collisions: {{Front: 0, Side: 0, Rear: 0, AtFaultOnly: true}}
    Displacement: {{Max: 30.0}}
"""


def scenario_text(name, data, model="planning_model.pt2", declared=False, scenes=None, raster=False, steps=60):
    unroll = (f"    Scenes: {scenes}\n" if scenes else "") + (
        "    Inputs: {Kind: raster, MapType: py_semantic, RasterSize: [112, 112], PixelSize: [0.5, 0.5], "
        "EgoCenter: [0.25, 0.5]}\n" if raster else "")
    return SCENARIO.format(name=name, data=data, format="        Format: scenarionet\n" if declared else "",
                           model=REPO_ROOT / "fixtures" / "models" / model, unroll=unroll, steps=steps)

def test_the_files_tell_the_format(shared_data, tmp_path):
    assert format_of(shared_data / "scenarionet" / "nuscenes") == "scenarionet"
    assert format_of(next((shared_data / "scenarionet" / "nuscenes").glob("*.pkl"))) == "scenarionet"
    assert format_of(REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr") == "l5kit"
    with pytest.raises(DataError, match="Format says l5kit, but the files are scenarionet's"):
        open_dataset(shared_data / "scenarionet" / "nuscenes", "l5kit")
    with pytest.raises(DataError, match="Format 'waymo' is not one of l5kit, scenarionet"):
        open_dataset(shared_data / "scenarionet" / "nuscenes", "waymo")


def test_the_planning_model_drives_the_real_nuscenes_scenes_from_a_scenario(pytester, shared_data):
    data = shared_data / "scenarionet" / "nuscenes"
    pytester.makefile(".scenario.yaml", declared=scenario_text("declared", data, declared=True),
                      found=scenario_text("found", data))
    pytester.runpytest("-p", "no:randomly")
    records = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]
    assert [r["scenario"] for r in records] == ["declared", "found"]
    for record in records:
        assert record["figures"]["scenes"] == 6 and record["figures"]["steps"] == 6 * 60
        assert [s["scene"] for s in record["details"]["scenes"]] == list(range(6))
        assert all(np.isfinite(s["max_displacement"]) for s in record["details"]["scenes"])
    # Declared or found from the files, the same reader: the same unroll, figure for figure.
    assert records[0]["figures"] == records[1]["figures"]
    assert records[0]["details"]["scenes"] == records[1]["details"]["scenes"]


def test_a_broken_scenario_in_a_folder_fails_alone_and_the_others_run(pytester, shared_data):
    import shutil

    folder = pytester.path / "scenes"
    folder.mkdir()
    real = sorted((shared_data / "scenarionet" / "nuscenes").glob("*.pkl"))
    for path in real[:2]:
        shutil.copy(path, folder / path.name)
    (folder / "sd_zz_cut.pkl").write_bytes(real[2].read_bytes()[:5000])  # truncated
    pytester.makefile(".scenario.yaml", cut=scenario_text("cut", folder))
    pytester.runpytest("-p", "no:randomly")
    record = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"][0]
    assert record["verdict"] == "failed"
    assert [s["scene"] for s in record["details"]["scenes"]] == [0, 1]  # the readable two were unrolled
    messages = [f["message"] for f in record["findings"] if f.get("scene") == 2]
    assert len(messages) == 1 and "scene 2 cannot be read:" in messages[0]
    assert "sd_zz_cut.pkl is not a readable pickle" in messages[0] and "truncated" in messages[0]


def test_the_raster_model_sees_the_scenarios_own_map_and_scenes_of_two_cities_are_refused(pytester, shared_data):
    def scenario(name, scenes):
        return scenario_text(name, shared_data / "scenarionet" / "nuscenes", "raster_model.pt2", scenes=scenes,
                             raster=True, steps=30)

    pytester.makefile(".scenario.yaml", boston=scenario("boston", "[1, 2]"), mixed=scenario("mixed", "[0, 1]"))
    pytester.runpytest("-p", "no:randomly")
    records = {r["scenario"]: r for r in
               json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]}
    assert records["boston"]["figures"]["scenes"] == 2 and records["boston"]["figures"]["steps"] == 60
    assert records["mixed"]["status"] == "failed"
    assert "lie on 2 maps (boston-seaport, singapore-onenorth)" in records["mixed"]["message"]
