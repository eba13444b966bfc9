"""The batched search on problems whose edge of failure is known exactly."""
from __future__ import annotations

import pytest
from hypothesis import strategies as st
from hypothesis.database import InMemoryExampleDatabase

from pytest_driveeval.search.engine import Example, SearchSettings, Verdict, search, tighten_many
from pytest_driveeval.strategies import CloudPerturbation, StartPerturbation, start_perturbations

RANGES = {"lateral": (-3.0, 3.0), "heading": (-0.2, 0.2)}
PERTURBATIONS = start_perturbations(lateral=RANGES["lateral"], heading=RANGES["heading"])


class Edge:
    """Case i fails beyond ``right[i]`` to the right (negative lateral) or ``left[i]`` to the left;
    records every batch it is given."""

    def __init__(self, left=(1.37, 2.2), right=(-2.6, -0.9)):
        self.left, self.right = left, right
        self.batches: list[list[Example]] = []

    def __call__(self, examples):
        self.batches.append(list(examples))
        out = []
        for e in examples:
            lat = e.perturbation.lateral
            failed = lat > self.left[e.case] or lat < self.right[e.case]
            out.append(Verdict(failed, "off the road" if failed else "", {"scene": e.case}))
        return out


def run(evaluate, **kw):
    settings = dict(examples=200, batch=16, seed=3, tolerance=0.001)
    settings.update(kw)
    return search(st.integers(0, 1), PERTURBATIONS, evaluate, RANGES, SearchSettings(**settings))


def test_it_reports_the_nearest_edge_on_either_side_within_tolerance():
    evaluate = Edge()
    result = run(evaluate)
    assert result.found
    # The smallest failure over both cases and both sides is case 1 at -0.9 (to the right).
    minimal = result.minimal
    assert minimal.case in (0, 1)
    edge = {0: 1.37, 1: -0.9}[minimal.case]
    assert abs(minimal.perturbation.lateral - edge) <= 0.001 * 6 + 1e-12
    assert minimal.perturbation.heading == 0.0  # it did not matter, so it shrank away
    assert result.verdict.failed and result.verdict.where == {"scene": minimal.case}
    assert abs(result.edges["lateral"] - edge) <= 0.001 * 6 + 1e-12
    assert not evaluate([Example(minimal.case, StartPerturbation(lateral=result.edges["lateral"]))])[0].failed


def test_generations_are_evaluated_in_batches_and_nothing_twice():
    evaluate = Edge()
    result = run(evaluate, batch=16)
    seen = [e for batch in evaluate.batches for e in batch]
    assert len(seen) == len(set(seen)) == result.examples
    assert max(len(b) for b in evaluate.batches) <= 16
    assert result.evaluations["search"] >= 2  # the first generation is evaluated as one call
    assert any(len(b) > 1 for b in evaluate.batches)


def test_a_robust_policy_passes_after_the_examples_asked():
    evaluate = Edge(left=(9, 9), right=(-9, -9))
    result = run(evaluate, examples=64, batch=16)
    assert not result.found and result.failures == 0
    assert result.generations == 4 and 1 < result.examples <= 64


def test_the_ci_profile_and_a_seed_each_give_the_same_search_twice():
    for kw in ({"derandomize": True}, {"seed": 11}):
        first, second = run(Edge(), **kw), run(Edge(), **kw)
        assert (first.minimal, first.examples, first.evaluations) == (second.minimal, second.examples,
                                                                      second.evaluations)


def test_a_stored_failure_is_replayed_first_under_its_own_key_only():
    db = InMemoryExampleDatabase()
    first = run(Edge(), database=db, key=b"scenario-a")
    again = run(Edge(), database=db, key=b"scenario-a")
    other = run(Edge(), database=db, key=b"scenario-b")
    assert first.replayed == 0 and again.replayed >= 1 and other.replayed == 0
    assert again.generations == 1 and again.evaluations["search"] < first.evaluations["search"] + 1
    assert again.minimal == first.minimal


