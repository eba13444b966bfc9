"""A model that never returns fails its own item, named by scene and step; the rest runs."""
from __future__ import annotations

import shutil

import pytest
from conftest import GAIN_SCENARIO, NO_HYPOTHESIS_PLUGIN, REPO_ROOT, save_torchscript

torch = pytest.importorskip("torch")

from test_closed_loop_usecase import scenario  # noqa: E402

REAL = REPO_ROOT / "fixtures" / "l5kit" / "single_scene.zarr"

SLEEPY = """\
import time
import torch


class Sleepy(torch.nn.Module):
    def forward(self, batch):
        time.sleep(3600)


def sleepy():
    return Sleepy()


def spin(x):
    while True:
        pass
"""


class Spin(torch.nn.Module):
    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        x = batch["history_positions"]
        while bool(x.sum() > -1.0e30):  # native code that never returns, holding no Python frame
            x = x + 1.0
        return {"positions": x, "yaws": x}


@pytest.fixture
def cl(pytester):
    shutil.copytree(REAL, pytester.path / "real.zarr")
    pytester.path.joinpath("sleepy.py").write_text(SLEEPY)
    pytester.syspathinsert()
    return pytester


def with_limit(text: str, seconds: float) -> str:
    return text.replace("Evaluation:", f"TimeLimit: {seconds}\nEvaluation:", 1)


def test_a_python_policy_that_never_returns_fails_its_item_naming_scene_and_step(cl):
    cl.makefile(".scenario.yaml", good=scenario(name="good", unroll="    StartFrame: 10\n    Steps: 5"),
                hangs=with_limit(scenario(name="hangs"), 1.5))
    cl.makeconftest("import pytest\nimport sleepy\n\n"
                    "@pytest.fixture\ndef driveeval_model(driveeval_scenario):\n"
                    "    if driveeval_scenario.name == 'hangs':\n        return sleepy.sleepy()\n"
                    "    from pytest_driveeval.policies.baselines import ReplayLogPolicy\n"
                    "    return ReplayLogPolicy()\n")
    result = cl.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(["*TimeLimitExceeded: scenario 'hangs' (closed_loop[[]logs[]]): time limit of 1.5 s "
                                 "exceeded in a model call that did not return at scenes [[]0[]], frame 10, step 0 "
                                 "(TimeLimit at hangs.scenario.yaml:3)"])
    assert "Traceback" not in result.stdout.str()


@pytest.mark.parametrize("xdist", [[], ["-n", "2"]], ids=["plain", "xdist"])
def test_a_torchscript_loop_is_left_behind_and_the_session_goes_on(cl, xdist):
    save_torchscript(Spin(), cl.path / "spin.pt")
    cl.makefile(".scenario.yaml", good=scenario(name="good", unroll="    StartFrame: 10\n    Steps: 5"),
                spins=with_limit(scenario(name="spins", model="spin.pt"), 2))
    # In its own process: the abandoned loop keeps a core busy until that process ends.
    result = cl.runpytest_subprocess("-q", "-p", "no:randomly", *NO_HYPOTHESIS_PLUGIN, *xdist, timeout=180)
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(["*TimeLimitExceeded: scenario 'spins'*time limit of 2 s exceeded in a model call "
                                 "that did not return at scenes [[]0[]], frame 10, step 0*"])
    # The loop still runs at exit; left to Python's finalization its thread would abort the
    # process (std::terminate: SIGABRT, 134).  The session ends with pytest's own code instead.
    assert result.ret == pytest.ExitCode.TESTS_FAILED
    if xdist:
        # A worker's own exit code is not the session's: the message named 0 in sessions that exit 1.
        result.stderr.fnmatch_lines(["pytest-driveeval: 1 model call(s) that never returned still run *; xdist "
                                     "worker gw? leaves without waiting for them (the session's exit status is the "
                                     "controller's)"])
        assert "exit code" not in result.stderr.str()
    else:
        result.stderr.fnmatch_lines(["pytest-driveeval: 1 model call(s) that never returned still run *; leaving "
                                     "with pytest's exit code 1 without waiting"])
    # On a line of its own, not glued to the end of pytest's "[100%]" on a shared terminal: it begins with a newline.
    at = next(i for i, line in enumerate(result.stderr.lines) if line.startswith("pytest-driveeval: 1 model"))
    assert at > 0 and result.stderr.lines[at - 1] == ""
    assert "terminate called" not in result.stderr.str()


def test_python_code_outside_a_model_call_is_interrupted_too(pytester):
    pytester.makepyfile(gain_usecase=__import__("conftest").GAIN_USECASE, mymodels="def forever(x):\n"
                        "    while True:\n        pass\n")
    pytester.makeconftest("import gain_usecase\n")
    pytester.syspathinsert()
    pytester.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"))
    pytester.makeini("[pytest]\ndriveeval_time_limit = 1\n")
    result = pytester.runpytest("-q", "--driveeval-model", "mymodels:forever")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*TimeLimitExceeded: scenario 'a' (gain): time limit of 1 s exceeded "
                                 "(--driveeval-time-limit / driveeval_time_limit)"])


@pytest.mark.parametrize("value", ["soon", "-3", "inf", "nan"])
def test_a_time_limit_that_is_not_a_number_of_seconds_is_a_usage_error(pytester, value):
    result = pytester.runpytest("--driveeval-time-limit", value)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines([f"*driveeval time limit must be a number of seconds >= 0 (0: none), got '{value}'*"])
