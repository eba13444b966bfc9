"""policy_benchmark on a CommonRoad scenario: items per planning problem, results independent of
xdist, a GIF of lanelets and obstacles, and bad input as item errors naming the YAML line, the file
and the element."""
from __future__ import annotations

import json
import shutil

import pytest
from conftest import NO_HYPOTHESIS_PLUGIN, REPO_ROOT
from module_pytester import module_pytester

pytest.importorskip("torch")
pytest.importorskip("scipy")

TUTORIAL = REPO_ROOT / "fixtures" / "commonroad" / "ZAM_Tutorial-1_2_T-1.xml"

SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint:
    CommonRoad: {path}{extra}
  Episodes: {episodes}
  Policies:
    mine: constant
    random: random
  Judged: [mine]
  Conditions:
    GoalRate: {{AtLeast: 50}}
    Beats: [{{Baseline: random, Metric: goal_rate}}]
  Artefacts: {{Animations: {animations}}}
"""


def scenario(name="cr", path="zam.xml", extra="", episodes=12, animations="failing") -> str:
    return SCENARIO.format(name=name, path=path, extra=extra, episodes=episodes, animations=animations)


def records(pytester) -> dict:
    data = json.loads((pytester.path / "driveeval-results" / "summary.json").read_text())
    return {r["nodeid"]: r for r in data["results"]}


def two_problems(pytester) -> None:
    """The tutorial with a second planning problem (id 101, its initial state 5 m further on)."""
    text = TUTORIAL.read_text()
    start, end = text.index("<planningProblem"), text.index("</planningProblem>") + len("</planningProblem>")
    second = text[start:end].replace('id="100"', 'id="101"', 1).replace("<x>15.0</x>", "<x>20.0</x>", 1)
    assert 'id="101"' in second
    (pytester.path / "zam.xml").write_text(text[:end] + "\n" + second + text[end:])


def test_one_item_per_policy_and_planning_problem_results_the_same_with_two_workers(pytester):
    two_problems(pytester)
    pytester.makefile(".scenario.yaml", cr=scenario(animations="all"))
    result = pytester.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(passed=4)
    serial = {k: (r["status"], r["figures"], r["details"]["intervals"]) for k, r in records(pytester).items()}
    assert set(serial) == {f"cr.scenario.yaml::policy_benchmark[{p}-problem{i}]" for p in ("mine", "random")
                           for i in (100, 101)}
    mine = records(pytester)["cr.scenario.yaml::policy_benchmark[mine-problem101]"]
    assert mine["figures"]["goal_rate"] == 100.0 and mine["details"]["blueprint"].endswith("problem 101")
    gifs = list((pytester.path / "driveeval-results").rglob(
        "*mine-problem100*/episode_seed_0_ZAM_Tutorial-1_1_T-1_problem100.gif"))
    assert len(gifs) == 1 and gifs[0].stat().st_size > 1000
    pytester.runpytest("-q", "-n", "2", *NO_HYPOTHESIS_PLUGIN)
    assert {k: (r["status"], r["figures"], r["details"]["intervals"]) for k, r in records(pytester).items()} == serial


def test_the_findings_summary_and_gif_name_the_benchmark_the_planning_problem_and_the_file(pytester):
    """A folder of one's own: the file's name is not its benchmark id (as ZAM_Loading_Bay-1_1_T.xml
    holds ZAM_Tutorial-1_1_T-1), so each place names both, with the planning problem."""
    shutil.copy(TUTORIAL, pytester.path / "my_bay.xml")
    text = scenario(path="my_bay.xml").replace("Judged: [mine]", "Judged: [random]").replace(
        "Baseline: random", "Baseline: mine")
    pytester.makefile(".scenario.yaml", cr=text)
    pytester.runpytest("-q", "-p", "no:randomly").assert_outcomes(passed=1, failed=1)
    record = records(pytester)["cr.scenario.yaml::policy_benchmark[random-problem100]"]
    name = "benchmark ZAM_Tutorial-1_1_T-1, planning problem 100 (my_bay.xml)"
    assert record["details"]["scene"] == {"benchmark_id": "ZAM_Tutorial-1_1_T-1", "planning_problem": 100,
                                          "file": "my_bay.xml", "name": name}
    assert record["findings"] and all(f["message"].startswith(name + ": ") for f in record["findings"])
    folder = pytester.path / "driveeval-results"
    assert json.loads((folder / record["artefacts"]["episodes"]).read_text())["scene"]["file"] == "my_bay.xml"
    gif = record["artefacts"][next(k for k in record["artefacts"] if k.endswith("_gif"))]
    assert gif.rsplit("/", 1)[-1].startswith("episode_seed_") and gif.endswith("_ZAM_Tutorial-1_1_T-1_problem100.gif")


def test_a_named_planning_problem_makes_one_item_per_policy(pytester):
    two_problems(pytester)
    pytester.makefile(".scenario.yaml", cr=scenario(extra="\n    PlanningProblem: 101"))
    pytester.runpytest("-q").assert_outcomes(passed=2)
    assert set(records(pytester)) == {"cr.scenario.yaml::policy_benchmark[mine]",
                                      "cr.scenario.yaml::policy_benchmark[random]"}


NOT_COMMONROAD = "<?xml version='1.0'?>\n<scenario id='1'/>\n"
FUTURE = TUTORIAL.read_text().replace('commonRoadVersion="2020a"', 'commonRoadVersion="2031x"')


BAD_FILES = [
    ({}, "", r"*bad.scenario.yaml:7: Evaluation.Blueprint.CommonRoad: CommonRoad scenario *absent.xml cannot be "
             r"read: No such file*"),
    ({"absent.xml": NOT_COMMONROAD}, "",
     "*bad.scenario.yaml:7: Evaluation.Blueprint.CommonRoad: *absent.xml:2: <scenario id=\"1\">: not a "
     "CommonRoad file*"),
    ({"absent.xml": FUTURE}, "", "*bad.scenario.yaml:7: *absent.xml:*<commonRoad*unknown commonRoadVersion '2031x'*"),
    ({"absent.xml": TUTORIAL.read_text()}, "\n    PlanningProblem: 7",
     "*bad.scenario.yaml:8: Evaluation.Blueprint.PlanningProblem: *absent.xml: no planning problem with id 7 "
     "(the file has: 100)*"),
]


@pytest.fixture(scope="module")
def bad_files_session(request, tmp_path_factory):
    """One session for the cases below (each was a session of its own, the good scenario's episodes run
    again in each): each case's bad scenario and files in a folder of its own (case0, case1, ...), the
    good scenario and zam.xml beside them.  Returns the session's result and its records."""
    with module_pytester(request, tmp_path_factory) as pytester:
        shutil.copy(TUTORIAL, pytester.path / "zam.xml")
        pytester.makefile(".scenario.yaml", good=scenario(name="good"))
        for case, (files, extra, _) in enumerate(BAD_FILES):
            folder = pytester.mkdir(f"case{case}")
            for name, text in files.items():
                (folder / name).write_text(text)
            (folder / "bad.scenario.yaml").write_text(scenario(name="bad", path="absent.xml", extra=extra))
        result = pytester.runpytest("-q", "-p", "no:randomly")
        return result, records(pytester)


