"""Scenario files: driving_log_replayer's envelope, validated, with source lines.

``load_scenario`` reads a file (``source``: safe YAML that remembers every
key's line), checks the envelope (``envelope``) and the use case's own part,
and turns every pydantic error into a located problem (``problems``).
"""
from .envelope import XFailSpec
from .load import NotAScenario, load_scenario
from .loaded import DatasetRef, Scenario

__all__ = ["DatasetRef", "NotAScenario", "Scenario", "XFailSpec", "load_scenario"]
