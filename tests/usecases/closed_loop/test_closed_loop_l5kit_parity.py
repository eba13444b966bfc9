"""The closed_loop options that reproduce l5kit's set-up give l5kit's figures on the real scene.

l5kit 1.5 with ``SimulationConfig(use_agents_gt=True, disable_new_agents=True,
distance_th_close=50, start_frame_index=0)``, its CLE metrics and no drift
reset: a parked ego is hit from behind and the side by tracks 1 and 23; a
constant-velocity ego that starts with the logged step hits nothing.  The
scene is fixtures/l5kit/single_scene.zarr, byte for byte l5kit's test
artefact (fixtures/SOURCES.md), so nothing here needs ../shared.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch")

from conftest import REPO_ROOT

REAL = REPO_ROOT / "fixtures" / "l5kit" / "single_scene.zarr"

L5KIT_SETUP = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - real: {{Path: {data}}}
  Model: {model}
{extra}  Unroll:
    StartFrame: 0
    DriftThreshold: null
    FreezeOnCollision: false
    Agents: {{Labels: [CAR], LabelThreshold: 0.5, WithinAtStart: 50.0}}
  Conditions:
    Collisions: {{Front: 0, Side: 0, Rear: 0}}
    Displacement: {{Max: 35.0}}
    DistanceToReference: {{Max: 4.0, Measure: l5kit}}
  Artefacts: {{Animations: none, Charts: false}}
"""

PARKED = """\
import pytest
import torch


class Parked(torch.nn.Module):
    def forward(self, batch):
        b = batch["centroid"].shape[0]
        return {"positions": torch.zeros(b, 12, 2), "yaws": torch.zeros(b, 12, 1)}


@pytest.fixture
def driveeval_model():
    return Parked()
"""

# l5kit's collisions of the parked ego: (frame, kind, track).
PARKED_HITS = ([(8, "rear", 1)] + [(t, "side", 1) for t in range(9, 14)] + [(14, "front", 1)]
               + [(34, "rear", 23), (35, "rear", 23), (36, "front", 23), (37, "front", 23)])


def test_parked_and_constant_velocity_reproduce_l5kit(pytester):
    pytester.mkdir("parked")
    (pytester.path / "parked" / "conftest.py").write_text(PARKED)
    (pytester.path / "parked" / "l5kit.scenario.yaml").write_text(
        L5KIT_SETUP.format(name="parked", data=REAL, model="log_replay", extra=""))
    pytester.makefile(".scenario.yaml", cv=L5KIT_SETUP.format(
        name="cv", data=REAL, model="constant_velocity", extra="  ConstantVelocity: {FirstStep: logged_next}\n"))
    pytester.runpytest("-q").assert_outcomes(passed=1, failed=1)
    out = pytester.path / "driveeval-results"
    records = {r["nodeid"].split("/")[0]: r for r in json.loads((out / "summary.json").read_text())["results"]}

    parked = records["parked"]
    assert parked["status"] == "failed"
    detail = json.loads((out / parked["artefacts"]["result"]).read_text())["scenes"][0]
    assert [(c["frame"], c["kind"], c["track_id"]) for c in detail["collisions"]] == PARKED_HITS

    cv = records["cv.scenario.yaml::closed_loop[real]"]
    assert cv["status"] == "passed"
    (scene,) = cv["details"]["scenes"]
    assert (scene["front"], scene["side"], scene["rear"], scene["steps"]) == (0, 0, 0, 248)
    assert scene["max_displacement"] == pytest.approx(31.934, abs=5e-4)
    assert scene["mean_displacement"] == pytest.approx(21.262, abs=5e-4)
    assert scene["max_distance_to_reference"] == pytest.approx(2.7726, abs=5e-5)
    assert scene["mean_distance_to_reference"] == pytest.approx(1.2981, abs=5e-5)


@pytest.fixture(scope="module")
def real():
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset

    return L5Dataset.open(REAL)


def _cv(real, first_step="logged_next", agents="l5kit"):
    from pytest_driveeval.policies.baselines import ConstantVelocityPolicy
    from pytest_driveeval.sim.logreplay import ReplayedAgents
    from pytest_driveeval.usecases.closed_loop.evaluate import unroll_scenes

    rule = ReplayedAgents(labels=["CAR"], within_at_start=50.0) if agents == "l5kit" else None
    return unroll_scenes(real, ConstantVelocityPolicy(first_step=first_step), [0], drift_threshold=None,
                         freeze_on_collision=False, agents=rule)


def test_each_l5kit_option_is_needed_for_its_figures(real):
    from pytest_driveeval.usecases.closed_loop.evaluate import (
        reference_distance,
        scene_figures,
    )

    l5kit = _cv(real)
    measured = np.flatnonzero(~np.isnan(reference_distance(l5kit, 0, "l5kit")))
    assert (measured[0], measured[-1], measured.size) == (0, 197, 198)  # int(0.8 * 248) frames
    # Every frame counts on the polyline, and the last ones run past the end of the logged path.
    assert scene_figures(l5kit, 0)["max_distance_to_reference"] > 30.0
    assert scene_figures(_cv(real, first_step="heading"), 0, "l5kit")["max_distance_to_reference"] > 3.0
    everyone = _cv(real, agents="all")
    assert (everyone.result.collision_kind[0] > 0).sum() > 0  # other agents' rows would be hit


def test_with_every_agent_the_partner_is_the_first_overlapping_row(real):
    # The case: 35 collision frames, 7 of which had another partner
    # when the lowest packed column (tracks sorted by id) was taken.
    from pytest_driveeval.geometry import oriented_boxes_overlap
    from pytest_driveeval.sim.logreplay import EGO_EXTENT

    r = _cv(real, agents="all").result
    scene = real.scene(0)
    frames = np.flatnonzero(r.collision_kind[0])
    assert frames.size == 35
    for t in frames:
        rows = scene.agents_of_frame(t)
        hit = oriented_boxes_overlap(r.driven_xy[0, t], r.driven_yaw[0, t], EGO_EXTENT[:2], rows["centroid"],
                                     rows["yaw"].astype(float), rows["extent"][:, :2].astype(float))
        assert r.collision_track_id[0, t] == rows["track_id"][np.argmax(hit)], t
