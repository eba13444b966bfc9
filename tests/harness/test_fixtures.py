"""Fixtures feed scenario items; conftest.py and options override them."""
from __future__ import annotations

import json

import pytest

from conftest import GAIN_SCENARIO, speed_scenario


def summary(pytester, folder="driveeval-results") -> dict:
    return json.loads((pytester.path / folder / "summary.json").read_text())


def figures(pytester) -> dict[str, float]:
    return {r["nodeid"]: r["figures"]["output"] for r in summary(pytester)["results"]}


def test_default_model_comes_from_the_use_case(gain):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"))
    gain.runpytest("-q").assert_outcomes(passed=1)
    assert figures(gain) == {"a.scenario.yaml::gain": 6.0}


def test_conftest_override_of_the_model_changes_what_a_yaml_scenario_evaluates(gain):
    for folder in ("mine", "theirs"):
        (gain.path / folder).mkdir()
        (gain.path / folder / "scenario.yaml").write_text(GAIN_SCENARIO.format(name=folder))
    (gain.path / "mine" / "conftest.py").write_text(
        "import pytest\n\n@pytest.fixture\ndef driveeval_model():\n    return lambda x: 10 * x\n")
    result = gain.runpytest("-q")
    result.assert_outcomes(passed=1, failed=1)
    assert figures(gain) == {"mine/scenario.yaml::gain": 30.0, "theirs/scenario.yaml::gain": 6.0}
    result.stdout.fnmatch_lines(["*scenario 'mine' (gain)*", "*FAILED: output 30.0*"])


def test_model_option_and_ini_replace_the_scenario_model(gain):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"))
    gain.runpytest("-q", "--driveeval-model", "mymodels:triple").assert_outcomes(passed=1)
    assert figures(gain) == {"a.scenario.yaml::gain": 9.0}
    gain.makeini("[pytest]\ndriveeval_model = mymodels:triple\n")
    gain.runpytest("-q").assert_outcomes(passed=1)
    assert figures(gain) == {"a.scenario.yaml::gain": 9.0}


def test_python_test_bound_to_a_scenario_gets_the_same_fixtures(gain):
    gain.makefile(".yaml", bound=GAIN_SCENARIO.format(name="bound"))
    gain.makepyfile(test_bound='''
        import pytest
        from pytest_driveeval import assert_figure_within

        @pytest.mark.driveeval_scenario("bound.yaml")
        def test_output_is_small(driveeval_run, driveeval_model):
            assert driveeval_model(1) == 2
            outcome = driveeval_run()
            assert_figure_within(outcome, "output", max=5)
        ''')
    result = gain.runpytest("-q")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*scenario 'bound [[]gain[]]': output = 6, outside [[]None, 5[]]*"])
    # The test's outcome reaches the summary like a YAML item's.
    (record,) = summary(gain)["results"]
    assert record["nodeid"] == "test_bound.py::test_output_is_small"
    assert record["figures"]["output"] == 6.0 and record["status"] == "failed"


def test_unbound_python_test_gets_a_clear_failure(gain):
    gain.makepyfile(test_unbound="def test_x(driveeval_model):\n    pass\n")
    result = gain.runpytest("-q")
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines(["*is not a scenario item; mark it with @pytest.mark.driveeval_scenario*"])


def test_relative_paths_resolve_against_the_yaml_folder(project):
    (project.path / "scenarios" / "deep").mkdir(parents=True)
    (project.path / "data").mkdir()
    (project.path / "slow.csv").rename(project.path / "data" / "slow.csv")
    text = speed_scenario("rel", datasets=()).replace("    []", "    - logged:\n        Path: ../../data/slow.csv")
    (project.path / "scenarios" / "deep" / "x.scenario.yaml").write_text(text)
    project.runpytest("-q").assert_outcomes(passed=1)


@pytest.mark.parametrize("how", ["option", "ini", "env"])
def test_dataset_names_resolve_under_the_data_root(project, monkeypatch, how):
    root = project.path / "datasets"
    root.mkdir()
    (project.path / "fast.csv").rename(root / "fast.csv")
    project.makefile(".scenario.yaml", a=speed_scenario("a", datasets=("fast.csv",), max_speed=25))
    args = ["-q"]
    if how == "option":
        args += ["--driveeval-data-root", str(root)]
    elif how == "ini":
        project.makeini("[pytest]\ndriveeval_data_root = datasets\n")
    else:
        monkeypatch.setenv("DRIVEEVAL_DATA_ROOT", str(root))
    project.runpytest(*args).assert_outcomes(passed=1)


@pytest.mark.parametrize("how, where", [("option", "--driveeval-data-root"), ("ini", "ini driveeval_data_root"),
                                        ("env", "environment variable DRIVEEVAL_DATA_ROOT")])
@pytest.mark.parametrize("root, problem", [
    ("nowhere", "the data root 'nowhere' does not exist ("),
    ("a-file.csv", "the data root 'a-file.csv' is not a folder ("),
    ("data\x1b[2J\nroot", r"the data root 'data\x1b[2J\nroot' holds control characters; give a folder's path"),
])
def test_a_bad_data_root_is_a_usage_error_naming_where_it_was_set(project, monkeypatch, how, where, root, problem):
    """Up front, before any item: otherwise each item would fail on its own missing dataset. Control
    characters are shown escaped, never sent to the terminal."""
    good = project.path / "datasets"
    good.mkdir()
    (project.path / "fast.csv").rename(good / "fast.csv")
    (project.path / "a-file.csv").write_text("t,x,y\n")
    project.makefile(".scenario.yaml", a=speed_scenario("a", datasets=("fast.csv",), max_speed=25))
    project.runpytest("-q", "--driveeval-data-root", str(good)).assert_outcomes(passed=1)
    args = ["-q"]
    if how == "option":
        args += ["--driveeval-data-root", root]
    elif how == "ini":
        if "\n" in root:
            pytest.skip("an ini value is one line")
        project.makeini(f"[pytest]\ndriveeval_data_root = {root}\n")
    else:
        monkeypatch.setenv("DRIVEEVAL_DATA_ROOT", root)
    result = project.runpytest(*args)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    err = result.stderr.str()
    assert f"ERROR: {where}: {problem}" in err, err
    assert "\x1b" not in err + result.stdout.str()


@pytest.mark.parametrize("seed", ["-1", str(2 ** 63)])
def test_a_seed_numpy_cannot_take_is_a_usage_error(gain, seed):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"))
    gain.runpytest("-q", "--driveeval-seed", str(2 ** 63 - 1)).assert_outcomes(passed=1)
    result = gain.runpytest("-q", "--driveeval-seed", seed)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    assert f"must be a whole number from 0 to 2**63 - 1, as numpy's generators take, got '{seed}'" in \
        result.stderr.str()


def test_item_seeds_are_stable_distinct_and_follow_the_seed_option(gain):
    gain.makefile(".scenario.yaml", a=GAIN_SCENARIO.format(name="a"), b=GAIN_SCENARIO.format(name="b"))

    def seeds(*args):
        gain.runpytest("-q", *args)
        return {r["nodeid"]: r["figures"]["seed"] for r in summary(gain)["results"]}

    first, again, other = seeds(), seeds(), seeds("--driveeval-seed", "7")
    assert first == again
    assert len(set(first.values())) == 2
    assert all(first[k] != other[k] for k in first)
