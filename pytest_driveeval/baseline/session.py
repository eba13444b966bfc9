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
                                  settings.baseline_prune, settings.baseline_strict)
        config.stash[_GATE_KEY] = Gate(options) if options.active else None
    return config.stash[_GATE_KEY]
