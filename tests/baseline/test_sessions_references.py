"""Baselines that do not fit: stale, missing, corrupt or left over; the Regression section's
overrides; --driveeval-compare with an earlier run; the options' usage errors."""
from __future__ import annotations

import json
import re
import shutil

import pytest

pytest.importorskip("torch")

from module_pytester import module_pytester  # noqa: E402
from baseline_sessions import (  # noqa: E402
    BASELINES,
    baseline_path,
    closed_loop,
    edit_baseline,
    policy_benchmark,
    records,
    run,
    statuses,
    summary,
    with_closed_loop_data,
)

DRIVE = "drive.scenario.yaml::closed_loop[logs]"
NO_BASELINE = "no baseline yet: run with --driveeval-baseline-update"


@pytest.fixture
def cl(pytester):
    with_closed_loop_data(pytester)
    return pytester


def short(**kw) -> str:
    return closed_loop(**{"scenes": "[0, 1]", "steps": 10, **kw})


@pytest.fixture(scope="module")
def short_updated(request, tmp_path_factory):
    """A folder with drive=short() and its baseline written, made once per module."""
    with module_pytester(request, tmp_path_factory) as pytester:
        with_closed_loop_data(pytester)
        pytester.makefile(".scenario.yaml", drive=short())
        run(pytester, "--driveeval-baseline-update").assert_outcomes(passed=1)
        return pytester.path


@pytest.fixture
def cl_updated(cl, short_updated):
    """``cl`` as it is after updating drive=short()'s baseline: a copy of the module's folder."""
    shutil.copytree(short_updated, cl.path, dirs_exist_ok=True)
    return cl


@pytest.mark.parametrize("before, after, said", [
    ("Steps: 10", "Steps: 12", "the settings changed (Evaluation.Unroll.Steps 10 -> 12)"),
    ("Scenes: [0, 1]", "Scenes: [0, 2]", "the settings changed (Evaluation.Unroll.Scenes [0, 1] -> [0, 2])"),
])
def test_a_baseline_made_with_other_settings_is_stale_not_compared_and_fails_only_when_strict(cl_updated, before, after,
                                                                                            said):
    cl = cl_updated
    path = cl.path / "drive.scenario.yaml"
    path.write_text(path.read_text().replace(before, after))
    result = run(cl)
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["driveeval baselines (baselines): 1 stale"])
    comparison = records(cl)[DRIVE]["comparison"]
    assert comparison["status"] == "stale" and comparison["changes"] == []
    assert said in comparison["message"] and comparison["message"].endswith("not compared (update the baseline)")
    # Without strict the item passes, and its row still says why the baseline is stale.
    table = " ".join(line.strip() for line in result.stdout.lines)
    assert f"baseline: stale baseline `no commit` (" in table and said in table
    result = run(cl, "--driveeval-baseline-strict")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["*BaselineRequired: stale baseline `no commit` (*): the settings changed (*"])


def test_a_policy_baseline_of_other_episodes_is_stale(cl):
    cl.makefile(".scenario.yaml", bench=policy_benchmark(policies="    idm: idm_expert", episodes=4))
    run(cl, "--driveeval-baseline-update").assert_outcomes(passed=1)
    cl.makefile(".scenario.yaml", bench=policy_benchmark(policies="    idm: idm_expert", episodes=4, first_seed=7))
    run(cl).assert_outcomes(passed=1)
    (comparison,) = [r["comparison"] for r in records(cl).values()]
    assert comparison["status"] == "stale" and "Evaluation.FirstSeed 100 -> 7" in comparison["message"]


def test_a_missing_baseline_is_reported_and_fails_only_when_strict(cl):
    cl.makefile(".scenario.yaml", drive=short())
    result = run(cl)
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["driveeval baselines (baselines): 1 missing; missing ones: run with "
                                 "--driveeval-baseline-update"])
    assert records(cl)[DRIVE]["comparison"]["message"] == NO_BASELINE
    assert not (cl.path / BASELINES).exists()  # comparing writes nothing
    result = run(cl, "--driveeval-baseline-strict")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines([f"*{NO_BASELINE}*"])
    cl.makeini("[pytest]\ndriveeval_baseline = baselines\ndriveeval_baseline_strict = true\n")
    result = cl.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines(["driveeval baselines (baselines): 1 missing; *"])
    assert records(cl)[DRIVE]["status"] == "failed"
    # With the ini's folder, an update makes it pass under the ini's strict.
    cl.runpytest("-q", "-p", "no:randomly", "--driveeval-baseline-update").assert_outcomes(passed=1)
    cl.runpytest("-q", "-p", "no:randomly").assert_outcomes(passed=1)
    assert statuses(cl) == {DRIVE: "unchanged"}


