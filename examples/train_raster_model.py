"""Train the shipped raster planning model (a CNN on l5kit's ``py_semantic`` rasters) by behaviour cloning.

    python examples/train_raster_model.py [--scenes 200] [--steps 1500] [--out fixtures/models/raster_model.pt2]

Data: generated L5 datasets with their semantic maps (``generate_zarr``
writes ``semantic_map.pb`` and ``meta.json`` beside the zarr), written to a
temporary folder: ``--scenes`` scenes from ``--train-seed`` (default 1) to
train on, ``--val-scenes`` from ``--val-seed`` (2) to validate on.  The demo's
scenes (``fixtures/l5kit/generated.zarr``, seed 0) are held out.  The real
sample scene is not used: no semantic map of its place is public.

Each step takes ``--batch-size`` different scenes and one random frame of
each.  Half the samples get their current pose moved off the log (a
lateral / longitudinal / heading offset that fades out over the history, as
closed-loop drift would leave it) before the raster is drawn, and their
target fades from the offset back onto the log over the horizon: without it
the model never sees the states its own drift puts it in.  The rasters are
drawn on the fly by :class:`pytest_driveeval.raster.Rasterizer`, from the
perturbed ego history, exactly as the closed loop draws them.

Finally a closed-loop check on the validation scenes against the
constant-velocity baseline, ``torch.export`` (a ``.pt2`` program), and the
figures in a JSON next to the model.  Deterministic: seeded, one fixed thread
count.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from pytest_driveeval.geometry import wrap_angle
from pytest_driveeval.io.l5.l5_semantic_map import read_semantic_map
from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
from pytest_driveeval.policies.raster_model import RasterPlanningModel
from pytest_driveeval.raster import RasterParams, Rasterizer
from pytest_driveeval.policies.baselines import ConstantVelocityPolicy
from pytest_driveeval.sim.logreplay import LogArrays, UnrollConfig, stack_scenes, unroll
from pytest_driveeval.synth.scenegen import generate_zarr
from pytest_driveeval.usecases.closed_loop.raster_inputs import raster_inputs
# The vector model's loss (smooth L1 on positions + yaw, heavier on the near future): the same targets.
from train_planning_model import horizon_weights, loss_fn  # noqa: E402  (examples/ is on sys.path when run)
from export_models import raster_inputs_on_generated  # noqa: E402  (the demo scenes' batch, to trace on)

from pytest_driveeval.policies.export import export_program  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
HISTORY, FUTURE = 10, 12
PARAMS = RasterParams(map_type="py_semantic", raster_size=(112, 112), pixel_size=(0.5, 0.5), ego_center=(0.25, 0.5),
                      history_num_frames=HISTORY, filter_agents_threshold=0.5)
# The demo's closed-loop settings (closed_loop use case defaults).
CLOSED_LOOP = UnrollConfig(history_frames=HISTORY, future_frames=FUTURE, drift_threshold=10.0,
                           freeze_on_collision=True)


class Data:
    """One generated dataset, stacked, with its rasterizer."""

    def __init__(self, folder: Path, scenes: int, frames: int, seed: int):
        if seed == 0:
            raise ValueError("seed 0 makes the demo scenes (fixtures/l5kit/generated.zarr); they are held out")
        path = generate_zarr(folder / f"seed{seed}.zarr", scenes, num_frames=frames, seed=seed,
                             map_dir=folder / f"seed{seed}_map")
        dataset = L5Dataset.open(path)
        self.scenes = [dataset.scene(i) for i in range(scenes)]
        self.log: LogArrays = stack_scenes(self.scenes)
        self.semantic_map = read_semantic_map(folder / f"seed{seed}_map" / "semantic_map.pb",
                                              folder / f"seed{seed}_map" / "meta.json")
        self.raster = Rasterizer(PARAMS, self.log, scenes=self.scenes, semantic_map=self.semantic_map)

    def frames_with_full_future(self) -> tuple[np.ndarray, np.ndarray]:
        rows = [np.full(int(n) - FUTURE, r) for r, n in enumerate(self.log.num_frames)]
        frames = [np.arange(int(n) - FUTURE) for n in self.log.num_frames]
        return np.concatenate(rows), np.concatenate(frames)

    def samples(self, rows: np.ndarray, frames: np.ndarray, offsets: np.ndarray) -> dict[str, torch.Tensor]:
        """Rasters and targets at (rows[i], frames[i]); the rows must differ (each gets its own ego history).

        ``offsets`` (B, 3): the current pose moved by (longitudinal, lateral, heading)
        in its own frame; the history bends into it linearly, the target fades out of it.
        """
        log = self.log
        ego_xy, ego_yaw = log.ego_xy.copy(), log.ego_yaw.copy()
        yaw0 = log.ego_yaw[rows, frames]
        c, s = np.cos(yaw0), np.sin(yaw0)
        d_xy = np.stack([c * offsets[:, 0] - s * offsets[:, 1], s * offsets[:, 0] + c * offsets[:, 1]], -1)
        back = frames[:, None] - np.arange(HISTORY + 1)
        fade = 1.0 - np.arange(HISTORY + 1) / HISTORY
        ok = back >= 0
        r2, b2 = np.broadcast_to(rows[:, None], back.shape)[ok], back[ok]
        ego_xy[r2, b2] += (fade[None, :, None] * d_xy[:, None])[ok]
        ego_yaw[r2, b2] += (fade[None] * offsets[:, 2:3])[ok]
        image = self.raster(rows, frames, ego_xy, ego_yaw)

        # Target: the logged future, pulled towards the offset near now and onto the log at the horizon,
        # in the frame of the (perturbed) current pose.
        ahead = np.minimum(frames[:, None] + 1 + np.arange(FUTURE), log.ego_xy.shape[1] - 1)
        f_fade = 1.0 - np.arange(1, FUTURE + 1) / FUTURE
        t_xy = log.ego_xy[rows[:, None], ahead] + f_fade[None, :, None] * d_xy[:, None]
        t_yaw = log.ego_yaw[rows[:, None], ahead] + f_fade[None] * offsets[:, 2:3]
        now_xy, now_yaw = ego_xy[rows, frames], ego_yaw[rows, frames]
        cn, sn = np.cos(now_yaw)[:, None], np.sin(now_yaw)[:, None]
        rel = t_xy - now_xy[:, None]
        local = np.stack([cn * rel[..., 0] + sn * rel[..., 1], -sn * rel[..., 0] + cn * rel[..., 1]], -1)
        target_ok = (frames[:, None] + 1 + np.arange(FUTURE)) < log.num_frames[rows][:, None]
        return {"image": torch.from_numpy(image),
                "target_positions": torch.from_numpy(local.astype(np.float32)),
                "target_yaws": torch.from_numpy(wrap_angle(t_yaw - now_yaw[:, None]).astype(np.float32))[..., None],
                "target_availabilities": torch.from_numpy(target_ok.astype(np.float32))}


def draw_batch(data: Data, rng: np.random.Generator, batch_size: int, prob: float = 0.5,
               std: tuple[float, float, float] = (0.8, 0.6, 0.06)) -> dict[str, torch.Tensor]:
    n_rows = data.log.shape[0]
    rows = rng.choice(n_rows, size=min(batch_size, n_rows), replace=False)
    frames = rng.integers(0, data.log.num_frames[rows] - FUTURE)
    on = rng.random(rows.size) < prob
    offsets = np.clip(rng.normal(size=(rows.size, 3)) * np.array(std), -3.0, 3.0) * on[:, None]
    return data.samples(rows, frames, offsets)


@torch.no_grad()
def open_loop_errors(model: torch.nn.Module, data: Data, batch_size: int = 64) -> tuple[float, float]:
    """ADE and FDE (m) on unperturbed samples: every row at frames 0, 10, 20, ..."""
    rows, frames = data.frames_with_full_future()
    keep = frames % 10 == 0
    rows, frames = rows[keep], frames[keep]
    ade, fde, n = 0.0, 0.0, 0
    for frame in np.unique(frames):  # one frame at a time: the rows of a call must differ
        r = rows[frames == frame]
        for i in range(0, r.size, batch_size):
            part = data.samples(r[i:i + batch_size], np.full(r[i:i + batch_size].size, frame),
                                np.zeros((r[i:i + batch_size].size, 3)))
            err = (model(part)["positions"] - part["target_positions"]).norm(dim=-1)
            ade += float(err.mean(-1).sum())
            fde += float(err[:, -1].sum())
            n += err.shape[0]
    return ade / max(n, 1), fde / max(n, 1)


def train(model: torch.nn.Module, data: Data, val: Data, *, steps: int, batch_size: int, lr: float, seed: int,
          eval_every: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps, pct_start=0.1)
    weights = horizon_weights()
    history, running, t0 = [], 0.0, time.perf_counter()
    for step in range(1, steps + 1):
        model.train()
        batch = draw_batch(data, rng, batch_size)
        loss = loss_fn(model(batch), batch, weights)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        sched.step()
        running += float(loss.detach())
        if step % eval_every == 0 or step == steps:
            model.eval()
            ade, fde = open_loop_errors(model, val)
            row = {"step": step, "loss": round(running / eval_every, 4), "val_ade": round(ade, 3),
                   "val_fde": round(fde, 3), "seconds": round(time.perf_counter() - t0, 1)}
            history.append(row)
            print("  ".join(f"{k} {v}" for k, v in row.items()), flush=True)
            running = 0.0
    return history


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=200)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--train-seed", type=int, default=1)
    parser.add_argument("--val-seed", type=int, default=2)
    parser.add_argument("--val-scenes", type=int, default=32)
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--lr", type=float, default=2e-3)
    parser.add_argument("--eval-every", type=int, default=250)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "fixtures" / "models" / "raster_model.pt2")
    args = parser.parse_args(argv)
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        data = Data(Path(tmp), args.scenes, args.frames, args.train_seed)
        val = Data(Path(tmp), args.val_scenes, args.frames, args.val_seed)
        print(f"data: {args.scenes} + {args.val_scenes} scenes x {args.frames} frames in "
              f"{time.perf_counter() - t_start:.1f} s; raster {PARAMS.map_type} {PARAMS.raster_size}, "
              f"{PARAMS.num_channels} channels", flush=True)
        model = RasterPlanningModel(PARAMS.num_channels, PARAMS.raster_size[0], FUTURE)
        history = train(model, data, val, steps=args.steps, batch_size=args.batch_size, lr=args.lr, seed=args.seed,
                        eval_every=args.eval_every)
        (example,) = raster_inputs_on_generated()[0]
        closed = closed_loop_check(export_program(model, (example,), args.out), val)
    meta = {
        "model": "pytest_driveeval.policies.raster_model.RasterPlanningModel",
        "raster": {"map_type": PARAMS.map_type, "raster_size": list(PARAMS.raster_size),
                   "pixel_size": list(PARAMS.pixel_size), "ego_center": list(PARAMS.ego_center),
                   "history_num_frames": HISTORY, "filter_agents_threshold": PARAMS.filter_agents_threshold},
        "future_frames": FUTURE,
        "parameters": sum(p.numel() for p in model.parameters()),
        "file_bytes": args.out.stat().st_size,
        "command": "python examples/train_raster_model.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "data": {"train": f"generate_zarr({args.scenes} scenes, {args.frames} frames, seed={args.train_seed})",
                 "validation": f"generate_zarr({args.val_scenes} scenes, {args.frames} frames, seed={args.val_seed})",
                 "held_out": "fixtures/l5kit/generated.zarr (seed 0) is never used"},
        "history": history,
        "closed_loop_val": closed,
        "train_seconds": round(time.perf_counter() - t_start, 1),
        "torch": torch.__version__,
    }
    args.out.with_suffix(".json").write_text(json.dumps(meta, indent=1) + "\n")
    print(f"wrote {args.out} and {args.out.with_suffix('.json')}; total {time.perf_counter() - t_start:.0f} s")
    return meta


def closed_loop_check(model, data: Data) -> dict:
    """The demo's closed-loop settings on the validation scenes, the model against constant velocity:
    at-fault collision frames, scenes with one, drift resets."""
    out = {}
    for name, policy in (("model", model), ("constant_velocity", ConstantVelocityPolicy(FUTURE))):
        result = unroll(data.log, policy, CLOSED_LOOP,
                        extra_inputs=raster_inputs(PARAMS, data.log, data.scenes, data.semantic_map))
        fault = result.collision_at_fault
        out[name] = {"scenes": int(fault.shape[0]), "at_fault_frames": int(fault.sum()),
                     "scenes_with_at_fault_collision": int(fault.any(1).sum()), "resets": int(result.reset.sum()),
                     "mean_displacement_m": round(float(np.nanmean(result.displacement_error)), 3),
                     "errors": sum(e is not None for e in result.errors)}
        print(f"closed loop, {name}: {out[name]}", flush=True)
    return out


if __name__ == "__main__":
    main()
