"""``Unroll.Inputs: raster`` in the closed loop: the YAML, and that the policy sees a raster of the
history it drove, not of the log."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from pytest_driveeval.core.errors import DataError

import closed_loop_yaml
from conftest import REPO_ROOT

torch = pytest.importorskip("torch")

GENERATED = REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr"
def load(tmp_path, unroll):
    return closed_loop_yaml.load(tmp_path, "  Unroll:\n" + unroll).config


def problems(tmp_path, unroll) -> list[str]:
    return closed_loop_yaml.problems(tmp_path, "  Unroll:\n" + unroll)


def test_vector_is_the_default_and_raster_takes_l5kits_parameters(tmp_path):
    assert load(tmp_path, "    StartFrame: 0\n").Unroll.Inputs.raster_params(10) is None
    params = load(tmp_path, "    HistoryFrames: 3\n    Inputs: {Kind: raster, MapType: box_debug, "
                            "RasterSize: [64, 48], PixelSize: [0.25, 0.25], EgoCenter: [0.5, 0.5]}\n"
                  ).Unroll.Inputs.raster_params(3)
    assert (params.map_type, tuple(params.raster_size), tuple(params.pixel_size), tuple(params.ego_center),
            params.history_num_frames) == ("box_debug", (64, 48), (0.25, 0.25), (0.5, 0.5), 3)
    assert load(tmp_path, "    Inputs: raster\n").Unroll.Inputs.MapType == "py_semantic"


@pytest.mark.parametrize("unroll, expected", [
    ("    Inputs: rastr\n", "k:8: Evaluation.Unroll.Inputs: expected vector, raster or a mapping; found 'rastr'"),
    ("    Inputs: {MapType: box_debug}\n",
     "k:8: Evaluation.Unroll.Inputs: MapType applies to Kind: raster; give Kind: raster too"),
    ("    Inputs: {Kind: raster, MapType: box_debug, SemanticMap: m.pb}\n",
     "k:8: Evaluation.Unroll.Inputs: SemanticMap and Meta apply to MapType: py_semantic"),
    ("    Inputs: {Kind: raster, PixelSize: [0.25, 0.5]}\n",
     "k:8: Evaluation.Unroll.Inputs: RasterParams.pixel_size must be square"),
])
def test_mistakes_are_located(tmp_path, unroll, expected):
    found = problems(tmp_path, unroll)
    assert len(found) == 1 and found[0].startswith(expected), found


class StandStill(torch.nn.Module):
    """Asks for the pose it is at, and keeps the images it was given."""

    def __init__(self):
        super().__init__()
        self.images = []

    def forward(self, data):
        self.images.append(data["image"].clone())
        b = data["image"].shape[0]
        return {"positions": torch.zeros(b, 12, 2), "yaws": torch.zeros(b, 12, 1)}


@pytest.mark.skipif(not GENERATED.exists(), reason="fixtures/l5kit/generated.zarr is absent: python examples/make_demo_data.py makes it")
def test_the_raster_shows_the_driven_history():
    """An ego that stands still from frame 20 on: eleven frames later its ten history channels all show
    the same box, where the log (which drives on) has them apart; the agents' channels stay the log's."""
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.raster import RasterParams, rasterize
    from pytest_driveeval.usecases.closed_loop.evaluate import kept_scenes, stack_log, unroll_scenes

    dataset = L5Dataset.open(GENERATED)
    params = RasterParams(map_type="box_debug", raster_size=(112, 112), history_num_frames=10)
    policy = StandStill()
    unroll_scenes(dataset, policy, [0], start_frame=20, steps=12, drift_threshold=None, freeze_on_collision=False,
                  raster=params)
    assert len(policy.images) == 11
    first, last = policy.images[0][0].numpy(), policy.images[-1][0].numpy()
    ego_now = last[11]
    # Standing still: every ego history channel of the last step is the current box.
    for channel in range(12, 22):
        np.testing.assert_array_equal(last[channel], ego_now)
    scenes = kept_scenes(dataset, [0], 20)
    log = stack_log(dataset, [0], 20, scenes=scenes)
    logged = rasterize(params, log, [0], [30], log.ego_xy, log.ego_yaw, scenes=scenes)[0]
    assert not np.array_equal(logged[12:22], last[12:22])  # the log moved on: its history boxes differ
    # At the start the driven history is the log's, so the whole raster is the log's.
    np.testing.assert_array_equal(first, rasterize(params, log, [0], [20], log.ego_xy, log.ego_yaw,
                                                   scenes=scenes)[0])


class RecordingConstantVelocity(torch.nn.Module):
    """Constant velocity, keeping the images it was given."""

    def __init__(self):
        super().__init__()
        from pytest_driveeval.policies.baselines import ConstantVelocityPolicy

        self.policy, self.images = ConstantVelocityPolicy(), []

    def forward(self, data):
        self.images.append(data["image"].clone())
        return self.policy(data)


@pytest.mark.skipif(not GENERATED.exists(), reason="fixtures/l5kit/generated.zarr is absent: python examples/make_demo_data.py makes it")
def test_with_reactive_agents_the_raster_shows_them_where_they_braked():
    """Generated scene 1: constant velocity stops short and the car behind brakes (reactive); every
    step's raster is the one drawn afresh from where the engine had the agents, not the log's."""
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.raster import RasterParams, rasterize
    from pytest_driveeval.sim.logreplay import ReactiveAgents
    from pytest_driveeval.usecases.closed_loop.evaluate import kept_scenes, stack_log, unroll_scenes

    dataset = L5Dataset.open(GENERATED)
    params = RasterParams(map_type="box_debug", raster_size=(112, 112), history_num_frames=10)
    policy = RecordingConstantVelocity()
    result = unroll_scenes(dataset, policy, [1], start_frame=10, reactive=ReactiveAgents(), raster=params).result
    assert result.reacted.any(), "an agent left its log"
    scenes = kept_scenes(dataset, [1], 10)
    log = stack_log(dataset, [1], 10, scenes=scenes)
    differs = 0
    for k, image in enumerate(policy.images):
        frame = 10 + k
        fresh = rasterize(params, result.agents, [0], [frame], result.driven_xy, result.driven_yaw, scenes=scenes)
        np.testing.assert_array_equal(image[0].numpy(), fresh[0], err_msg=f"frame {frame}")
        logged = rasterize(params, log, [0], [frame], result.driven_xy, result.driven_yaw, scenes=scenes)
        differs += not np.array_equal(logged[0, :11], fresh[0, :11])
    assert differs > 0, "the braking car is drawn where it braked, not where the log has it"


def test_a_missing_semantic_map_is_named(tmp_path):
    from pytest_driveeval.usecases.closed_loop.raster_inputs import load_semantic_map

    (tmp_path / "d.zarr").mkdir()
    with pytest.raises(DataError, match=r"semantic_map\.pb: no such file .*Inputs\.SemanticMap"):
        load_semantic_map(tmp_path / "d.zarr")


SCENE = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: raster
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - logs: {{Path: gen.zarr}}
  Model: {model}
  Unroll:
    Scenes: [0, 1]
    StartFrame: 10
    Steps: 30
    Inputs: {{Kind: raster, MapType: py_semantic, RasterSize: [112, 112]}}
  Conditions:
    Collisions: {{Front: 1000, Side: 1000, Rear: 1000}}
"""


