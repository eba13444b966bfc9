"""Create or check the venv that holds nuplan-devkit, the oracle for nuPlan's closed-loop score.

nuplan-devkit is not on PyPI: its source is taken from a git repository (by default the local
mirror below; ``--devkit PATH`` for another bare repository, a checkout, or a plain source tree),
extracted with ``git archive`` into the venv's folder and put on the venv's path with a .pth file.
Beside it go only the packages that the closed-loop metric modules import (directly or through
the devkit modules they import), at pins that install on Python 3.11; the devkit's own lock
(numpy 1.23.4, scipy 1.9.1, pyarrow 9.0.0, ...) has no 3.11 wheels for some of them. The venv
lives at ``~/.cache/driveeval-bench/nuplan``, is made on first use and is never part of the
package's requirements. Run it as a script or call ``oracle_python()``: both are idempotent and
print what they did.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: the venv helpers they share
from reference_venvs import import_check, install_pins, say_to, venv_python  # noqa: E402

VENV = Path.home() / ".cache" / "driveeval-bench" / "nuplan"
DEFAULT_DEVKIT = Path("/work/.mirror/motional+nuplan-devkit/repo")
METRICS = Path(__file__).with_name("nuplan_metrics.py")
PTH = "nuplan_devkit.pth"
READY = "oracle-ready.json"  # written after the import check passes; existing_python() looks for it
# Who imports what (module level, through the metric classes, MetricsEngine, SimulationHistory and the
# aggregator): numpy, scipy (savgol), shapely (boxes, map); pandas (metric_dataframe, aggregator);
# geopandas (maps_datatypes); sympy (drivable_area_compliance); pyarrow (abstract_metric_aggregator);
# boto3, aioboto3, aiofiles, retry (common/utils/s3_utils and io_utils, imported by metric_dataframe
# and the engine); pyyaml for nuplan_metrics.py to read the devkit's metric configs.
# Not installed: cv2, PIL, matplotlib, pyquaternion, pytest, imported only by the sensor modules
# that nuplan_metrics.py stubs; torch, hydra, ray, SQLAlchemy, bokeh (never imported on this path).
PINS = {
    "numpy": "1.23.5",
    "scipy": "1.9.3",
    "shapely": "2.0.1",
    "pandas": "1.5.3",
    "geopandas": "0.14.4",
    "pyproj": "3.6.1",
    "sympy": "1.11.1",
    "mpmath": "1.2.1",
    "pyarrow": "11.0.0",
    "boto3": "1.24.59",
    "aioboto3": "10.4.0",
    "aiofiles": "23.1.0",
    "retry": "0.9.2",
    "pyyaml": "6.0.1",
}
# Imports nuplan_metrics.py by path (its sensor stubs, then every metric module and the aggregator).
CHECK = ("import importlib.util, json, sys, importlib.metadata as m;"
         "spec = importlib.util.spec_from_file_location('nuplan_metrics', sys.argv[1]);"
         "mod = importlib.util.module_from_spec(spec); spec.loader.exec_module(mod);"
         "configs = mod.metric_configs();"
         "[mod._instantiate(c, **{p: None for p in c.get('required_metrics', {})}) for _, c in configs];"
         "print(json.dumps({'devkit': str(mod.DEVKIT_ROOT), 'metrics': len(configs),"
         " 'versions': {n: m.version(n) for n in sys.argv[2:]}}))")


def site_packages(python: Path) -> Path:
    done = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True)
    return Path(done.stdout.strip())


def git_commit(devkit: Path) -> str | None:
    """The HEAD commit if ``devkit`` is a git repository (bare or a checkout), else None."""
    done = subprocess.run(["git", "--git-dir", str(devkit), "rev-parse", "HEAD"], capture_output=True, text=True)
    if done.returncode != 0:
        done = subprocess.run(["git", "-C", str(devkit), "rev-parse", "HEAD"], capture_output=True, text=True)
    return done.stdout.strip() if done.returncode == 0 else None


def devkit_source(devkit: Path, venv: Path, say) -> Path:
    """The folder to put on the path: the extracted commit, or ``devkit`` itself for a plain source tree."""
    if not devkit.exists():
        raise RuntimeError(f"nuplan-devkit source not found at {devkit}: pass --devkit PATH (a git repository "
                           "of github.com/motional/nuplan-devkit, bare or checked out, or its source tree)")
    commit = git_commit(devkit)
    if commit is None:
        if not (devkit / "nuplan" / "planning" / "metrics").is_dir():
            raise RuntimeError(f"{devkit} is neither a git repository nor a nuplan-devkit source tree")
        say(f"using the source tree {devkit} in place (not a git repository)")
        return devkit
    target = venv / "src" / f"nuplan-devkit-{commit[:12]}"
    if (target / "nuplan" / "planning" / "metrics").is_dir():
        say(f"nuplan-devkit {commit[:12]} already extracted at {target}")
        return target
    say(f"extracting nuplan-devkit {commit[:12]} from {devkit} (git archive) into {target}")
    git_dir = ["--git-dir", str(devkit)] if (devkit / "objects").is_dir() else ["-C", str(devkit)]
    with tempfile.TemporaryDirectory(dir=venv) as tmp:
        archive = Path(tmp) / "devkit.tar"
        subprocess.run(["git", *git_dir, "archive", "--format=tar", "-o", str(archive), commit, "nuplan"],
                       check=True)
        staging = Path(tmp) / "src"
        with tarfile.open(archive) as tar:
            # the "data" filter (refuse links and paths leading out) exists from Python 3.11.4
            tar.extractall(staging, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
        target.parent.mkdir(parents=True, exist_ok=True)
        staging.rename(target)
    return target


def oracle_python(venv: Path = VENV, devkit: Path = DEFAULT_DEVKIT, quiet: bool = False) -> Path:
    """The venv's python, after creating the venv, extracting the devkit and installing what is missing or differs."""
    say = say_to("nuplan", quiet)
    python = venv_python(venv, "nuplan oracle", say)
    install_pins(python, PINS, say)
    source = devkit_source(devkit, venv, say)
    pth = site_packages(python) / PTH
    if not pth.exists() or pth.read_text().strip() != str(source):
        say(f"putting {source} on the venv's path ({pth.name})")
        pth.write_text(f"{source}\n")
    else:
        say(f"{pth.name} points at {source}")
    found = json.loads(import_check(python, ["-c", CHECK, str(METRICS), *PINS], "nuplan-devkit's metrics", venv))
    found["commit"] = git_commit(devkit)
    (venv / READY).write_text(json.dumps(found, indent=1))
    say(f"imports fine: devkit {found['commit'] or source}, {found['metrics']} metrics configured, "
        f"versions {json.dumps(found['versions'])}")
    return python


def existing_python(venv: Path = VENV) -> Path | None:
    """The venv's python if it passed its import check before, else None; creates nothing (for skips)."""
    python = venv / "bin" / "python"
    return python if python.exists() and (venv / READY).exists() else None


def run_metrics(cases: list[dict], python: Path | None = None, repeat: int = 1, timeout: float = 1800) -> list[dict]:
    """Run nuplan_metrics.py in the venv on ``cases`` (CASE_FORMAT dicts); its JSON lines, parsed, one per case."""
    python = python or oracle_python(quiet=True)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "cases.json"
        path.write_text(json.dumps(cases))
        done = subprocess.run([str(python), str(METRICS), str(path), "--repeat", str(repeat)],
                              capture_output=True, text=True, timeout=timeout)
    results = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    if len(results) != len(cases):
        raise RuntimeError(f"{METRICS.name} answered {len(results)} of {len(cases)} cases:\n{done.stderr[-4000:]}")
    return results


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--devkit", type=Path, default=DEFAULT_DEVKIT,
                        help="nuplan-devkit: a git repository (bare or checkout) or a source tree")
    parser.add_argument("--venv", type=Path, default=VENV)
    args = parser.parse_args()
    print(oracle_python(args.venv, args.devkit))
    sys.exit(0)
