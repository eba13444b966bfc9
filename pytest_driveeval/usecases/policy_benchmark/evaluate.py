"""Run policies on the same seeded episodes and judge them: the Python API of ``policy_benchmark``.

``run_policy`` steps all episodes of one policy together (one policy call per
step for the whole batch); ``judge`` turns the per-episode outcomes of the
policy and of the baselines it is compared with into decisions with
confidence intervals (:mod:`pytest_driveeval.metrics.benchmark_stats`).
Episode ``i`` is drawn from seed ``first_seed + i`` for every policy, so the
comparisons are paired.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from pytest_driveeval.core.deadline import TimeLimitExceeded, guarded_call, note
from pytest_driveeval.core.errors import ModelError
from pytest_driveeval.sim.torch_threads import one_torch_thread
from pytest_driveeval.metrics.episode_outcomes import COLLISION, GOAL, OFF_ROAD, OUTCOME_NAMES, STEP_LIMIT

__all__ = ["PolicyRun", "observe", "observer", "run_policy", "seeds_for"]

#: called after every step with the episodes, for pictures of an episode
StepSink = Callable[[Any], None]


@dataclass
class PolicyRun:
    """Per-episode results of one policy; arrays over episodes in seed order."""

    policy: str
    blueprint: str
    seeds: np.ndarray
    strata: np.ndarray
    outcome: np.ndarray  # codes of metrics.episode_outcomes
    returns: np.ndarray
    steps: np.ndarray

    def rate_of(self, code: int) -> np.ndarray:
        return self.outcome == code

    @property
    def goal(self) -> np.ndarray:
        return self.rate_of(GOAL)

    @property
    def collision(self) -> np.ndarray:
        return self.rate_of(COLLISION)

    @property
    def off_road(self) -> np.ndarray:
        return self.rate_of(OFF_ROAD)

    @property
    def step_limit(self) -> np.ndarray:
        return self.rate_of(STEP_LIMIT)

    def outcome_names(self) -> list[str]:
        return [OUTCOME_NAMES[int(c)] for c in self.outcome]

    def figures(self) -> dict[str, float]:
        n = len(self.seeds)
        return {"episodes": n, "goal_rate": 100.0 * self.goal.mean(), "collision_rate": 100.0 * self.collision.mean(),
                "off_road_rate": 100.0 * self.off_road.mean(), "step_limit_rate": 100.0 * self.step_limit.mean(),
                "mean_return": float(self.returns.mean()), "mean_steps": float(self.steps.mean())}


def seeds_for(first_seed: int, episodes: int, strata: int) -> tuple[np.ndarray, np.ndarray]:
    """Episode seeds and their strata: consecutive seeds in ``strata`` groups of (nearly) equal size."""
    seeds = np.arange(first_seed, first_seed + episodes, dtype=np.int64)
    groups = min(strata, episodes)
    return seeds, (np.arange(episodes) * groups) // episodes


def observer(episodes: Any, agent_limit: int) -> Callable[[Any], Any]:
    """``observe(episodes)`` -> the flat graph observation (E, D) float32 of every
    episode (seed 002's encoding), with the normalisation of these episodes' map
    worked out once rather than every step."""
    from pytest_driveeval.policies.graph import ObservationRanges
    from pytest_driveeval.policies.graph_jit import observer as graph_observer

    observe = graph_observer(ObservationRanges.from_bounding_box(*episodes.map_bounds), agent_limit)

    def observe_now(now: Any):
        return observe(now.xy, now.yaw, now.speed, now.valid, now.goal_centre, now.goal_speed)

    return observe_now


def observe(episodes: Any, agent_limit: int):
    """The flat graph observation (E, D) float32 of every episode, once."""
    return observer(episodes, agent_limit)(episodes)


def _actions(out: Any, episodes: Any, policy: str, step: int) -> np.ndarray:
    """The policy's output as (E, 2) float64, or a ModelError naming the episode and step."""
    try:
        actions = np.asarray(out.detach().cpu().numpy() if hasattr(out, "detach") else out, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ModelError(f"policy '{policy}' returned {type(out).__name__} at step {step}, not actions: {exc}") \
            from None
    expected = (episodes.num_episodes, 2)
    if actions.shape != expected:
        raise ModelError(f"policy '{policy}' returned actions of shape {actions.shape} at step {step}; expected "
                         f"{expected} (episodes, [acceleration m/s^2, steering rad])")
    running = ~episodes.done
    bad = np.flatnonzero(running & ~np.isfinite(actions).all(axis=1))
    if bad.size:
        first = int(bad[0])
        raise ModelError(f"policy '{policy}' returned {actions[first].tolist()} for episode {first} "
                         f"(seed {int(episodes.seeds[first])}) at step {step}"
                         + (f", and non-finite actions for {bad.size - 1} more episode(s)" if bad.size > 1 else ""))
    # Finished episodes ignore their action; keep whatever the policy said there from tripping the engine.
    return np.where(running[:, None], actions, 0.0)


def run_policy(blueprint: Any, seeds: Sequence[int], policy: Callable, name: str, *, strata: Sequence[int] | None = None,
               agent_limit: int = 12, on_step: StepSink | None = None,
               perturbation: np.ndarray | None = None,
               progress: Callable[[int, int], None] | None = None) -> PolicyRun:
    """Run ``policy`` on one episode per seed until every episode has ended.

    ``perturbation``: one row per seed moving that episode's start
    (:data:`pytest_driveeval.sim.episodes.PERTURBATION_COLUMNS`), or None.

    ``progress(done, total)``: episodes ended of all, after each step.

    ``policy`` is a callable from the flat graph observation (E, D) tensor to
    actions (E, 2) (a torch module or any function), or an object with
    ``act_on_episodes(episodes)`` for baselines that read the simulator's state.
    """
    import torch

    from pytest_driveeval.sim.episodes import reset

    episodes = reset(blueprint, np.asarray(seeds, dtype=np.int64), agent_limit, perturbation=perturbation)
    on_state = getattr(policy, "act_on_episodes", None)
    observe_now = observer(episodes, agent_limit)
    step = 0
    if on_step is not None:
        on_step(episodes)
    with torch.no_grad(), one_torch_thread():
        while not episodes.done.all():
            note(policy=name, step=step)
            try:
                out = on_state(episodes) if on_state is not None else guarded_call(policy, observe_now(episodes))
            except (TimeLimitExceeded, ModelError):
                raise
            except Exception as exc:  # a broken policy fails its item, not the session
                raise ModelError(f"policy '{name}' raised {type(exc).__name__} at step {step}: {exc}") from None
            episodes.step(_actions(out, episodes, name, step))
            step += 1
            if progress is not None:
                progress(int(episodes.done.sum()), len(episodes.done))
            if on_step is not None:
                on_step(episodes)
    seeds = np.asarray(seeds, dtype=np.int64)
    return PolicyRun(name, episodes.blueprint.name, seeds,
                     np.zeros(len(seeds), np.int64) if strata is None else np.asarray(strata),
                     episodes.outcome.copy(), episodes.returns.copy(), episodes.steps.copy())
