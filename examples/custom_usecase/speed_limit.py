"""A complete custom use case in a few dozen lines: speed and acceleration limits
on a logged trajectory (CSV with columns t, x, y).

Register it from a conftest.py (``import speed_limit``) or, in a package, through
the ``pytest_driveeval.usecases`` entry-point group.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, PositiveFloat

from pytest_driveeval import ConditionsModel, DataError, Outcome, UseCase, register_usecase
from pytest_driveeval.verdict import within


class Limits(BaseModel, extra="forbid"):
    MaxSpeed: PositiveFloat  # m/s
    MaxAcceleration: PositiveFloat | None = None  # m/s^2


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
        try:
            table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
        except ValueError as exc:
            raise DataError(f"{path}: not a CSV of t,x,y: {exc}") from None
        if table.shape[1] != 3 or len(table) < 3:
            raise DataError(f"{path}: expected >= 3 rows of t,x,y, found shape {table.shape}")
        return table

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
