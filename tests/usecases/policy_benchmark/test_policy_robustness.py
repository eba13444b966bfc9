"""The policy benchmark's robustness search end to end: broken baselines, replay, reproducibility, YAML errors."""
from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint: {{Name: merging}}
  Episodes: {episodes}
  Policies:
{policies}
  Perturbation:
{perturbation}
"""

RANGES = """\
    Lateral: [-0.5, 0.5]
    Heading: [-0.05, 0.05]
    SpeedScale: [0.8, 1.2]
    AgentsSpeedScale: [0.8, 1.2]
    GapScale: [0.7, 1.5]
    Examples: 200
"""

# Test doubles: the IDM expert (which reaches every merging goal unperturbed) broken on purpose.
DOUBLES = """\
import weakref

import numpy as np

from pytest_driveeval.policies.idm_expert import IDMExpert


class Fragile:
    '''The expert, except that an episode whose ego starts turned left by more than ``heading`` rad
    (or whose seed is ``seed``) steers hard left throughout and leaves the road.'''

    def __init__(self, heading=1.0, seed=-1):
        self.heading, self.seed = heading, seed
        self.expert = IDMExpert()
        self.start = weakref.WeakKeyDictionary()

    def act_on_episodes(self, episodes):
        start = self.start.setdefault(episodes, episodes.yaw[:, 0].copy())  # merging's lanes head along +x
        actions = self.expert.act_on_episodes(episodes)
        broken = (start > self.heading) | (episodes.seeds == self.seed)
        actions[broken] = [0.0, episodes.blueprint.params.ego_max_steer]
        return actions
