"""Every item has a time limit unless told otherwise: a sleeping policy, a runaway
``max_steps`` or ``Examples`` fail their own item with a located message, the items beside
them pass, and ``0`` turns the limit off."""
from __future__ import annotations

import pytest

from pytest_driveeval.harness import settings

pytest.importorskip("torch")

BENCH = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
{extra}Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint:
    Name: merging
    Params: {{max_steps: {steps}}}
  Episodes: 3
  Policies:
    mine: {policy}
{rest}"""

POLICIES = """\
import time

import numpy as np


def sleeps():
    def act(observations):
        time.sleep(3600)
    return act


def naps():
    def act(observations):
        time.sleep(0.5)
        return np.zeros((len(observations), 2))
    return act


def brakes():
    # stands still on the merge lane, before its end: no goal, no collision, no leaving the road
    return lambda observations: np.tile(np.array([-5.0, 0.0]), (len(observations), 1))
"""

SEARCH = "  Perturbation:\n    Lateral: [-0.5, 0.5]\n    Examples: 1000000000\n"


def bench(name: str, policy: str = "constant", steps: int = 200, extra: str = "", rest: str = "") -> str:
    return BENCH.format(name=name, policy=policy, steps=steps, extra=extra, rest=rest)


@pytest.fixture
def bench_dir(pytester, monkeypatch):
    pytester.makepyfile(policies=POLICIES)
    pytester.syspathinsert()
    # The default itself (half an hour) is what a user gets; a few seconds here keep the test short.
    # Not fewer: on a loaded machine the search needs more than two to reach the case that the
    # message must locate.
    monkeypatch.setattr(settings, "DEFAULT_TIME_LIMIT", 4.0)
    return pytester


def test_without_any_limit_set_the_default_ends_hangs_and_runaway_sizes(bench_dir):
    # the good item's own generous limit: on a loaded machine it may need more than the test's default
    bench_dir.makefile(".scenario.yaml", good=bench("good", extra="TimeLimit: 600\n"),
                       sleeps=bench("sleeps", policy="policies:sleeps"),
                       steps=bench("steps", policy="policies:brakes", steps=1_000_000_000),
                       search=bench("search", policy="idm_expert", rest=SEARCH))
    result = bench_dir.runpytest("-q", "-p", "no:randomly", "--driveeval-allow-scenario-code")
    result.assert_outcomes(passed=1, failed=3)
    default = "(the default of 4 s; set TimeLimit in the scenario or --driveeval-time-limit / driveeval_time_limit, 0 for none)"
    result.stdout.fnmatch_lines_random([
        # where the limit strikes: in the model call that never returns, or, on a loaded machine, before step 0's
        # call began (test_time_limit.py checks the model call's wording with a limit that leaves room)
        f"*TimeLimitExceeded: scenario 'sleeps' (policy_benchmark[[]mine[]]): time limit of 4 s exceeded*at policy mine, "
        f"step 0 {default}",
        f"*TimeLimitExceeded: scenario 'steps' (policy_benchmark[[]mine[]]): time limit of 4 s exceeded*at policy mine, "
        f"step * {default}",
        f"*TimeLimitExceeded: scenario 'search' (policy_benchmark[[]mine[]]): time limit of 4 s exceeded at * {default}",
    ])
    assert "Traceback" not in result.stdout.str()


def test_a_scenario_time_limit_is_named_by_its_line(bench_dir):
    bench_dir.makefile(".scenario.yaml", steps=bench("steps", policy="policies:brakes", steps=1_000_000_000,
                                                     extra="Marks: [slow]\nTimeLimit: 2\n"))
    result = bench_dir.runpytest("-q", "--driveeval-allow-scenario-code")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*time limit of 2 s exceeded*at policy mine, step * (TimeLimit at steps.scenario.yaml:4)"])


@pytest.mark.parametrize("how", ["option", "ini", "scenario"])
def test_zero_turns_the_limit_off(bench_dir, monkeypatch, how):
    # three policy calls of 0.5 s each at least: above a default of 1 s however fast the machine,
    # and no limit stops them
    monkeypatch.setattr(settings, "DEFAULT_TIME_LIMIT", 1.0)
    extra = "TimeLimit: 0\n" if how == "scenario" else ""
    bench_dir.makefile(".scenario.yaml", naps=bench("naps", policy="policies:naps", steps=3, extra=extra))
    args = ["--driveeval-time-limit", "0"] if how == "option" else []
    if how == "ini":
        bench_dir.makeini("[pytest]\ndriveeval_time_limit = 0\n")
    result = bench_dir.runpytest("-q", "--driveeval-allow-scenario-code", *args)
    result.assert_outcomes(passed=1)


def test_the_default_is_half_an_hour_and_documented():
    assert settings.DEFAULT_TIME_LIMIT == 1800.0
    from conftest import REPO_ROOT

    assert "default 1800, half an hour per item" in (REPO_ROOT / "docs" / "options.md").read_text()


@pytest.mark.parametrize("args, line", [
    ([], "driveeval: each scenario item may run 1800 s (the default time limit); --driveeval-time-limit / "
         "driveeval_time_limit SECONDS sets another, 0: none; a scenario's TimeLimit key sets its own"),
    (["--driveeval-time-limit", "90"], "driveeval: each scenario item may run 90 s (--driveeval-time-limit / "
                                       "driveeval_time_limit); a scenario's TimeLimit key sets its own, 0: none"),
    (["--driveeval-time-limit", "0"], "driveeval: no time limit on scenario items (--driveeval-time-limit / "
                                      "driveeval_time_limit is 0); a scenario's TimeLimit key sets its own"),
])
def test_the_session_header_says_which_time_limit_applies_and_how_to_change_it(pytester, args, line):
    result = pytester.runpytest(*args)
    result.stdout.fnmatch_lines([line])
    header = result.stdout.lines.index(line)
    assert header < next(i for i, text in enumerate(result.stdout.lines) if text.startswith("collected"))
