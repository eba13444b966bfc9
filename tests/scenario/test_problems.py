"""Malformed scenario files: one located, tracebackless failure each; the rest run."""
from __future__ import annotations

import json

import pytest

from conftest import speed_scenario

GOOD = speed_scenario("good")

# name -> (file text, lines the failure must show)
MALFORMED = {
    "syntax": (
        "ScenarioFormatVersion: 3.0.0\nScenarioName: x\nEvaluation:\n  UseCaseName: [speed_limit\n",
        ["*syntax.scenario.yaml:4: YAML syntax error*"],
    ),
    "wrong_type": (
        speed_scenario("w").replace("MaxSpeed: 14.0", "MaxSpeed: fast"),
        ["*wrong_type.scenario.yaml:10: Evaluation.Conditions.MaxSpeed: expected a valid number*found 'fast' (str)"],
    ),
    "missing_key": (
        speed_scenario("m").replace("ScenarioName: m\n", ""),
        ["*missing_key.scenario.yaml:1: missing required key 'ScenarioName'"],
    ),
    "unknown_key": (
        speed_scenario("u").replace("ScenarioDescription", "ScenarioDescripton"),
        ["*unknown_key.scenario.yaml:3: ScenarioDescripton: unknown key 'ScenarioDescripton'; "
         "did you mean 'ScenarioDescription'?"],
    ),
    "misspelt_condition": (
        speed_scenario("c").replace("MaxSpeed", "MaxSped"),
        ["*misspelt_condition.scenario.yaml:10: Evaluation.Conditions.MaxSped: unknown key 'MaxSped'; "
         "did you mean 'MaxSpeed'?"],
    ),
    "scenario_version": (
        speed_scenario("v").replace("ScenarioFormatVersion: 3.0.0", "ScenarioFormatVersion: 9.0.0"),
        ["*scenario_version.scenario.yaml:1: ScenarioFormatVersion: unsupported version '9.0.0'; supported: 2.x, 3.x"],
    ),
    "usecase_version": (
        speed_scenario("uv").replace("UseCaseFormatVersion: 0.1.0", "UseCaseFormatVersion: 7.0.0"),
        ["*usecase_version.scenario.yaml:6: Evaluation.UseCaseFormatVersion: unsupported version '7.0.0' "
         "of use case 'speed_limit'; supported: 0.1.0"],
    ),
    "unknown_usecase": (
        speed_scenario("uu").replace("UseCaseName: speed_limit", "UseCaseName: sped_limit"),
        ["*unknown_usecase.scenario.yaml:5: Evaluation.UseCaseName: unknown use case 'sped_limit'; "
         "did you mean 'speed_limit'?"],
    ),
    "duplicate_key": (
        speed_scenario("d").replace("    MaxSpeed: 14.0", "    MaxSpeed: 14.0\n    MaxSpeed: 15.0"),
        ["*duplicate_key.scenario.yaml:11: YAML syntax error*duplicate key 'MaxSpeed' (first defined on line 10)"],
    ),
    "empty": ("", ["*empty.scenario.yaml:1: expected a mapping at the top level; found an empty file"]),
    "dataset_entry": (
        speed_scenario("de").replace("    - slow.csv: {}", "    - {a: {}, b: {}}"),
        ["*dataset_entry.scenario.yaml:8: Evaluation.Datasets[[]0[]]: each dataset entry is a mapping with one key*"],
    ),
    "alias_bomb": (
        # "Billion laughs": 300 bytes that expand to 10**9 values.
        "a: &a [" + ", ".join(["lol"] * 9) + "]\n"
        + "".join(f"{k}: &{k} [{', '.join([f'*{p}'] * 9)}]\n" for p, k in zip("abcdefgh", "bcdefghi")),
        ["*alias_bomb.scenario.yaml:6: this value expands to 597,871 values through anchors and aliases*"
         "at most 100,000"],
    ),
    "recursive_alias": ("a: &a [1, *a]\n", ["*recursive_alias.scenario.yaml:1: an alias refers to a value that "
                                             "contains it*"]),
    "nested_brackets": ("[" * 20_000, ["*nested_brackets.scenario.yaml:1: values nested too deeply*"]),
    "nested_mappings": ("a:\n" + "".join("  " * i + f"k{i}:\n" for i in range(1, 80)),
                        ["*nested_mappings.scenario.yaml:17: from here down, values are nested more than 64 levels deep*"]),
}


@pytest.mark.parametrize("kind", sorted(MALFORMED))
def test_malformed_file_fails_alone_with_a_located_message(project, kind):
    text, expected = MALFORMED[kind]
    project.makefile(".scenario.yaml", good=GOOD, **{kind: text})
    result = project.runpytest("-q")
    result.assert_outcomes(passed=1, failed=1)
    assert result.ret == 1
    result.stdout.fnmatch_lines(expected)
    assert "Traceback" not in result.stdout.str()
    assert "pytest_driveeval/" not in result.stdout.str()  # none of our frames


def test_several_problems_in_one_file_are_all_listed(project):
    text = speed_scenario("many").replace("MaxSpeed: 14.0", "MaxSpeed: -3\n    Extra: 1").replace(
        "ScenarioDescription", "Descr")
    project.makefile(".scenario.yaml", many=text)
    result = project.runpytest("-q")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines([
        "*many.scenario.yaml (3 problems):",
        "*:3: Descr: unknown key 'Descr'*",
        "*:10: Evaluation.Conditions.MaxSpeed: expected greater than 0*",
        "*:11: Evaluation.Conditions.Extra: unknown key 'Extra'*",
    ])


