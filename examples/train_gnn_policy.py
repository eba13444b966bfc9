"""Train the shipped GNN actor (seed 002), or the MLP actor it is compared with, by soft actor-critic
warm-started by DAgger from IDMExpert.

    python examples/train_gnn_policy.py --network gnn --blueprint merging --minutes 20 --seed 0

Writes ``<out>`` (default fixtures/models/<network>_actor_<blueprint>.pt2; a
torch.export program; input the flat graph observation (E, 279) float32 of
``evaluate.observe`` with agent_limit 12, output the deterministic action
(E, 2) = (acceleration m/s^2, steering rad)), and next to it
``<stem>_training.csv`` and ``<stem>_training.png``: the learning curve on 64
held-out episodes (seeds 0..63, the evaluation range, never trained on), with
the collection throughput so far (``env_steps_per_s``: steps of running
episodes per second spent collecting, i.e. acting, labelling by the expert,
simulating and observing; torch on ``--threads`` threads, 2 by default).

``--network`` (gnn: policies/gnn.py, mlp: policies/mlp.py, the seed's "SAC") is
the only thing that differs between runs compared: same seeds, DAgger rounds,
SAC, budget and reward.  The pieces other than the loop are in
examples/policy_training.py.

Method, in two phases; both collect experience from ``--envs`` episodes of the
batched simulator stepped together, on training seeds from ``--train-seed``
(default 100000) upwards, disjoint from the evaluation seeds 0..999:

1. Warm start, DAgger from :class:`IDMExpert` (``--dagger-rounds``): round 0
   drives the expert itself, later rounds drive the current actor (with the
   expert taking over with probability ``beta = 0.5**round`` per episode, as in
   Ross et al. 2011), and every visited state is labelled with the expert's
   action; the actor regresses its deterministic action onto the aggregated
   labels (MSE in actions scaled to [-1, 1]).  Why: SAC from scratch on this
   budget learns to stop and idle (the merge lane ends in a wall and every
   crash costs -1), which never reaches the goal; labelling the actor's own
   states keeps the clone from drifting into states the expert never visits.
2. SAC fine-tuning (Haarnoja et al. 2018, as in the seed): twin critics with
   target networks by Polyak averaging (``--tau``), automatic entropy
   temperature towards an entropy of -|A|, a replay buffer holding the
   DAgger data and the actor's own transitions.  The critics are first fitted
   alone (``--critic-warmup`` updates) so the actor's first gradients come
   from a Q that knows the warm-started policy; the actor loss keeps a
   behaviour-cloning term towards the expert's label of each replayed state,
   ``--bc-weight`` decaying linearly to 0 over the updates (TD3+BC's idea,
   Fujimoto & Gu 2021), so an early bad Q cannot undo the warm start.

Reward for training, shaped (the benchmark judges outcomes, not returns): the
seed's +1 goal, -1 collision / off-road, but *no* +0.01 per-step bonus (it
pays idling to the step limit more than reaching the goal), plus progress
``(d_before - d_after) / 100`` with d the ego's distance to the goal centre
in m.  Reaching the step limit is a truncation (bootstrapped), not a terminal.

The shipped actor is the one with the best goal rate on a validation range
(seeds 50000..50063, neither training nor evaluation), ties broken by fewer
collisions and then by the earlier checkpoint; the curve reports the held-out
range.  In the run that made fixtures/models/gnn_actor_merging.pt2 (seed 0,
``--dagger-rounds 8 --bc-epochs 8 --steps 25000 --minutes 22``) DAgger round 5
already reached 100 % goals, 0 % collisions on both ranges and SAC fine-tuning
held that for 23,579 updates without beating it, so the shipped weights are
that DAgger checkpoint.  Deterministic for a seed
with ``--steps`` (torch and numpy seeded, the same ``--threads``); ``--minutes`` stops on
wall time, so a run cut by it depends on the machine's speed.
"""
from __future__ import annotations

import argparse
import copy
import csv
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))  # policy_training, next to this script

