"""Command-line options and their ini / environment equivalents."""
from __future__ import annotations

import hashlib
import math
import os
import re
import tempfile
import unicodedata
from dataclasses import dataclass
from pathlib import Path

import pytest

from .runs import DEFAULT_KEEP_RUNS, RunIdentity, damaged_entry, new_identity, run_dir

# ``*.scenario.yaml`` declares a scenario by its name; the others are
# driving_log_replayer's names (scenario.yaml, scenario.ja.yaml,
# scenario_detection_only.yaml, ...), collected only when the file has the
# scenario envelope.
#: the output folder when neither --driveeval-output nor ini driveeval_output names one
DEFAULT_OUTPUT = "driveeval-results"
DEFAULT_PATTERNS = ["*.scenario.yaml", "*.scenario.yml", "scenario*.yaml", "scenario*.yml"]
DECLARED_SUFFIXES = (".scenario.yaml", ".scenario.yml")
DATA_ROOT_ENV = "DRIVEEVAL_DATA_ROOT"
SEARCH_DATABASE = "search-examples"
SEED_LIMIT = 2 ** 63
#: seconds a scenario item may run when neither its TimeLimit nor the option says: half an hour, far
#: above the slowest demo item (a few minutes on two cores shared with six other test runs), so that
#: only a hang meets it, and CI never waits forever on one scenario
DEFAULT_TIME_LIMIT = 1800.0
TIME_LIMIT_KEYS = "--driveeval-time-limit / driveeval_time_limit"


@dataclass(frozen=True)
class Settings:
    output_dir: Path
    data_root: Path | None
    model: str | None
    seed: int
    patterns: tuple[str, ...]
    allow_scenario_code: bool = False
    run: RunIdentity | None = None
    #: seconds per item, None: no limit (given as 0)
    time_limit: float | None = DEFAULT_TIME_LIMIT
    #: who set ``time_limit``, for the message of an item that meets it
    time_limit_source: str = "default"
    #: bytes an item may plan to use (checked at the scenario's lines); None: half the machine's memory, 0: none
    memory_limit: int | None = None
    keep_runs: int = DEFAULT_KEEP_RUNS
    search_examples: int | None = None
    replay: str | None = None
    search_profile: str = "default"
    #: where items run their chunks, as --driveeval-executor gives it (checked by the plugin)
    executor: str | None = None
    #: the folder of baseline files (--driveeval-baseline / driveeval_baseline), or None
    baseline_dir: Path | None = None
    baseline_update: bool = False
    baseline_prune: bool = False
    baseline_strict: bool = False
    #: --driveeval-compare as given: last, a run id, a summary.json (resolved by the plugin)
    compare: str | None = None

    @property
    def search_database(self) -> Path:
        """The example database of robustness searches: failures found are replayed first next time."""
        return self.output_dir / SEARCH_DATABASE

    @property
    def run_dir(self) -> Path:
        assert self.run is not None
        return run_dir(self.output_dir, self.run.id)

    def item_dir(self, nodeid: str) -> Path:
        return self.run_dir / "items" / safe_name(nodeid)


# File systems cap a name at 255 bytes; a scenario deep in folders has a
# longer node id.
MAX_NAME = 120


def safe_name(nodeid: str) -> str:
    """A readable folder name for a node id (``a/b.yaml::c[d]`` -> ``a_b.yaml__c_d``);
    a long one keeps its end (the file and item) and a hash of the whole."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", nodeid).strip("_") or "item"
    if len(name) <= MAX_NAME:
        return name
    digest = hashlib.sha256(nodeid.encode()).hexdigest()[:12]
    return f"{digest}_{name[-(MAX_NAME - len(digest) - 1):].lstrip('_.')}"


def item_seed(base_seed: int, nodeid: str) -> int:
    """A seed per item that is the same in every process: derived from the node id,
    never from collection order or Python's salted ``hash``."""
    digest = hashlib.sha256(f"{base_seed}:{nodeid}".encode()).digest()
    return int.from_bytes(digest[:4], "little")


