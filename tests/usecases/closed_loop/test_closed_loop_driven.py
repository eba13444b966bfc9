"""closed_loop.json keeps each scene's ego as driven (the frames, their times, the box centre's poses and the
box), so that an outside scorer (benchmarks/nuplan_oracle/oracle_scenes.py) scores the drive the harness
scored.  The repository's three real nuScenes scenes (fixtures/scenarionet/nuscenes) need no shared data."""
import json

import numpy as np
import pytest

pytest.importorskip("torch")  # a Python without torch skips the file

from conftest import REPO_ROOT  # noqa: E402
from pytest_driveeval.closed_loop import unroll_scenes  # noqa: E402
from pytest_driveeval.sim.logreplay import EGO_EXTENT  # noqa: E402
from pytest_driveeval.usecases.closed_loop.baselines import baseline  # noqa: E402
from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig  # noqa: E402
from pytest_driveeval.usecases.closed_loop.datasets import open_dataset  # noqa: E402
from pytest_driveeval.usecases.closed_loop.evaluate import driven_json  # noqa: E402

SCENES = REPO_ROOT / "fixtures" / "scenarionet" / "nuscenes"

SCENARIO = f"""\
ScenarioFormatVersion: 3.0.0
ScenarioName: drive
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - nuscenes:
        Path: {SCENES}
  Model: constant_velocity
  Unroll:
    StartFrame: 10
    Steps: 6
  Artefacts: {{Charts: false, Animations: none}}
{{executor}}"""


def test_a_log_replay_drives_the_logged_poses_at_the_log_frames_and_says_so():
    dataset = open_dataset(SCENES, None)
    unroll = unroll_scenes(dataset, baseline("log_replay", ClosedLoopConfig(Model="log_replay")), [1], start_frame=10,
                           steps=6)
    driven = driven_json(unroll, 0)
    assert driven["frames"] == list(range(10, 16))
    assert np.allclose(driven["times"], np.arange(10, 16) * unroll.step_time)
    source = dataset.source(1)
    logged = np.concatenate([source.tracks.position[source.sdc][10:16, :2],
                             source.tracks.heading[source.sdc][10:16, None]], axis=1)
    assert np.allclose(driven["center"], logged, atol=1e-6)
    assert (driven["length"], driven["width"]) == (float(EGO_EXTENT[0]), float(EGO_EXTENT[1]))
    json.dumps(driven)  # plain JSON


@pytest.mark.parametrize("executor", ["", "  Executor: {Kind: local, ChunkSize: 2}\n"], ids=["one_unroll", "chunks"])
def test_closed_loop_json_holds_each_scenes_driven_poses_beside_its_score(pytester, executor):
    # in chunks, each worker's verdicts carry the poses back to where closed_loop.json is written
    pytester.makefile(".scenario.yaml", drive=SCENARIO.replace("{executor}", executor))
    pytester.runpytest("-q", "-p", "no:randomly")
    folder = pytester.path / "driveeval-results"
    (record,) = json.loads((folder / "summary.json").read_text())["results"]
    assert ("executor" in record["details"]) == bool(executor)
    scenes = json.loads((folder / record["artefacts"]["result"]).read_text())["scenes"]
    assert [s["scene"] for s in scenes] == [0, 1, 2]
    for scene, summary_scene in zip(scenes, record["details"]["scenes"]):
        driven = scene["driven"]
        assert driven["frames"] == list(range(10, 16)) and len(driven["center"]) == 6
        assert all(len(pose) == 3 for pose in driven["center"])
        # constant velocity: the ego moves on from where the log put it at the start
        assert np.hypot(*np.subtract(driven["center"][-1][:2], driven["center"][0][:2])) > 0
        assert summary_scene["scene"] == scene["scene"] and "score" in summary_scene
