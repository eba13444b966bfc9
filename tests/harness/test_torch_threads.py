"""Every scenario item's model runs on one torch intra-op thread (two xdist workers on two cores
otherwise spin against each other: 90 s instead of 12 s for the demo's 16 generated scenes), and
the rest of the session keeps torch's own setting."""
from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")

from conftest import REPO_ROOT  # noqa: E402

REAL = REPO_ROOT / "fixtures" / "l5kit" / "single_scene.zarr"

MODEL = """\
import json, torch
from pytest_driveeval.policies.baselines import ReplayLogPolicy

class Counting(ReplayLogPolicy):
    seen = set()

    def forward(self, batch):
        Counting.seen.add(torch.get_num_threads())
        with open("threads.json", "w") as f:
            json.dump(sorted(Counting.seen), f)
        return super().forward(batch)
"""

CONFTEST = """\
import pytest, torch, counting

torch.set_num_threads(2)

@pytest.fixture
def driveeval_model():
    return counting.Counting()
"""

SCENARIO = f"""\
ScenarioFormatVersion: 3.0.0
ScenarioName: threads
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - logs:
        Path: {REAL}
  Unroll:
    StartFrame: 10
    Steps: 5
  Conditions:
    Collisions: {{Front: 0, Side: 0, Rear: 0, AtFaultOnly: true}}
"""

AFTER = """\
import torch

def test_zz_after_the_item():
    assert torch.get_num_threads() == 2
"""


def test_the_model_runs_on_one_thread_and_the_session_keeps_its_setting(pytester):
    pytester.makepyfile(counting=MODEL, test_zz_after=AFTER)
    pytester.makeconftest(CONFTEST)
    pytester.makefile(".scenario.yaml", threads=SCENARIO)
    # in a fresh process: the thread count is the process's, and this suite's own setting must not leak in
    result = pytester.runpytest_subprocess("-p", "no:randomly", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=2)
    assert json.loads((pytester.path / "threads.json").read_text()) == [1]