def add_options(parser: pytest.Parser) -> None:
    group = parser.getgroup("driveeval", "driving-software evaluation (pytest-driveeval)")
    group.addoption("--driveeval-output", metavar="DIR", default=None,
                    help="where results and artefacts go (ini: driveeval_output; default: driveeval-results)")
    group.addoption("--driveeval-data-root", metavar="DIR", default=None,
                    help=f"folder holding the datasets scenarios name (ini: driveeval_data_root; env: {DATA_ROOT_ENV})")
    group.addoption("--driveeval-model", metavar="SPEC", default=None,
                    help="evaluate this model in every scenario instead of the scenario's own: a TorchScript file, "
                         "'weights.pt=module:factory', or 'module:factory' (ini: driveeval_model)")
    group.addoption("--driveeval-seed", metavar="N", type=int, default=None,
                    help="base seed; every item derives its own from it and its id (ini: driveeval_seed; default 0)")
    group.addoption("--driveeval-time-limit", metavar="SECONDS", default=None,
                    help="fail a scenario item that runs longer, naming where it was (a scenario's TimeLimit "
                         f"key wins; ini: driveeval_time_limit; default: {DEFAULT_TIME_LIMIT:g}; 0: none)")
    group.addoption("--driveeval-memory-limit", metavar="GIB", default=None,
                    help="refuse, at its line, a scenario whose sizes (episodes, agents, raster, ghost points, "
                         "a CommonRoad scene's steps) "
                         "would need more memory per item (ini: driveeval_memory_limit; default: half this "
                         "machine's memory; 0: no check)")
    group.addoption("--driveeval-allow-scenario-code", action="store_true", default=None,
                    help="let scenario files name code to run: 'Model: pickle:file' or 'module:factory' "
                         "(ini: driveeval_allow_scenario_code; off by default: scenario files travel with data)")
    group.addoption("--driveeval-search-examples", metavar="N", default=None,
                    help="examples a robustness search tries (a scenario's Perturbation.Examples otherwise; "
                         "ini: driveeval_search_examples)")
    group.addoption("--driveeval-search-profile", choices=("default", "ci"), default=None,
                    help="ci: derandomised searches without the example database (default when the CI "
                         "environment variable is set; ini: driveeval_search_profile)")
    group.addoption("--driveeval-replay", metavar="CASE", default=None,
                    help="evaluate exactly this perturbed case instead of searching, e.g. "
                         "'scene=0,lateral=1.73' (a failing search prints the line)")
    group.addoption("--driveeval-executor", metavar="SPEC", default=None,
                    help="run the chunks of every item that has them here, replacing each key a scenario's "
                         "Executor section sets: local, ray, or a mapping such as "
                         "'{Kind: ray, Address: ray://head:10001, ChunkSize: 64}' (ini: driveeval_executor)")
    group.addoption("--driveeval-baseline", metavar="DIR", default=None,
                    help="compare each scenario item with its baseline file in DIR and fail it when it got worse "
                         "(ini: driveeval_baseline)")
    group.addoption("--driveeval-baseline-update", action="store_true", default=False,
                    help="write the baselines of the items that ran (the others keep theirs)")
    group.addoption("--driveeval-baseline-prune", action="store_true", default=False,
                    help="with --driveeval-baseline-update: remove the baselines of items that no longer exist")
    group.addoption("--driveeval-baseline-strict", action="store_true", default=None,
                    help="fail an item without a baseline, or whose baseline is stale "
                         "(ini: driveeval_baseline_strict)")
    group.addoption("--driveeval-compare", metavar="RUN", default=None,
                    help="compare with an earlier run instead of baselines: 'last' (or 'last~N', N runs before it), "
                         "a run id from the output folder's runs/, or the path of a summary.json")
    parser.addini("driveeval_baseline", "folder of baseline files every item is compared with", default="")
    parser.addini("driveeval_baseline_strict", "fail items without a current baseline", type="bool", default=False)
    parser.addini("driveeval_executor", "local | ray | {Kind: ray, Address: ..., ChunkSize: ...} for every item",
                  default="")
    parser.addini("driveeval_search_examples", "examples a robustness search tries", default="")
    parser.addini("driveeval_search_profile", "default | ci", default="")
    parser.addini("driveeval_output", "where results and artefacts go", default=DEFAULT_OUTPUT)
    parser.addini("driveeval_data_root", "folder holding the datasets scenarios name", default="")
    parser.addini("driveeval_model", "model evaluated instead of each scenario's own", default="")
    parser.addini("driveeval_seed", "base seed", default="0")
    parser.addini("driveeval_allow_scenario_code", "let scenario files name code to run (pickle:, module:factory)",
                  type="bool", default=False)
    parser.addini("driveeval_time_limit", f"seconds a scenario item may run (default {DEFAULT_TIME_LIMIT:g}; 0: none)",
                  default="")
    parser.addini("driveeval_memory_limit", "GiB of memory a scenario item may plan to use (default: half the "
                  "machine's; 0: no check)", default="")
    parser.addini("driveeval_keep_runs", "finished runs kept under the output folder's runs/ (0: all)",
                  default=str(DEFAULT_KEEP_RUNS))
    parser.addini("driveeval_patterns", "file name patterns collected as scenarios", type="linelist",
                  default=DEFAULT_PATTERNS)


