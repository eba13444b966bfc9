"""A scene's score from its terms, and an item's from its scenes' (nuplan-devkit's weighted-average
aggregator: docs/nuplan_score.md §4-6)."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from . import kernels
from .comfort import ego_is_comfortable
from .inputs import ScoreInputs
from .route import InOneLane, centre_route, lanes_lists
from .term import MULTIPLIERS, TERMS, WEIGHTS, Term
from .collisions import nuplan_collisions
from .progress import expert_progress
from .terms import (driving_direction_compliance, drivable_area_compliance, ego_corners, ego_is_making_progress,
                    no_ego_at_fault_collisions, speed_limit_compliance)
from .ttc import time_to_collision_within_bound


@dataclass
class SceneScore:
    score: float
    terms: dict[str, Term]

    def figures_of_terms(self) -> dict[str, float]:
        """The score and each available term, as numbers (the terms' own measures: ``Term.detail``)."""
        return {"score": self.score} | {n: t.value for n, t in self.terms.items() if t.value is not None}

    def not_available(self) -> dict[str, str]:
        return {name: term.reason for name, term in self.terms.items() if term.value is None}

    def failed(self) -> list[Term]:
        """The terms that cost the scene something, in the score's order."""
        return [t for t in self.terms.values() if t.used is not None and t.used < 1.0]


def combine(terms: dict[str, Term]) -> float:
    """Multipliers times the weighted mean of the weighted terms, each over those the score uses."""
    product = 1.0
    for name in MULTIPLIERS:
        if terms[name].used is not None:
            product *= terms[name].used
    used = [(WEIGHTS[n], terms[n].used) for n in WEIGHTS if terms[n].used is not None]
    total = sum(w for w, _ in used)
    return product * (sum(w * v for w, v in used) / total if total else 0.0)


def score_scene(inputs: ScoreInputs) -> SceneScore:
    compiled = kernels.wanted()
    start = time.perf_counter()
    score = _score_scene(inputs)
    if not compiled:
        kernels.spent_without(time.perf_counter() - start)
    return score


def _score_scene(inputs: ScoreInputs) -> SceneScore:
    corners = ego_corners(inputs)
    heading = inputs.ego.center[:, 2]
    t = inputs.num_frames
    if inputs.map is not None:
        score_map = inputs.map
        # one lookup for the centres, the corners and the expert's centres
        holding, held, touched = score_map.lanes_holding(np.concatenate([inputs.ego.center[:, :2],
                                                                         corners.reshape(-1, 2), inputs.expert[:, :2]]))
        here = lanes_lists(holding, touched)
        centre_here, corner_here, expert_here = here[:t], here[t:5 * t], here[5 * t:]
        corner_on_lane = held[t:5 * t]
        route = centre_route(score_map, inputs.ego.center[:, :2], heading, holding[:t], here=centre_here)
        in_one_lane = InOneLane(score_map, corners, corner_here)
        in_intersection = score_map.in_intersection(inputs.ego.rear_axle)
        expert_route = centre_route(score_map, inputs.expert[:, :2], inputs.expert[:, 2], holding[5 * t:],
                                    here=expert_here)
        progress = expert_progress(inputs, expert_route, centre_here, expert_here)
    else:  # as nuplan-devkit's extractor finds no lane anywhere
        corner_on_lane, route = None, [[] for _ in range(inputs.num_frames)]
        in_one_lane = np.zeros(inputs.num_frames, dtype=bool)
        in_intersection = np.zeros(inputs.num_frames, dtype=bool)
        progress = expert_progress(inputs)
    later: dict[int, int] = {}
    if inputs.blame == "nuplan":
        collisions, later = nuplan_collisions(inputs, in_one_lane)
    else:
        collisions = inputs.collisions
    terms = {
        "no_ego_at_fault_collisions": no_ego_at_fault_collisions(inputs, collisions, later),
        "drivable_area_compliance": drivable_area_compliance(inputs, corners, corner_on_lane, route),
        "ego_is_making_progress": ego_is_making_progress(progress),
        "driving_direction_compliance": driving_direction_compliance(inputs, route),
        "ego_progress_along_expert_route": progress,
        "time_to_collision_within_bound": time_to_collision_within_bound(inputs, in_one_lane, in_intersection,
                                                                         collisions),
        "speed_limit_compliance": speed_limit_compliance(inputs, route),
        "ego_is_comfortable": ego_is_comfortable(inputs),
    }
    assert tuple(terms) == TERMS
    return SceneScore(combine(terms), terms)


def item_figures(scenes: list[dict]) -> dict[str, float]:
    """nuPlan's final score, the mean of the scenes' scores, and each term's mean over the scenes where it
    is available, from each scene's :meth:`SceneScore.figures_of_terms`."""
    out = {}
    for name in ("score", *TERMS):
        values = [figures[name] for figures in scenes if name in figures]
        if values:
            out[name] = float(np.mean(values))
    return out
