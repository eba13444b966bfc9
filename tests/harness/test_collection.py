"""Scenario files become items: patterns, ids, order, marks."""
from __future__ import annotations

import shutil

from conftest import POLICY_BENCHMARK_HEAD, speed_scenario


def collected_ids(result) -> list[str]:
    return [line for line in result.outlines if "::" in line]


def test_every_default_file_pattern_is_collected(project):
    project.makefile(".scenario.yaml", a=speed_scenario("a"))
    project.makefile(".scenario.yml", b=speed_scenario("b"))
    (project.path / "sub").mkdir()
    (project.path / "sub" / "scenario.yaml").write_text(speed_scenario("c", datasets=("../slow.csv",)))
    (project.path / "other").mkdir()
    (project.path / "other" / "scenario.yml").write_text(speed_scenario("d", datasets=("../slow.csv",)))
    project.makefile(".yaml", not_a_scenario=speed_scenario("e"))
    result = project.runpytest("--collect-only", "-q")
    assert collected_ids(result) == [
        "a.scenario.yaml::speed_limit[slow.csv]",
        "b.scenario.yml::speed_limit[slow.csv]",
        "other/scenario.yml::speed_limit[../slow.csv]",
        "sub/scenario.yaml::speed_limit[../slow.csv]",
    ]


DLR_NAMES = ("scenario.yaml", "scenario.ja.yaml", "scenario_detection_only.yaml", "scenario_non_detection_only.yaml")


def test_driving_log_replayer_names_are_collected_and_other_yaml_so_named_is_skipped(project):
    for name in DLR_NAMES:
        (project.path / "dlr").mkdir(exist_ok=True)
        (project.path / "dlr" / name).write_text(speed_scenario(name.split(".")[0], datasets=("../slow.csv",)))
    (project.path / "dlr" / "scenario_settings.yaml").write_text("colour: blue\nsizes: [1, 2]\n")
    (project.path / "dlr" / "scenario_list.yaml").write_text("- a\n- b\n")
    # Named as a scenario, it is one: an envelope-less file is an error, not skipped.
    project.makefile(".scenario.yaml", declared="colour: blue\n")
    result = project.runpytest("--collect-only", "-q")
    assert collected_ids(result) == ["declared.scenario.yaml::scenario"] + sorted(
        f"dlr/{name}::speed_limit[../slow.csv]" for name in DLR_NAMES)


def test_the_real_driving_log_replayer_samples_are_collected_without_options(project, shared_data):
    for path in sorted((shared_data / "driving_log_replayer" / "obstacle_segmentation").glob("scenario*.yaml")):
        shutil.copy(path, project.path / path.name)
    shutil.copy(project.path / "scenario.yaml", project.path / "scenario.ja.yaml")
    result = project.runpytest("--collect-only", "-q")
    assert collected_ids(result) == sorted(f"{name}::obstacle_segmentation[sample_dataset]" for name in DLR_NAMES)


def test_ini_option_changes_the_patterns(project):
    project.makeini("[pytest]\ndriveeval_patterns = *.case.yaml\n")
    project.makefile(".case.yaml", mine=speed_scenario("mine"))
    project.makefile(".scenario.yaml", ignored=speed_scenario("ignored"))
    result = project.runpytest("--collect-only", "-q")
    assert collected_ids(result) == ["mine.case.yaml::speed_limit[slow.csv]"]


def test_one_item_per_dataset_in_file_order_and_deterministic(project):
    project.makefile(".scenario.yaml", multi=speed_scenario("m", datasets=("slow.csv", "fast.csv")))
    first = collected_ids(project.runpytest("--collect-only", "-q"))
    second = collected_ids(project.runpytest("--collect-only", "-q"))
    assert first == second == [
        "multi.scenario.yaml::speed_limit[slow.csv]",
        "multi.scenario.yaml::speed_limit[fast.csv]",
    ]


def test_scenario_without_datasets_gives_one_item_named_by_use_case(project):
    project.makefile(".scenario.yaml", nodata=speed_scenario("n", datasets=()))
    assert collected_ids(project.runpytest("--collect-only", "-q")) == ["nodata.scenario.yaml::speed_limit"]


def test_marks_from_yaml_select_with_m(project):
    project.makefile(".scenario.yaml", quick=speed_scenario("quick", extra="Marks: [smoke]\n"))
    project.makefile(".scenario.yaml", longer=speed_scenario("longer"))
    result = project.runpytest("-m", "smoke", "-q")
    result.assert_outcomes(passed=1, deselected=1)
    result = project.runpytest("-m", "not smoke", "-q")
    result.assert_outcomes(passed=1, deselected=1)


