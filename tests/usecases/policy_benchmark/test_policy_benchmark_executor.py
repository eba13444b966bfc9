"""The Executor section and --driveeval-executor in policy_benchmark, without a Ray cluster:
which executor an item gets, chunked episodes merged as one batch, what the report says,
and the errors.  tests/usecases/policy_benchmark/test_policy_benchmark_ray.py runs them on one."""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pytest_driveeval.execute import ExecutorSpec, executor_from_option
from pytest_driveeval.core.outcome import PASSED, Outcome
from pytest_driveeval.report.attachments import executor_lines
from pytest_driveeval.usecases.executor import chunked_executor

pytest.importorskip("torch")
pytest.importorskip("scipy")

REPO = Path(__file__).resolve().parents[3]
GNN = REPO / "fixtures" / "models" / "gnn_actor_merging.pt2"

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: bench
Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint: {{Name: merging}}
  Episodes: 6
  Policies:
    mine: constant
  Judged: [mine]
{executor}"""


def session(text: str | None):
    return SimpleNamespace(executor=executor_from_option(text) if text else None)


def test_the_session_option_replaces_the_keys_it_gives_and_keeps_the_scenarios_others():
    scenario = ExecutorSpec(Kind="ray", Address="ray://head:10001", ChunkSize=16, Retries=1)
    assert chunked_executor(session(None), None) is None, "nothing asked: the plain local path"
    assert chunked_executor(session(None), scenario) == scenario
    assert chunked_executor(session(None), ExecutorSpec(Kind="local")) is None
    # a ChunkSize with Kind local: the chunks a Ray run would run, here, to reproduce it
    assert chunked_executor(session(None), ExecutorSpec(Kind="local", ChunkSize=4)).ChunkSize == 4
    assert chunked_executor(session("local"), ExecutorSpec(Kind="ray")) is None, "the session runs it all here"
    assert chunked_executor(session("local"), scenario).is_local
    merged = chunked_executor(session("{Address: auto, ChunkSize: 2}"), scenario)
    assert (merged.Kind, merged.Address, merged.ChunkSize, merged.Retries) == ("ray", "auto", 2, 1)
    kept = chunked_executor(session("ray"), ExecutorSpec(ChunkSize=8))
    assert (kept.Kind, kept.ChunkSize, kept.Address) == ("ray", 8, None)
    assert chunked_executor(session("{Kind: ray, MaxInFlight: 3}"), None).MaxInFlight == 3


def test_chunks_of_seeds_merge_into_the_arrays_of_one_batch():
    from pytest_driveeval.policies.loading import load_model
    from pytest_driveeval.sim.blueprints import make_blueprint
    from pytest_driveeval.usecases.policy_benchmark.chunked import PolicySource, run_policies_chunked
    from pytest_driveeval.usecases.policy_benchmark.evaluate import run_policy, seeds_for

    blueprint = make_blueprint("merging")
    seeds, strata = seeds_for(3, 13, 4)
    drawn = []
    ctx = SimpleNamespace(case=SimpleNamespace(name="bench[gnn]"),
                          progress=lambda label: lambda done, total: drawn.append((label, done, total)))
    sources = {"gnn": PolicySource(GNN.name, str(GNN.parent)), "random": PolicySource("random", None)}
    # the local path of run_chunks, chunk after chunk in this process: 13 seeds in chunks of 5
    runs, chunk_run, described = run_policies_chunked(ctx, ExecutorSpec(ChunkSize=5), blueprint, {}, seeds, strata,
                                                      sources, 12)
    from pytest_driveeval.usecases.policy_benchmark import baseline

    whole = {"gnn": run_policy(blueprint, seeds, load_model(str(GNN)), "gnn", strata=strata),
             "random": run_policy(blueprint, seeds, baseline("random"), "random", strata=strata)}
    for name, run in runs.items():
        for field in ("seeds", "strata", "outcome", "returns", "steps"):
            assert np.array_equal(getattr(run, field), getattr(whole[name], field)), (name, field)
            assert getattr(run, field).dtype == getattr(whole[name], field).dtype
        assert run.figures() == whole[name].figures()
    assert described == ["gnn seeds 3..7", "gnn seeds 8..12", "gnn seeds 13..15",
                         "random seeds 3..7", "random seeds 8..12", "random seeds 13..15"]
    assert len(chunk_run.placements) == 6
    assert drawn == [("chunks", done, 6) for done in range(7)]


def test_the_report_says_where_each_chunk_ran():
    outcome = Outcome("policy_benchmark", PASSED, "fine", details={"executor": {
        "executor": "ray (auto)", "summary": "2 chunks on ray (auto) in 1.0 s, 2 node(s) (a/1234abcd: 1, b/9876fedc: 1)",
        "chunks": [{"chunk": 0, "work": "gnn seeds 0..3", "host": "a", "node": "1234abcd99", "pid": 7, "attempts": 1,
                    "seconds": 0.4},
                   {"chunk": 1, "work": "gnn seeds 4..7", "host": "b", "node": "9876fedc99", "pid": 8, "attempts": 2,
                    "seconds": 0.5}]}})
    assert executor_lines(outcome) == [
        "executor: 2 chunks on ray (auto) in 1.0 s, 2 node(s) (a/1234abcd: 1, b/9876fedc: 1)",
        "chunk 0 (gnn seeds 0..3): a node 1234abcd pid 7, 0.4 s",
        "chunk 1 (gnn seeds 4..7): b node 9876fedc pid 8, 2 attempts, 0.5 s"]
    assert executor_lines(Outcome("policy_benchmark", PASSED, "fine")) == []


def test_a_bad_session_option_stops_the_session_naming_the_option(pytester):
    pytester.makefile(".scenario.yaml", bench=SCENARIO.format(executor=""))
    result = pytester.runpytest("--driveeval-executor", "{Kind: dask}")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*--driveeval-executor / driveeval_executor: executor option*Kind*"])
    pytester.makeini("[pytest]\ndriveeval_executor = rays\n")
    result = pytester.runpytest()
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*executor option 'rays' is neither local, ray nor a YAML mapping*"])


def test_a_mistake_in_the_executor_section_is_located(pytester):
    pytester.makefile(".scenario.yaml", bench=SCENARIO.format(executor="  Executor: {Kind: ray, Chunksize: 8}\n"))
    result = pytester.runpytest("-q")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*bench.scenario.yaml:11: Evaluation.Executor.Chunksize: unknown key*ChunkSize*"])


def test_local_chunks_give_the_plain_runs_outcome_and_say_where_they_ran(pytester):
    pytester.makefile(".scenario.yaml", bench=SCENARIO.format(executor="  Executor: {Kind: local, ChunkSize: 4}\n"))
    pytester.runpytest("-q", "--driveeval-output", "chunked").assert_outcomes(passed=1)
    pytester.makefile(".scenario.yaml", bench=SCENARIO.format(executor="  Executor: {Kind: local}\n"))
    pytester.runpytest("-q", "--driveeval-output", "plain").assert_outcomes(passed=1)
    (chunked,), (plain,) = (json.loads((pytester.path / out / "summary.json").read_text())["results"]
                            for out in ("chunked", "plain"))
    assert chunked["figures"] == plain["figures"] and chunked["findings"] == plain["findings"]
    assert "executor" not in plain["details"]
    where = chunked["details"].pop("executor")
    assert chunked["details"] == plain["details"]
    assert [c["work"] for c in where["chunks"]] == ["mine seeds 0..3", "mine seeds 4..5"]
    assert {c["node"] for c in where["chunks"]} == {"local"} and where["summary"].startswith("2 chunks on local")


CONFTEST = """\
import pytest
from pytest_driveeval.policies.control_baselines import ConstantAction


