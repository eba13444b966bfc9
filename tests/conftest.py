"""Shared test configuration.

Real sample data lives outside the repository, in ``../shared/data`` next to the
clone (CI has it; a plain checkout may not).  Tests that need it take the
``shared_data`` fixture, which skips cleanly when the folder is absent.
"""
from __future__ import annotations

import os
from pathlib import Path

# One intra-op thread for torch (and OpenMP) in this process and every process it starts (inner
# sessions, their xdist workers, scripts, Ray workers): the suite runs on two xdist workers on two
# cores, and more threads than free cores wait on each other at every operator (the demo's 16
# generated scenes: 90 s on two threads beside another job, 12 s on one).  Set before numpy and
# torch start their thread pools; a value the caller set is kept.
os.environ.setdefault("OMP_NUM_THREADS", "1")

import pytest
from hypothesis import settings

pytest_plugins = ["pytester"]

# Under -n, a module's tests that share a module-scoped fixture run on one worker (tests/xdist_modules.py).
from xdist_modules import pytest_xdist_make_scheduler  # noqa: E402,F401

# CI runs the same examples every time (a red build must be reproducible); shared,
# noisy machines make hypothesis's per-example deadline meaningless.
settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
settings.register_profile("dev", deadline=None)
settings.load_profile("ci" if os.environ.get("CI") else "dev")

try:
    import numba
except ImportError:  # the obstacle kernel's numpy path runs instead
    numba = None
if numba is not None:
    # pytester's in-process runs drop the modules first imported inside them. numba
    # imports some on its first compile and registers their types in registries that
    # outlive the run, so a second run re-registers them and fails ("duplicate
    # registration"). One compile here, before any pytester run, makes them permanent.
    numba.njit(lambda: 0)()

try:
    # The same trap for torch: an in-process pytester run that first imports it drops it
    # afterwards, and torch imported a second time in one process crashes it.
    import torch

    if os.environ["OMP_NUM_THREADS"].isdigit() and int(os.environ["OMP_NUM_THREADS"]) > 0:
        torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))  # in case torch started before this file
except ImportError:
    pass

REPO_ROOT = Path(__file__).resolve().parents[1]


def module_at(path: Path, name: str):
    """The Python file at ``path`` (a benchmark or oracle script, a helper of another test folder) as a
    module named ``name``: they are not packages, so a test loads them by path."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def fresh_pytest_run(folder: Path, *args: str, timeout: float):
    """``pytest ARGS`` in ``folder`` in a fresh Python (a module fixture's session, which several tests read:
    pytester's folder lives for one test only), as subprocess.run gives it back: this checkout's package
    first on the path, no colours, and not the outer session's PYTEST_ADDOPTS (CI's --durations)."""
    import subprocess
    import sys

    env = {**{k: v for k, v in os.environ.items() if k != "PYTEST_ADDOPTS"}, "PY_COLORS": "0",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO_ROOT), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "pytest", *args], cwd=folder, env=env, capture_output=True,
                          text=True, timeout=timeout)

try:
    import torch
except ImportError:
    torch = None
if torch is not None:
    # Likewise torch.export.load: its first call imports modules that register operator
    # libraries once per process ("Only a single TORCH_LIBRARY ..." when a second pytester run
    # imports them again). Loading the smallest shipped program here makes them permanent.
    from pytest_driveeval.policies.pt2_archive import load_exported_program

    load_exported_program(REPO_ROOT / "fixtures" / "models" / "gnn_actor_merging.pt2").module()
# pytester gives each inner run a fresh HOME, so each inner process (every -n 2 worker) built matplotlib's
# font cache again: seconds, and past 5 s matplotlib logs a warning that allure attaches to the item. The
# outer session's cache, fixed here before any pytester moves HOME, holds the same fonts.
os.environ.setdefault("MPLCONFIGDIR", str(Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "matplotlib"))
# For an inner pytest in a fresh process that runs no @given test: hypothesis's pytest plugin imports
# all of hypothesis at every session's end to print its statistics, about as long as the rest of
# pytest's start (2.5 s of CPU where no bytecode is cached).
NO_HYPOTHESIS_PLUGIN = ("-p", "no:hypothesispytest")
SHARED_DATA = Path(os.environ.get("DRIVEEVAL_SHARED_DATA", REPO_ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real sample data absent: {SHARED_DATA} is not a folder (put the shared data there, ../shared/data beside the clone, or set DRIVEEVAL_SHARED_DATA)")
    return SHARED_DATA


# The envelope of a policy_benchmark scenario ({name} to format); a test adds its Evaluation keys.
POLICY_BENCHMARK_HEAD = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
"""

