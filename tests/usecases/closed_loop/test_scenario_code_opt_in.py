"""A scenario file must not run code on its own say: pickle: and module:factory
need the person running pytest to opt in; the command line keeps working."""
from __future__ import annotations

import shutil

import pytest

torch = pytest.importorskip("torch")

from conftest import REPO_ROOT  # noqa: E402
from test_closed_loop_usecase import scenario  # noqa: E402

REAL = REPO_ROOT / "fixtures" / "l5kit" / "single_scene.zarr"

EVIL_MODULE = """\
from pathlib import Path


def boom():
    Path("factory_ran").write_text("yes")
    from pytest_driveeval.policies.baselines import ReplayLogPolicy
    return ReplayLogPolicy()
"""


class _Evil:
    def __reduce__(self):
        return (exec, ("open('pickle_ran', 'w').write('yes')",))


@pytest.fixture
def cl(pytester):
    shutil.copytree(REAL, pytester.path / "real.zarr")
    pytester.path.joinpath("evilmod.py").write_text(EVIL_MODULE)
    torch.save(_Evil(), pytester.path / "evil.pkl")
    pytester.syspathinsert()
    pytester.makefile(".scenario.yaml", good=scenario(name="good", unroll="    StartFrame: 10\n    Steps: 5"),
                      by_pickle=scenario(name="p", model="pickle:evil.pkl"),
                      by_factory=scenario(name="f", model="evilmod:boom", unroll="    StartFrame: 10\n    Steps: 5"))
    return pytester


def test_scenario_code_is_refused_with_how_to_opt_in(cl):
    result = cl.runpytest("-q", "-p", "no:randomly")
    result.assert_outcomes(passed=1, errors=2)
    assert not (cl.path / "pickle_ran").exists() and not (cl.path / "factory_ran").exists()
    result.stdout.fnmatch_lines([
        "*ModelError: by_factory.scenario.yaml:9: Model 'evilmod:boom' would run Python code named by the "
        "scenario file (importing and calling a factory). If you trust this file, run with "
        "--driveeval-allow-scenario-code (ini: driveeval_allow_scenario_code = true)*",
        "*ModelError: by_pickle.scenario.yaml:9: Model 'pickle:evil.pkl' would run Python code*(unpickling)*",
    ])


def test_opting_in_by_option_or_ini_runs_the_named_code(cl):
    result = cl.runpytest("-q", "--driveeval-allow-scenario-code", "by_factory.scenario.yaml", "good.scenario.yaml")
    assert (cl.path / "factory_ran").exists()
    result.assert_outcomes(passed=2)
    cl.makeini("[pytest]\ndriveeval_allow_scenario_code = true\n")
    cl.runpytest("-q", "by_pickle.scenario.yaml")
    assert (cl.path / "pickle_ran").exists()


def test_the_command_line_needs_no_opt_in(cl):
    result = cl.runpytest("-q", "--driveeval-model", "evilmod:boom", "good.scenario.yaml")
    result.assert_outcomes(passed=1)
    assert (cl.path / "factory_ran").exists()


@pytest.mark.parametrize("spec, message", [
    ("os:system", "cannot call os:system() without arguments to build the model: *"),
    ("os:sep", "'os:sep' is a str, not a factory to call"),
    ("os:getcwd", "os:getcwd() returned a str, not a model*"),
    (".", "model * is a folder; give the model file inside it"),
])
def test_a_model_option_that_cannot_be_a_model_is_a_clear_error(cl, spec, message):
    result = cl.runpytest("-q", "--driveeval-model", spec, "good.scenario.yaml")
    result.assert_outcomes(errors=1)
    result.stdout.fnmatch_lines([f"*ModelError: {message}"])
    assert "Traceback" not in result.stdout.str()


def test_a_crafted_pt2_named_by_a_scenario_runs_no_code_and_the_other_items_run(cl):
    # The .pt2 path needs no opt-in, so it must run nothing of the file's: here its sample
    # inputs are a pickle that torch.export.load would have run (issue 34).
    import zipfile

    shipped = REPO_ROOT / "fixtures" / "models" / "planning_model.pt2"
    with zipfile.ZipFile(shipped) as src, zipfile.ZipFile(cl.path / "crafted.pt2", "w") as dst:
        for info in src.infolist():
            is_sample = "/data/sample_inputs/" in info.filename
            dst.writestr(info.filename, (cl.path / "evil.pkl").read_bytes() if is_sample else src.read(info))
        config = next(n for n in src.namelist() if n.endswith("model_weights_config.json"))
    with zipfile.ZipFile(cl.path / "pickled_weight.pt2", "w") as dst, zipfile.ZipFile(shipped) as src:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == config:
                data = data.replace(b'"use_pickle": false', b'"use_pickle": true', 1)
            elif info.filename.endswith("/data/weights/weight_0"):
                data = (cl.path / "evil.pkl").read_bytes()
            dst.writestr(info.filename, data)
    cl.makefile(".scenario.yaml", crafted=scenario(name="c", model="crafted.pt2", unroll="    StartFrame: 10\n    Steps: 5"),
                weights=scenario(name="w", model="pickled_weight.pt2", unroll="    StartFrame: 10\n    Steps: 5"))
    result = cl.runpytest("-q", "crafted.scenario.yaml", "weights.scenario.yaml", "good.scenario.yaml")
    assert not (cl.path / "pickle_ran").exists()
    # The sample inputs are never read, so that file's model runs; the pickled weight is refused.
    result.assert_outcomes(passed=2, errors=1)
    result.stdout.fnmatch_lines(["error *weights.scenario.yaml::closed_loop*", "*ModelError: refused exported program*",
                                 "*pickled_weight.pt2:*", "*'ego_tag' is stored as a*", "*pickle (use_pickle)*"])
