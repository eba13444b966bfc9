"""policy_benchmark end to end: YAML -> seeded episodes per policy -> decisions with intervals."""
from __future__ import annotations

import json

import pytest
from conftest import NO_HYPOTHESIS_PLUGIN

pytest.importorskip("torch")
pytest.importorskip("scipy")

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint: {{Name: merging{params}}}
  Episodes: {episodes}
  AgentLimit: {agent_limit}
  Policies:
    mine: {mine}
    random: random
    constant: constant
  Judged: [mine]
  Conditions:
{conditions}
"""

CONDITIONS = """\
    GoalRate: {AtLeast: 50}
    CollisionRate: {AtMost: 60}
    Beats: [{Baseline: random, Metric: collision_rate}]
"""


def scenario(name="b", mine="constant", episodes=24, agent_limit=12, params="", conditions=CONDITIONS) -> str:
    return SCENARIO.format(name=name, mine=mine, episodes=episodes, agent_limit=agent_limit, params=params,
                           conditions=conditions)


def records(pytester) -> dict:
    data = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())
    return {r["nodeid"]: r for r in data["results"]}


def test_one_item_per_policy_and_the_judged_one_is_decided_on_intervals(pytester):
    pytester.makefile(".scenario.yaml", bench=scenario())
    result = pytester.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(passed=2, failed=1)
    # The point estimate is printed with its interval, the confidence and the number of episodes.
    result.stdout.fnmatch_lines(["*goal rate 0.0 % [[]0.0, *[]] (95 % Wilson CI, 24 episodes) is not >= 50 %*"
                                 "(bench.scenario.yaml:15)"])
    by_id = records(pytester)
    mine = by_id["bench.scenario.yaml::policy_benchmark[mine]"]
    assert mine["status"] == "failed" and mine["details"]["judged"] is True
    assert mine["figures"]["episodes"] == 24
    goal = mine["details"]["intervals"]["goal_rate"]
    assert goal["low"] <= goal["point"] <= goal["high"] and goal["n"] == 24
    assert set(mine["details"]["compared"]) == {"random"}
    baseline = by_id["bench.scenario.yaml::policy_benchmark[random]"]
    assert baseline["status"] == "passed" and baseline["details"]["judged"] is False


def test_results_are_the_same_serially_and_with_two_workers(pytester):
    pytester.makefile(".scenario.yaml", bench=scenario(episodes=16))

    def outcome():
        return {k: (r["status"], r["figures"], r["details"]["intervals"]) for k, r in records(pytester).items()}

    pytester.runpytest("-q", "-p", "no:randomly")
    serial = outcome()
    pytester.runpytest("-q", "-n", "2", *NO_HYPOTHESIS_PLUGIN)
    assert outcome() == serial


def test_a_passing_condition_set_passes(pytester):
    easy = "    CollisionRate: {AtMost: 95}\n"
    pytester.makefile(".scenario.yaml", easy=scenario(conditions=easy, episodes=40))
    pytester.runpytest("-q").assert_outcomes(passed=3)


@pytest.mark.parametrize("change, expected", [
    (dict(params=", Params: {gapp: [7, 17]}"), "*easy.scenario.yaml:6: Evaluation.Blueprint.Params.gapp: "
                                                "unknown parameter (did you mean 'gap'?)*"),
    (dict(params=", Params: {gap: [17, 7]}"), "*easy.scenario.yaml:6: Evaluation.Blueprint.Params.gap: *"),
    (dict(agent_limit=0), "*easy.scenario.yaml:8: Evaluation.AgentLimit: the agent limit counts the ego, so it "
                          "is at least 1*"),
    (dict(conditions="    Beats: [{Baseline: rnd}]\n"),
     "*easy.scenario.yaml:15: Evaluation.Conditions.Beats[[]0[]].Baseline: 'rnd' is not one of this scenario's "
     "Policies (mine, random, constant)*"),
    (dict(conditions="    GoalRate: {AtLeast: 0}\n  Compare: [random, rnd]\n"),
     "*easy.scenario.yaml:16: Evaluation.Compare[[]1[]]: 'rnd' is not one of this scenario's "
     "Policies (mine, random, constant)*"),
])
def test_bad_scenario_values_are_located(pytester, change, expected):
    pytester.makefile(".scenario.yaml", easy=scenario(**change))
    result = pytester.runpytest("-q")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines([expected])
    assert "Traceback" not in result.stdout.str()


POLICIES = """\
import torch


