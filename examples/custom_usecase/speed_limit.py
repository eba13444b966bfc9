"""A complete custom use case in a few dozen lines: speed and acceleration limits
on a logged trajectory (CSV with columns t, x, y).

Register it from a conftest.py (``import speed_limit``) or, in a package, through
the ``pytest_driveeval.usecases`` entry-point group.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import BaseModel, PositiveFloat

from pytest_driveeval import ConditionsModel, DataError, Outcome, UseCase, register_usecase
from pytest_driveeval.verdict import within


class Limits(BaseModel, extra="forbid"):
    MaxSpeed: PositiveFloat  # m/s
    MaxAcceleration: PositiveFloat | None = None  # m/s^2


def read_trajectory(path: Path) -> np.ndarray:
    """Rows of t,x,y under a header line.  Errors name the file and line and
    quote nothing of it: a mistyped path may point at a secret."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read a CSV of t,x,y: {getattr(exc, 'strerror', None) or exc.reason}") from None
    rows = []
    for number, line in enumerate(lines[1:], start=2):
        try:
            row = [float(v) for v in line.split(",")]
        except ValueError:
            row = []
        if len(row) != 3:
            raise DataError(f"{path}:{number}: not a CSV of t,x,y: expected 3 numbers separated by commas")
        rows.append(row)
    if len(rows) < 3:
        raise DataError(f"{path}: expected >= 3 rows of t,x,y, found {len(rows)}")
    return np.array(rows)


class SpeedLimitConfig(ConditionsModel):
    Conditions: Limits


@register_usecase
class SpeedLimit(UseCase):
    name = "speed_limit"
    format_versions = ("0.1.0",)
    config_model = SpeedLimitConfig
    fixtures = ("driveeval_dataset",)

    def load_dataset(self, ctx):
        path = super().load_dataset(ctx)  # resolves the path, names it if missing
        return read_trajectory(path)

    def run(self, config: SpeedLimitConfig, ctx) -> Outcome:
        t, xy = ctx.fixtures["driveeval_dataset"][:, 0], ctx.fixtures["driveeval_dataset"][:, 1:]
        speed = np.linalg.norm(np.diff(xy, axis=0), axis=1) / np.diff(t)
        accel = np.abs(np.diff(speed)) / np.diff(t)[1:]
        findings = [within(speed, figure="speed", max=config.Conditions.MaxSpeed, unit=" m/s",
                           keypath=("Evaluation", "Conditions", "MaxSpeed"))]
        if config.Conditions.MaxAcceleration is not None:
            findings.append(within(accel, figure="acceleration", max=config.Conditions.MaxAcceleration,
                                   unit=" m/s^2", keypath=("Evaluation", "Conditions", "MaxAcceleration")))
        findings = [f for f in findings if f is not None]
        figures = {"max_speed": float(speed.max()), "max_acceleration": float(accel.max()), "frames": len(t)}
        verdict = "failed" if findings else "passed"
        summary = f"max speed {speed.max():.2f} m/s, max |acceleration| {accel.max():.2f} m/s^2"
        return Outcome(self.name, verdict, summary, figures=figures, findings=findings)
