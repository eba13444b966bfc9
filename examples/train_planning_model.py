"""Train the shipped planning model by behaviour cloning on L5-format data.

    python examples/train_planning_model.py [--scenes 200] [--epochs 9] [--out fixtures/models/planning_model.pt2]

Data (fixtures/l5kit/generated.zarr, generated with seed 0, is held out: the
demo scenarios evaluate on it):

* training: ``--scenes`` generated scenes (``generate_scenes`` with
  ``--train-seed``, default 1) and the real sample scene's frames whose whole
  12-frame future ends before ``--real-split`` (default 180 of 248);
* validation: ``--val-scenes`` generated scenes from ``--val-seed`` (default 2)
  and the real scene's frames from ``--real-split`` on.

Open loop: every (scene, frame) is one sample with the logged history and the
logged future as the target.  Half the samples get their current pose
perturbed (a lateral / longitudinal / heading offset fading out over the
history, l5kit's perturbation idea), and their target fades back onto the log
over the horizon: without it the model never sees the states its own drift
puts it in and the closed loop wanders off.

Finally a closed-loop check on the validation scenes (``unroll`` with the
demo's settings: drift reset at 10 m, freeze on collision) against the
constant-velocity baseline, then ``torch.export`` (policies.export: a ``.pt2`` program) and
the figures in a JSON next to the model.  Deterministic: seeded, one fixed
thread count.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Callable, Dict

import numpy as np
import torch

from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
from pytest_driveeval.policies.baselines import ConstantVelocityPolicy
from pytest_driveeval.policies.planning_model import PlanningModel
from pytest_driveeval.sim.logreplay import (LogArrays, UnrollConfig, UnrollResult, build_batch, scenes_from_arrays,
                                            stack_scenes, unroll)
from pytest_driveeval.synth.scenegen import generate_scenes

ROOT = Path(__file__).resolve().parents[1]
REAL_SCENE = ROOT / "fixtures" / "l5kit" / "single_scene.zarr"
HISTORY, FUTURE = 10, 12
STEP_TIME = 0.1
# The demo's closed-loop settings (closed_loop use case defaults).
CLOSED_LOOP = UnrollConfig(history_frames=HISTORY, future_frames=FUTURE, drift_threshold=10.0,
                           freeze_on_collision=True)

# Only what the model reads and the loss needs; the rest of the batch would
# triple the memory of the sample table for nothing.
KEYS = ("history_positions", "history_yaws", "history_availabilities", "speed", "target_positions", "target_yaws",
        "target_availabilities", "all_other_agents_history_positions", "all_other_agents_history_yaws",
        "all_other_agents_history_extents", "all_other_agents_history_availability", "all_other_agents_types")

Batch = Dict[str, torch.Tensor]


# --------------------------------------------------------------------------- data

def generated_log(num_scenes: int, seed: int, num_frames: int = 150) -> LogArrays:
    if seed == 0:
        raise ValueError("seed 0 makes the demo scenes (fixtures/l5kit/generated.zarr); they are held out")
    return stack_scenes(scenes_from_arrays(generate_scenes(num_scenes, num_frames, seed=seed)))


def samples(log: LogArrays, rows: np.ndarray, frames: np.ndarray) -> Batch:
    """Open-loop samples at (rows[i], frames[i]): logged history in, logged future as target."""
    batch = build_batch(log, rows, frames, log.ego_xy, log.ego_yaw, history_frames=HISTORY, future_frames=FUTURE)
    return {k: batch[k] for k in KEYS}


def frames_with_full_future(log: LogArrays, first: int = 0, stop: np.ndarray | int | None = None
                            ) -> tuple[np.ndarray, np.ndarray]:
    """All (row, frame) pairs whose 12 future frames are logged and end before ``stop`` (default: scene end)."""
    end = log.num_frames if stop is None else np.minimum(log.num_frames, stop)
    rows = [np.full(max(int(e) - FUTURE - first, 0), r) for r, e in enumerate(end)]
    frames = [np.arange(first, max(int(e) - FUTURE, first)) for e in end]
    return np.concatenate(rows), np.concatenate(frames)


def concat(parts: list[Batch]) -> Batch:
    """Join sample tables whose agent axes may differ (pad to the widest with empty slots)."""
    n = max(p["all_other_agents_types"].shape[1] for p in parts)
    out = {}
    for k in KEYS:
        tensors = []
        for p in parts:
            v = p[k]
            if k.startswith("all_other_agents") and v.shape[1] < n:
                pad = torch.zeros((v.shape[0], n - v.shape[1]) + tuple(v.shape[2:]), dtype=v.dtype)
                v = torch.cat([v, pad], 1)
            tensors.append(v)
        out[k] = torch.cat(tensors)
    return out


def take(batch: Batch, idx: torch.Tensor) -> Batch:
    return {k: v[idx] for k, v in batch.items()}


# --------------------------------------------------------------------------- perturbation

def _rotate(xy: torch.Tensor, cos: torch.Tensor, sin: torch.Tensor) -> torch.Tensor:
    return torch.stack([cos * xy[..., 0] - sin * xy[..., 1], sin * xy[..., 0] + cos * xy[..., 1]], -1)


def perturb(batch: Batch, gen: torch.Generator, prob: float = 0.5, lateral: float = 0.6, longitudinal: float = 0.8,
            heading: float = 0.06) -> Batch:
    """Move the current ego pose off the log, as closed-loop drift would, and re-express the sample there.

    Per chosen sample an offset (dx, dy, dyaw) of the current pose, in the
    ego frame, with normal std ``longitudinal``, ``lateral`` (m) and
    ``heading`` (rad).  The history bends into it linearly (full offset now,
    none H frames back), so the history's last steps carry the lateral drift
    and a speed error; the target fades from the offset back onto the log
    over the horizon, which is the correction we want the model to make.
    Then everything (history, target, agents) is moved into the perturbed
    ego frame and ``speed`` recomputed from the bent history.
    """
    b, h = batch["history_positions"].shape[:2]
    f = batch["target_positions"].shape[1]
    on = (torch.rand(b, generator=gen) < prob).float()
    off = torch.randn(b, 3, generator=gen) * torch.tensor([longitudinal, lateral, heading]) * on[:, None]
    off = off.clamp(-3.0, 3.0)
    d_xy, d_yaw = off[:, :2], off[:, 2]

    h_fade = (1.0 - torch.arange(h, dtype=torch.float32) / (h - 1))[None, :]
    f_fade = (1.0 - torch.arange(1, f + 1, dtype=torch.float32) / f)[None, :]
    h_ok, f_ok = batch["history_availabilities"], batch["target_availabilities"]
    hist = batch["history_positions"] + h_fade[..., None] * d_xy[:, None] * h_ok[..., None]
    hyaw = batch["history_yaws"][..., 0] + h_fade * d_yaw[:, None] * h_ok
    tgt = batch["target_positions"] + f_fade[..., None] * d_xy[:, None] * f_ok[..., None]
    tyaw = batch["target_yaws"][..., 0] + f_fade * d_yaw[:, None] * f_ok

    # Into the frame of the perturbed pose: p' = R(-dyaw) (p - d).
    cos, sin = torch.cos(-d_yaw), torch.sin(-d_yaw)
    c1, s1 = cos[:, None], sin[:, None]
    out = dict(batch)
    out["history_positions"] = _rotate(hist - d_xy[:, None], c1, s1) * h_ok[..., None]
    out["history_yaws"] = ((hyaw - d_yaw[:, None]) * h_ok)[..., None]
    out["target_positions"] = _rotate(tgt - d_xy[:, None], c1, s1) * f_ok[..., None]
    out["target_yaws"] = ((tyaw - d_yaw[:, None]) * f_ok)[..., None]
    a_ok = batch["all_other_agents_history_availability"]
    c2, s2 = cos[:, None, None], sin[:, None, None]
    a_xy = batch["all_other_agents_history_positions"] - d_xy[:, None, None]
    out["all_other_agents_history_positions"] = _rotate(a_xy, c2, s2) * a_ok[..., None]
    out["all_other_agents_history_yaws"] = ((batch["all_other_agents_history_yaws"][..., 0]
                                              - d_yaw[:, None, None]) * a_ok)[..., None]
    has_past = h_ok[:, 1] > 0
    step = out["history_positions"][:, 0] - out["history_positions"][:, 1]
    out["speed"] = torch.where(has_past, step.norm(dim=-1) / STEP_TIME, batch["speed"])
    return out


def drop_agents(batch: Batch, gen: torch.Generator, prob: float = 0.1) -> Batch:
    """Empty a random share of the agent slots, so no single agent becomes a
    cue the model cannot do without (perception misses agents too)."""
    keep = (torch.rand(batch["all_other_agents_types"].shape, generator=gen) >= prob).float()
    out = dict(batch)
    out["all_other_agents_history_availability"] = batch["all_other_agents_history_availability"] * keep[..., None]
    out["all_other_agents_history_positions"] = batch["all_other_agents_history_positions"] * keep[..., None, None]
    out["all_other_agents_types"] = batch["all_other_agents_types"] * keep
    return out


# --------------------------------------------------------------------------- training

def horizon_weights(future: int = FUTURE) -> torch.Tensor:
    """Heavier on the near future: the closed loop executes only the first pose,
    but the far poses still teach braking early for what lies ahead."""
    w = 1.0 / (1.0 + 0.15 * torch.arange(future, dtype=torch.float32))
    return w / w.mean()


def loss_fn(pred: Batch, batch: Batch, weights: torch.Tensor, yaw_weight: float = 5.0) -> torch.Tensor:
    ok = batch["target_availabilities"]
    pos = torch.nn.functional.smooth_l1_loss(pred["positions"], batch["target_positions"], reduction="none",
                                             beta=0.5).sum(-1)
    yaw = (pred["yaws"][..., 0] - batch["target_yaws"][..., 0]).abs()
    per = (pos + yaw_weight * yaw) * weights[None] * ok
    return per.sum() / ok.sum().clamp(min=1.0)


@torch.no_grad()
def open_loop_errors(model: Callable, data: Batch, batch_size: int = 512) -> tuple[float, float]:
    """ADE and FDE (m) over samples with a full logged future."""
    ade, fde, n = 0.0, 0.0, 0
    for i in range(0, data["speed"].shape[0], batch_size):
        part = {k: v[i:i + batch_size] for k, v in data.items()}
        full = part["target_availabilities"].all(-1)
        err = (model(part)["positions"] - part["target_positions"]).norm(dim=-1)[full]
        ade += float(err.mean(-1).sum())
        fde += float(err[:, -1].sum())
        n += int(full.sum())
    return ade / max(n, 1), fde / max(n, 1)


def train(model: torch.nn.Module, data: Batch, val: dict[str, Batch], *, epochs: int, batch_size: int = 128,
          lr: float = 1e-3, seed: int = 0, max_steps: int | None = None, log: Callable[[str], None] = print,
          sample_weights: torch.Tensor | None = None) -> list[dict]:
    """AdamW + one-cycle cosine schedule; returns per-epoch figures."""
    gen = torch.Generator().manual_seed(seed)
    n = data["speed"].shape[0]
    steps_per_epoch = max(n // batch_size, 1)
    total = epochs * steps_per_epoch if max_steps is None else min(max_steps, epochs * steps_per_epoch)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=total, pct_start=0.1)
    weights = horizon_weights(data["target_positions"].shape[1])
    history, step = [], 0
    for epoch in range(epochs):
        model.train()
        t0 = time.perf_counter()
        if sample_weights is None:
            order = torch.randperm(n, generator=gen)
        else:  # oversample the rare real rows without duplicating the table
            order = torch.multinomial(sample_weights, n, replacement=True, generator=gen)
        running = 0.0
        for i in range(steps_per_epoch):
            if step >= total:
                break
            part = drop_agents(perturb(take(data, order[i * batch_size:(i + 1) * batch_size]), gen), gen)
            loss = loss_fn(model(part), part, weights)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            opt.step()
            sched.step()
            running += float(loss.detach())
            step += 1
        model.eval()
        row = {"epoch": epoch + 1, "steps": step, "loss": running / max(min(steps_per_epoch, step), 1),
               "seconds": round(time.perf_counter() - t0, 1)}
        for name, v in val.items():
            ade, fde = open_loop_errors(model, v)
            row[f"{name}_ade"], row[f"{name}_fde"] = round(ade, 3), round(fde, 3)
        history.append(row)
        log("  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))
        if step >= total:
            break
    return history


# --------------------------------------------------------------------------- closed loop

def closed_loop_figures(result: UnrollResult) -> dict:
    """Per-run figures: at-fault collision frames by kind, collision events, displacement, resets."""
    fault = result.collision_at_fault
    kinds = result.collision_kind
    # An event: a run of consecutive colliding frames (freeze keeps the ego in contact for a while).
    hit = kinds > 0
    starts = hit & ~np.concatenate([np.zeros((hit.shape[0], 1), bool), hit[:, :-1]], 1)
    return {
        "scenes": int(result.valid.shape[0]),
        "at_fault_frames": {name: int((fault & (kinds == k)).sum()) for k, name in ((1, "front"), (2, "side"),
                                                                                     (3, "rear"))},
        "at_fault_total": int(fault.sum()),
        "collision_events": int(starts.sum()),
        "scenes_with_at_fault_collision": int(fault.any(1).sum()),
        "mean_displacement_m": round(float(np.nanmean(result.displacement_error)), 3),
        "resets": int(result.reset.sum()),
        "errors": sum(e is not None for e in result.errors),
    }


def closed_loop_check(model: Callable, log: LogArrays, config: UnrollConfig = CLOSED_LOOP) -> dict:
    out = {}
    for name, policy in (("model", model), ("constant_velocity", ConstantVelocityPolicy(FUTURE))):
        out[name] = closed_loop_figures(unroll(log, policy, config))
    return out


def export(model: torch.nn.Module, path: Path, example: dict | None = None) -> Callable:
    """Save ``model`` as a torch.export program, traced on ``example`` (default: the real scene's
    batch of examples/export_models.py); returns the program as ``load_model`` gives it."""
    from pytest_driveeval.policies.export import export_program

    if example is None:
        from export_models import planning_inputs

        (example,) = planning_inputs()[0]
    return export_program(model, (example,), path)


def _fmt(figs: dict) -> str:
    return (f"at-fault frames {figs['at_fault_total']} {figs['at_fault_frames']}, scenes with at-fault "
            f"{figs['scenes_with_at_fault_collision']}/{figs['scenes']}, collision events {figs['collision_events']}, "
            f"mean displacement {figs['mean_displacement_m']:.2f} m, resets {figs['resets']}")


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=200)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--train-seed", type=int, default=1)
    parser.add_argument("--val-seed", type=int, default=2)
    parser.add_argument("--val-scenes", type=int, default=32)
    parser.add_argument("--real", type=Path, default=REAL_SCENE)
    parser.add_argument("--real-split", type=int, default=180)
    parser.add_argument("--real-weight", type=float, default=25.0, help="oversampling of the real scene's rows")
    parser.add_argument("--epochs", type=int, default=9)
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "fixtures" / "models" / "planning_model.pt2")
    args = parser.parse_args(argv)
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    t_start = time.perf_counter()

    train_log = generated_log(args.scenes, args.train_seed, args.frames)
    val_log = generated_log(args.val_scenes, args.val_seed, args.frames)
    real = stack_scenes([L5Dataset.open(args.real).scene(0)])
    gen_train = samples(train_log, *frames_with_full_future(train_log))
    real_train = samples(real, *frames_with_full_future(real, stop=args.real_split))
    data = concat([gen_train, real_train])
    n_gen, n_real = gen_train["speed"].shape[0], real_train["speed"].shape[0]
    weights = torch.cat([torch.ones(n_gen), torch.full((n_real,), args.real_weight)])
    val = {"val_gen": samples(val_log, *frames_with_full_future(val_log)),
           "val_real": samples(real, *frames_with_full_future(real, first=args.real_split))}
    print(f"training rows: {n_gen} generated ({args.scenes} scenes, seed {args.train_seed}) + {n_real} real "
          f"(frames < {args.real_split}, x{args.real_weight:g}); validation rows: "
          + ", ".join(f"{k} {v['speed'].shape[0]}" for k, v in val.items())
          + f"; built in {time.perf_counter() - t_start:.1f} s")

    model = PlanningModel(HISTORY, FUTURE)
    cv = ConstantVelocityPolicy(FUTURE)
    baseline = {k: [round(x, 3) for x in open_loop_errors(cv, v)] for k, v in val.items()}
    print("constant velocity open loop (ADE, FDE):", baseline)
    history = train(model, data, val, epochs=args.epochs, batch_size=args.batch_size, lr=args.lr, seed=args.seed,
                    sample_weights=weights)
    train_seconds = time.perf_counter() - t_start

    reloaded = export(model, args.out)
    closed = closed_loop_check(reloaded, val_log)
    print(f"closed loop on {args.val_scenes} held-out generated scenes (seed {args.val_seed}):")
    for name, figs in closed.items():
        print(f"  {name:18s} {_fmt(figs)}")
    # The real scene: from frame 10 (mostly trained-on frames) and from the split (held out).
    closed_real = {f"from_frame_{start}": closed_loop_check(reloaded, real, replace(CLOSED_LOOP, start_frame=start))
                   for start in (10, args.real_split)}
    for part, figs_by in closed_real.items():
        print(f"closed loop on the real scene {part}:")
        for name, figs in figs_by.items():
            print(f"  {name:18s} {_fmt(figs)}")
    params = sum(p.numel() for p in model.parameters())
    meta = {
        "model": "pytest_driveeval.policies.planning_model.PlanningModel",
        "config": {"history_frames": HISTORY, "future_frames": FUTURE, "d": 128, "layers": 2, "heads": 4,
                   "ffn": 256},
        "parameters": params,
        "file_bytes": args.out.stat().st_size,
        "command": "python examples/train_planning_model.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "data": {"train": f"generate_scenes({args.scenes}, {args.frames}, seed={args.train_seed}) + real sample "
                          f"frames with future before {args.real_split}",
                 "validation": f"generate_scenes({args.val_scenes}, {args.frames}, seed={args.val_seed}) + real "
                               f"sample frames {args.real_split}..end",
                 "held_out": "fixtures/l5kit/generated.zarr (seed 0) is never used",
                 "train_rows": {"generated": n_gen, "real": n_real}},
        "open_loop_constant_velocity": baseline,
        "epochs": history,
        "closed_loop_val": {"config": "drift_threshold 10 m, freeze_on_collision, all frames", **closed},
        "closed_loop_real_scene": closed_real,
        "train_seconds": round(train_seconds, 1),
        "torch": torch.__version__,
    }
    meta_path = args.out.with_suffix(".json")
    meta_path.write_text(json.dumps(meta, indent=1) + "\n")
    print(f"wrote {args.out} ({meta['file_bytes'] / 1e6:.2f} MB, {params} parameters) and {meta_path}; "
          f"total {time.perf_counter() - t_start:.0f} s")
    return meta


if __name__ == "__main__":
    main()