"""


def scenario(name="search", policies="    mine: constant", perturbation=RANGES, episodes=16) -> str:
    return SCENARIO.format(name=name, policies=policies, perturbation=perturbation, episodes=episodes)


# For the tests that compare two searches only: the failing episode's GIF (about a fifth of such an
# item's time, profiled) is drawn after the search, from the case it found; the tests above check it.
NO_ANIMATIONS = "  Artefacts: {Animations: none}\n"


@pytest.fixture
def project(pytester):
    pytester.makepyfile(doubles=DOUBLES)
    pytester.syspathinsert()
    return pytester


def with_double(pytester, double: str):
    pytester.makeconftest(f"import pytest\nimport doubles\n\n@pytest.fixture\ndef driveeval_model():\n"
                          f"    return doubles.{double}\n")


def records(pytester, output="driveeval-results") -> dict:
    data = json.loads((pytester.path / output / "summary.json").read_text())
    return {r["nodeid"].split("[")[-1].rstrip("]"): r for r in data["results"]}


def replay_value(search: dict) -> tuple[str, str]:
    line = search["replay"]
    assert line.startswith("pytest ") and " --driveeval-replay " in line
    node, value = line[len("pytest "):].split(" --driveeval-replay ")
    return node.strip("'"), value.strip("'")


def test_random_and_constant_are_broken_within_200_examples_and_the_replay_line_reproduces_it(project):
    project.makefile(".scenario.yaml", search=scenario(policies="    random: random\n    constant: constant"))
    project.runpytest("-q", "-p", "no:randomly").assert_outcomes(failed=2)
    for name, record in records(project).items():
        search = record["details"]["search"]
        assert record["verdict"] == "failed" and search["minimal"] is not None
        # Found while generating, within the 200 examples asked (shrinking and tightening come after).
        assert search["generations"] * search["batch"] <= 200 and search["examples_asked"] == 200
        assert search["shown_verdict"] == "failed"
        assert f"episode_{search['where']['seed']}_gif" in record["artefacts"]
        node, value = replay_value(search)
        project.runpytest(node, "--driveeval-replay", value, "--driveeval-output", f"replay-{name}"
                          ).assert_outcomes(failed=1)
        (replayed,) = records(project, f"replay-{name}").values()
        case = replayed["details"]["failing_case"] if "failing_case" in replayed["details"] else replayed["details"]
        assert replayed["details"]["replay"] == value
        assert case["seed"] == search["where"]["seed"] and case["steps"] == search["where"]["step"]
        assert case["perturbation"] == search["minimal"]["perturbation"]
        assert any(search["reason"] in f["message"] for f in replayed["findings"])


def test_the_search_finds_the_edge_of_a_perturbation_only_failure_and_the_edge_next_to_it_passes(project):
    with_double(project, "Fragile(heading=0.03)")
    perturbation = "    Heading: [-0.08, 0.08]\n    Examples: 200\n    Tolerance: 0.005\n"
    project.makefile(".scenario.yaml", search=scenario(perturbation=perturbation, episodes=4))
    project.runpytest("-q", "--driveeval-search-profile=ci").assert_outcomes(failed=1)
    search = records(project)["mine"]["details"]["search"]
    heading = search["minimal"]["perturbation"]["heading"]
    edge = search["edge"]["heading"]
    # Within the tolerance (0.5 % of the 0.16 rad range) of where the double breaks, failing side.
    assert 0.03 < heading <= 0.03 + 0.005 * 0.16 and edge <= 0.03
    assert search["reason"].startswith(("left the road at step", "collision at step"))  # steering into the main lane
    node, value = replay_value(search)
    project.runpytest(node, "--driveeval-replay", value, "--driveeval-output", "fails").assert_outcomes(failed=1)
    project.runpytest(node, "--driveeval-replay", f"seed={search['where']['seed']},heading={edge!r}",
                      "--driveeval-output", "passes").assert_outcomes(passed=1)


def test_the_ci_profile_gives_the_same_search_twice(project):
    with_double(project, "Fragile(heading=0.03)")
    perturbation = "    Heading: [-0.08, 0.08]\n    GapScale: [0.8, 1.2]\n    Examples: 64\n    Batch: 16\n"
    project.makefile(".scenario.yaml", search=scenario(perturbation=perturbation, episodes=4) + NO_ANIMATIONS)
    runs = []
    for output in ("first", "second"):
        project.runpytest("-q", "--driveeval-search-profile=ci", "--driveeval-output", output
                          ).assert_outcomes(failed=1)
        search = records(project, output)["mine"]["details"]["search"]
        runs.append({k: v for k, v in search.items() if k != "seconds"})
    assert runs[0] == runs[1]
    assert runs[0]["replayed_from_database"] == 0


def test_a_policy_that_never_fails_passes_after_the_examples_asked(project):
    project.makefile(".scenario.yaml", search=scenario(policies="    idm: idm_expert", episodes=8,
                                                       perturbation=RANGES + "    Batch: 16\n"))
    result = project.runpytest("-q", "--driveeval-search-examples", "48")
    result.assert_outcomes(passed=1)
    record = records(project)["idm"]
    search = record["details"]["search"]
    assert search["examples_asked"] == 48 and search["generations"] == 3 and search["failures"] == 0
    assert 16 < search["examples"] <= 48 and record["figures"]["search_examples"] == search["examples"]
    assert "no perturbation within the ranges broke it" in record["summary"]


def test_a_failure_is_stored_and_replayed_first_by_the_next_search(project):
    # Seed 5 fails whatever the perturbation: the first generation (no change on seed 0) cannot find it.
    with_double(project, "Fragile(seed=5)")
    project.makefile(".scenario.yaml", search=scenario(perturbation=RANGES + "    Batch: 4\n", episodes=8))
    project.runpytest("-q", "--driveeval-search-profile=default").assert_outcomes(failed=1)
    first = records(project)["mine"]["details"]["search"]
    assert first["where"]["seed"] == 5 and first["generations"] > 1 and first["replayed_from_database"] == 0
    project.runpytest("-q", "--driveeval-search-profile=default").assert_outcomes(failed=1)
    again = records(project)["mine"]["details"]["search"]
    assert again["replayed_from_database"] >= 1 and again["generations"] == 1
    assert again["minimal"] == first["minimal"]


def test_serial_and_two_workers_give_the_same_search(project):
    project.makefile(".scenario.yaml", search=scenario(policies="    random: random\n    constant: constant",
                                                       episodes=8) + NO_ANIMATIONS)
    runs = {}
    # Serially in this process (the search's draws do not depend on what it imported before: the
    # engine hides hypothesis's local constants), against two worker processes.
    for name, run, extra in (("serial", project.runpytest, []), ("xdist", project.runpytest_subprocess, ["-n", "2"])):
        run("--driveeval-output", name, *extra).assert_outcomes(failed=2)
        runs[name] = {policy: {k: v for k, v in r["details"]["search"].items() if k != "seconds"}
                      for policy, r in records(project, name).items()}
    assert runs["serial"] == runs["xdist"]


@pytest.mark.parametrize("perturbation, expected", [
    ("    Lateral: [0.5, 1.0]\n", "*search.scenario.yaml:11: Evaluation.Perturbation.Lateral: the range [[]0.5, 1[]] "
                                  "must contain 0 (no change)*"),
    ("    Lateral: [-1, 1]\n    GapScale: [0, 2]\n", "*search.scenario.yaml:12: Evaluation.Perturbation.GapScale: "
                                                     "a gap scale must stay above 0*"),
    ("    Lateral: [-1, 1]\n    Latteral: [-1, 1]\n", "*search.scenario.yaml:12: Evaluation.Perturbation.Latteral*"),
    ("    Lateral: [-1, 1]\n    FailOn: [crash]\n", "*search.scenario.yaml:12: Evaluation.Perturbation.FailOn*"),
    ("    Examples: 50\n", "*give at least one range to search*"),
])
def test_a_bad_perturbation_section_is_located(project, perturbation, expected):
    project.makefile(".scenario.yaml", search=scenario(perturbation=perturbation))
    result = project.runpytest("-q")
    result.stdout.fnmatch_lines([expected])
    assert "Traceback" not in result.stdout.str()


def test_a_replay_of_an_unknown_seed_or_field_says_what_is_known(project):
    project.makefile(".scenario.yaml", search=scenario(episodes=4))
    result = project.runpytest("-q", "--driveeval-replay", "seed=9,lateral=0.1")
    assert "seed 9 is not one of this item's (0, 1, 2, 3)" in result.stdout.str()
    result = project.runpytest("-q", "--driveeval-replay", "seed=1,gapscale=0.5")
    assert "gapscale not a perturbation of policy_benchmark" in result.stdout.str() and "GapScale" in \
        result.stdout.str()
