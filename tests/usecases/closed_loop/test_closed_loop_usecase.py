"""The closed_loop use case end to end: YAML scenario -> unroll -> verdicts, artefacts, errors."""
from __future__ import annotations

import json
import shutil

import pytest

pytest.importorskip("torch")

from conftest import REPO_ROOT  # noqa: E402

REAL = REPO_ROOT / "fixtures" / "l5kit" / "single_scene.zarr"
GENERATED = REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr"

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - logs:
        Path: {data}
  Model: {model}
  Unroll:
{unroll}
  Conditions:
    Collisions: {{Front: 0, Side: 0, Rear: 0, AtFaultOnly: {at_fault}}}
    Displacement: {{Max: 5.0}}
  Artefacts: {{Animations: {animations}}}
"""


def scenario(name="s", data="real.zarr", model="log_replay", unroll="    StartFrame: 10\n    Steps: 60",
             at_fault="true", animations="failing"):
    return SCENARIO.format(name=name, data=data, model=model, unroll=unroll, at_fault=at_fault,
                           animations=animations)


@pytest.fixture
def cl(pytester):
    shutil.copytree(REAL, pytester.path / "real.zarr")
    shutil.copytree(GENERATED, pytester.path / "gen.zarr")
    return pytester


def summary(pytester) -> dict:
    data = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())
    return {r["nodeid"]: r for r in data["results"]}


def test_log_replay_passes_with_zero_collisions_and_drift(cl):
    cl.makefile(".scenario.yaml", replay=scenario())
    cl.runpytest("-q").assert_outcomes(passed=1)
    (record,) = summary(cl).values()
    assert record["figures"]["front"] == record["figures"]["side"] == record["figures"]["rear"] == 0
    assert record["figures"]["max_displacement"] < 1e-3
    assert record["figures"]["steps"] == 60
    assert set(record["artefacts"]) == {"result", "chart"}  # no GIF for a passing scene by default


def test_constant_velocity_fails_naming_scene_frame_agent_with_artefacts(cl):
    cl.makefile(".scenario.yaml", cv=scenario(model="constant_velocity", unroll="    StartFrame: 10\n    Steps: 100"))
    result = cl.runpytest("-q")
    result.assert_outcomes(failed=1)
    # the scene by its index and its zarr: a user with several stores sees which one
    result.stdout.fnmatch_lines(["*scene 0 (real.zarr): 1 at-fault front collision frame(s), 0 allowed; first at "
                                 "frame 73 with agent 1 (cv.scenario.yaml:14)"])
    (record,) = summary(cl).values()
    assert record["status"] == "failed" and record["figures"]["at_fault"] >= 1
    assert record["figures"]["drift_resets"] == 3 and "displacement_error" not in record["figures"]
    assert "3 drift reset(s)" in record["summary"]
    out = cl.path / "driveeval-results"
    for name in ("result", "chart", "scene_0_gif"):
        assert (out / record["artefacts"][name]).stat().st_size > 1000
    detail = json.loads((out / record["artefacts"]["result"]).read_text())["scenes"][0]
    assert {"frame": 73, "kind": "front", "track_id": 1, "at_fault": True} in detail["collisions"]
    assert detail["scene"] == 0 and detail["identity"] == {"index": 0, "zarr": "real.zarr"}
    assert detail["name"] == "real.zarr" and detail["findings"][0]["message"].startswith("scene 0 (real.zarr): ")
    (scene,) = record["details"]["scenes"]
    assert scene["scene"] == 0 and scene["name"] == "real.zarr"
    assert record["artefacts"]["scene_0_gif"].endswith("scene_0_real.gif")


def test_allowing_not_at_fault_collisions_changes_the_verdict(cl):
    cl.makefile(".scenario.yaml", strict=scenario(model="constant_velocity", at_fault="false").replace("Max: 5.0", "Max: 50.0"),
                lenient=scenario(model="constant_velocity").replace("Front: 0", "Front: 5").replace(
                    "Max: 5.0", "Max: 50.0"))
    cl.runpytest("-q").assert_outcomes(passed=1, failed=1)
    assert summary(cl)["lenient.scenario.yaml::closed_loop[logs]"]["status"] == "passed"


def test_scene_stride_selects_every_nth_scene(cl):
    cl.makefile(".scenario.yaml", stride=scenario(data="gen.zarr", unroll="    SceneStride: 5\n    Steps: 20"))
    cl.runpytest("-q").assert_outcomes(passed=1)
    (record,) = summary(cl).values()
    assert [s["scene"] for s in record["details"]["scenes"]] == [0, 5, 10, 15]


def test_out_of_range_scene_is_named_and_other_scenes_are_kept(cl):
    cl.makefile(".scenario.yaml", oob=scenario(data="gen.zarr", unroll="    Scenes: [1, 99]\n    Steps: 20"))
    result = cl.runpytest("-q")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*scene 99 is out of range: *gen.zarr has scenes 0..15*"])
    (record,) = summary(cl).values()
    assert [s["scene"] for s in record["details"]["scenes"]] == [1]


def test_start_frame_past_the_end_is_located_and_names_the_scene_and_its_length(cl):
    cl.makefile(".scenario.yaml", late=scenario(unroll="    StartFrame: 100000"),
                two=scenario(data="gen.zarr", unroll="    Scenes: [0, 1]\n    StartFrame: 150\n    Steps: 5"))
    result = cl.runpytest("-q")
    result.assert_outcomes(failed=2)
    located = "*StartFrame 100000 is past the end of scene 0 of *real.zarr (248 frames, 0..247) (late.scenario.yaml:11)"
    result.stdout.fnmatch_lines([located, "*11 |     StartFrame: 100000"])
    result.stdout.fnmatch_lines(["*StartFrame 150 is past the end of scene 0 of *gen.zarr (150 frames, 0..149)*",
                                 "*StartFrame 150 is past the end of scene 1 of *gen.zarr (150 frames, 0..149)*"])
    assert "Traceback" not in result.stdout.str() and "IndexError" not in result.stdout.str()
    assert "0 of 0 scene(s)" not in result.stdout.str()


def test_start_frame_past_the_end_in_python_is_a_data_error():
    from pytest_driveeval.core.errors import DataError
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.policies.baselines import ReplayLogPolicy
    from pytest_driveeval.usecases.closed_loop.evaluate import unroll_scenes

    with pytest.raises(DataError, match=r"start_frame 248 is past the end of scene 0 \(248 frames, 0..247\)"):
        unroll_scenes(L5Dataset.open(REAL), ReplayLogPolicy(), scenes=[0], start_frame=248)


BAD_MODELS = {
    "nan_first_row": ("import torch\nfrom pytest_driveeval.policies.baselines import ReplayLogPolicy\n"
                      "class M(ReplayLogPolicy):\n"
                      "    def forward(self, batch):\n"
                      "        out = super().forward(batch)\n"
                      "        if batch['centroid'].shape[0] == 3:\n"
                      "            out['positions'][0] = float('nan')\n"
                      "        return out\n",
                      # the engine's message, named as every finding of a scene is
                      "*scene 2 (gen.zarr): model returned NaN/inf in its first pose at frame 5*"),
    "wrong_shape": ("import torch\nclass M(torch.nn.Module):\n"
                    "    def forward(self, batch):\n"
                    "        b = batch['centroid'].shape[0]\n"
                    "        return {'positions': torch.zeros(b, 12, 3), 'yaws': torch.zeros(b, 12, 1)}\n",
                    "*model output at frame 5 for scenes [[]2, 3, 4[]]: expected 'positions' as a float tensor of "
                    "shape (B=3, T, 2), found shape (3, 12, 3)*"),
    "raises": ("import torch\nclass M(torch.nn.Module):\n"
               "    def forward(self, batch):\n"
               "        raise RuntimeError('CUDA out of memory (simulated)')\n",
               "*model output at frame 5 for scenes [[]2, 3, 4[]]: policy raised RuntimeError: CUDA out of memory*"),
}


@pytest.mark.parametrize("kind", sorted(BAD_MODELS))
def test_bad_model_output_fails_clearly_and_keeps_results(cl, kind):
    source, expected = BAD_MODELS[kind]
    cl.makepyfile(badmodel=source)
    cl.makeconftest("import pytest, badmodel\n\n@pytest.fixture\ndef driveeval_model():\n    return badmodel.M()\n")
    cl.makefile(".scenario.yaml", bad=scenario(data="gen.zarr", unroll="    Scenes: [2, 3, 4]\n    StartFrame: 5\n"
                                                                      "    Steps: 30"))
    result = cl.runpytest("-q")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines([expected])
    assert "Traceback" not in result.stdout.str()
    (record,) = summary(cl).values()
    steps = {s["scene"]: s["steps"] for s in record["details"]["scenes"]}
    if kind == "nan_first_row":
        assert steps == {2: 1, 3: 30, 4: 30}  # only its logged start frame; the others ran to the end
        error = {s["scene"]: s["error"] for s in record["details"]["scenes"]}[2]
        assert error.startswith("scene 2 (gen.zarr): model returned NaN/inf")
    assert set(steps) == {2, 3, 4}


def test_corrupt_zarr_missing_array_and_wrong_dtype(cl):
    shutil.rmtree(cl.path / "real.zarr" / "agents")
    shutil.copytree(REAL, cl.path / "dtype.zarr")
    meta = cl.path / "dtype.zarr" / "frames" / ".zarray"
    meta.write_text(meta.read_text().replace('"<i8"', '"<i4"', 1))
    cl.makefile(".scenario.yaml", missing=scenario(), dtype=scenario(data="dtype.zarr"),
                fine=scenario(data="gen.zarr", unroll="    Scenes: [0]\n    Steps: 10"))
    result = cl.runpytest("-q")
    result.assert_outcomes(passed=1, errors=2)
    result.stdout.fnmatch_lines(["*L5FormatError:*real.zarr*agents*"])
    result.stdout.fnmatch_lines(["*L5FormatError:*dtype.zarr*frames*"])


def test_model_option_overrides_the_scenario_model(cl):
    cl.makefile(".scenario.yaml", cv=scenario(model="constant_velocity", unroll="    StartFrame: 10\n    Steps: 100"))
    cl.runpytest("-q", "--driveeval-model", "log_replay").assert_outcomes(passed=1)


def test_same_summary_with_two_workers(cl):
    cl.makefile(".scenario.yaml", a=scenario(data="gen.zarr", model="constant_velocity",
                                            unroll="    Scenes: [0, 1]\n    Steps: 40"),
                b=scenario(model="constant_velocity"))
    cl.runpytest("-q")
    alone = {k: {f: v[f] for f in ("status", "figures", "details", "findings")} for k, v in summary(cl).items()}
    cl.runpytest("-q", "-n", "2")
    both = {k: {f: v[f] for f in ("status", "figures", "details", "findings")} for k, v in summary(cl).items()}
    assert both == alone