@pytest.mark.parametrize("case", range(len(BAD_FILES)))
def test_bad_files_and_problems_are_item_errors_naming_the_yaml_line_and_the_element(bad_files_session, case):
    result, found = bad_files_session
    expected = BAD_FILES[case][2]
    # both policies' items of each case fail; the good scenario's two pass
    result.assert_outcomes(passed=2, failed=2 * len(BAD_FILES))
    result.stdout.fnmatch_lines([f"*case{case}/{expected.lstrip('*')}"])
    assert [r["status"] for k, r in found.items() if k.startswith(f"case{case}/")] == ["failed"] * 2
    goods = [r["status"] for k, r in found.items() if k.startswith("good")]
    assert goods == ["passed"] * 2


@pytest.mark.parametrize("change, expected", [
    ("    Name: merging\n", "*Blueprint.Name*either Name*or CommonRoad*"),
    ("    Traffic: reckless\n", "*Blueprint.Traffic*'replay' or 'reactive'*"),
    ("    PlanningProblem: 100\n    Name: merging\n", "*Blueprint.Name*either Name*or CommonRoad*"),
    ("    Params: {gap: [1, 2]}\n", "*Blueprint.Params.gap*does not apply to a CommonRoad scene*"),
    ("    Params: {dt: 0.2}\n", "*Blueprint.Params.dt*timeStepSize*"),
])
def test_bad_blueprint_keys_are_located(pytester, change, expected):
    shutil.copy(TUTORIAL, pytester.path / "zam.xml")
    pytester.makefile(".scenario.yaml", cr=scenario().replace("    CommonRoad: zam.xml\n",
                                                              "    CommonRoad: zam.xml\n" + change))
    result = pytester.runpytest("-q")
    result.stdout.fnmatch_lines([expected])
    assert result.ret != 0