from policy_training import (  # noqa: E402
    AGENT_LIMIT,
    BLUEPRINTS,
    HELD_OUT,
    NETWORKS,
    SCALING_SEED,
    VALIDATION,
    Collector,
    Replay,
    action_bounds,
    bc_loss,
    default_out,
    evaluate,
    expert_states,
    fit_node_scaling,
    plot,
)

from pytest_driveeval.policies.control_baselines import ConstantAction, RandomAction  # noqa: E402
from pytest_driveeval.policies.export import export_program  # noqa: E402
from pytest_driveeval.policies.idm_expert import IDMExpert  # noqa: E402
from pytest_driveeval.sim.blueprints import make_blueprint  # noqa: E402
from pytest_driveeval.sim.episodes import reset  # noqa: E402
from pytest_driveeval.usecases.policy_benchmark.evaluate import observe, run_policy  # noqa: E402


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--network", default="gnn", choices=sorted(NETWORKS),
                   help="gnn: policies/gnn.py; mlp: policies/mlp.py; nothing else differs between the two")
    p.add_argument("--blueprint", default="merging", choices=BLUEPRINTS)
    p.add_argument("--steps", type=int, default=20000, help="SAC gradient updates (after the critic warm-up)")
    p.add_argument("--minutes", type=float, default=20.0,
                   help="wall-time budget: no DAgger round, critic warm-up update or SAC update starts after it "
                        "(the last evaluations and the export come on top)")
    p.add_argument("--threads", type=int, default=2,
                   help="torch threads; on a machine whose cores other jobs keep busy, 1 can be 10-50x faster "
                        "(the second thread's wake-ups wait for a core)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=None, help="default fixtures/models/<network>_actor_<blueprint>.pt2")
    p.add_argument("--envs", type=int, default=32, help="episodes stepped together")
    p.add_argument("--train-seed", type=int, default=100000, help="first training seed (evaluation uses 0..999)")
    p.add_argument("--dagger-rounds", type=int, default=6, help="0: SAC from scratch")
    p.add_argument("--dagger-batches", type=int, default=4, help="batches of --envs episodes per DAgger round")
    p.add_argument("--bc-epochs", type=int, default=4, help="passes over the aggregated labels per DAgger round")
    p.add_argument("--critic-warmup", type=int, default=1500)
    p.add_argument("--bc-weight", type=float, default=2.0)
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--lr", type=float, default=3e-4)
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--tau", type=float, default=0.005)
    p.add_argument("--alpha", type=float, default=0.02, help="initial entropy temperature")
    p.add_argument("--buffer", type=int, default=400_000)
    p.add_argument("--updates-per-step", type=int, default=1, help="gradient updates per batched simulator step")
    p.add_argument("--eval-every", type=int, default=1000, help="SAC updates between evaluations")
    p.add_argument("--progress-scale", type=float, default=0.01, help="shaping reward per m towards the goal")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    out = args.out or default_out(args.network, args.blueprint)
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(args.threads)
    # Saturated sigmoids on states far off the road leave denormal floats that slow every
    # matmul by 10-30x on x86; flushed to zero they change nothing we can measure.
    torch.set_flush_denormal(True)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    start = time.monotonic()
    deadline = start + 60.0 * args.minutes

    def elapsed() -> float:
        return time.monotonic() - start

    blueprint = make_blueprint(args.blueprint)
    network = NETWORKS[args.network]
    actor = network.make_actor(**action_bounds(blueprint)).train()
    critic = network.make_critic(**action_bounds(blueprint))
    fit_node_scaling([actor, critic], expert_states(blueprint, args.envs, SCALING_SEED, 1)[0].numpy())
    target = copy.deepcopy(critic).requires_grad_(False)
    obs_size = actor.encoder.observation_size
    replay = Replay(args.buffer, obs_size)
    collector = Collector(blueprint, args.envs, args.train_seed, args.progress_scale)
    actor_opt = torch.optim.Adam(actor.parameters(), lr=args.lr)
    critic_opt = torch.optim.Adam(critic.parameters(), lr=args.lr)
    log_alpha = torch.tensor(float(np.log(args.alpha)), requires_grad=True)
    alpha_opt = torch.optim.Adam([log_alpha], lr=args.lr)
    target_entropy = -2.0

    baselines = {name: run_policy(blueprint, HELD_OUT, pol, name, agent_limit=AGENT_LIMIT).figures()
                 for name, pol in (("random", RandomAction()), ("constant", ConstantAction()),
                                   ("idm_expert", IDMExpert()))}
    for name, fig in baselines.items():
        print(f"{name:>10}: goal {fig['goal_rate']:.1f} %  collision {fig['collision_rate']:.1f} %  "
              f"off-road {fig['off_road_rate']:.1f} %", flush=True)

    curve: list[dict] = []
    best = {"score": (-1.0, 0.0), "state": copy.deepcopy(actor.state_dict()), "row": None}

    def checkpoint(phase: str, updates: int) -> None:
        held = evaluate(actor, blueprint, HELD_OUT, args.network)
        val = evaluate(actor, blueprint, VALIDATION, args.network)
        row = {"phase": phase, "updates": updates, "episodes": collector.episodes_done,
               "transitions": replay.size, "minutes": round(elapsed() / 60.0, 2),
               "env_steps": collector.env_steps, "env_steps_per_s": round(collector.steps_per_second, 1),
               "alpha": round(float(log_alpha.detach().exp()), 5),
               **{f"held_out_{k}": round(held[k], 2) for k in ("goal_rate", "collision_rate", "off_road_rate",
                                                                "step_limit_rate")},
               "validation_goal_rate": round(val["goal_rate"], 2),
               "validation_collision_rate": round(val["collision_rate"], 2)}
        curve.append(row)
        score = (val["goal_rate"], -val["collision_rate"])
        if score > best["score"]:
            best.update(score=score, state=copy.deepcopy(actor.state_dict()), row=row)
        print(f"[{row['minutes']:6.2f} min] {phase:>6} {updates:6d} upd  held-out goal {row['held_out_goal_rate']:5.1f} %"
              f"  coll {row['held_out_collision_rate']:5.1f} %  off {row['held_out_off_road_rate']:5.1f} %"
              f"  | val goal {row['validation_goal_rate']:5.1f} %  alpha {row['alpha']:.4f}", flush=True)

    checkpoint("init", 0)

    # Phase 1: DAgger from the expert.
    bc_updates = 0
    for rnd in range(args.dagger_rounds):
        if rnd and time.monotonic() >= deadline:
            print(f"DAgger stopped after {rnd} rounds: the --minutes budget is spent", flush=True)
            break
        beta = 0.5 ** rnd
        for _ in range(args.dagger_batches):
            takeover = rng.random(args.envs) < beta

            def act(obs, episodes, expert):
                if takeover.all():  # round 0: the expert drives every episode, the actor is not asked
                    return expert
                with torch.no_grad():
                    own = actor(torch.from_numpy(obs)).numpy()
                return np.where(takeover[:, None], expert, own)

            collector.episodes_of(act, replay=replay)
        epochs = args.bc_epochs * max(1, replay.size // args.batch)
        for _ in range(epochs):
            obs, _, expert, *_ = replay.sample(rng, args.batch)
            loss = bc_loss(actor, obs, expert)
            actor_opt.zero_grad()
            loss.backward()
            actor_opt.step()
            bc_updates += 1
        print(f"DAgger round {rnd}: beta {beta:.3f}, {replay.size} labelled states, bc loss {float(loss.detach()):.4f}",
              flush=True)
        checkpoint("dagger", bc_updates)
    if args.dagger_rounds:
        # Fine-tune from the best clone, not from whatever the last round left.
        actor.load_state_dict(best["state"])

    # Phase 2: SAC.
    def sac_update(step: int, actor_too: bool) -> None:
        obs, action, expert, reward, next_obs, terminal = replay.sample(rng, args.batch)
        alpha = log_alpha.exp().detach()
        with torch.no_grad():
            next_action, next_logp = actor.sample(next_obs)
            tq1, tq2 = target(next_obs, next_action)
            backup = reward + args.gamma * (1.0 - terminal) * (torch.min(tq1, tq2) - alpha * next_logp)
        q1, q2 = critic(obs, action)
        critic_loss = F.mse_loss(q1, backup) + F.mse_loss(q2, backup)
        critic_opt.zero_grad()
        critic_loss.backward()
        critic_opt.step()
        if actor_too:
            new_action, logp = actor.sample(obs)
            critic.requires_grad_(False)
            q1_pi, q2_pi = critic(obs, new_action)
            critic.requires_grad_(True)
            weight = args.bc_weight * max(0.0, 1.0 - step / max(args.steps, 1))
            actor_loss = (alpha * logp - torch.min(q1_pi, q2_pi)).mean()
            if weight > 0.0:
                actor_loss = actor_loss + weight * bc_loss(actor, obs, expert)
            actor_opt.zero_grad()
            actor_loss.backward()
            actor_opt.step()
            alpha_loss = -(log_alpha * (logp.detach() + target_entropy)).mean()
            alpha_opt.zero_grad()
            alpha_loss.backward()
            alpha_opt.step()
        with torch.no_grad():
            for p, tp in zip(critic.parameters(), target.parameters()):
                tp.mul_(1.0 - args.tau).add_(p, alpha=args.tau)

    def sac_act(obs, episodes, expert):
        with torch.no_grad():
            action, _ = actor.sample(torch.from_numpy(obs))
        return action.numpy()

    if replay.size < args.batch:  # from scratch: fill the buffer with the untrained actor's experience
        while replay.size < 10 * args.batch:
            replay.add(*collector.step(sac_act))
    warmup = 0
    while warmup < args.critic_warmup and (warmup == 0 or time.monotonic() < deadline):
        sac_update(0, actor_too=False)
        warmup += 1
    print(f"critic warm-up: {warmup} updates, {elapsed() / 60:.1f} min", flush=True)

    updates = 0
    while updates < args.steps and time.monotonic() < deadline:
        replay.add(*collector.step(sac_act))
        for _ in range(args.updates_per_step):
            sac_update(updates, actor_too=True)
            updates += 1
        if updates % args.eval_every == 0:
            checkpoint("sac", updates)
    if not curve or curve[-1]["updates"] != updates or curve[-1]["phase"] != "sac":
        checkpoint("sac", updates)

    actor.load_state_dict(best["state"])
    actor.eval()
    example = observe(reset(blueprint, np.arange(8), agent_limit=AGENT_LIMIT), AGENT_LIMIT)
    program = export_program(actor, (example,), out)
    final = run_policy(blueprint, HELD_OUT, program, args.network, agent_limit=AGENT_LIMIT).figures()

    stem = out.with_suffix("")
    csv_path = stem.parent / f"{stem.name}_training.csv"
    with open(csv_path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(curve[0]))
        writer.writeheader()
        writer.writerows(curve)
    plot(curve, baselines, best["row"], args, collector.steps_per_second, stem.parent / f"{stem.name}_training.png")

    print(f"\nshipped: {out} (chosen at {best['row']['phase']} {best['row']['updates']} updates), "
          f"{elapsed() / 60:.1f} min, {updates} SAC updates, {bc_updates} BC updates, "
          f"{collector.episodes_done} training episodes, {replay.size} transitions in the buffer")
    print(f"collection throughput: {collector.steps_per_second:,.0f} env steps/s ({collector.env_steps} steps in "
          f"{collector.seconds:.1f} s of collection, {torch.get_num_threads()} threads, {args.network}, "
          f"{args.blueprint})")
    print(f"held-out seeds 0..63: {args.network} goal {final['goal_rate']:.1f} % collision {final['collision_rate']:.1f} % "
          f"off-road {final['off_road_rate']:.1f} % step limit {final['step_limit_rate']:.1f} %")
    for name, fig in baselines.items():
        print(f"{'':14}{name} goal {fig['goal_rate']:.1f} % collision {fig['collision_rate']:.1f} % "
              f"off-road {fig['off_road_rate']:.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
