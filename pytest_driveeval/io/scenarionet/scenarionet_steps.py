"""Whether a scenario's timestamps suit the closed loop's fixed step, within a stated tolerance.

Real logs are not sampled exactly: a real Waymo scene steps every 0.0999889 s (its median); Waymo's
own frames are 99.96 to 100.08 ms apart, and 200 ms where a frame is missing (waymo-open-dataset
issue 158).  ScenarioNet's nuPlan converter accepts a log interval within 1e-3 s of 0.1 s.  So a
scenario drives at the closed loop's step when

- its median step is within :data:`MEDIAN_TOLERANCE` (1 %) of the closed loop's step, the nuPlan
  converter's own bound, and
- each of its steps is within :data:`STEP_TOLERANCE` (5 %, 5 ms at 0.1 s) of it: fifty times the
  jitter Waymo's frames show, and far from a missing frame (100 %);

and it is then treated as sampled at the closed loop's step, with a note of the jitter and of how
far the timestamps drift from that grid.  A step outside the tolerance is refused, located by its
step number and times; so is a median step outside it (a dataset converted at another rate).
"""
from __future__ import annotations

import numpy as np

from ...core.errors import display_path
from .scenarionet import ScenarioNetError, ScenarioNetScene

#: the median step may differ from the closed loop's step by this fraction of it
MEDIAN_TOLERANCE = 0.01
#: each step may differ from the closed loop's step by this fraction of it
STEP_TOLERANCE = 0.05
#: seconds: a difference below this is exact (float32 timestamps of a 20 s log differ by ~1e-6 s)
EXACT = 1e-5


def check_steps(scene: ScenarioNetScene, step: float) -> str | None:
    """None when ``scene`` is sampled every ``step`` s (to within :data:`EXACT`); a note saying how its
    timestamps jitter when they are within the tolerance; else :class:`ScenarioNetError`."""
    here = f"{display_path(scene.path)} (scenario {scene.id})"
    accepts = (f"the closed loop steps every {step:g} s and accepts a median step within "
               f"{MEDIAN_TOLERANCE:.0%} and each step within {STEP_TOLERANCE:.0%} of it")
    declared = scene.metadata.get("sample_rate")
    if declared is not None and abs(scene.sample_rate - step) > MEDIAN_TOLERANCE * step:
        raise ScenarioNetError(f"{here}: sampled every {scene.sample_rate:g} s (metadata.sample_rate); {accepts} "
                               f"(convert the dataset with ScenarioNet at {1 / step:g} Hz)")
    if scene.steps < 2:
        return None
    times = scene.timestamps
    steps = np.diff(times)
    median = float(np.median(steps))
    if abs(median - step) > MEDIAN_TOLERANCE * step:
        raise ScenarioNetError(f"{here}: sampled every {median:g} s (the median step of metadata.ts); {accepts} "
                               f"(convert the dataset with ScenarioNet at {1 / step:g} Hz)")
    off = np.abs(steps - step)
    worst = int(np.argmax(off))
    if off[worst] > STEP_TOLERANCE * step:
        raise ScenarioNetError(
            f"{here}: metadata.ts steps {steps[worst]:g} s from step {worst} to {worst + 1} ({times[worst]:g} s to "
            f"{times[worst + 1]:g} s): {'a gap, a frame missing there' if steps[worst] > step else 'a step too short'}"
            f"; {accepts}; cut the scenario there or resample it at {1 / step:g} Hz")
    drift = np.abs(times - times[0] - step * np.arange(len(times)))
    if off[worst] <= EXACT and float(drift.max()) <= EXACT:
        return None
    return (f"timestamps jitter up to {1e3 * off[worst]:.3g} ms around {step:g} s (steps {1e3 * steps.min():.4g} "
            f"to {1e3 * steps.max():.4g} ms, median {1e3 * median:.4g} ms) and drift up to "
            f"{1e3 * float(drift.max()):.3g} ms from a {step:g} s grid; treated as {step:g} s (accepted: a median "
            f"step within {MEDIAN_TOLERANCE:.0%} and each step within {STEP_TOLERANCE:.0%} of {step:g} s)")