def test_an_unroutable_goal_fails_the_idm_expert_item_at_its_policy_line(pytester):
    """(idm_expert driving CommonRoad scenes: tests/policies/test_commonroad_expert.py and the demo.)"""
    off_road = ("<rectangle><length>4.0</length><width>2.0</width><center><x>50.0</x><y>40.0</y></center>"
                "<orientation>0.0</orientation></rectangle>")
    (pytester.path / "off.xml").write_text(TUTORIAL.read_text().replace('<lanelet ref="1"/>', off_road))
    pytester.makefile(".scenario.yaml", offroad=scenario(name="offroad", path="off.xml", episodes=4, animations="none")
                      .replace("    random: random\n", "    random: random\n    idm: idm_expert\n"))
    result = pytester.runpytest("-q", "-p", "no:randomly")
    # The expert's item fails before any episode, saying why; the file's other items run (the judged
    # constant policy fails its goal rate: nothing reaches a goal off the road).
    result.assert_outcomes(passed=1, failed=2)
    result.stdout.fnmatch_lines(["*offroad.scenario.yaml:12: Evaluation.Policies.idm: idm_expert cannot drive this "
                                 "planning problem: off.xml: planning problem 100: the goal (rectangle at (50.00, "
                                 "40.00)): it lies off every lanelet*"])
    assert records(pytester)["offroad.scenario.yaml::policy_benchmark[random-problem100]"]["status"] == "passed"


def test_a_robustness_search_perturbs_the_ego_start(pytester):
    shutil.copy(TUTORIAL, pytester.path / "zam.xml")
    text = scenario(episodes=4, extra="\n    PlanningProblem: 100").split("  Judged")[0] + (
        "  Perturbation:\n    Lateral: [-2.5, 2.5]\n    Heading: [-0.2, 0.2]\n    Examples: 64\n    Batch: 8\n")
    pytester.makefile(".scenario.yaml", cr=text)
    result = pytester.runpytest("-q", "-p", "no:randomly")
    mine = records(pytester)["cr.scenario.yaml::policy_benchmark[mine]"]
    # Keeping speed and heading passes unperturbed (the demo) and fails from a start moved far enough.
    assert mine["status"] == "failed", result.stdout.str()[-2000:]
    assert mine["figures"]["search_failures"] > 0 and mine["figures"]["search_examples"] > 8
    assert any(k in mine["figures"] for k in ("minimal_lateral", "minimal_heading"))