@pytest.mark.skipif(not GENERATED.exists(), reason="fixtures/l5kit/generated.zarr is absent: python examples/make_demo_data.py makes it")
def test_a_raster_scenario_runs_with_the_map_beside_the_dataset_and_an_empty_or_missing_map_is_named(pytester):
    shutil.copytree(GENERATED, pytester.path / "gen.zarr")
    for name in ("semantic_map.pb", "meta.json"):
        shutil.copy(GENERATED.parent / name, pytester.path / name)
    # A 0-byte semantic_map.pb decodes as a map without a road: the rasters would lack it silently.
    (pytester.path / "empty.pb").write_bytes(b"")
    model = REPO_ROOT / "fixtures" / "models" / "raster_model.pt2"
    if not model.exists():
        pytest.skip(f"{model} is absent: python examples/train_raster_model.py trains it")
    scene = SCENE.format(model=model)
    pytester.makefile(".scenario.yaml", raster=scene,
                      empty=scene.replace("RasterSize: [112, 112]", "RasterSize: [112, 112], SemanticMap: empty.pb"))
    out = pytester.runpytest("-q")
    out.assert_outcomes(passed=1, failed=1)
    out.stdout.fnmatch_lines(["*empty.pb: the semantic map holds no lanes and no crosswalks (0 bytes), so it "
                              "cannot be the map of *gen.zarr that Inputs: raster with MapType py_semantic draws; "
                              "give Inputs.SemanticMap to point at the dataset's map, or MapType: box_debug*"])
    results = {r["nodeid"]: r for r in
               json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]}
    result = results["raster.scenario.yaml::closed_loop[logs]"]
    assert result["status"] == "passed"
    assert result["figures"]["scenes"] == 2 and result["figures"]["steps"] > 0
    # Without its map beside the dataset the item fails and names the missing file.
    (pytester.path / "semantic_map.pb").unlink()
    out = pytester.runpytest("-q", "raster.scenario.yaml")
    out.assert_outcomes(failed=1)
    out.stdout.fnmatch_lines(["*semantic_map.pb: no such file*"])