def test_a_corrupt_baseline_fails_its_item_naming_file_and_key_and_the_others_run(cl):
    names = ("good", "cut", "text", "moved", "dataset", "commit", "search", "newer")
    cl.makefile(".scenario.yaml", **{n: short(name=n) for n in names})
    run(cl, "--driveeval-baseline-update").assert_outcomes(passed=len(names))
    node = {n: f"{n}.scenario.yaml::closed_loop[logs]" for n in names}
    cut = baseline_path(cl, node["cut"])
    cut.write_text(cut.read_text()[:200])
    edit_baseline(cl, node["text"], lambda d: d["figures"].update(
        max_displacement="__import__('pathlib').Path('pwned').touch() or 0"))
    edit_baseline(cl, node["moved"], lambda d: d["key"].update(nodeid=node["good"]))
    edit_baseline(cl, node["dataset"], lambda d: d["fingerprint"].update(dataset="gen.zarr"))
    edit_baseline(cl, node["commit"], lambda d: d["run"].update(commit=1234))
    edit_baseline(cl, node["search"], lambda d: d.update(search={"broke": True, "minimal": [0.1]}))
    edit_baseline(cl, node["newer"], lambda d: d.update(driveeval_baseline=2))
    result = run(cl)
    result.assert_outcomes(passed=1, failed=len(names) - 1)
    by_id = records(cl)
    assert by_id[node["good"]]["comparison"]["status"] == "unchanged"
    messages = {n: by_id[node[n]]["comparison"]["message"] for n in names[1:]}
    assert all(by_id[node[n]]["comparison"]["status"] == "error" for n in names[1:])
    where = {n: f"baseline {BASELINES}/{n}.scenario.yaml.d/closed_loop[logs].json" for n in names}
    assert messages["cut"].startswith(f"{where['cut']} of {node['cut']} is not valid JSON (truncated?)")
    assert messages["moved"].startswith(f"{where['moved']}: key 'key.nodeid' says '{node['good']}'")
    assert messages["newer"].startswith(f"{where['newer']}: format 2 (key 'driveeval_baseline') is newer than this pytest-driveeval reads (1)")
    for name, key in [("text", "'figures.max_displacement' is not a number"),
                      ("dataset", "'fingerprint.dataset' is a str, not a dict"),
                      ("commit", "'run.commit' is a int, not a str"),
                      ("search", "'search.minimal' is a list, not a dict")]:
        assert messages[name] == f"{where[name]} of {node[name]}: key {key}; rewrite it with " \
                                 "--driveeval-baseline-update"
    for n in names[1:]:
        result.stdout.fnmatch_lines([f"*{re.sub(r'[][]', '?', messages[n][:90])}*"])
    assert "Traceback" not in result.stdout.str()
    assert not list(cl.path.rglob("pwned"))  # a baseline is read as data, never run
    # An update rewrites them.
    run(cl, "--driveeval-baseline-update").assert_outcomes(passed=len(names))
    run(cl).assert_outcomes(passed=len(names))


def test_a_hand_edited_earlier_run_fails_the_item_naming_the_run_and_key(cl):
    cl.makefile(".scenario.yaml", drive=short(), other=short(name="other"))
    cl.runpytest("-q", "-p", "no:randomly").assert_outcomes(passed=2)
    path = cl.path / "driveeval-results" / "runs" / summary(cl)["run"]["id"] / "summary.json"
    data = json.loads(path.read_text())
    next(r for r in data["results"] if r["nodeid"] == DRIVE)["baseline"]["figures"]["at_fault"] = "0"
    path.write_text(json.dumps(data))
    result = cl.runpytest("-q", "-p", "no:randomly", "--driveeval-compare", str(path))
    result.assert_outcomes(passed=1, failed=1)
    assert records(cl)[DRIVE]["comparison"]["message"] == (
        f"run {data['run']['id']} ({path.relative_to(cl.path)}): the record of {DRIVE} cannot be compared: "
        "key 'figures.at_fault' is not a number")