def test_the_observation_holds_the_obstacles_present_and_an_exported_actor_drives(tmp_path):
    import numpy as np

    from pytest_driveeval.policies.graph import decode
    from pytest_driveeval.policies.loading import load_model
    from pytest_driveeval.sim.commonroad_scene import commonroad_scene
    from pytest_driveeval.sim.episodes import reset
    from pytest_driveeval.usecases.policy_benchmark.evaluate import observer, run_policy

    # The goal's time interval moved to steps 50..60, so the episode outlives the recording (steps 0..40).
    late = tmp_path / "late.xml"
    text = TUTORIAL.read_text()
    goal = text.index("<goalState>")
    late.write_text(text[:goal] + text[goal:].replace("<intervalStart>35</intervalStart>",
                                                      "<intervalStart>50</intervalStart>", 1)
                    .replace("<intervalEnd>40</intervalEnd>", "<intervalEnd>60</intervalEnd>", 1))
    scene = commonroad_scene(late, 100)
    assert scene.max_steps == 60
    episodes = reset(scene, np.array([0]), 12)
    observe = observer(episodes, 12)
    counts = {}
    for k in range(1, 46):
        episodes.step(np.zeros((1, 2)))
        counts[k] = int(decode(observe(episodes)).count[0])
    # The ego, the parked car and the two recorded cars until step 40; then the parked car alone.
    assert counts[10] == counts[40] == 4 and counts[41] == counts[45] == 2, counts
    assert not episodes.done.any()

    run = run_policy(scene, np.arange(4), load_model(str(REPO_ROOT / "fixtures" / "models" / "gnn_actor_merging.pt2")),
                     "gnn")
    assert run.outcome.shape == (4,) and np.all((run.outcome >= 1) & (run.outcome <= 4))


def test_chunks_of_seeds_give_the_figures_of_one_batch(pytester):
    """Executor chunks (here Kind local with a ChunkSize: the chunks a Ray run would send) rebuild the
    scene from the file's path, planning problem and traffic; merged, they are the one batch's."""
    shutil.copy(TUTORIAL, pytester.path / "zam.xml")
    plain = scenario(episodes=10, extra="\n    Traffic: reactive\n  StepLimit: 38")
    pytester.makefile(".scenario.yaml", cr=plain)
    pytester.runpytest("-q", "-p", "no:randomly").assert_outcomes(passed=2)
    one_batch = {k: (r["figures"], r["details"]["episode_outcomes"]) for k, r in records(pytester).items()}
    pytester.makefile(".scenario.yaml", cr=plain + "  Executor: {Kind: local, ChunkSize: 3}\n")
    pytester.runpytest("-q", "-p", "no:randomly").assert_outcomes(passed=2)
    chunked = records(pytester)
    assert {k: (r["figures"], r["details"]["episode_outcomes"]) for k, r in chunked.items()} == one_batch
    assert all("executor" in r["details"] for r in chunked.values())


