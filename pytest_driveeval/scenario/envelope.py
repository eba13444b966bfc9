"""The envelope of a scenario file: driving_log_replayer's keys, and ours in their style.

The envelope is driving_log_replayer's (``ScenarioFormatVersion``,
``ScenarioName``, ``Evaluation: {UseCaseName, UseCaseFormatVersion, Datasets,
...}``) so their files load unchanged.  Harness keys in the same style
(``Marks``, ``Skip``, ``XFail``) carry pytest marks.  The use case named by
``UseCaseName`` validates the rest of ``Evaluation`` with its own model.
"""
from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, StringConstraints

from ..baseline.rules import RegressionSpec

MarkName = Annotated[str, StringConstraints(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")]


class _Forbid(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class XFailSpec(_Forbid):
    Reason: str
    Strict: bool = False


class DatasetOptions(BaseModel):
    # driving_log_replayer puts launch options here (VehicleId, LaunchSensing, ...);
    # we keep whatever is given and read only what we know.
    model_config = ConfigDict(extra="allow")
    path: str | None = Field(None, alias="Path")
    VehicleId: str | None = None
    LocalMapPath: str | None = None


class EvaluationHead(BaseModel):
    model_config = ConfigDict(extra="allow")
    UseCaseName: str
    UseCaseFormatVersion: str
    Datasets: list[dict[str, DatasetOptions | None]] = []


class Envelope(_Forbid):
    ScenarioFormatVersion: str
    ScenarioName: str
    ScenarioDescription: str = ""
    SensorModel: str | None = None
    VehicleModel: str | None = None
    VehicleId: str | None = None
    LocalMapPath: str | None = None
    Marks: list[MarkName] = []
    Skip: str | None = None
    XFail: str | XFailSpec | None = None
    # seconds for the whole item, 0: none; --driveeval-time-limit (or its default) otherwise
    TimeLimit: float | None = Field(None, ge=0.0, allow_inf_nan=False)
    # what counts as worse than the item's baseline (pytest_driveeval.baseline.rules)
    Regression: RegressionSpec | None = None
    Evaluation: EvaluationHead