def test_prune_removes_baselines_of_items_gone_and_keeps_those_not_selected(cl):
    policies = "    idm: idm_expert\n    steady: constant"
    cl.makefile(".scenario.yaml", a=short(name="a"), b=short(name="b"),
                bench=policy_benchmark(policies=policies, episodes=4))
    run(cl, "--driveeval-baseline-update").assert_outcomes(passed=4)
    (cl.path / "b.scenario.yaml").unlink()
    cl.makefile(".scenario.yaml", bench=policy_benchmark(policies="    idm: idm_expert", episodes=4))
    gone = [baseline_path(cl, "b.scenario.yaml::closed_loop[logs]"),
            baseline_path(cl, "bench.scenario.yaml::policy_benchmark[steady]")]
    kept = [baseline_path(cl, "a.scenario.yaml::closed_loop[logs]"),
            baseline_path(cl, "bench.scenario.yaml::policy_benchmark[idm]")]
    result = run(cl, "-k", "bench")
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["driveeval baselines: 2 of items that no longer exist (baselines/b.scenario.yaml.d/"
                                 "closed_loop[[]logs[]].json, baselines/bench.scenario.yaml.d/"
                                 "policy_benchmark[[]steady[]].json); --driveeval-baseline-update "
                                 "--driveeval-baseline-prune removes them"])
    assert all(p.is_file() for p in gone + kept)
    before = kept[0].read_text()
    result = run(cl, "-k", "bench", "--driveeval-baseline-update", "--driveeval-baseline-prune")
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["driveeval baselines: removed 2 of items that no longer exist"])
    assert not any(p.exists() for p in gone) and not (cl.path / BASELINES / "b.scenario.yaml").exists()
    assert all(p.is_file() for p in kept)  # a.scenario.yaml was only not selected
    assert kept[0].read_text() == before  # and an update leaves the baselines of items that did not run alone
    result = run(cl)
    result.assert_outcomes(passed=2)
    assert "no longer exist" not in result.stdout.str()


def test_an_item_that_cannot_run_keeps_its_baseline_through_an_update(cl_updated):
    cl = cl_updated
    before = baseline_path(cl, DRIVE).read_text()
    shutil.rmtree(cl.path / "gen.zarr")
    result = run(cl, "--driveeval-baseline-update")
    assert result.ret == pytest.ExitCode.TESTS_FAILED and records(cl)[DRIVE]["status"] == "error"
    result.stdout.fnmatch_lines(["driveeval baselines: wrote 0 in baselines"])
    assert baseline_path(cl, DRIVE).read_text() == before


def test_a_bad_figure_name_in_the_regression_section_is_located(cl):
    cl.makefile(".scenario.yaml", drive=short(regression="Regression:\n  Figures:\n    max_displacment: {Atol: 1}\n"))
    result = run(cl)
    result.assert_outcomes(failed=1)  # as every invalid scenario file: a failed item, no run
    result.stdout.fnmatch_lines(["*drive.scenario.yaml:19: Regression.Figures.max_displacment: 'max_displacment' is "
                                 "not a figure closed_loop compares with a baseline; did you mean 'max_displacement'?"])
    assert "Traceback" not in result.stdout.str()


@pytest.mark.parametrize("regression, status", [
    ("", "regressed"),
    ("Regression:\n  Figures:\n    max_displacement: {Atol: 0.5}\n", "unchanged"),
    ("Regression:\n  Figures:\n    max_displacement: {Ignore: true}\n", "unchanged"),
])
def test_the_regression_section_decides_what_counts_as_worse(cl, regression, status):
    # constant velocity for 20 steps: about a metre off the log, no collision
    cl.makefile(".scenario.yaml", drive=short(model="constant_velocity", steps=20, regression=regression))
    run(cl, "--driveeval-baseline-update").assert_outcomes(passed=1)
    now = records(cl)[DRIVE]["figures"]["max_displacement"]
    assert now > 0.5
    edit_baseline(cl, DRIVE, lambda d: d["figures"].update(max_displacement=now - 0.3))
    run(cl).assert_outcomes(**({"failed": 1} if status == "regressed" else {"passed": 1}))
    record = records(cl)[DRIVE]
    assert record["comparison"]["status"] == status
    assert ("max_displacement" in record["baseline"]["figures"]) == ("Ignore" not in regression)
    if status == "regressed":
        (change,) = record["comparison"]["changes"]
        assert change["text"].startswith(f"max_displacement {now - 0.3:.4g} -> {now:.4g} (lower is better; tolerance ")