def test_bad_numbers_special_files_and_sizes_fail_their_own_item_at_their_line(pytester):
    """Each case ends as its item's located error: the YAML line, the CommonRoad file, its line and
    element; sizes are refused before the arrays are allocated.  The good scenario beside them runs."""
    import os

    text = TUTORIAL.read_text()
    shutil.copy(TUTORIAL, pytester.path / "zam.xml")
    # the first <x> of the file is lanelet 1's first left point, on line 15
    (pytester.path / "nan.xml").write_text(text.replace("<x>0.0</x>", "<x>nan</x>", 1))
    (pytester.path / "dt.xml").write_text(text.replace('timeStepSize="0.1"', 'timeStepSize="0"'))
    os.mkfifo(pytester.path / "pipe.xml")
    (pytester.path / "zero.xml").symlink_to("/dev/zero")
    pytester.makefile(".scenario.yaml", good=scenario(name="good"), nan=scenario(name="nan", path="nan.xml"),
                      dt=scenario(name="dt", path="dt.xml"), pipe=scenario(name="pipe", path="pipe.xml"),
                      zero=scenario(name="zero", path="zero.xml"),
                      fine=scenario(name="fine", extra="\n    Params: {resolution: 1.0e-6}"),
                      long=scenario(name="long", extra="\n    Params: {max_steps: 1.0e+9}"),
                      many=scenario(name="many", extra="\n    Params: {max_steps: 1000000}"))
    # 0.2 GiB: 10^6 steps of no obstacle fit when the scenario loads, of the file's 3 obstacles not.
    # In a subprocess with a timeout: a FIFO would block a reader that waits for its writer for ever.
    result = pytester.runpytest_subprocess("-q", "-p", "no:randomly", *NO_HYPOTHESIS_PLUGIN,
                                           "--driveeval-memory-limit", "0.2", timeout=300)
    assert all(r["status"] == "passed" for k, r in records(pytester).items() if k.startswith("good"))
    out = " ".join(result.stdout.str().split())  # the table wraps its lines
    for expected in [
        "nan.scenario.yaml:7: Evaluation.Blueprint.CommonRoad: nan.xml:15: <x> in <lanelet id=\"1\">: x: expected a "
        "finite number, got 'nan': give the value this element stands for",
        "dt.scenario.yaml:7: Evaluation.Blueprint.CommonRoad: dt.xml:2: <commonRoad>: timeStepSize: expected the "
        "seconds of one time step, above 0, got 0",
        "pipe.scenario.yaml:7: Evaluation.Blueprint.CommonRoad: pipe.xml: is a FIFO (named pipe), not a CommonRoad "
        "XML file: name the scenario's .xml file itself",
        "zero.scenario.yaml:7: Evaluation.Blueprint.CommonRoad: /dev/zero: is a character device, not a CommonRoad "
        "XML file",
        "fine.scenario.yaml:8: Evaluation.Blueprint.Params.resolution: zam.xml's lanelets: the road's drivable area "
        "(209 m x 20.5 m) would be a raster of 4.28e+15 cells at 1e-06 m, above the limit of 1.07e+09 cells (1 GiB); "
        "give a coarser resolution",
        "long.scenario.yaml:8: Evaluation.Blueprint.Params.max_steps: a CommonRoad scene of 1000000000 steps (its "
        "recording is held for every step) would need about 119 GiB of memory, more than the 205 MiB an item may use "
        "(--driveeval-memory-limit / driveeval_memory_limit)",
        "many.scenario.yaml:8: Evaluation.Blueprint.Params.max_steps: 1000000 steps (max_steps) of the 3 recorded "
        "obstacles of zam.xml would need about 328 MiB of memory, more than the 205 MiB an item may use "
        "(--driveeval-memory-limit / driveeval_memory_limit): give fewer steps",
    ]:
        assert expected in out, expected
    assert "Traceback" not in out and "MemoryError" not in out


def test_shared_format_files_run_or_say_they_cannot_be_driven(pytester, shared_data):
    # test_reading_all: an occupancy-set obstacle, signal states, environment and phantom obstacles;
    # test_reading_pm_state: point-mass obstacle states; test_reading_lanelets: a map without a problem
    for name in ("test_reading_all.xml", "test_reading_pm_state.xml", "test_reading_lanelets.xml"):
        shutil.copy(shared_data / "commonroad" / name, pytester.path / name)
    pytester.makefile(".scenario.yaml", **{
        "all": scenario(name="all", path="test_reading_all.xml", episodes=2),
        "pm": scenario(name="pm", path="test_reading_pm_state.xml", episodes=2, extra="\n    Params: {max_steps: 10}"),
        "map": scenario(name="map", path="test_reading_lanelets.xml", episodes=2)})
    result = pytester.runpytest("-q", "-p", "no:randomly")
    result.stdout.fnmatch_lines(["*map.scenario.yaml:7: Evaluation.Blueprint.CommonRoad: *test_reading_lanelets.xml "
                                 "has no <planningProblem> (it holds 6 lanelet(s) and 0 obstacle(s) only): *this "
                                 "file cannot be driven*"])
    found = records(pytester)
    ran = {k: r for k, r in found.items() if not k.startswith("map")}
    assert set(ran) == {f"{s}.scenario.yaml::policy_benchmark[{p}-problem{i}]" for s, i in (("all", 1000), ("pm", 29))
                        for p in ("mine", "random")}
    for key, record in ran.items():
        assert "goal_rate" in record["figures"], (key, record)