@pytest.fixture
def driveeval_model():
    return ConstantAction()
"""


def test_a_model_from_a_conftest_fixture_stays_local_and_the_report_says_why(pytester):
    # A live object has no loading spec a worker could use; the item never reaches for Ray.
    pytester.makeconftest(CONFTEST)
    pytester.makefile(".scenario.yaml", bench=SCENARIO.format(
        executor="  Executor: {Kind: ray, Address: 'ray://nowhere.invalid:10001'}\n"))
    pytester.runpytest("-q").assert_outcomes(passed=1)
    record, = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())["results"]
    assert record["details"]["executor"]["executor"] == "local"
    assert "driveeval_model fixture's object" in record["details"]["executor"]["summary"]
    assert record["figures"]["episodes"] == 6


CODE_BASELINE = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: bench
Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint: {Name: merging}
  Episodes: 4
  Policies:
    mine: constant
    other: "builtins:print"
  Judged: [mine]
  Conditions:
    Beats:
      - {Baseline: other, Metric: goal_rate}
  Executor: {Kind: local, ChunkSize: 2}
"""


def test_a_compared_policy_that_names_code_is_refused_in_chunks_too(pytester):
    """The chunks load the compared policy from its spec on the workers: it must pass the same
    opt-in check as when it is loaded here, not run ``builtins:print`` there."""
    pytester.makefile(".scenario.yaml", bench=CODE_BASELINE)
    result = pytester.runpytest("-q", "-k", "mine")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*bench.scenario.yaml:10: Model 'builtins:print' would run Python code*"])
    result.stdout.no_fnmatch_line("*returned a NoneType*")