def test_compare_with_an_earlier_run_by_last_run_id_or_summary_path(cl):
    cl.makefile(".scenario.yaml", drive=short())
    cl.runpytest("-q", "-p", "no:randomly").assert_outcomes(passed=1)
    first = summary(cl)["run"]["id"]
    compare = ["-q", "-p", "no:randomly", "--driveeval-compare"]
    result = cl.runpytest(*compare, "last")
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines([f"driveeval baselines (run driveeval-results/runs/{first}/summary.json): 1 unchanged"])
    assert records(cl)[DRIVE]["comparison"]["against"].startswith(f"run {first} (")
    result = cl.runpytest(*compare, first, "--driveeval-model", "constant_velocity")
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines([f"*regression against run {first} (`no commit`, *):",
                                 "    max_displacement * -> * (lower is better; tolerance *"])
    path = f"driveeval-results/runs/{first}/summary.json"
    cl.runpytest(*compare, path).assert_outcomes(passed=1)
    assert statuses(cl) == {DRIVE: "unchanged"}
    fourth = summary(cl)["run"]["id"]
    # 'last' is the newest run before this session's
    cl.runpytest(*compare, "last", "--driveeval-model", "constant_velocity").assert_outcomes(failed=1)
    assert records(cl)[DRIVE]["comparison"]["against"].startswith(f"run {fourth} (")
    assert statuses(cl) == {DRIVE: "regressed"}


@pytest.mark.parametrize("args, said", [
    (["--driveeval-compare", "nosuchrun"], "*--driveeval-compare: 'nosuchrun' is neither 'last', 'last~N', a run id*"),
    (["--driveeval-baseline-update"], "*--driveeval-baseline-update / -prune need the baseline folder*"),
    (["--driveeval-baseline", "b", "--driveeval-baseline-prune"],
     "*--driveeval-baseline-prune removes baselines while updating them: add --driveeval-baseline-update"),
    (["--driveeval-baseline", "notes.txt"], "*--driveeval-baseline notes.txt: */notes.txt is a file, not a folder; the "
                                            "baselines are a folder of files, one per item*"),
    (["--driveeval-baseline", "notes.txt", "--driveeval-baseline-update"], "*notes.txt is a file, not a folder*"),
])
def test_options_that_cannot_work_are_usage_errors(cl, args, said):
    cl.makefile(".scenario.yaml", drive=short())
    (cl.path / "notes.txt").write_text("not a folder")
    result = cl.runpytest("-q", *args)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines([said])
    assert not (cl.path / "driveeval-results").exists() and not (cl.path / "b").exists()


@pytest.mark.parametrize("tolerance, said", [
    ("{lateral: 0.1, speedscale: 0.2}", "'speedscale' is not a parameter closed_loop's robustness search reports; "
                                        "did you mean 'speed_scale'?"),
    ("{Lateral: 0.1}", "'Lateral' is not a parameter closed_loop's robustness search reports; did you mean 'lateral'?"),
])
def test_a_misspelt_search_tolerance_parameter_is_located(cl, tolerance, said):
    cl.makefile(".scenario.yaml", drive=short(regression=f"Regression:\n  Search:\n    Tolerance: {tolerance}\n"))
    result = run(cl)
    result.assert_outcomes(failed=1)
    result.stdout.fnmatch_lines([f"*drive.scenario.yaml:19: Regression.Search.Tolerance.*: {said}"])
    assert "Traceback" not in result.stdout.str()


def test_the_names_a_search_tolerance_takes_are_those_its_search_reports():
    import dataclasses

    from pytest_driveeval.scenario.load import searched_parameters
    from pytest_driveeval.strategies import CloudPerturbation, EpisodePerturbation, StartPerturbation
    from pytest_driveeval.core.usecase import get_usecase

    for name, kind in (("closed_loop", StartPerturbation), ("policy_benchmark", EpisodePerturbation),
                       ("obstacle_segmentation", CloudPerturbation)):
        assert searched_parameters(get_usecase(name)) == [f.name for f in dataclasses.fields(kind)]