def test_an_unregistered_mark_warns_at_its_line_of_the_yaml_file(project):
    project.makefile(".scenario.yaml", copied=speed_scenario("copied", extra="Marks: [smoke, mymark]\n"))
    result = project.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["*copied.scenario.yaml:4: PytestUnknownMarkWarning: unknown mark 'mymark' in Marks, "
                                 "a typo or not registered: register it under 'markers' in pytest.ini*",
                                 "    Marks: [[]smoke, mymark[]]"])
    assert "collect.py" not in result.stdout.str()
    assert "'smoke'" not in result.stdout.str()  # registered in the project's ini
    # The mark is still the item's: -m selects it.
    project.runpytest("-q", "-m", "mymark").assert_outcomes(passed=1)


def test_an_unregistered_mark_under_strict_markers_fails_its_file_alone_at_its_line(project):
    project.makefile(".scenario.yaml", copied=speed_scenario("copied", extra="Marks:\n  - smoke\n  - mymark\n"),
                     other=speed_scenario("other"))
    result = project.runpytest("-q", "--strict-markers", "-p", "no:randomly")
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(["*invalid scenario file copied.scenario.yaml:",
                                 "*copied.scenario.yaml:6: Marks[[]1[]]: mark 'mymark' is not registered, and "
                                 "--strict-markers is on: register it under 'markers' in pytest.ini*"])
    assert "collect.py" not in result.stdout.str()


def test_k_matches_file_name_dataset_use_case_and_marks(project):
    project.makefile(".scenario.yaml", one=speed_scenario("highway-merge", datasets=("slow.csv", "fast.csv"),
                                                          max_speed=30, extra="Marks: [smoke]\n"))
    project.makefile(".scenario.yaml", two=speed_scenario("parking"))
    project.runpytest("-k", "one", "-q").assert_outcomes(passed=2, deselected=1)
    project.runpytest("-k", "fast", "-q").assert_outcomes(passed=1, deselected=2)
    project.runpytest("-k", "speed_limit and not one", "-q").assert_outcomes(passed=1, deselected=2)
    project.runpytest("-k", "smoke", "-q").assert_outcomes(passed=2, deselected=1)


def test_k_does_not_match_the_scenario_name_or_description(project):
    """The demo's -k urban took on_ramp too (ScenarioName on-ramp-urban-limit): free text selects nothing."""
    project.makefile(".scenario.yaml", urban=speed_scenario("urban-speed-limit", datasets=("slow.csv",)))
    project.makefile(".scenario.yaml", on_ramp=speed_scenario("on-ramp-urban-limit", datasets=("fast.csv",))
                     .replace("speeds under the limit", "an urban on-ramp"))
    result = project.runpytest("--collect-only", "-q", "-k", "urban")
    assert collected_ids(result) == ["urban.scenario.yaml::speed_limit[slow.csv]"]
    assert collected_ids(project.runpytest("--collect-only", "-q", "-k", "ramp")) == [
        "on_ramp.scenario.yaml::speed_limit[fast.csv]"]


def test_k_selects_the_policy_of_a_benchmark_named_after_two_policies(project):
    """The demo's -k gnn selected every policy of highway-gnn-vs-mlp."""
    project.makefile(".scenario.yaml", highway=POLICY_BENCHMARK_HEAD.format(name="highway-gnn-vs-mlp") + """\
  Blueprint: {Name: highway}
  Episodes: 4
  Policies: {gnn: constant, mlp: random, idm: idm_expert, constant: constant}
  Judged: [gnn, mlp]
  Conditions:
    GoalRate: {AtLeast: 0}
""")
    result = project.runpytest("--collect-only", "-q", "-k", "gnn")
    assert collected_ids(result) == ["highway.scenario.yaml::policy_benchmark[gnn]"]
    result = project.runpytest("--collect-only", "-q", "-k", "highway and not gnn and not mlp")
    assert collected_ids(result) == ["highway.scenario.yaml::policy_benchmark[idm]",
                                     "highway.scenario.yaml::policy_benchmark[constant]"]


def test_skip_and_xfail_from_yaml(project):
    project.makefile(".scenario.yaml", skipped=speed_scenario("s", extra="Skip: map not released yet\n"))
    project.makefile(".scenario.yaml", known=speed_scenario(
        "k", datasets=("fast.csv",), extra="XFail: planner overshoots, ticket 12\n"))
    project.makefile(".scenario.yaml", strict=speed_scenario(
        "st", extra="XFail:\n  Reason: should fail\n  Strict: true\n"))
    result = project.runpytest("-rsxX", "-q")
    result.assert_outcomes(skipped=1, xfailed=1, failed=1)
    result.stdout.fnmatch_lines(["*XPASS?strict?*should fail*"])
    result.stdout.fnmatch_lines(["*map not released yet*", "*planner overshoots, ticket 12*"])


def test_reportinfo_points_at_the_yaml_file(project):
    project.makefile(".scenario.yaml", located=speed_scenario("loc", datasets=("fast.csv",)))
    result = project.runpytest("-q")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*loc [[]speed_limit[[]fast.csv[]][]]*"])