def test_every_malformed_file_at_once_leaves_the_good_ones_running(project):
    project.makefile(".scenario.yaml", good=GOOD, also_good=speed_scenario("g2"),
                     **{k: v[0] for k, v in MALFORMED.items()})
    result = project.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(passed=2, failed=len(MALFORMED))


def test_missing_dataset_is_a_clear_runtime_failure(project):
    project.makefile(".scenario.yaml", good=GOOD, nodata=speed_scenario("nd", datasets=("absent.csv",)))
    result = project.runpytest("-q")
    # The dataset fixture fails in setup, which pytest counts as an error.
    result.assert_outcomes(passed=1, errors=1)
    result.stdout.fnmatch_lines(["*DataError: dataset 'absent.csv' not found at *absent.csv*nodata.scenario.yaml:8*"])
    assert "Traceback" not in result.stdout.str()


def test_corrupt_dataset_names_the_file(project):
    (project.path / "garbage.csv").write_text("t,x,y\n1,2\nnot,a,number\n")
    project.makefile(".scenario.yaml", bad=speed_scenario("b", datasets=("garbage.csv",)))
    result = project.runpytest("-q")
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines(["*DataError: *garbage.csv:2: not a CSV of t,x,y: expected 3 numbers separated by commas"])
    assert "Traceback" not in result.stdout.str()


@pytest.mark.parametrize("content", [
    "-----BEGIN OPENSSH PRIVATE KEY-----\nb3BlbnNzaC1rZXktdjEAAAAABG5vbmUAAAAE\n-----END OPENSSH PRIVATE KEY-----\n",
    "root:x:0:0:root:/root:/bin/bash\ndaemon:x:1:1:daemon:/usr/sbin:/usr/sbin/nologin\n",
    "header\n\x1b[2J\x00\x07" + "binary" * 20 + "\n",
])
def test_a_file_that_is_not_the_expected_format_is_named_never_quoted(project, content):
    secret = project.path / "elsewhere" / "passwd"
    secret.parent.mkdir()
    secret.write_text(content)
    text = speed_scenario("p", datasets=("secret",)).replace("    - secret: {}", "    - secret: {Path: elsewhere/passwd}")
    project.makefile(".scenario.yaml", good=GOOD, leak=text)
    result = project.runpytest("-q")
    result.assert_outcomes(passed=1, errors=1)
    result.stdout.fnmatch_lines(["*DataError: *elsewhere/passwd:2: not a CSV of t,x,y: "
                                 "expected 3 numbers separated by commas"])
    out = project.path / "driveeval-results"
    run = out / "runs" / json.loads((out / "summary.json").read_text())["run"]["id"]
    second = content.splitlines()[1]
    for shown in (result.stdout.str(), *(p.read_text() for p in (out / "summary.json", out / "summary.md",
                                                                   run / "summary.json", run / "summary.md"))):
        assert second[:6] not in shown and "\x1b" not in shown


def test_bug_in_a_use_case_still_shows_its_traceback(project):
    # Our errors hide the traceback; a genuine exception in user code keeps it.
    project.makeconftest("import speed_limit\n"
                         "import pytest\n"
                         "@pytest.fixture\n"
                         "def driveeval_dataset():\n"
                         "    raise ZeroDivisionError('bug in my loader')\n")
    project.makefile(".scenario.yaml", good=GOOD)
    result = project.runpytest("-q")
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines(["*ZeroDivisionError: bug in my loader*"])
    assert "def driveeval_dataset" in result.stdout.str()


def test_a_scenario_symlink_that_leads_nowhere_is_a_located_failure(project):
    project.makefile(".scenario.yaml", good=GOOD)
    (project.path / "loop.scenario.yaml").symlink_to("loop.scenario.yaml")
    (project.path / "gone.scenario.yaml").symlink_to("deleted.yaml")
    result = project.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(passed=1, failed=2)
    result.stdout.fnmatch_lines_random([
        "*gone.scenario.yaml: a symbolic link to *deleted.yaml, which does not exist",
        "*loop.scenario.yaml: cannot open the file: *loop*",
    ])
    assert "Traceback" not in result.stdout.str()


def test_a_dataset_path_that_is_a_symlink_loop_or_a_folder_fails_alone(project):
    (project.path / "a").symlink_to("b")
    (project.path / "b").symlink_to("a")
    (project.path / "folder.csv").mkdir()
    loop = speed_scenario("l", datasets=("looped",)).replace("    - looped: {}", "    - looped: {Path: a}")
    project.makefile(".scenario.yaml", good=GOOD, loop=loop, folder=speed_scenario("f", datasets=("folder.csv",)))
    result = project.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(passed=1, failed=1, errors=1)
    result.stdout.fnmatch_lines_random([
        "*loop.scenario.yaml:8: Evaluation.Datasets[[]0[]]: dataset 'looped': cannot resolve *a: *loop*",
        "*DataError: *folder.csv: cannot read a CSV of t,x,y: Is a directory",
    ])
    assert "Traceback" not in result.stdout.str()
