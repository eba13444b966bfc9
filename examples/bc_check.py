"""The supervised check of the actor networks (issue 24, as seed 002 does): behaviour cloning of the IDM
expert, the same data, loss, optimiser and updates for each network, judged by the imitation error
on states of held-out seeds.

    python examples/bc_check.py --blueprint all --train-batches 8 --epochs 32 --seed 0 --threads 1

Data, per blueprint: the expert drives ``--train-batches`` batches of 32 episodes on the training
seeds of examples/train_gnn_policy.py (100000 upwards; this is its DAgger round 0) and one batch of
64 on the held-out seeds 0..63; every state it visits is labelled with its action.  Each network
(policies/gnn.py, policies/mlp.py) starts from ``torch.manual_seed(seed)`` and regresses its
deterministic action onto the labels with Adam (``--lr``), ``--epochs`` passes of minibatches of
``--batch`` drawn by the same generator for both, the loss of the training script (MSE in actions
scaled to [-1, 1], labels clamped to +-0.97).  Reported: that loss on the training states and on the
held-out states, as a table and in ``--out`` (default fixtures/models/bc_check.csv, next to the
actors).  Deterministic for a seed and thread count.
"""
from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))  # policy_training, next to this script

from policy_training import (  # noqa: E402
    BLUEPRINTS, HELD_OUT, NETWORKS, action_bounds, bc_loss, expert_states, fit_node_scaling)

from pytest_driveeval.policies.mlp import parameter_count  # noqa: E402
from pytest_driveeval.sim.blueprints import make_blueprint  # noqa: E402

TRAIN_SEED = 100000
FIELDS = ["blueprint", "network", "parameters", "train_states", "held_out_states", "updates", "train_mse",
          "held_out_mse", "seconds"]


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--blueprint", default="all", choices=["all", *BLUEPRINTS])
    p.add_argument("--networks", nargs="+", default=sorted(NETWORKS), choices=sorted(NETWORKS))
    p.add_argument("--train-batches", type=int, default=8, help="batches of 32 expert episodes to train on")
    p.add_argument("--epochs", type=int, default=32, help="passes over the training states")
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--lr", type=float, default=3e-4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path,
                   default=Path(__file__).resolve().parents[1] / "fixtures" / "models" / "bc_check.csv")
    return p.parse_args(argv)


def clone(network: str, obs: torch.Tensor, labels: torch.Tensor, args, blueprint) -> tuple[torch.nn.Module, int]:
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    actor = NETWORKS[network].make_actor(**action_bounds(blueprint)).train()
    fit_node_scaling([actor], obs.numpy())
    optimiser = torch.optim.Adam(actor.parameters(), lr=args.lr)
    updates = args.epochs * max(1, len(obs) // args.batch)
    for _ in range(updates):
        idx = torch.from_numpy(rng.integers(0, len(obs), args.batch))
        loss = bc_loss(actor, obs[idx], labels[idx])
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return actor.eval(), updates


def imitation_error(actor, obs: torch.Tensor, labels: torch.Tensor) -> float:
    with torch.no_grad():
        return float(bc_loss(actor, obs, labels))


def main(argv=None) -> int:
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)  # as the training script: denormals off the road slow matmuls
    blueprints = BLUEPRINTS if args.blueprint == "all" else (args.blueprint,)
    rows = []
    for name in blueprints:
        blueprint = make_blueprint(name)
        train_obs, train_labels = expert_states(blueprint, 32, TRAIN_SEED, args.train_batches)
        held_obs, held_labels = expert_states(blueprint, len(HELD_OUT), int(HELD_OUT[0]), 1)
        for network in args.networks:
            start = time.perf_counter()
            actor, updates = clone(network, train_obs, train_labels, args, blueprint)
            rows.append({"blueprint": name, "network": network, "parameters": parameter_count(actor),
                         "train_states": len(train_obs), "held_out_states": len(held_obs), "updates": updates,
                         "train_mse": round(imitation_error(actor, train_obs, train_labels), 5),
                         "held_out_mse": round(imitation_error(actor, held_obs, held_labels), 5),
                         "seconds": round(time.perf_counter() - start, 1)})
            print(" ".join(f"{k}={v}" for k, v in rows[-1].items()), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    print(f"\nbehaviour cloning of the IDM expert, seed {args.seed}, {args.threads} thread(s), "
          f"{args.train_batches} x 32 training episodes, "
          f"{args.epochs} epochs; MSE in scaled actions (written to {args.out})")
    print(f"{'blueprint':<13}{'network':<8}{'params':>8}{'train states':>14}{'held-out states':>17}"
          f"{'train MSE':>11}{'held-out MSE':>14}")
    for r in rows:
        print(f"{r['blueprint']:<13}{r['network']:<8}{r['parameters']:>8}{r['train_states']:>14}"
              f"{r['held_out_states']:>17}{r['train_mse']:>11.4f}{r['held_out_mse']:>14.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
