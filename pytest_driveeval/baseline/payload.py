"""What a run keeps of an item for later comparison: its key figures, how each unit ended, the
robustness search's result, and the fingerprint of what produced them.

The fingerprint is everything that makes the figures besides the model under test: the dataset's
content, the scenario's settings (its ``Evaluation`` without the keys that only judge or show the
figures, or name the model), the item's seed and the session's search options.  The model is not
in it: a new model is what a comparison is for.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.outcome import Outcome, jsonable
from .rules import Rules, effective_rules

if TYPE_CHECKING:
    from ..scenario.loaded import DatasetRef, Scenario

PAYLOAD_VERSION = 1
#: Evaluation keys that judge the figures, show them, say where they are computed (chunks give the
#: same figures, which the executor tests check) or name the model under test: not in the fingerprint
NOT_FINGERPRINT = ("Conditions", "Artefacts", "Executor", "Model", "Policies", "Judged", "Datasets",
                   "UseCaseFormatVersion")
#: Up to this many bytes of a dataset are hashed whole; beyond, each file's size and its first and
#: last MiB, so that a 10 GB bag costs milliseconds, not a minute, per session
WHOLE_HASH_LIMIT = 64 * 2 ** 20
_EDGE = 2 ** 20
_identities: dict[tuple, dict[str, Any]] = {}


def dataset_identity(ref: "DatasetRef | None") -> dict[str, Any] | None:
    """The dataset's content as a digest (cached per process by the files' sizes and times)."""
    if ref is None:
        return None
    path = Path(ref.path)
    if not path.exists():
        return {"name": ref.name, "missing": True}
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    stats = [(p, p.stat()) for p in files]
    key = (str(path), tuple((str(p), s.st_size, s.st_mtime_ns) for p, s in stats))
    if key not in _identities:
        total = sum(s.st_size for _, s in stats)
        digest = hashlib.sha256()
        for p, s in stats:
            # Names inside the dataset are its content; its own name is where it lies (a copy
            # renamed is the same dataset, as a folder renamed is).
            name = "" if p == path else p.relative_to(path).as_posix()
            digest.update(f"{name}\0{s.st_size}\0".encode())
            with open(p, "rb") as handle:
                if total <= WHOLE_HASH_LIMIT or s.st_size <= 2 * _EDGE:
                    for block in iter(lambda: handle.read(2 ** 20), b""):
                        digest.update(block)
                else:
                    digest.update(handle.read(_EDGE))
                    handle.seek(-_EDGE, os.SEEK_END)
                    digest.update(handle.read(_EDGE))
        _identities[key] = {"name": ref.name, "files": len(stats), "bytes": total,
                            "sha256": digest.hexdigest()[:16],
                            **({} if total <= WHOLE_HASH_LIMIT else {"hashed": "sizes, first and last MiB"})}
    return _identities[key]


def settings_of(scenario: "Scenario", search: Any = None) -> dict[str, Any]:
    evaluation = scenario.raw.get("Evaluation") or {}
    settings = {k: v for k, v in evaluation.items() if k not in NOT_FINGERPRINT}
    if search is not None and evaluation.get("Perturbation") is not None:
        # The session's options replace the scenario's own for every search.  Not the profile: CI's
        # derandomised search and a laptop's find the same smallest case from the same seed (the
        # search's tolerance covers a shrink that stops a step apart).
        settings["session search"] = {"examples": search.examples, "replay": search.replay}
    return json.loads(json.dumps(jsonable(settings), sort_keys=True))


def fingerprint(scenario: "Scenario", dataset: "DatasetRef | None", seed: int, search: Any = None) -> dict[str, Any]:
    return {"use_case": scenario.use_case, "format_version": scenario.format_version, "seed": seed,
            "settings": settings_of(scenario, search), "dataset": dataset_identity(dataset)}


def scenario_rules(scenario: "Scenario | None", use_case: Any) -> Rules:
    defaults = getattr(use_case, "regression_figures", {}) if use_case is not None else {}
    if scenario is None:
        return effective_rules(defaults, None)
    conditions = getattr(scenario.config, "Conditions", None)
    return effective_rules(defaults, scenario.regression, getattr(conditions, "Confidence", None))


def search_result(outcome: Outcome) -> dict[str, Any] | None:
    """A robustness search's result: whether it broke the item, the smallest breaking change."""
    search = outcome.details.get("search")
    if not isinstance(search, dict):
        return None
    minimal = {k.removeprefix("minimal_"): v for k, v in outcome.figures.items() if k.startswith("minimal_")}
    return {"broke": bool(outcome.figures.get("search_failures") or minimal), "minimal": minimal,
            "text": search.get("minimal_text") or search.get("reason"), "replay": search.get("replay"),
            "examples": search.get("examples")}


def make_payload(outcome: Outcome, nodeid: str, *, use_case: Any = None, scenario: "Scenario | None" = None,
                 dataset: "DatasetRef | None" = None, seed: int | None = None, search: Any = None,
                 item: str = "", file: str = "") -> dict[str, Any]:
    """The comparable record of an item's outcome.  Without a scenario (an outcome a Python test
    made by itself) there is no fingerprint, and a comparison cannot tell a stale baseline."""
    rules = scenario_rules(scenario, use_case)
    units = use_case.regression_units(outcome) if use_case is not None else None
    searched = search_result(outcome)
    figures = {k: outcome.figures[k] for k in rules.figures if k in outcome.figures}
    return jsonable({
        "version": PAYLOAD_VERSION,
        "key": {"file": file, "scenario": scenario.name if scenario is not None else outcome.scenario,
                "item": item, "nodeid": nodeid},
        "use_case": outcome.use_case, "verdict": outcome.verdict, "summary": outcome.summary,
        "model": outcome.details.get("model") or outcome.details.get("policy"),
        "figures": figures,
        "units": units.to_json() if units is not None else None,
        "search": searched,
        "fingerprint": fingerprint(scenario, dataset, seed or 0, search) if scenario is not None else None,
        "rules": rules.to_json(),
    })
