"""What counts as worse than a baseline for the policy benchmark: a rate over the seeded episodes,
tested paired (both runs played the same seeds): worse only when the paired interval of the
difference excludes zero at the scenario's confidence; the episodes that changed are named by seed."""
from __future__ import annotations

from pytest_driveeval.baseline.rules import FigureRule
from pytest_driveeval.baseline.units import Units, compact_ids, expand_ids
from pytest_driveeval.core.outcome import Outcome

# One character per episode outcome (metrics.episode_outcomes.OUTCOME_NAMES).
CODES = {"running": "r", "goal": "g", "collision": "c", "off_road": "o", "step_limit": "s"}
LEGEND = {code: name.replace("_", " ") for name, code in CODES.items()}
FIGURES = {
    "goal_rate": FigureRule("higher", paired=("outcome", "g"), unit="%"),
    "collision_rate": FigureRule("lower", paired=("outcome", "c"), unit="%"),
    "off_road_rate": FigureRule("lower", paired=("outcome", "o"), unit="%"),
}


def episode_outcomes(seeds: list[int], names: list[str]) -> dict:
    """The per-episode ends for ``Outcome.details``: seeds compacted, one character each."""
    return {"seeds": compact_ids([str(int(s)) for s in seeds]), "codes": "".join(CODES[name] for name in names)}


def episode_units(outcome: Outcome) -> Units | None:
    episodes = outcome.details.get("episode_outcomes")
    if not isinstance(episodes, dict) or outcome.details.get("search"):
        return None
    seeds = expand_ids(episodes["seeds"])
    return Units("episode", seeds, {"outcome": episodes["codes"]}, LEGEND, {"outcome": "g"})