def test_shrinking_stops_at_its_budget_and_the_smallest_failure_seen_is_tightened():
    evaluate = Edge()
    result = run(evaluate, max_shrink_evaluations=1)
    assert result.found and result.evaluations.get("shrink", 0) <= 1 + 16
    assert abs(abs(result.minimal.perturbation.lateral) - {0: 1.37, 1: 0.9}[result.minimal.case]) < 0.01


def test_tighten_resets_a_field_that_does_not_matter_and_bisects_integers():
    evaluate = Edge()
    example = Example(0, StartPerturbation(lateral=2.5, heading=0.15))
    minimal, edges = tighten_many(example, evaluate, RANGES, tolerance=0.001)
    assert minimal.perturbation.heading == 0.0 and abs(minimal.perturbation.lateral - 1.37) < 0.01

    def ghost_fails(examples):
        return [Verdict(e.perturbation.ghost_points >= 37) for e in examples]

    minimal, edges = tighten_many(Example(0, CloudPerturbation(ghost_points=90)), ghost_fails, {"ghost_points": (0, 100)})
    assert minimal.perturbation.ghost_points == 37 and edges["ghost_points"] == 36


def test_an_evaluation_that_breaks_ends_the_search_with_its_own_error_at_once():
    with pytest.raises(RuntimeError, match=r"returned 1 verdicts for \d+ examples"):
        run(lambda examples: [Verdict(False)])
    calls = []

    def broken(examples):
        calls.append(len(examples))
        raise ValueError("the model returned NaN at frame 12")

    with pytest.raises(ValueError, match="NaN at frame 12"):
        run(broken)
    assert len(calls) == 1  # not shrunk as if it were a failure of the policy


SEARCH_IN_A_FRESH_PROCESS = """
import hashlib, sys
sys.path[:0] = [{tests!r}, {extra!r}]
if {preload!r}:
    import preloaded_constants_x
from test_search_engine import Edge, run
evaluate = Edge(left=(9, 9), right=(-9, -9))
run(evaluate, examples=160, batch=16, seed=5)
print(hashlib.sha256(repr([e for b in evaluate.batches for e in b]).encode()).hexdigest())
"""


def test_modules_imported_before_do_not_change_the_search(tmp_path):
    """Hypothesis mixes into its draws constants from the source of local modules
    imported so far; a search must draw the same examples whatever else the
    process (a pytest-xdist worker, say) imported before it."""
    import subprocess
    import sys
    from pathlib import Path

    (tmp_path / "preloaded_constants_x.py").write_text("VALUES = [0.123456, 2.718281, 1.414213]\n")
    digests = set()
    for preload in (False, True):
        code = SEARCH_IN_A_FRESH_PROCESS.format(tests=str(Path(__file__).parent), extra=str(tmp_path),
                                                preload=preload)
        digests.add(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True
                                   ).stdout.strip())
    assert len(digests) == 1


def test_a_slow_machine_searches_the_same_examples(monkeypatch):
    # Hypothesis stops generating 10 s after the first failure when it may report several
    # bugs; a search on a loaded machine then saw fewer examples (and could report another
    # minimum) than on a quiet one.  Here every clock read jumps a minute.
    quiet = run(Edge(), derandomize=True)
    import hypothesis.internal.conjecture.engine as conjecture_engine

    clock = iter(range(0, 10**9, 60))
    monkeypatch.setattr(conjecture_engine.time, "monotonic", lambda: float(next(clock)))
    slow = run(Edge(), derandomize=True)
    assert (slow.examples, slow.failures, slow.minimal) == (quiet.examples, quiet.failures, quiet.minimal)


def test_progress_counts_the_examples_evaluated_up_to_the_total_asked():
    never = Edge(left=(9.0, 9.0), right=(-9.0, -9.0))  # nothing fails: the whole budget is searched
    seen = []
    result = search(st.integers(0, 1), PERTURBATIONS, never, RANGES,
                    SearchSettings(examples=64, batch=16, seed=3, tolerance=0.001),
                    progress=lambda done, total: seen.append((done, total)))
    assert not result.found and seen
    assert [done for done, _ in seen] == sorted({done for done, _ in seen})  # one call per batch, growing
    assert seen[-1][0] == result.examples and all(total == max(64, done) for done, total in seen)