class Broken(torch.nn.Module):
    def __init__(self, what):
        super().__init__()
        self.what = what
        self.calls = 0

    def forward(self, obs):
        self.calls += 1
        if self.what == "shape":
            return torch.zeros(obs.shape[0], 3)
        out = torch.zeros(obs.shape[0], 2)
        if self.calls == 4:
            out[2, 1] = float("nan")
        return out
"""


@pytest.mark.parametrize("what, message", [
    ("nan", "*ModelError: policy 'mine' returned [[]0.0, nan[]] for episode 2 (seed 2) at step 3*"),
    ("shape", "*ModelError: policy 'mine' returned actions of shape (8, 3) at step 0; expected (8, 2)*"),
])
def test_a_policy_returning_nan_or_the_wrong_shape_names_episode_and_step(pytester, what, message):
    pytester.makepyfile(policies=POLICIES)
    pytester.syspathinsert()
    pytester.makeconftest("import pytest\nimport policies\n\n@pytest.fixture\ndef driveeval_model():\n"
                          f"    return policies.Broken({what!r})\n")
    pytester.makefile(".scenario.yaml", bench=scenario(episodes=8))
    result = pytester.runpytest("-q", "-k", "mine")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines([message])
    assert "Traceback" not in result.stdout.str()


def test_a_torch_policy_sees_the_seeds_flat_graph_observation(pytester):
    pytester.makepyfile(policies="import json\nimport torch\n\n"
                        "def keep_lane(obs):\n    with open('seen.jsonl', 'a') as f:\n"
                        "        f.write(json.dumps([list(obs.shape), obs[:, :3].tolist()]) + '\\n')\n"
                        "    return torch.zeros(len(obs), 2)\n")
    pytester.syspathinsert()
    pytester.makeconftest("import pytest\nimport policies\n\n@pytest.fixture\ndef driveeval_model():\n"
                          "    return policies.keep_lane\n")
    pytester.makefile(".scenario.yaml", bench=scenario(episodes=4, conditions="    Beats: []\n"))
    result = pytester.runpytest("-q", "-k", "mine")
    result.assert_outcomes(passed=1)
    seen = [json.loads(line) for line in (pytester.path / "seen.jsonl").read_text().splitlines()]
    assert seen
    for shape, headers in seen:
        # Seed 002's flat graph: header [agent limit, agent count, features], 12 x 11 nodes, 12 x 12 adjacency.
        assert shape == [4, 3 + 12 * 11 + 12 * 12]
        assert all(k == 12 and 1 <= n <= 12 and f == 11 for k, n, f in headers)


def test_artefacts_gif_of_a_failing_episode_with_its_graph_and_the_comparison_plot(pytester):
    from PIL import Image

    pytester.makefile(".scenario.yaml", bench=scenario(episodes=8))
    pytester.runpytest("-q", "-k", "mine")
    (record,) = records(pytester).values()
    out = pytester.path / "driveeval-results"
    assert set(record["artefacts"]) >= {"episodes", "comparison"}
    (gif,) = [out / p for name, p in record["artefacts"].items() if name.endswith("_gif")]
    with Image.open(gif) as frames:
        assert frames.n_frames > 2
        # The ego is drawn red in the middle of every frame.
        assert frames.convert("RGB").getpixel((180, 180)) == (211, 47, 47)
    episodes = json.loads((out / record["artefacts"]["episodes"]).read_text())["episodes"]
    assert [e["seed"] for e in episodes] == list(range(8))
    with Image.open(out / record["artefacts"]["comparison"]) as comparison:
        assert comparison.size[0] > 300


def test_no_animation_when_the_scenario_asks_for_none(pytester):
    text = scenario(episodes=4) + "  Artefacts: {Animations: none, ComparisonPlot: false}\n"
    pytester.makefile(".scenario.yaml", bench=text)
    pytester.runpytest("-q", "-k", "mine")
    (record,) = records(pytester).values()
    assert set(record["artefacts"]) == {"episodes"}


def test_policies_side_by_side_with_intervals_in_the_summary_and_the_html_report(pytester):
    pytester.makefile(".scenario.yaml", bench=scenario(episodes=8))
    pytester.runpytest("-q", "--html=report.html", "--self-contained-html")
    markdown = (pytester.path / "driveeval-results" / "summary.md").read_text()
    table = markdown.split("### Policies by scenario")[1].strip().splitlines()
    assert table[0] == "| use case | data | `constant` | `mine` | `random` |"
    row = table[2].split(" | ")
    assert row[:2] == ["| policy_benchmark", "merging (b)"]
    assert all("goal 0 % [0, " in cell and "collision " in cell for cell in row[2:])
    # Only the judged policy has a verdict mark; the baselines say so instead of a pass.
    constant, mine, random_ = row[2:]
    assert mine.startswith(("✅", "❌")) and constant.startswith("baseline: goal") and random_.startswith("baseline:")
    assert "✅" not in constant + random_
    html = (pytester.path / "report.html").read_text()
    assert "Policies by scenario" in html and "merging (b)" in html
    policies = html[html.index("Policies by scenario"):]
    policies = policies[:policies.index("</table>")]
    assert "border:1px solid" in policies and "padding:3px 8px" in policies and "baseline: goal" in policies


def test_allure_names_each_policy_and_shows_plain_numbers(pytester):
    pytest.importorskip("allure_pytest")
    pytester.makefile(".scenario.yaml", bench=scenario(episodes=4))
    pytester.runpytest("-q", "--alluredir=allure")
    results = [json.loads(p.read_text()) for p in (pytester.path / "allure").glob("*-result.json")]
    # Five policies of one scenario were five results named "b".
    assert sorted(r["name"] for r in results) == ["b [constant]", "b [mine]", "b [random]"]
    for r in results:
        params = {p["name"]: p["value"] for p in r["parameters"]}
        assert params["policy"] == repr(r["name"][3:-1])
        # The rates are numpy scalars in the outcome; allure showed np.float64(75.0).
        assert float(params["goal_rate"]) == 0.0 and not any("np." in v for v in params.values())


def test_compared_policies_are_reported_paired_and_decide_nothing(pytester):
    # The IDM expert merges and the constant action does not: on the same seeds the expert does better
    # on goals, and the comparison is reported beside a verdict that it does not change.
    compare = "    CollisionRate: {AtMost: 100}\n  Compare: [constant, random]\n"
    pytester.makefile(".scenario.yaml", bench=scenario(mine="idm_expert", episodes=16, conditions=compare))
    pytester.runpytest("-q", "-p", "no:randomly").assert_outcomes(passed=3)
    by_id = records(pytester)
    mine = by_id["bench.scenario.yaml::policy_benchmark[mine]"]
    intervals = mine["details"]["intervals"]
    goal = intervals["vs_constant_goal_rate"]
    assert goal["improvement"]["low"] > 0.5
    own, other = mine["figures"]["goal_rate"], mine["details"]["compared"]["constant"]["goal_rate"]
    assert goal["difference"]["point"] == pytest.approx(own - other)
    assert {"vs_random_goal_rate", "vs_random_collision_rate", "vs_constant_collision_rate"} <= set(intervals)
    # A baseline's item compares nothing: only a judged item does.
    constant = by_id["bench.scenario.yaml::policy_benchmark[constant]"]
    assert not any(k.startswith("vs_") for k in constant["details"]["intervals"])
    markdown = (pytester.path / "driveeval-results" / "summary.md").read_text()
    table = markdown.split("### Paired comparisons (the same seeded episodes)")[1].strip().splitlines()
    assert len(table) == 2 + 4  # header, rule, (constant, random) x (goal, no collision)
    row = next(line for line in table if "| constant | goal |" in line)
    assert row.startswith("| b | mine | constant | goal | ")
    assert f"{goal['improvement']['point']:.2f} [{goal['improvement']['low']:.2f}, " in row


def test_progress_counts_the_episodes_ended_after_each_step():
    from pytest_driveeval.policies.control_baselines import ConstantAction
    from pytest_driveeval.sim.blueprints import make_blueprint
    from pytest_driveeval.usecases.policy_benchmark.evaluate import run_policy

    seen = []
    run = run_policy(make_blueprint("merging"), list(range(6)), ConstantAction(), "constant",
                     progress=lambda done, total: seen.append((done, total)))
    assert seen and all(total == 6 for _, total in seen)
    assert [done for done, _ in seen] == sorted(done for done, _ in seen) and seen[-1][0] == 6
    assert len(seen) == int(run.steps.max())  # one call per step of the longest episode