def settings_from_config(config: pytest.Config) -> Settings:
    invocation = Path(config.invocation_params.dir)
    ini_base = Path(config.inipath).parent if config.inipath else config.rootpath

    def pick(option: str, ini: str) -> tuple[str | None, Path]:
        value = config.getoption(option)
        if value not in (None, ""):
            return str(value), invocation
        value = config.getini(ini)
        return (str(value) if value not in (None, "") else None), ini_base

    output, base = pick("driveeval_output", "driveeval_output")
    model, _ = pick("driveeval_model", "driveeval_model")
    seed, _ = pick("driveeval_seed", "driveeval_seed")
    try:
        seed_value = int(seed or 0)
    except ValueError:
        seed_value = -1
    if not 0 <= seed_value < SEED_LIMIT:
        raise pytest.UsageError(f"driveeval seed (--driveeval-seed / driveeval_seed) must be a whole number from 0 "
                                f"to 2**63 - 1, as numpy's generators take, got {seed!r}")
    limit, _ = pick("driveeval_time_limit", "driveeval_time_limit")
    time_limit = _time_limit(limit)
    memory, _ = pick("driveeval_memory_limit", "driveeval_memory_limit")
    keep = config.getini("driveeval_keep_runs")
    if not str(keep).isdigit():
        raise pytest.UsageError(f"driveeval_keep_runs must be a whole number (0: keep all), got {keep!r}")
    examples, _ = pick("driveeval_search_examples", "driveeval_search_examples")
    if examples is not None and not (examples.isdigit() and int(examples) > 0):
        raise pytest.UsageError(f"driveeval search examples must be a whole number > 0, got {examples!r}")
    profile, _ = pick("driveeval_search_profile", "driveeval_search_profile")
    profile = profile or ("ci" if os.environ.get("CI", "").lower() not in ("", "0", "false") else "default")
    if profile not in ("default", "ci"):
        raise pytest.UsageError(f"driveeval search profile must be 'default' or 'ci', got {profile!r}")
    executor, _ = pick("driveeval_executor", "driveeval_executor")
    baseline, baseline_base = pick("driveeval_baseline", "driveeval_baseline")
    update = bool(config.getoption("driveeval_baseline_update"))
    prune = bool(config.getoption("driveeval_baseline_prune"))
    if (update or prune) and not baseline:
        raise pytest.UsageError("--driveeval-baseline-update / -prune need the baseline folder: "
                                "--driveeval-baseline DIR or ini driveeval_baseline")
    if prune and not update:
        raise pytest.UsageError("--driveeval-baseline-prune removes baselines while updating them: "
                                "add --driveeval-baseline-update")
    baseline_dir = (baseline_base / baseline).resolve() if baseline else None
    if baseline_dir is not None and baseline_dir.exists() and not baseline_dir.is_dir():
        # Read as a folder, a file holds no baselines: every item would be "missing", and an
        # update could write none.
        given = "--driveeval-baseline" if config.getoption("driveeval_baseline") else "ini driveeval_baseline"
        raise pytest.UsageError(f"{given} {baseline}: {baseline_dir} is a file, not a folder; the baselines are a "
                                "folder of files, one per item (--driveeval-baseline-update writes them): name "
                                "a folder, or one that does not exist yet")
    # Workers take the controller's run, so one session writes one run folder.
    shared = getattr(config, "workerinput", {}).get(RUN_KEY)
    run = RunIdentity(**shared) if shared else new_identity(config.rootpath)
    return Settings(
        output_dir=(base / (output or DEFAULT_OUTPUT)).resolve(),
        data_root=_data_root(config, invocation, ini_base),
        model=model,
        seed=seed_value,
        patterns=tuple(config.getini("driveeval_patterns") or DEFAULT_PATTERNS),
        allow_scenario_code=bool(config.getoption("driveeval_allow_scenario_code")
                                 or config.getini("driveeval_allow_scenario_code")),
        run=run,
        keep_runs=int(keep),
        time_limit=time_limit,
        time_limit_source=TIME_LIMIT_KEYS if limit else "default",
        memory_limit=_memory_limit(memory),
        search_examples=int(examples) if examples else None,
        replay=config.getoption("driveeval_replay") or None,
        search_profile=profile,
        executor=executor,
        baseline_dir=baseline_dir,
        baseline_update=update,
        baseline_prune=prune,
        baseline_strict=bool(config.getoption("driveeval_baseline_strict")
                             or config.getini("driveeval_baseline_strict")),
        compare=config.getoption("driveeval_compare") or None,
    )


