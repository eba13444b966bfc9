"""The public perturbation strategies: values in range, and failures shrink to the smallest change."""
from __future__ import annotations

import math

import pytest
from hypothesis import find, given
from hypothesis import settings as hsettings

from pytest_driveeval.strategies import (
    CloudPerturbation,
    EpisodePerturbation,
    StartPerturbation,
    cloud_perturbations,
    describe,
    episode_perturbations,
    start_perturbations,
    tighten,
)

FULL = dict(lateral=(-3.0, 3.0), longitudinal=(-5.0, 5.0), heading=(-0.3, 0.3), speed_scale=(0.5, 1.5),
            agents_speed_scale=(0.8, 1.2))


@given(start_perturbations(**FULL))
def test_start_perturbations_stay_in_their_ranges(p):
    for name, (low, high) in FULL.items():
        assert low <= getattr(p, name) <= high


def test_a_failure_shrinks_to_a_simple_offset_with_everything_else_unchanged_then_tightens_to_the_edge():
    # A policy that fails once the ego starts more than 1.3 m off its lane.
    def fails(p):
        return abs(p.lateral) > 1.3

    found = find(start_perturbations(**FULL), fails, settings=hsettings(max_examples=2000, database=None))
    assert abs(found.lateral) > 1.3
    assert (found.longitudinal, found.heading, found.speed_scale, found.agents_speed_scale) == (0.0, 0.0, 1.0, 1.0)
    edge = tighten(found, fails, tolerance=1e-4)
    assert 1.3 < abs(edge.lateral) <= 1.3 + 1e-4 and fails(edge)


def test_tighten_resets_fields_that_do_not_matter_and_bisects_integers():
    p = CloudPerturbation(dropout=0.5, range_noise=0.2, ghost_points=40)
    edge = tighten(p, lambda q: q.ghost_points >= 17)
    assert edge == CloudPerturbation(ghost_points=17)


def test_scale_factors_shrink_towards_one():
    found = find(episode_perturbations(gap_scale=(0.3, 2.0), speed_scale=(0.5, 1.5)), lambda p: p.gap_scale < 0.8,
                 settings=hsettings(max_examples=2000, database=None))
    assert found.gap_scale < 0.8 and found.speed_scale == 1.0
    assert 0.799 <= tighten(found, lambda p: p.gap_scale < 0.8).gap_scale < 0.8


def test_cloud_dropout_shrinks_towards_none():
    found = find(cloud_perturbations(dropout=(0.0, 0.9), ghost_points=(0, 50)), lambda p: p.dropout >= 0.25,
                 settings=hsettings(max_examples=2000, database=None))
    assert found.dropout >= 0.25 and found.ghost_points == 0 and found.range_noise == 0.0


@pytest.mark.parametrize("make, message", [
    (lambda: start_perturbations(lateral=(0.5, 2.0)), "lateral: the range (0.5, 2.0) must contain 0"),
    (lambda: start_perturbations(speed_scale=(1.1, 1.5)), "speed_scale: the range (1.1, 1.5) must contain 1"),
    (lambda: cloud_perturbations(dropout=(0.0, 1.5)), "dropout: a fraction range within [0, 1]"),
    (lambda: start_perturbations(lateral=(-math.inf, math.inf)), "lateral: a range of finite numbers is needed"),
    (lambda: episode_perturbations(gap_scale=(math.nan, 1.0)), "gap_scale: a range of finite numbers is needed"),
    (lambda: cloud_perturbations(range_noise=(0.0, math.inf)), "range_noise: a range of finite numbers is needed"),
])
def test_a_range_without_the_unperturbed_value_is_refused(make, message):
    with pytest.raises(ValueError) as error:
        make()
    assert message in str(error.value)


def test_describe_names_only_what_changed():
    assert describe(StartPerturbation(lateral=1.25, heading=-0.05)) == "lateral=1.25, heading=-0.05"
    assert describe(StartPerturbation()) == "no perturbation" and StartPerturbation().is_identity()
    assert describe(CloudPerturbation(ghost_points=12)) == "ghost_points=12"
    assert EpisodePerturbation().to_json() == {**StartPerturbation().to_json(), "gap_scale": 1.0}
    assert EpisodePerturbation().is_identity() and not EpisodePerturbation(gap_scale=0.7).is_identity()
    assert describe(EpisodePerturbation(gap_scale=0.7)) == "gap_scale=0.7"


@given(episode_perturbations(**FULL, gap_scale=(0.5, 2.0)))
def test_episode_perturbations_stay_in_their_ranges(p):
    assert isinstance(p, EpisodePerturbation) and isinstance(p, StartPerturbation)
    for name, (low, high) in {**FULL, "gap_scale": (0.5, 2.0)}.items():
        assert low <= getattr(p, name) <= high
