"""GNN actor throughput on one core, against an edge-list (index_add) implementation of the same network.

Part 1: observations per second of :func:`pytest_driveeval.policies.gnn.make_actor`
(the shipped configuration, deterministic action) on flat graph observations
of ``--batch`` episodes (default 256), eager and TorchScript.  The reference,
timed in the same run on the same weights and inputs, is how message passing
is usually written: decode, an edge list from the adjacency, gather the
senders, the message MLP per edge, ``index_add_`` into the receivers, every
node in every round.  Its actions are checked against ours before timing.
Target: >= 200,000 observations/s.

Part 2: :func:`~pytest_driveeval.policies.graph.graph_observation` +
:func:`~pytest_driveeval.policies.graph.encode` for ``--episodes`` (16) x
``--agents`` (12) from numpy arrays, as the simulator calls it every step.

Single-threaded (``--threads``, default 1, and OMP_NUM_THREADS=1 unless set).
Each figure is the median of ``--rounds`` timed rounds.  Nothing is asserted.

    python benchmarks/bench_gnn.py [--batch 256] [--rounds 7] [--episodes 16] [--agents 12] [--threads 1] [--smoke]
"""
from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # before torch starts its thread pool

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pytest_driveeval.policies.gnn import GNNActor, make_actor
from pytest_driveeval.policies.graph import (
    ObservationRanges,
    decode,
    encode,
    graph_observation,
)

TARGET = 200_000
SMOKE_HELP = "every part at tiny sizes in seconds, reference venvs skipped: checks the script runs, measures nothing"
# A 4-lane highway section 400 m long, as BARK-ML's highway blueprint.
RANGES = ObservationRanges.from_bounding_box(0.0, -8.0, 400.0, 8.0)


def traffic(episodes: int, agents: int, seed: int = 0) -> dict:
    """Random highway traffic: agents on 4 lanes within 120 m, some slots invalid."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(100.0, 220.0, (episodes, agents))
    y = rng.integers(0, 4, (episodes, agents)) * 4.0 - 6.0 + rng.normal(0.0, 0.3, (episodes, agents))
    valid = rng.random((episodes, agents)) < 0.9
    valid[:, 0] = True
    return {"xy": np.stack([x, y], axis=-1), "yaw": rng.normal(0.0, 0.05, (episodes, agents)),
            "speed": rng.uniform(10.0, 20.0, (episodes, agents)), "valid": valid,
            "goal_xy": np.tile([380.0, 2.0], (episodes, 1)), "goal_speed": np.full(episodes, 15.0)}


def observations(batch: int, agents: int) -> torch.Tensor:
    return encode(graph_observation(**traffic(batch, agents), ranges=RANGES))


def index_add_actor(actor: GNNActor, flat: torch.Tensor) -> torch.Tensor:
    """The actor's deterministic action computed over an edge list, one message per edge."""
    encoder = actor.encoder
    graph = decode(flat)
    index = torch.full(graph.mask.shape, -1, dtype=torch.long)
    index[graph.mask] = torch.arange(int(graph.mask.sum()))
    b, i, j = (graph.adjacency > 0).nonzero(as_tuple=True)
    receivers, senders, edges = index[b, i], index[b, j], graph.edge_features[b, i, j]
    h = torch.relu(encoder.embed(graph.nodes[graph.mask]))
    for layer in [*encoder.inner, encoder.last]:
        hidden = torch.relu(layer.sender(h[senders]) + layer.edge(edges))
        message = torch.zeros_like(h).index_add_(0, receivers, layer.message(hidden))
        gate, candidate = layer.update(torch.cat([h, message], dim=-1)).chunk(2, dim=-1)
        h = h + torch.sigmoid(gate) * (torch.tanh(candidate / 2) - h)
    mean, _ = actor.head(h[index[:, 0]]).chunk(2, dim=-1)
    return actor.action_center + actor.action_half_range * torch.tanh(mean)


def median_seconds(call: Callable[[], object], rounds: int, calls: int) -> float:
    for _ in range(max(3, calls // 10)):
        call()
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        for _ in range(calls):
            call()
        times.append((time.perf_counter() - t0) / calls)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--calls", type=int, default=50, help="calls per timed round")
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--agents", type=int, default=12)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--smoke", action="store_true", help=SMOKE_HELP)
    args = parser.parse_args()
    if args.smoke:
        args.batch, args.rounds, args.calls, args.episodes = 16, 1, 2, 4
        print("smoke run: tiny sizes; the figures mean nothing")
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    print(f"threads: torch {torch.get_num_threads()}, OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']}; "
          f"torch {torch.__version__}")

    print(f"== part 1: GNN actor, batch {args.batch}, observations of up to 20 agents (agent limit 12)")
    actor = make_actor()
    scripted = torch.jit.script(actor)
    flat = observations(args.batch, 20)
    with torch.inference_mode():
        ours = actor(flat)
        torch.testing.assert_close(index_add_actor(actor, flat), ours, atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(scripted(flat), ours)
        edges = int((decode(flat).adjacency > 0).sum())
        rates = {}
        for name, call in [("reference: edge list + index_add_", lambda: index_add_actor(actor, flat)),
                           ("ours, eager", lambda: actor(flat)), ("ours, TorchScript", lambda: scripted(flat))]:
            seconds = median_seconds(call, args.rounds, args.calls)
            rates[name] = args.batch / seconds
            print(f"{name:36s} {1e3 * seconds:7.3f} ms/batch -> {rates[name]:11,.0f} observations/s")
    reference = rates["reference: edge list + index_add_"]
    for name in ("ours, eager", "ours, TorchScript"):
        verdict = "meets" if rates[name] >= TARGET else "misses"
        print(f"{name}: {rates[name] / reference:.1f}x the reference; {verdict} the {TARGET:,}/s target")
    print(f"({edges / args.batch:.1f} directed edges per graph, self-loops included)")

    print(f"\n== part 2: graph_observation + encode, {args.episodes} episodes x {args.agents} agents, from numpy")
    state = traffic(args.episodes, args.agents, seed=1)
    seconds = median_seconds(lambda: encode(graph_observation(**state, ranges=RANGES)), args.rounds, args.calls)
    print(f"{1e3 * seconds:.3f} ms per call -> {args.episodes * args.agents / seconds:,.0f} agent-observations/s, "
          f"{1 / seconds:,.0f} simulator steps/s")


if __name__ == "__main__":
    main()
