"""Sizes that cannot fit in memory are refused at their line when the scenario loads, before
anything is allocated; the other scenarios of the session still collect and run."""
from __future__ import annotations

import pytest

from conftest import NO_HYPOTHESIS_PLUGIN, POLICY_BENCHMARK_HEAD, REPO_ROOT
from pytest_driveeval.core.usecase import memory_budget, set_memory_budget

pytest.importorskip("torch")

BENCH = POLICY_BENCHMARK_HEAD + """\
  Blueprint:
    Name: merging
    Params: {{length: {length}, max_steps: {steps}}}
  Episodes: {episodes}
  AgentLimit: {agents}
  Policies:
    mine: constant
"""

CLOSED_LOOP = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: raster
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - logs: {Path: real.zarr}
  Model: constant_velocity
  Unroll:
    Inputs:
      Kind: raster
      MapType: box_debug
      RasterSize: [100000, 100000]
"""

SPRAY = (REPO_ROOT / "scenario_tests" / "obstacle_segmentation" / "robustness" / "spray.scenario.yaml").read_text()

BUDGET = ("more than the * an item may use (half this machine's memory; --driveeval-memory-limit / "
          "driveeval_memory_limit sets another, 0: no check)")


def bench(name, length=300.0, episodes=4, agents=12, steps=200):
    return BENCH.format(name=name, length=length, episodes=episodes, agents=agents, steps=steps)


@pytest.fixture(autouse=True)
def default_budget():
    # the plugin sets the budget per process from the options; leave the default for the next test
    yield
    set_memory_budget(None)


def test_each_size_that_cannot_fit_fails_alone_at_its_line_and_the_good_scenario_runs(pytester):
    # the good item runs: a few steps show that, the sizes refused beside it are what is checked
    pytester.makefile(".scenario.yaml", good=bench("good", steps=10), episodes=bench("episodes", episodes=1_000_000_000),
                      agents=bench("agents", agents=100_000), length=bench("length", length="1.0e+9"),
                      raster=CLOSED_LOOP,
                      ghosts=SPRAY.replace("GhostPoints: [0, 40]", "GhostPoints: [0, 1000000000]"))
    # In a subprocess with a timeout: an allocation that slipped through would take the machine's memory.
    result = pytester.runpytest_subprocess("-q", "-p", "no:randomly", *NO_HYPOTHESIS_PLUGIN, timeout=240)
    result.assert_outcomes(passed=1, failed=5)
    result.stdout.fnmatch_lines_random([
        "  episodes.scenario.yaml:9: Evaluation.Episodes: 1000000000 episodes of 12 agents stepped together would "
        f"need about * TiB of memory, {BUDGET}",
        "  agents.scenario.yaml:10: Evaluation.AgentLimit: one episode of 100000 agents (its graph observation grows "
        f"with the agents squared) would need about * GiB of memory, {BUDGET}",
        "  length.scenario.yaml:8: Evaluation.Blueprint.Params.length: the road's drivable area (1e+09 m x 17 m) would "
        "be a raster of 1.7e+12 cells at 0.1 m, above the limit of 1.07e+09 cells (1 GiB)",
        "  raster.scenario.yaml:13: Evaluation.Unroll.Inputs.RasterSize: one scene's 100000 x 100000 raster of 22 "
        f"channels would need about * TiB of memory, {BUDGET}",
        "  ghosts.scenario.yaml:39: Evaluation.Perturbation.GhostPoints: 20 perturbed clouds of up to 1000000000 ghost "
        f"points each would need about * TiB of memory, {BUDGET}",
    ])
    assert "Traceback" not in result.stdout.str() and "MemoryError" not in result.stdout.str()


def test_the_budget_follows_the_option_and_zero_turns_the_check_off(pytester):
    # 4 episodes of 1000 agents: about 185 MiB, within the default budget, not within 0.1 GiB
    pytester.makefile(".scenario.yaml", big=bench("big", agents=1000))
    result = pytester.runpytest("-q", "--driveeval-memory-limit", "0.1")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*big.scenario.yaml:9: Evaluation.Episodes: 4 episodes of 1000 agents stepped "
                                 "together would need about 185 MiB of memory, more than the 102 MiB an item may use "
                                 "(--driveeval-memory-limit / driveeval_memory_limit)"])
    for args in ([], ["--driveeval-memory-limit", "0"]):
        result = pytester.runpytest("-q", "--collect-only", *args)
        result.stdout.fnmatch_lines(["*big.scenario.yaml::policy_benchmark[[]mine[]]*"])
        assert "invalid scenario" not in result.stdout.str()


@pytest.mark.parametrize("value", ["lots", "-1", "inf"])
def test_a_memory_limit_that_is_not_a_size_is_a_usage_error(pytester, value):
    result = pytester.runpytest("--driveeval-memory-limit", value)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines([f"*driveeval memory limit must be a number of GiB >= 0 (0: no check), got '{value}'*"])


def test_the_default_budget_is_half_the_machines_memory():
    import os

    budget, source = memory_budget()
    assert budget == os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2
    assert source.startswith("half this machine's memory")


def test_running_out_of_memory_while_loading_fails_that_file_alone(pytester):
    # a use case whose validation allocates what no check foresaw
    pytester.makeconftest('''
from pydantic import model_validator
from pytest_driveeval.core.usecase import ConditionsModel, UseCase, register_usecase


class Greedy(ConditionsModel):
    Size: int = 1

    @model_validator(mode="after")
    def _allocate(self):
        if self.Size > 1:
            raise MemoryError()
        return self


@register_usecase
class GreedyUseCase(UseCase):
    name = "greedy"
    config_model = Greedy

    def run(self, config, ctx):
        from pytest_driveeval.core.outcome import Outcome, PASSED
        return Outcome(use_case="greedy", verdict=PASSED, summary="fine")
''')
    scenario = ("ScenarioFormatVersion: 3.0.0\nScenarioName: {name}\nEvaluation:\n  UseCaseName: greedy\n"
                "  UseCaseFormatVersion: 0.1.0\n  Size: {size}\n")
    pytester.makefile(".scenario.yaml", big=scenario.format(name="big", size=10 ** 12),
                      small=scenario.format(name="small", size=1))
    result = pytester.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(["  big.scenario.yaml: loading it ran out of memory (MemoryError): a size in it is too "
                                 "large for this machine"])


UNROLL = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - logs: {{Path: {data}}}
  Model: constant_velocity
  Unroll:
    Scenes: [0]
    Steps: 5
    {key}: {value}
"""


