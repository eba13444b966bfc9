"""The base of every scenario mapping's model.

Its own module, below the use-case registry: the baseline's rules are scenario mappings
too, and the scenario envelope holds them, so importing ``Section`` from the registry
(which names the scenario's types) closed a circle: baseline/rules -> usecase ->
scenario/loaded -> scenario/envelope -> baseline/rules.
"""
from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Section(BaseModel):
    """A mapping of a scenario: unknown keys are errors, so typos are caught; a number is finite,
    since ``.inf`` or ``.nan`` in a YAML file is a slip, and would surface only deep in a run."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
