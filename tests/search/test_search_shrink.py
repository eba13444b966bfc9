"""Batched shrinking: the candidates of a round, and tightening both sides in the same batches."""
from __future__ import annotations

from dataclasses import asdict, replace

import pytest

from pytest_driveeval.search.engine import Example, SearchSettings, Verdict, search
from pytest_driveeval.search.examples import rank
from pytest_driveeval.search.shrink import shrink_candidates, tighten_many
from pytest_driveeval.strategies import EpisodePerturbation, episode_perturbations

RANGES = {"lateral": (-0.3, 0.3), "longitudinal": (0.0, 0.0), "heading": (-0.03, 0.03), "speed_scale": (0.9, 1.1),
          "agents_speed_scale": (0.9, 1.1), "gap_scale": (0.85, 1.2)}
WIDTHS = {k: hi - lo for k, (lo, hi) in RANGES.items()}


def test_a_round_resets_every_subset_of_the_changed_fields_smallest_first():
    example = Example(3, EpisodePerturbation(lateral=0.2, heading=-0.01, gap_scale=0.9))
    candidates = shrink_candidates(example, WIDTHS)
    assert len(candidates) == 7 and len(set(candidates)) == 7  # 2**3 - 1 subsets, none twice
    assert candidates[0] == Example(3, EpisodePerturbation())  # everything reset first
    assert all(c.case == 3 for c in candidates)
    ranks = [rank(c, WIDTHS) for c in candidates]
    assert ranks == sorted(ranks) and ranks[-1] < rank(example, WIDTHS)
    assert shrink_candidates(Example(0, EpisodePerturbation()), WIDTHS) == []  # no change: nothing to shrink


def sequential_tighten(example, fails, ranges, tolerance=0.01, points=15):
    """The former tighten_many: one question at a time, then each side's bisection in turn."""
    neutral = type(example.perturbation)()
    current = example
    edges = {}
    for name, value in asdict(example.perturbation).items():
        base = getattr(neutral, name)
        if value == base:
            continue

        def at(v):
            return Example(current.case, replace(current.perturbation, **{name: v}))

        if fails(at(base)):
            current = at(base)
            continue
        low, high = ranges.get(name, (min(value, base), max(value, base)))
        other = low if value > base else high
        sides = [value] + ([other] if other != base and fails(at(other)) else [])
        step_limit = tolerance * ((high - low) or 1.0)
        found = []
        for side in sides:
            passing, failing = base, side
            while abs(failing - passing) > step_limit:
                values = [passing + (failing - passing) * (i + 1) / (points + 1) for i in range(points)]
                failed = [fails(at(v)) for v in values]
                first = next((i for i, f in enumerate(failed) if f), len(values))
                if first < len(values):
                    failing = values[first]
                if first > 0:
                    passing = values[first - 1]
            found.append((failing, passing))
        failing, passing = min(found, key=lambda edge: abs(edge[0] - base))
        current = at(failing)
        edges[name] = passing
    return current, edges


def breaks_when(example):
    """Fails when the ego is moved far enough either way, or faster in denser traffic."""
    p = example.perturbation
    return p.lateral > 0.21 or p.lateral < -0.08 + 0.5 * (p.speed_scale - 1) or \
        (p.speed_scale - 1) - 0.6 * (p.gap_scale - 1) > 0.11


@pytest.mark.parametrize("start", [
    EpisodePerturbation(lateral=0.29, heading=0.02, speed_scale=1.08, gap_scale=0.86),
    EpisodePerturbation(lateral=-0.25, speed_scale=0.95),
    EpisodePerturbation(speed_scale=1.1, gap_scale=0.88, agents_speed_scale=0.93),
])
def test_tightening_in_batches_gives_what_asking_one_at_a_time_gave(start):
    example = Example(1, start)
    assert breaks_when(example)
    batches = []

    def evaluate(examples):
        batches.append(len(examples))
        return [Verdict(breaks_when(e)) for e in examples]

    assert tighten_many(example, evaluate, RANGES) == sequential_tighten(example, breaks_when, RANGES)
    assert max(batches) <= 32 and len(batches) <= 3 * len(asdict(start))


def test_the_search_shrinks_in_batches_and_reports_a_failure_no_subset_of_whose_changes_fails():
    batches = []

    def evaluate(examples):
        batches.append(list(examples))
        return [Verdict(breaks_when(e)) for e in examples]

    settings = SearchSettings(examples=256, batch=32, seed=7, tolerance=0.01)
    result = search(st_cases(), episode_perturbations(**RANGES), evaluate, RANGES, settings)
    assert result.found and breaks_when(result.minimal)
    for candidate in shrink_candidates(result.shrunk, WIDTHS):
        assert not breaks_when(candidate)
    assert result.evaluations.get("shrink", 0) <= 64
    single = [b for b in batches if len(b) == 1]
    assert len(single) <= 1, "shrinking and tightening ask in batches"


def st_cases():
    from hypothesis import strategies as st

    return st.integers(0, 3)