def _data_root(config: pytest.Config, invocation: Path, ini_base: Path) -> Path | None:
    """The data root, checked here: a mistyped one would otherwise only show as every dataset
    missing, one item at a time."""
    given = (("--driveeval-data-root", config.getoption("driveeval_data_root"), invocation),
             (f"environment variable {DATA_ROOT_ENV}", os.environ.get(DATA_ROOT_ENV), invocation),
             ("ini driveeval_data_root", config.getini("driveeval_data_root"), ini_base))
    where, text, base = next(((w, str(v), b) for w, v, b in given if v not in (None, "")), (None, None, None))
    if text is None:
        return None
    # repr escapes control characters, so a stray escape sequence is shown, not played on the terminal.
    if any(unicodedata.category(ch) == "Cc" for ch in text):
        raise pytest.UsageError(f"{where}: the data root {text!r} holds control characters; give a folder's path")
    try:
        path = (base / text).resolve()
    except (RuntimeError, OSError) as exc:  # a symlink loop (RuntimeError before Python 3.13)
        raise pytest.UsageError(f"{where}: cannot resolve the data root {text!r}: {exc}") from None
    if not path.exists():
        raise pytest.UsageError(f"{where}: the data root {text!r} does not exist ({path})")
    if not path.is_dir():
        raise pytest.UsageError(f"{where}: the data root {text!r} is not a folder ({path})")
    return path


def _non_negative(text: str, below: float, what: str) -> float:
    """``text`` as a finite number in [0, below), else a usage error saying ``what`` it must be."""
    try:
        number = float(text)
    except ValueError:
        number = math.nan
    if not (math.isfinite(number) and 0 <= number < below):
        raise pytest.UsageError(f"driveeval {what}, got {text!r}")
    return number


