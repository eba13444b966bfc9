"""The session's baseline options, made once per process from the command line and ini."""
from __future__ import annotations

from pathlib import Path

import pytest

from ..harness.settings import get_settings
from .gate import BaselineOptions, Gate
from .store import resolve_compare

_GATE_KEY = pytest.StashKey["Gate | None"]()
#: workerinput key: the summary.json the controller resolved --driveeval-compare to
COMPARE_KEY = "driveeval_compare"


def session_gate(config: pytest.Config) -> Gate | None:
    """The session's baselines (--driveeval-baseline, --driveeval-compare), or None.  The controller
    resolves --driveeval-compare once (a usage error when it names no run); workers take its answer,
    so every item of a session meets the same run even if another session finishes meanwhile."""
    if _GATE_KEY not in config.stash:
        settings = get_settings(config)
        compare_with = None
        worker = getattr(config, "workerinput", None)
        if worker is not None and worker.get(COMPARE_KEY):
            compare_with = Path(worker[COMPARE_KEY])
        elif settings.compare:
            try:
                compare_with = resolve_compare(settings.compare, settings.output_dir, settings.run.id)
            except ValueError as exc:
                raise pytest.UsageError(f"--driveeval-compare: {exc}") from None
        options = BaselineOptions(settings.baseline_dir, compare_with, settings.baseline_update,
                                  settings.baseline_prune, settings.baseline_strict, rootdir_moved(config))
        config.stash[_GATE_KEY] = Gate(options) if options.active else None
    return config.stash[_GATE_KEY]


def rootdir_moved(config: pytest.Config) -> str | None:
    """Why pytest's rootdir is not the one the test paths alone give, or None when it is.

    pytest chooses the rootdir before it loads plugins, so it takes the value of an option it
    does not know yet (``--driveeval-baseline ../baselines``) for a test path, and only when
    that path exists: the session after the one that created the folder gets another rootdir.
    Node ids are relative to the rootdir, and a baseline file is found by its item's node id."""
    from _pytest.config.findpaths import determine_setup

    option = config.option
    try:
        intended = determine_setup(inifile=option.inifilename, override_ini=option.override_ini,
                                   args=[str(a) for a in (option.file_or_dir or [])],
                                   rootdir_cmd_arg=option.rootdir or None,
                                   invocation_dir=config.invocation_params.dir)[0]
    except Exception:  # a pytest whose internals differ: say nothing rather than something wrong
        return None
    if Path(intended) == config.rootpath:
        return None
    args = list(config.invocation_params.args)
    culprits = [f"{name} {value}" for name, value in zip(args, args[1:])
                if name.startswith("--driveeval-") and "=" not in name
                and value == str(config.getoption(name[2:].replace("-", "_"), None))
                and (config.invocation_params.dir / value).exists()]
    given = " or ".join(f"`{c}`" for c in culprits) or "an option's value"
    fix = " or ".join(f"`{c.replace(' ', '=', 1)}`" for c in culprits) or "`--option=value`"
    return (f"pytest's rootdir is {config.rootpath}, not {intended}: pytest chose it before it knew "
            f"pytest-driveeval's options, and took {given} for a test path because that path exists now. Node ids, "
            f"and the baseline files found by them, moved with the rootdir. Write {fix}, or fix the rootdir "
            "(--rootdir, or an ini file such as pytest.ini beside the scenarios)")
