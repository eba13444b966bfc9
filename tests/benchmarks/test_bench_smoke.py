"""Every benchmark script runs, start to end, at its ``--smoke`` size: tiny inputs, reference venvs
and clusters skipped, the full code path otherwise.  A script that rots (a changed signature, a
renamed option) fails here rather than on the day someone wants its figures.

Each script must print its headline figure; the test reads the number from it.  The figures of a
smoke run mean nothing and are never compared with a target.
"""
from __future__ import annotations

import importlib.util
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO_ROOT

BENCHMARKS = REPO_ROOT / "benchmarks"
NUMBER = r"([0-9][0-9,]*(?:\.[0-9]+)?)"

# script: (the line that carries its figure, with the number as group 1; modules it needs beyond the core install)
SMOKED = {
    "bench_baseline_overhead.py": (rf"^comparison's own cost: {NUMBER} % of the session", ("torch",)),
    "bench_birdseye_map.py": (rf"^map / no map: {NUMBER}x", ()),
    "bench_closed_loop_search.py": (rf"^ratio: {NUMBER}x \(target", ("torch", "hypothesis")),
    "bench_commonroad_expert.py": (rf"^expert: lowest goal rate {NUMBER} % over \d+ reachable problem", ("torch",)),
    "bench_commonroad_step.py": (rf"^commonroad: {NUMBER} live agent-steps/s per core", ("torch",)),
    "bench_gnn.py": (rf"^ours, eager: {NUMBER}x the reference;", ("torch",)),
    "bench_map_inputs.py": (rf"^  map / agent inputs: {NUMBER}x", ("torch",)),
    "bench_metrics.py": (rf"^ours, one scene per call\s+:\s+{NUMBER} ms/scene", ()),
    "bench_nuplan_score.py": (rf"^score vs harness: {NUMBER} % of the unroll's harness time", ("torch",)),
    "bench_obstacle_frame.py": (rf"evaluate_cloud, numpy kernel: median {NUMBER} ms", ()),
    "bench_pdm_closed.py": (rf"^pdm_closed: {NUMBER} ms per scene per step", ("torch",)),
    "bench_pointcloud2.py": (rf"^  stream / page cache: median {NUMBER} of the faster reference", ("rosbags",)),
    "bench_policy_benchmark_step.py": (rf"ours merging\s+E=\s*2:\s+{NUMBER} live agent-steps/s", ()),
    "bench_pt2_loading.py": (rf"^median ours / torch.export.load over \d+ model\(s\): {NUMBER}x", ("torch",)),
    "bench_policy_training.py": (rf"^collection at \d+ threads / 1 thread: median {NUMBER}x", ("torch",)),
    # The row's columns: case (16), outcome (44), examples, search s, cpu s, engine %, examples per minute,
    # then the one-at-a-time search's s, cpu s, examples per minute, and the ratio.
    "bench_policy_search.py": (rf"^gnn-wide {{9}}.{{44}} +\d+ +[0-9.]+ +[0-9.]+ +\d+% +{NUMBER} +[0-9.]+ +[0-9.]+ "
                               rf"+{NUMBER} +[0-9.]+ ", ("torch", "hypothesis")),
    "bench_raster.py": (rf"^box_debug .*new arrays\s+1 scene: {NUMBER}/s", ()),
    "bench_raster_closed_loop.py": (rf"^\s+2 scene\(s\):\s+{NUMBER} scene-steps/s", ("torch",)),
    "bench_ray.py": (rf"^  chunks here: .* speed-up over one batch {NUMBER}x; results identical", ("torch",)),
    "bench_scenarionet.py": (rf"^median read/unroll over \d+ scene\(s\): {NUMBER}x", ("torch",)),
    "bench_semantic_map.py": (rf"read best of 1: {NUMBER} s", ()),
    "bench_unroll.py": (rf"^engine vs issue 14: {NUMBER} scene-steps/s", ("torch",)),
    "bench_unroll_memory.py": (rf"^peak RSS {NUMBER} MB", ("torch",)),
    # 0 of 0 where the shared data or the oracle's venv is absent: the script says which and stops there.
    "nuplan_oracle/compare_scenes.py": (rf"^terms agreeing with nuplan-devkit: {NUMBER} of", ("torch",)),
}
# Scripts with no smoke run, and why; tests/raster/test_l5kit_oracle.py runs l5kit's where its venv exists,
# the nuPlan score comparison test nuplan-devkit's, tests/io/test_commonroad_oracle.py commonroad-io's.
NOT_SMOKED = {
    "commonroad_oracle/check_trajectory.py": "imports the drivability checker: runs inside the crime venv only",
    "commonroad_oracle/compare_trajectories.py": "an agreement table against the crime venv, no timing; "
                                                 "tests/io/test_commonroad_trajectory_oracle.py runs it",
    "commonroad_oracle/oracle_venv.py": "creates commonroad-io's venv: pip installs, minutes",
    "commonroad_oracle/read_scenario.py": "imports commonroad-io: runs inside its venv only",
    "l5kit_oracle/compare_rasters.py": "compares with l5kit itself, in its own venv",
    "l5kit_oracle/compare_vectors.py": "compares with l5kit itself, in its own venv; tests/sim/test_map_inputs_l5kit.py "
                                       "runs it",
    "l5kit_oracle/oracle_venv.py": "creates l5kit's venv: pip installs, minutes",
    "l5kit_oracle/rasterize.py": "imports l5kit: runs inside its venv only",
    "l5kit_oracle/vectorize.py": "imports l5kit: runs inside its venv only",
    "nuplan_oracle/cases.py": "writes the score cases and sets oracle answers against them; no timing of its own",
    "nuplan_oracle/crime_ttc.py": "imports commonroad-crime: runs inside its own venv only",
    "nuplan_oracle/nuplan_metrics.py": "imports nuplan-devkit: runs inside its venv only",
    "nuplan_oracle/oracle_venv.py": "creates nuplan-devkit's venv: pip installs, minutes",
    "nuplan_oracle/oracle_scenes.py": "imports nuplan-devkit: runs inside its venv only (tests/metrics/"
                                      "test_nuplan_oracle_scenes.py runs it on a real run)",
    "nuplan_oracle/scenario_case.py": "the oracle's case building: imported by oracle_scenes.py, no script",
    "nuplan_oracle/scenario_map.py": "the oracle's map layers from a ScenarioNet file: a module, no script",
    "nuplan_oracle/scenario_pickle.py": "the oracle's restricted unpickler: a module, no script",
    "reference_venvs.py": "helpers the oracle venv scripts share: no script of its own",
}