EXAMPLE_USECASE = REPO_ROOT / "examples" / "custom_usecase" / "speed_limit.py"

SPEED_SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
ScenarioDescription: speeds under the limit
{extra}Evaluation:
  UseCaseName: speed_limit
  UseCaseFormatVersion: 0.1.0
  Datasets:
{datasets}
  Conditions:
    MaxSpeed: {max_speed}
"""


def speed_scenario(name="urban", datasets=("slow.csv",), max_speed=14.0, extra="") -> str:
    lines = "\n".join(f"    - {d}: {{}}" for d in datasets) if datasets else "    []"
    return SPEED_SCENARIO.format(name=name, datasets=lines, max_speed=max_speed, extra=extra)


def write_trajectory(path: Path, speed: float, frames: int = 30) -> None:
    t = [0.1 * i for i in range(frames)]
    path.write_text("t,x,y\n" + "".join(f"{ti},{speed * ti},0\n" for ti in t))


def speed_project(pytester):
    """``pytester``'s folder made a project where the example speed_limit use case is registered
    and two trajectories exist: slow.csv (10 m/s) and fast.csv (20 m/s)."""
    pytester.path.joinpath("speed_limit.py").write_text(EXAMPLE_USECASE.read_text())
    pytester.makeconftest("import speed_limit\n")
    pytester.makeini("[pytest]\nmarkers =\n    smoke: quick scenarios\n")
    write_trajectory(pytester.path / "slow.csv", 10.0)
    write_trajectory(pytester.path / "fast.csv", 20.0)
    return pytester


@pytest.fixture
def project(pytester):
    """A pytester folder made a speed_limit project (:func:`speed_project`)."""
    return speed_project(pytester)


GAIN_USECASE = '''
import importlib
from pytest_driveeval import ConditionsModel, Outcome, UseCase, register_usecase
from pydantic import BaseModel


class GainConditions(BaseModel, extra="forbid"):
    Input: float
    MaxOutput: float


class GainConfig(ConditionsModel):
    Conditions: GainConditions


@register_usecase
class Gain(UseCase):
    """The model is a function of one number; the scenario bounds its output."""
    name = "gain"
    config_model = GainConfig
    fixtures = ("driveeval_model",)

    def load_model(self, ctx, spec):
        if spec:
            module, attr = spec.split(":")
            return getattr(importlib.import_module(module), attr)
        return lambda x: 2 * x

    def run(self, config, ctx):
        out = ctx.fixtures["driveeval_model"](config.Conditions.Input)
        path = ctx.artefact("output.json")
        path.write_text(str(out))
        verdict = "passed" if out <= config.Conditions.MaxOutput else "failed"
        return Outcome(self.name, verdict, f"output {out}", figures={"output": out, "seed": ctx.seed},
                       artefacts={"output": path})
'''

GAIN_SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: gain
  UseCaseFormatVersion: 0.1.0
  Conditions:
    Input: 3.0
    MaxOutput: 10.0
"""


@pytest.fixture
def gain(pytester):
    pytester.makepyfile(gain_usecase=GAIN_USECASE, mymodels="def triple(x):\n    return 3 * x\n")
    pytester.makeconftest("import gain_usecase\n")
    return pytester


def torchscript(module):
    """``torch.jit.script(module)`` without torch's deprecation warning: the tests make TorchScript
    on purpose, as the file a user already has (the loader reads it) or to check a model compiles."""
    import warnings

    import torch

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", r".*torch\.jit\.(script|save)` is deprecated", DeprecationWarning)
        return torch.jit.script(module)


def save_torchscript(module, path) -> None:
    """``torch.jit.save(torch.jit.script(module), path)``: a TorchScript file as a user has one."""
    import warnings

    import torch

    scripted = torchscript(module)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", r".*torch\.jit\.(script|save)` is deprecated", DeprecationWarning)
        torch.jit.save(scripted, str(path))
