"""Throughput of examples/train_gnn_policy.py's two costs, per blueprint and network (issue 24).

Collection: environment steps per second (steps of running episodes) of its collector, 32 episodes
stepped together with the actor sampling its actions as in the SAC phase (the expert labels each
state, as in training).  Updates: SAC gradient updates per second (critic, actor, temperature,
targets) at batch 256 on the collected transitions.  Each at ``--threads`` (default 2, the training
script's) and at 1 thread, since on a machine whose cores other jobs keep busy the second thread can
cost more than it gives.  Medians of ``--rounds``.  Nothing is asserted.

    python benchmarks/bench_policy_training.py [--steps 100] [--updates 30] [--rounds 3] [--smoke]
"""
from __future__ import annotations

import argparse
import copy
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "examples"))

from policy_training import BLUEPRINTS, NETWORKS, Collector, Replay  # noqa: E402

from pytest_driveeval.sim.blueprints import make_blueprint  # noqa: E402


def collection_rate(blueprint, actor, steps: int, seed: int) -> tuple[float, Collector]:
    collector = Collector(blueprint, 32, 100000 + seed, progress_scale=0.01)

    def sample(obs, episodes, expert):
        with torch.no_grad():
            return actor.sample(torch.from_numpy(obs))[0].numpy()

    replay = Replay(64 * steps, actor.encoder.observation_size)
    for _ in range(steps):
        replay.add(*collector.step(sample))
    return collector.steps_per_second, replay


def update_rate(actor, critic, replay: Replay, updates: int) -> float:
    target = copy.deepcopy(critic).requires_grad_(False)
    actor_opt, critic_opt = torch.optim.Adam(actor.parameters(), 3e-4), torch.optim.Adam(critic.parameters(), 3e-4)
    rng = np.random.default_rng(0)
    start = time.perf_counter()
    for _ in range(updates):
        obs, action, _, reward, next_obs, terminal = replay.sample(rng, 256)
        with torch.no_grad():
            next_action, next_logp = actor.sample(next_obs)
            tq1, tq2 = target(next_obs, next_action)
            backup = reward + 0.99 * (1.0 - terminal) * (torch.min(tq1, tq2) - 0.02 * next_logp)
        q1, q2 = critic(obs, action)
        critic_opt.zero_grad()
        (F.mse_loss(q1, backup) + F.mse_loss(q2, backup)).backward()
        critic_opt.step()
        new_action, logp = actor.sample(obs)
        critic.requires_grad_(False)
        actor_loss = (0.02 * logp - torch.min(*critic(obs, new_action))).mean()
        critic.requires_grad_(True)
        actor_opt.zero_grad()
        actor_loss.backward()
        actor_opt.step()
        with torch.no_grad():
            for p, tp in zip(critic.parameters(), target.parameters()):
                tp.mul_(0.995).add_(p, alpha=0.005)
    return updates / (time.perf_counter() - start)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=100, help="collector steps (of 32 episodes) per round")
    p.add_argument("--updates", type=int, default=30, help="SAC updates per round")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--blueprints", nargs="+", default=list(BLUEPRINTS), choices=BLUEPRINTS)
    p.add_argument("--smoke", action="store_true", help="tiny sizes: checks the script runs, figures mean nothing")
    args = p.parse_args(argv)
    if args.smoke:
        args.steps, args.updates, args.rounds, args.blueprints = 3, 2, 1, ["merging"]
        print("smoke run: figures mean nothing")
    torch.set_flush_denormal(True)
    print(f"{'blueprint':<13}{'network':<8}{'threads':>8}{'env steps/s':>13}{'SAC updates/s':>15}")
    ratios = []
    for name in args.blueprints:
        blueprint = make_blueprint(name)
        for network in sorted(NETWORKS):
            rates = {}
            for threads in dict.fromkeys((args.threads, 1)):
                torch.set_num_threads(threads)
                torch.manual_seed(0)
                actor, critic = NETWORKS[network].make_actor().train(), NETWORKS[network].make_critic()
                steps, updates = [], []
                for r in range(args.rounds):
                    rate, replay = collection_rate(blueprint, actor, args.steps, r)
                    steps.append(rate)
                    updates.append(update_rate(actor, critic, replay, args.updates))
                rates[threads] = (statistics.median(steps), statistics.median(updates))
                print(f"{name:<13}{network:<8}{threads:>8}{rates[threads][0]:>13,.0f}{rates[threads][1]:>15,.1f}",
                      flush=True)
            ratios.append(rates[args.threads][0] / rates[1][0])
    print(f"collection at {args.threads} threads / 1 thread: median {statistics.median(ratios):.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
