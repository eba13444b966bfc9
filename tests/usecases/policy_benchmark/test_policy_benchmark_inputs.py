"""Issue 21: numbers a simulator cannot take (seeds past int64, infinite or NaN ranges and replays) and a
policy judged against itself are refused at their YAML line or as the option, while the scenario
beside them runs."""
from __future__ import annotations

import pytest

from conftest import POLICY_BENCHMARK_HEAD

pytest.importorskip("torch")

SCENARIO = POLICY_BENCHMARK_HEAD + """\
  Blueprint: {{Name: merging}}
  Episodes: 4
  Policies:
    mine: idm_expert
{extra}"""

SEARCH = """\
  Perturbation:
    Lateral: [-0.5, 0.5]
    Examples: 8
"""

# name: (lines under Evaluation from line 10 on, the located problem)
BAD = {
    "first_seed": ("  FirstSeed: 18446744073709551616\n",
                   "first_seed.scenario.yaml:10: Evaluation.FirstSeed: the episodes' seeds (FirstSeed .. FirstSeed "
                   "+ Episodes - 1) must stay below 2**63 = 9223372036854775808; the last would be "
                   "18446744073709551619"),
    "last_seed": (f"  FirstSeed: {2 ** 63 - 3}\n",
                  "last_seed.scenario.yaml:10: Evaluation.FirstSeed: the episodes' seeds (FirstSeed .. FirstSeed "
                  "+ Episodes - 1) must stay below 2**63"),
    "infinite_range": ("  Perturbation:\n    Lateral: [-.inf, .inf]\n",
                       "infinite_range.scenario.yaml:11: Evaluation.Perturbation.Lateral: a range of finite numbers "
                       "is needed, got [-inf, inf]"),
    "nan_range": ("  Perturbation:\n    Heading: [.nan, 0.1]\n",
                  "nan_range.scenario.yaml:11: Evaluation.Perturbation.Heading: a range of finite numbers is "
                  "needed, got [nan, 0.1]"),
    "nan_confidence": ("  Conditions:\n    Confidence: .nan\n",
                       "nan_confidence.scenario.yaml:11: Evaluation.Conditions.Confidence: expected a finite number; "
                       "found nan (float)"),
    "infinite_replay": ("  Perturbation:\n    Lateral: [-1, 1]\n    Replay: {Seed: 0, Lateral: .inf}\n",
                        "infinite_replay.scenario.yaml:12: Evaluation.Perturbation.Replay.Lateral: expected a finite "
                        "number; found inf (float)"),
    "replay_out_of_range": ("  Perturbation:\n    Lateral: [-1, 1]\n    Replay: {Seed: 0, Lateral: 2}\n",
                            "replay_out_of_range.scenario.yaml:12: Evaluation.Perturbation.Replay.Lateral: outside "
                            "the scenario's range Lateral: [-1, 1]; got 2.0"),
    "replay_no_gap": ("  Perturbation:\n    Lateral: [-1, 1]\n    Replay: {Seed: 0, GapScale: 0}\n",
                      "replay_no_gap.scenario.yaml:12: Evaluation.Perturbation.Replay.GapScale: a gap scale must "
                      "stay above 0; got 0.0"),
    "own_baseline": ("  Judged: [mine]\n  Conditions:\n    Beats: [{Baseline: mine}]\n",
                     "own_baseline.scenario.yaml:12: Evaluation.Conditions.Beats[0].Baseline: 'mine' is judged "
                     "(Judged lists it), and a policy cannot be its own baseline: compare with another policy, or "
                     "leave it out of Judged"),
}


def test_each_bad_number_or_baseline_is_located_and_the_good_scenario_beside_it_passes(pytester):
    for name, (extra, _) in BAD.items():
        pytester.makefile(".scenario.yaml", **{name: SCENARIO.format(name=name, extra=extra)})
    pytester.makefile(".scenario.yaml", good=SCENARIO.format(
        name="good", extra="  FirstSeed: 1000\n  Conditions:\n    GoalRate: {AtLeast: 10}\n"))
    result = pytester.runpytest("-q")
    result.assert_outcomes(passed=1, failed=len(BAD))
    out = result.stdout.str()
    for _, problem in BAD.values():
        assert problem in out, problem
    assert "Traceback" not in out and "OverflowError" not in out


def test_a_default_judged_policy_cannot_be_its_own_baseline_either(pytester):
    """Without Judged, the policies that are not baselines are judged: one of them as a Beats baseline
    would be compared with itself in its own item."""
    pytester.makefile(".scenario.yaml", own=SCENARIO.format(
        name="own", extra="    gnn: gnn.pt\n  Conditions:\n    Beats: [{Baseline: gnn}]\n"))
    result = pytester.runpytest("-q")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*own.scenario.yaml:12: Evaluation.Conditions.Beats[[]0[]].Baseline: 'gnn' is "
                                 "judged (without Judged, every policy that is not a baseline is judged)*"])


@pytest.mark.parametrize("replay, problem", [
    ("seed=0,lateral=nan", "ERROR: --driveeval-replay: 'lateral=nan': a finite number is needed"),
    ("seed=0,lateral=1e400", "ERROR: --driveeval-replay: 'lateral=1e400': a finite number is needed"),
    ("seed=0,lateral=inf", "ERROR: --driveeval-replay: 'lateral=inf': a finite number is needed"),
])
def test_a_replay_that_is_not_a_finite_number_is_a_usage_error(pytester, replay, problem):
    pytester.makefile(".scenario.yaml", search=SCENARIO.format(name="search", extra=SEARCH))
    result = pytester.runpytest("-q", "--driveeval-replay", replay)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    assert problem in result.stderr.str()


def test_a_replay_outside_the_scenarios_rules_names_its_key_and_the_other_items_run(pytester):
    pytester.makefile(".scenario.yaml", search=SCENARIO.format(name="search", extra=SEARCH),
                      plain=SCENARIO.format(name="plain", extra=""))
    for replay, problem in (("seed=0,gap_scale=0", "--driveeval-replay: gap_scale=0.0: a gap scale must stay above 0"),
                            ("seed=0,lateral=0.7", "--driveeval-replay: lateral=0.7: outside the scenario's range "
                                                   "Lateral: [-0.5, 0.5]")):
        result = pytester.runpytest("-q", "--driveeval-replay", replay)
        result.assert_outcomes(passed=1, failed=1)
        assert problem in result.stdout.str()
    # Within the range, the same replay runs.
    pytester.runpytest("-q", "--driveeval-replay", "seed=0,lateral=0.25").assert_outcomes(passed=2)
