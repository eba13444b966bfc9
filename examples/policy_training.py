"""The pieces of examples/train_gnn_policy.py that are not the training loop: the networks it can
train, the replay buffer, the batched experience collector (which also measures the environment
steps per second), the behaviour-cloning loss, evaluation and the learning-curve plot.
examples/bc_check.py uses them too, so the supervised check sees the same data and loss."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from pytest_driveeval.policies import gnn, mlp
from pytest_driveeval.policies.gnn import NodeScaling
from pytest_driveeval.policies.graph import HEADER
from pytest_driveeval.policies.idm_expert import IDMExpert
from pytest_driveeval.sim.episodes import reset
from pytest_driveeval.usecases.policy_benchmark.evaluate import observer, run_policy

AGENT_LIMIT = 12
HELD_OUT = np.arange(0, 64)
VALIDATION = np.arange(50000, 50064)
# The expert's episodes that set the networks' feature scaling: seeds no run trains or is judged on.
SCALING_SEED = 900_000
# The only thing that differs between the runs compared: the module building actor and critic.
NETWORKS = {"gnn": gnn, "mlp": mlp}
BLUEPRINTS = ("highway", "merging", "intersection")


def action_bounds(blueprint) -> dict[str, tuple[float, float]]:
    """make_actor's action bounds for ``blueprint``: the ego's own (acceleration, steering) limits.
    The networks' defaults are BARK-ML's (-5..4 m/s^2, +-0.2 rad), which are the highway's and the
    merging's; the intersection lets the ego steer 0.5 rad because its left turn needs it, and an actor
    squashed to 0.2 rad could never make the turn its expert shows it."""
    p = blueprint.params
    return {"action_low": (p.ego_accel[0], -p.ego_max_steer), "action_high": (p.ego_accel[1], p.ego_max_steer)}


def fit_node_scaling(modules, obs: np.ndarray, floor: float = 0.01) -> None:
    """Set every NodeScaling in ``modules`` to the mean and standard deviation of each node feature
    over the nodes in use in ``obs`` (flat observations, the expert's states).  ``floor`` keeps a
    feature that barely varies in these states (the goal's speed) from being blown up where it does."""
    k, _, f = (int(v) for v in obs[0, :HEADER])
    nodes = obs[:, HEADER:HEADER + k * f].reshape(len(obs), k, f).astype(np.float64)
    in_use = np.arange(k)[None, :] < obs[:, 1:2]
    features = nodes[in_use]
    shift = torch.tensor(features.mean(axis=0), dtype=torch.float32)
    scale = torch.tensor(np.maximum(features.std(axis=0), floor), dtype=torch.float32)
    with torch.no_grad():
        for module in modules:
            for part in module.modules():
                if isinstance(part, NodeScaling):
                    part.shift.copy_(shift)
                    part.scale.copy_(scale)


def default_out(network: str, blueprint: str) -> Path:
    return Path(__file__).resolve().parents[1] / "fixtures" / "models" / f"{network}_actor_{blueprint}.pt2"


class Replay:
    """Transitions with the expert's label of each state, in preallocated arrays."""

    def __init__(self, capacity: int, obs_size: int):
        self.obs = np.zeros((capacity, obs_size), np.float32)
        self.next_obs = np.zeros((capacity, obs_size), np.float32)
        self.action = np.zeros((capacity, 2), np.float32)
        self.expert = np.zeros((capacity, 2), np.float32)
        self.reward = np.zeros(capacity, np.float32)
        self.terminal = np.zeros(capacity, np.float32)
        self.capacity, self.size, self.head = capacity, 0, 0

    def add(self, obs, action, expert, reward, next_obs, terminal) -> None:
        n = len(obs)
        idx = (self.head + np.arange(n)) % self.capacity
        self.obs[idx], self.action[idx], self.expert[idx] = obs, action, expert
        self.reward[idx], self.next_obs[idx], self.terminal[idx] = reward, next_obs, terminal
        self.head = (self.head + n) % self.capacity
        self.size = min(self.size + n, self.capacity)

    def sample(self, rng: np.random.Generator, batch: int):
        idx = rng.integers(0, self.size, batch)
        return tuple(torch.from_numpy(a[idx]) for a in
                     (self.obs, self.action, self.expert, self.reward, self.next_obs, self.terminal))


class Collector:
    """``envs`` episodes stepped together; a new batch of seeds once all of them have ended.

    ``env_steps`` counts the steps of running episodes (one transition each) and ``seconds`` the
    wall time spent in :meth:`step` (the acting policy, the expert's labels, the simulator and the
    observation), so ``env_steps / seconds`` is the collection throughput."""

    def __init__(self, blueprint, envs: int, first_seed: int, progress_scale: float):
        self.blueprint, self.envs, self.next_seed = blueprint, envs, first_seed
        self.progress_scale = progress_scale
        self.expert = IDMExpert()
        self.episodes_done = 0
        self.env_steps, self.seconds = 0, 0.0
        self.outcomes: list[np.ndarray] = []
        self._new_batch()

    @property
    def steps_per_second(self) -> float:
        return self.env_steps / self.seconds if self.seconds > 0 else 0.0

    def _new_batch(self) -> None:
        seeds = np.arange(self.next_seed, self.next_seed + self.envs)
        self.next_seed += self.envs
        self.episodes = reset(self.blueprint, seeds, AGENT_LIMIT)
        self.observe = observer(self.episodes, AGENT_LIMIT)
        self.obs = self.observe(self.episodes).numpy()
        self.distance = self._goal_distance()

    def _goal_distance(self) -> np.ndarray:
        return np.linalg.norm(self.episodes.xy[:, 0] - self.episodes.goal_centre, axis=1)

    def step(self, act) -> tuple:
        """One step of every running episode; ``act(obs, episodes, expert) -> actions (E, 2)``.  Returns
        the running episodes' transitions (obs, action, expert label, shaped reward, next obs, terminal)."""
        start = time.perf_counter()
        ep = self.episodes
        running = ~ep.done
        expert = self.expert.act_on_episodes(ep)
        actions = np.where(running[:, None], act(self.obs, ep, expert), 0.0)
        result = ep.step(actions)
        next_obs = self.observe(ep).numpy()
        distance = self._goal_distance()
        # The seed's reward without its per-step bonus, plus progress towards the goal.
        reward = (result.goal.astype(np.float32) - (result.collision | result.off_road)
                  + self.progress_scale * (self.distance - distance))
        terminal = result.goal | result.collision | result.off_road
        out = (self.obs[running], actions[running].astype(np.float32), expert[running].astype(np.float32),
               reward[running].astype(np.float32), next_obs[running], terminal[running].astype(np.float32))
        self.obs, self.distance = next_obs, distance
        if ep.done.all():
            self.outcomes.append(ep.outcome.copy())
            self.episodes_done += self.envs
            self._new_batch()
        self.env_steps += int(running.sum())
        self.seconds += time.perf_counter() - start
        return out

    def episodes_of(self, act, batches: int = 1, replay: Replay | None = None) -> list[tuple]:
        """Drive ``batches`` whole batches of episodes with ``act``; their transitions go to ``replay``
        if given, and are returned otherwise."""
        kept = []
        for _ in range(batches):
            first = self.episodes_done
            while self.episodes_done == first:
                transitions = self.step(act)
                if replay is not None:
                    replay.add(*transitions)
                else:
                    kept.append(transitions)
        return kept


def expert_acts(obs, episodes, expert):
    return expert


def expert_states(blueprint, envs: int, first_seed: int, batches: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Every state the expert visits on ``batches`` batches of ``envs`` seeds, and its action there."""
    collector = Collector(blueprint, envs, first_seed, progress_scale=0.0)
    transitions = collector.episodes_of(expert_acts, batches)
    obs = np.concatenate([t[0] for t in transitions])
    labels = np.concatenate([t[2] for t in transitions])
    return torch.from_numpy(obs), torch.from_numpy(labels)


def scaled(actor, action: torch.Tensor) -> torch.Tensor:
    return (action - actor.action_center) / actor.action_half_range


def bc_loss(actor, obs: torch.Tensor, expert: torch.Tensor) -> torch.Tensor:
    # The expert often acts at a bound, where tanh cannot reach: aim just inside it.
    target = scaled(actor, expert).clamp(-0.97, 0.97)
    return F.mse_loss(scaled(actor, actor(obs)), target)


def evaluate(actor, blueprint, seeds: np.ndarray, name: str) -> dict[str, float]:
    actor.eval()
    figures = run_policy(blueprint, seeds, actor, name, agent_limit=AGENT_LIMIT).figures()
    actor.train()
    return figures


def plot(curve: list[dict], baselines: dict, chosen: dict | None, args, steps_per_second: float,
         path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.arange(len(curve))
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for key, label, colour in (("held_out_goal_rate", "goal", "tab:green"),
                               ("held_out_collision_rate", "collision", "tab:red"),
                               ("held_out_off_road_rate", "off-road", "tab:orange"),
                               ("held_out_step_limit_rate", "step limit", "tab:gray")):
        ax.plot(x, [r[key] for r in curve], marker="o", ms=3, label=f"{args.network} {label}", color=colour)
    styles = {"random": ":", "constant": "-.", "idm_expert": "--"}
    for name, fig_ in baselines.items():
        ax.axhline(fig_["goal_rate"], ls=styles[name], color="tab:green", alpha=0.5, lw=1,
                   label=f"{name} goal ({fig_['goal_rate']:.0f} %)")
    dagger = [i for i, r in enumerate(curve) if r["phase"] == "dagger"]
    if dagger:
        ax.axvspan(-0.5, dagger[-1] + 0.5, color="tab:blue", alpha=0.07, label="DAgger warm start")
    if chosen is not None:
        ax.axvline(curve.index(chosen), color="k", lw=0.8, label="shipped checkpoint")
    ticks = x[::max(1, len(x) // 12)]
    ax.set_xticks(ticks)
    ax.set_xticklabels([f"{curve[i]['phase'][0]}{curve[i]['updates']}" for i in ticks], rotation=45, fontsize=7)
    ax.set_xlabel("checkpoint (i: init, d: DAgger BC updates, s: SAC updates)")
    ax.set_ylabel("% of 64 held-out episodes (seeds 0..63)")
    ax.set_ylim(-2, 102)
    ax.set_title(f"{args.network.upper()} actor on {args.blueprint}: DAgger warm start + SAC (seed {args.seed}); "
                 f"collection {steps_per_second:,.0f} env steps/s, {torch.get_num_threads()} threads", fontsize=9)
    ax.legend(fontsize=7, loc="center right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
