"""The ``Executor`` section of a scenario, and the session-wide option that replaces it.

    Executor:
      Kind: ray                 # local (the default): in this process, chunk after chunk
      Address: auto             # auto | local | ray://host:10001 | host:6379; unset: Ray's own
                                # choice (RAY_ADDRESS, else the cluster `ray start` left here,
                                # else a private one for this session)
      ChunkSize: 64             # scenes or episodes per task; unset: the use case's own
      MaxInFlight: 16           # tasks submitted and not yet collected; unset: twice the
                                # cluster's CPUs over NumCpus
      Retries: 3                # new attempts of a chunk whose worker or node died
      NumCpus: 1                # CPUs each task reserves (fractions pack tasks onto a node)
      RuntimeEnv: {env_vars: {OMP_NUM_THREADS: "1"}}   # Ray's runtime_env for every task
                                # (needs ray[default] on the cluster for pip/working_dir)
"""
from __future__ import annotations

import re
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, NonNegativeInt, PositiveInt, ValidationError, field_validator

__all__ = ["ExecutorSpec", "executor_from_option"]

# host:port, with a host name, an IPv4 address or a bracketed IPv6 one.
_HOST_PORT = r"(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):\d{1,5}"
_ADDRESS = re.compile(rf"auto|local|ray://{_HOST_PORT}|{_HOST_PORT}")
_ENDPOINT = re.compile(rf"(?:ray://)?{_HOST_PORT}")


def host_port(address: str) -> tuple[str, int] | None:
    """The host (brackets of an IPv6 one removed) and port of ``host:port`` or
    ``ray://host:port``; None for ``auto``, ``local`` or anything else."""
    found = _ENDPOINT.fullmatch(address)
    if found is None:
        return None
    host = found.group(1)
    return host.strip("[]"), int(address.rsplit(":", 1)[1])


class ExecutorSpec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    Kind: Literal["local", "ray"] = Field("local", description=(
        "where the item's scenes or episodes run: local (here, the default) or ray (chunks as Ray tasks)"))
    Address: str | None = Field(None, description=(
        "the Ray cluster: auto, local, host:6379 (the head's GCS) or ray://host:10001 (Ray Client); unset: Ray's "
        "own choice (RAY_ADDRESS, else the cluster ray start left here, else a private one for this session)"))
    ChunkSize: PositiveInt | None = Field(None, description=(
        "episodes (policy_benchmark, default 64) or scenes (closed_loop, default 8) per task; with Kind: local "
        "the same chunks run one after the other here"))
    MaxInFlight: PositiveInt | None = Field(None, description=(
        "tasks submitted and not yet collected; default: twice the cluster's CPUs over NumCpus"))
    Retries: NonNegativeInt = Field(3, le=100, description="new attempts of a chunk whose worker or node died")
    NumCpus: float = Field(1.0, gt=0.0, description="CPUs each task reserves (fractions pack tasks onto a node)")
    RuntimeEnv: dict[str, Any] | None = Field(None, description=(
        "Ray's runtime_env for the workers (e.g. {pip: [...]}, needs ray[default] on the cluster)"))

    @field_validator("Address")
    @classmethod
    def _an_address_ray_understands(cls, value: str | None) -> str | None:
        if value is not None and not _ADDRESS.fullmatch(value):
            raise ValueError(f"expected auto, local, ray://host:port (Ray Client) or host:port (the head's "
                             f"GCS), got {value!r}")
        return value

    @property
    def is_local(self) -> bool:
        return self.Kind == "local"

    def describe(self) -> str:
        if self.is_local:
            return "local"
        return f"ray ({self.Address or 'default address'})"


def executor_from_option(text: str) -> ExecutorSpec:
    """The executor a command-line option or ini key sets for a whole session: ``local``,
    ``ray``, or the scenario's own mapping in YAML flow style,
    ``{Kind: ray, Address: auto, ChunkSize: 64}``.  Raises ``ValueError`` naming the problem."""
    text = text.strip()
    if text in ("local", "ray"):
        return ExecutorSpec(Kind=text)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"executor option {text!r} is neither local, ray nor a YAML mapping: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"executor option {text!r} is neither local, ray nor a YAML mapping "
                         "such as {Kind: ray, Address: auto}")
    try:
        return ExecutorSpec.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'Executor'}: {e['msg']}" for e in exc.errors())
        raise ValueError(f"executor option {text!r}: {problems}") from None