def _time_limit(text: str | None) -> float | None:
    if not text:
        return DEFAULT_TIME_LIMIT
    return _non_negative(text, math.inf, "time limit must be a number of seconds >= 0 (0: none)") or None


def time_limit_header(settings: Settings) -> str:
    """The session header's line on the time limit: a hang ends only there, so say at the start what
    it is and how to change it."""
    own = "a scenario's TimeLimit key sets its own"
    if settings.time_limit is None:
        return f"driveeval: no time limit on scenario items ({TIME_LIMIT_KEYS} is 0); {own}"
    if settings.time_limit_source == "default":
        return (f"driveeval: each scenario item may run {settings.time_limit:g} s (the default time limit); "
                f"{TIME_LIMIT_KEYS} SECONDS sets another, 0: none; {own}")
    return (f"driveeval: each scenario item may run {settings.time_limit:g} s ({TIME_LIMIT_KEYS}); "
            f"{own}, 0: none")


def _memory_limit(text: str | None) -> int | None:
    if not text:
        return None
    return int(_non_negative(text, 2 ** 33, "memory limit must be a number of GiB >= 0 (0: no check)") * 2 ** 30)


RUN_KEY = "driveeval_run"


# Kernel views, not storage: as root, os.access says yes to them all.
VIRTUAL_ROOTS = (Path("/proc"), Path("/sys"))


def check_output_dir(path: Path) -> None:
    """Fail at the start, not after an hour of evaluation, when results cannot
    be written there or the folder's own files are damaged."""
    where = "(set --driveeval-output or driveeval_output)"
    virtual = next((root for root in VIRTUAL_ROOTS if path.is_relative_to(root)), None)
    if virtual is not None:
        raise pytest.UsageError(f"driveeval output {path} is in {virtual}, a view of the kernel, "
                                f"not a place for files {where}")
    existing = path
    while not existing.exists():
        if existing.is_symlink():  # a dangling link: mkdir would fail later
            break
        existing = existing.parent
    if not existing.is_dir():
        what = "is not a folder" if existing == path else f"cannot be created: {existing} is not a folder"
        raise pytest.UsageError(f"driveeval output {path} {what} {where}")
    try:
        try:
            _try_writing(path)
        except FileNotFoundError:
            # Another session starting now may have made the folder for its own
            # trial and removed it again under ours.
            _try_writing(path)
    except OSError as exc:
        raise pytest.UsageError(f"driveeval output {path} cannot be written: "
                                f"{exc.strerror or exc} ({exc.filename or path}) {where}") from None
    problem = damaged_entry(path, folders=(SEARCH_DATABASE,))
    if problem is not None:
        raise pytest.UsageError(f"driveeval output {path}: {problem} {where}")


def _try_writing(path: Path) -> None:
    """Create and remove a file in ``path`` (and the folders it needs): the
    permission bits do not say what a read-only mount or root refuses.  A
    session without scenario items leaves no folder behind."""
    missing, folder = [], path
    while not folder.exists():
        missing.append(folder)
        folder = folder.parent
    created = []
    try:
        for folder in reversed(missing):
            try:
                folder.mkdir()
                created.append(folder)
            except FileExistsError:
                pass  # another session made it at the same time
        fd, trial = tempfile.mkstemp(prefix=".driveeval-write-test.", dir=path)
        os.close(fd)
        os.unlink(trial)
    finally:
        for folder in reversed(created):
            try:
                folder.rmdir()
            except OSError:
                pass  # another session has started writing there


SETTINGS_KEY = pytest.StashKey[Settings]()


def get_settings(config: pytest.Config) -> Settings:
    if SETTINGS_KEY not in config.stash:
        config.stash[SETTINGS_KEY] = settings_from_config(config)
    return config.stash[SETTINGS_KEY]
