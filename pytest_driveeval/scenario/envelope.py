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
    Reason: str = Field(description="why the item is expected to fail; shown in the report")
    Strict: bool = Field(False, description=(
        "true: an item that passes fails the session (XPASS(strict)), as pytest's strict xfail"))


class DatasetOptions(BaseModel):
    # driving_log_replayer puts launch options here (VehicleId, LaunchSensing, ...);
    # we keep whatever is given and read only what we know.
    model_config = ConfigDict(extra="allow")
    path: str | None = Field(None, alias="Path", description=(
        "the dataset's file or folder, relative to the scenario file; without it the dataset's name resolves "
        "under --driveeval-data-root, else beside the scenario file"))
    VehicleId: str | None = Field(None, description="driving_log_replayer's launch option, kept and not read here")
    LocalMapPath: str | None = Field(None, description="driving_log_replayer's launch option, kept and not read here")


class EvaluationHead(BaseModel):
    model_config = ConfigDict(extra="allow")
    UseCaseName: str = Field(description=(
        "the use case that reads the rest of Evaluation: closed_loop, obstacle_segmentation, policy_benchmark, or "
        "one registered by a conftest.py or a package"))
    UseCaseFormatVersion: str = Field(description=(
        "the version of the use case's keys that this file is written in; the use case refuses a version it does "
        "not read"))
    Datasets: list[dict[str, DatasetOptions | None]] = Field([], description=(
        "one pytest item per entry (per policy too in policy_benchmark): a mapping of the dataset's name to its "
        "options (Path), or to nothing"))


class Envelope(_Forbid):
    ScenarioFormatVersion: str = Field(description=(
        "driving_log_replayer's format version of the envelope (3.0.0 in the demo); required as in their files"))
    ScenarioName: str = Field(description="the scenario's name, shown in failures and reports")
    ScenarioDescription: str = Field("", description=(
        "what the scenario checks, shown in the reports (allure's description)"))
    SensorModel: str | None = Field(None, description="driving_log_replayer's key, kept and not read here")
    VehicleModel: str | None = Field(None, description="driving_log_replayer's key, kept and not read here")
    VehicleId: str | None = Field(None, description="driving_log_replayer's key, kept and not read here")
    LocalMapPath: str | None = Field(None, description="driving_log_replayer's key, kept and not read here")
    Marks: list[MarkName] = Field([], description="pytest marks put on every item of the file (select with -m)")
    Skip: str | None = Field(None, description="skip every item of the file, with this reason")
    XFail: str | XFailSpec | None = Field(None, description=(
        "every item is expected to fail: the reason, or a mapping with Reason and Strict"))
    # seconds for the whole item, 0: none; --driveeval-time-limit (or its default) otherwise
    TimeLimit: float | None = Field(None, ge=0.0, allow_inf_nan=False, description=(
        "seconds the whole item may run, 0 for no limit; without it --driveeval-time-limit (default 1800) applies"))
    # what counts as worse than the item's baseline (pytest_driveeval.baseline.rules)
    Regression: RegressionSpec | None = Field(None, description=(
        "what counts as worse than the item's baseline (with --driveeval-baseline); default: the use case's own "
        "rules"))
    Evaluation: EvaluationHead = Field(description=(
        "what to evaluate: the use case, its format version, the datasets and the use case's own keys (below, per "
        "use case)"))
