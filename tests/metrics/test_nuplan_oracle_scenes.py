"""nuplan-devkit's score of the drives a closed-loop run reported, on every real ScenarioNet scene in the
shared data, against the score that run wrote to summary.json (benchmarks/nuplan_oracle/oracle_scenes.py).

A scenario file drives every scene by log replay and by constant velocity (StartFrame 10, 80 steps: nuPlan's
protocol), in a pytest run of its own; then the oracle, in its own venv, rebuilds each scene's map, agents and
ego states from the raw file and the driven poses, and compares term by term.  Skipped where the shared data
or the oracle's venv is absent (``python benchmarks/nuplan_oracle/oracle_venv.py`` builds the venv).
"""
import json
import re
import subprocess

import pytest

from conftest import NO_HYPOTHESIS_PLUGIN, REPO_ROOT, fresh_pytest_run, module_at

pytestmark = pytest.mark.slow  # two closed-loop items over six scenes, then nuplan-devkit: a few minutes

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {policy}
Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - scenarionet:
        Path: {data}
  Model: {policy}
  Unroll:
    StartFrame: 10
    Steps: 80
  Conditions:
    Score: {{AtLeast: 0.0}}
  Artefacts: {{Charts: false, Animations: none}}
"""
POLICIES = ("log_replay", "constant_velocity")
ORACLE = REPO_ROOT / "benchmarks" / "nuplan_oracle"


def _oracle_venv():
    return module_at(ORACLE / "oracle_venv.py", "nuplan_oracle_venv")


@pytest.fixture(scope="module")
def oracle_run(shared_data, tmp_path_factory):
    """(the run's summary.json, the oracle's exit status, its printout)."""
    python = _oracle_venv().existing_python()
    if python is None:
        pytest.skip("nuplan-devkit oracle venv absent: `python benchmarks/nuplan_oracle/oracle_venv.py` builds it "
                    "(about 2 minutes) in ~/.cache/driveeval-bench/nuplan")
    data = shared_data / "scenarionet"
    folder = tmp_path_factory.mktemp("oracle_run")
    for policy in POLICIES:
        (folder / f"{policy}.scenario.yaml").write_text(SCENARIO.format(policy=policy, data=data))
    run = fresh_pytest_run(folder, "-q", "-p", "no:cacheprovider", "-p", "no:randomly", "-p", "no:xdist",
                           *NO_HYPOTHESIS_PLUGIN, timeout=1800)  # scenario items only: no @given test
    summary = folder / "driveeval-results" / "summary.json"
    assert summary.is_file(), run.stdout[-3000:] + run.stderr[-3000:]
    oracle = subprocess.run([str(python), str(ORACLE / "oracle_scenes.py"),
                             str(summary), "--data", str(data)], capture_output=True, text=True, timeout=1800)
    print(oracle.stdout)  # the agreement tables, shown with -s or on failure
    return json.loads(summary.read_text()), oracle.returncode, oracle.stdout + oracle.stderr


def _scenes(summary) -> list[str]:
    return [f"{r['scenario']}/scene{s['scene']}" for r in summary["results"] for s in r["details"]["scenes"]]


def test_the_oracle_scores_every_scene_the_run_scored(oracle_run, shared_data):
    summary, status, printed = oracle_run
    scenes = _scenes(summary)
    files = [p for p in (shared_data / "scenarionet").rglob("*.pkl") if p.name not in
             {"dataset_summary.pkl", "dataset_mapping.pkl"}]
    assert len(scenes) == len(POLICIES) * len(files)
    assert "FAILED " not in printed, printed[-4000:]
    assert f"{len(scenes)} scene(s) compared" in printed, printed[-4000:]
    for scene in scenes:
        assert f"#### {scene}\n" in printed
    # The exit status says whether anything differs, and each difference is printed
    disagreements = re.findall(r"^DISAGREES (.*)$", printed, flags=re.M)
    assert status == (1 if disagreements else 0), printed[-4000:]


def test_on_log_replay_every_term_and_score_agrees(oracle_run):
    """The ego is the expert: whatever the constant-velocity drives still show, a log replay agrees everywhere."""
    _, _, printed = oracle_run
    off = [line for line in re.findall(r"^DISAGREES (.*)$", printed, flags=re.M) if line.startswith("log_replay/")]
    assert off == []


def test_every_term_and_score_agrees_within_1e_6(oracle_run):
    _, status, printed = oracle_run
    assert status == 0, "\n".join(re.findall(r"^DISAGREES .*$", printed, flags=re.M))