class Done:
    """What the test reads of a finished run: as subprocess.CompletedProcess."""

    def __init__(self, returncode: int, stdout: str, stderr: str):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


@pytest.fixture(scope="module")
def run_smoke(tmp_path_factory):
    """``run_smoke(script)`` runs ``python benchmarks/SCRIPT --smoke`` in a process of its own, forked
    from one that imported torch and the package once (smoke_forkserver.py): each script still runs
    start to end, only the interpreter's start and the imports are not paid twenty times over."""
    # This checkout's package, not whichever one the environment has installed.
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO_ROOT), os.environ.get("PYTHONPATH")]))}
    server = subprocess.Popen([sys.executable, str(Path(__file__).with_name("smoke_forkserver.py"))],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=REPO_ROOT, env=env)
    assert json.loads(server.stdout.readline()) == {"ready": True}
    folder = tmp_path_factory.mktemp("smoke")

    def run(script: str) -> Done:
        out, err = folder / f"{script.replace('/', '_')}.out", folder / f"{script.replace('/', '_')}.err"
        out.touch()
        err.touch()
        ask = {"script": str(BENCHMARKS / script), "out": str(out), "err": str(err), "cwd": str(REPO_ROOT),
               "timeout": 600}
        server.stdin.write(json.dumps(ask) + "\n")
        server.stdin.flush()
        answer = json.loads(server.stdout.readline())
        return Done(answer["returncode"], out.read_text(), err.read_text())

    yield run
    server.stdin.close()
    server.wait(timeout=60)


@pytest.mark.parametrize("script", sorted(SMOKED))
def test_the_script_runs_at_smoke_size_and_prints_its_figure(script, run_smoke):
    pattern, needs = SMOKED[script]
    for module in needs:
        if importlib.util.find_spec(module) is None:
            pytest.skip(f"{script} needs {module}")
    done = run_smoke(script)
    assert done.returncode == 0, f"{script} --smoke failed:\n{done.stderr[-3000:]}"
    assert "smoke run:" in done.stdout, "a smoke run says so, so its figures are not mistaken for real ones"
    found = re.search(pattern, done.stdout, re.MULTILINE)
    assert found, f"{script} printed no line matching {pattern!r}:\n{done.stdout[-3000:]}"
    figure = float(found.group(1).replace(",", ""))
    assert math.isfinite(figure) and figure >= 0


def test_every_benchmark_script_has_a_smoke_run_or_a_reason():
    scripts = {p.relative_to(BENCHMARKS).as_posix() for p in BENCHMARKS.rglob("*.py")}
    assert scripts - set(SMOKED) - set(NOT_SMOKED) == set(), "add the new script to SMOKED (give it --smoke)"
    assert set(SMOKED) | set(NOT_SMOKED) <= scripts, "SMOKED or NOT_SMOKED names a script that is gone"
    for script in SMOKED:
        assert '"--smoke"' in (BENCHMARKS / script).read_text(encoding="utf-8"), f"{script} has no --smoke option"