def test_history_future_and_agent_counts_that_cannot_fit_fail_alone_at_their_line(pytester):
    """One scene's inputs are built in one call per step, which --driveeval-time-limit cannot
    interrupt: a count whose inputs cannot fit is refused when the scenario loads."""
    data = REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr"
    pytester.makefile(".scenario.yaml", **{
        name: UNROLL.format(name=name, data=data, key=key, value=value) for name, key, value in (
            ("good", "HistoryFrames", 10), ("history", "HistoryFrames", 1_000_000_000),
            ("future", "FutureFrames", 10_000_000_000), ("agents", "MaxAgents", 1_000_000_000))})
    result = pytester.runpytest_subprocess("-q", "-p", "no:randomly", *NO_HYPOTHESIS_PLUGIN, timeout=240)
    result.assert_outcomes(passed=1, failed=3)
    result.stdout.fnmatch_lines_random([
        "  history.scenario.yaml:12: Evaluation.Unroll.HistoryFrames: one scene's policy inputs per step (1000000000 "
        f"history frames of 30 agents, 12 future frames) would need about * TiB of memory, {BUDGET}",
        "  future.scenario.yaml:12: Evaluation.Unroll.FutureFrames: one scene's policy inputs per step (10 history "
        f"frames of 30 agents, 10000000000 future frames) would need about * TiB of memory, {BUDGET}",
        "  agents.scenario.yaml:12: Evaluation.Unroll.MaxAgents: one scene's policy inputs per step (10 history "
        f"frames of 1000000000 agents, 12 future frames) would need about * TiB of memory, {BUDGET}",
    ])
    assert "Traceback" not in result.stdout.str() and "MemoryError" not in result.stdout.str()
