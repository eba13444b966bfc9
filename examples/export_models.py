"""Convert the shipped models from TorchScript (.pt) to torch.export programs (.pt2), weights unchanged.

    python examples/export_models.py [--models planning raster gnn] [--from-dir fixtures/models]

For each model: its TorchScript archive's weights go into the model's own class, which is
exported on real inputs and saved beside it as ``<name>.pt2``; the program's outputs must equal
the TorchScript's on those inputs, and they are kept as ``<name>.reference.npz`` so that
tests/policies/test_exported_models.py checks the shipped program against them.  The training
scripts save ``.pt2`` directly; this step is for the models trained before (or a TorchScript
file of yours: the same three model classes).

Real inputs: the planning model's l5kit batch on the real Lyft scene (fixtures/l5kit/single_scene.zarr)
at five frames; the raster model's batch and rasters on the demo's generated scenes at two
frames; the GNN actor's graph observations of 32 merging episodes at their start and after 20
steps standing still.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Callable

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "fixtures" / "models"
L5 = ROOT / "fixtures" / "l5kit"


def planning_inputs() -> list[tuple]:
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.sim.logreplay import build_batch, stack_scenes

    log = stack_scenes([L5Dataset.open(L5 / "single_scene.zarr").scene(0)])
    frames = np.array([10, 40, 90, 150, 200])
    return [(build_batch(log, np.zeros(len(frames), np.int64), frames, log.ego_xy, log.ego_yaw),)]


def raster_params():
    """The rasters the shipped raster model was trained on (its JSON)."""
    from pytest_driveeval.raster import RasterParams

    meta = json.loads((MODELS / "raster_model.json").read_text())["raster"]
    return RasterParams(map_type=meta["map_type"], raster_size=tuple(meta["raster_size"]),
                        pixel_size=tuple(meta["pixel_size"]), ego_center=tuple(meta["ego_center"]),
                        history_num_frames=meta["history_num_frames"],
                        filter_agents_threshold=meta["filter_agents_threshold"])


def raster_inputs_on_generated() -> list[tuple]:
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.sim.logreplay import build_batch, stack_scenes
    from pytest_driveeval.usecases.closed_loop.raster_inputs import load_semantic_map, raster_inputs

    params = raster_params()
    dataset = L5Dataset.open(L5 / "generated.zarr")
    scenes = [dataset.scene(i) for i in (0, 1)]
    log = stack_scenes(scenes)
    draw = raster_inputs(params, log, scenes, load_semantic_map(L5 / "generated.zarr"))
    out = []
    for t in (20, 60):
        rows = np.array([0, 1])
        batch = build_batch(log, rows, np.full(2, t), log.ego_xy, log.ego_yaw)
        # The rasterizer draws into one buffer step after step: keep a copy of each.
        batch.update({k: v.clone() for k, v in draw(rows, t, log.ego_xy, log.ego_yaw, log).items()})
        out.append((batch,))
    return out


def gnn_inputs() -> list[tuple]:
    from pytest_driveeval.sim.episodes import reset
    from pytest_driveeval.usecases.policy_benchmark.evaluate import observe

    episodes = reset("merging", np.arange(32), agent_limit=12)
    start = observe(episodes, 12)
    for _ in range(20):
        episodes.step(np.zeros((32, 2)))
    return [(start,), (observe(episodes, 12),)]


def _planning_module() -> torch.nn.Module:
    from pytest_driveeval.policies.planning_model import PlanningModel

    return PlanningModel(**json.loads((MODELS / "planning_model.json").read_text())["config"])


def _raster_module() -> torch.nn.Module:
    from pytest_driveeval.policies.raster_model import RasterPlanningModel

    params = raster_params()
    future = json.loads((MODELS / "raster_model.json").read_text())["future_frames"]
    return RasterPlanningModel(params.num_channels, params.raster_size[0], future)


def _gnn_module() -> torch.nn.Module:
    from pytest_driveeval.policies.gnn import make_actor

    return make_actor()


#: name -> (file stem, the model's class as built for the shipped weights, its real inputs)
SHIPPED: dict[str, tuple[str, Callable[[], torch.nn.Module], Callable[[], list[tuple]]]] = {
    "planning": ("planning_model", _planning_module, planning_inputs),
    "raster": ("raster_model", _raster_module, raster_inputs_on_generated),
    "gnn": ("gnn_actor_merging", _gnn_module, gnn_inputs),
}


def outputs(model: Callable, inputs: list[tuple]) -> dict[str, np.ndarray]:
    """Every output tensor of ``model`` on each input, flat, by ``<input>/<key>``."""
    flat = {}
    with torch.no_grad():
        for i, args in enumerate(inputs):
            out = model(*args)
            for key, value in (out.items() if isinstance(out, dict) else [("out", out)]):
                flat[f"{i}/{key}"] = value.detach().numpy().copy()
    return flat


def convert(name: str, source_dir: Path = MODELS, out_dir: Path = MODELS) -> float:
    """Convert one model; returns the largest difference from the TorchScript's outputs."""
    from pytest_driveeval.policies.export import export_program

    stem, build, real_inputs = SHIPPED[name]
    scripted = torch.jit.load(str(source_dir / f"{stem}.pt"), map_location="cpu").eval()
    module = build().eval()
    state = scripted.state_dict()
    # TorchScript keeps non-persistent buffers (the GNN's edge columns) in its state_dict: they
    # must equal the class's own, which the state_dict of the class leaves out.
    own = dict(module.named_buffers())
    for key in set(state) - set(module.state_dict()):
        assert torch.equal(state.pop(key), own[key]), f"{stem}.pt: buffer {key} differs from the class's"
    module.load_state_dict(state)
    inputs = real_inputs()
    program = export_program(module, inputs[0], out_dir / f"{stem}.pt2")
    expected, found = outputs(scripted, inputs), outputs(program, inputs)
    worst = max(float(np.abs(expected[k] - found[k]).max()) for k in expected)
    for key in expected:
        np.testing.assert_allclose(found[key], expected[key], rtol=0, atol=1e-5, err_msg=f"{name} {key}")
    np.savez_compressed(out_dir / f"{stem}.reference.npz", **expected)
    return worst


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="+", choices=sorted(SHIPPED), default=sorted(SHIPPED))
    parser.add_argument("--from-dir", type=Path, default=MODELS, help="where the TorchScript .pt files are")
    args = parser.parse_args(argv)
    for name in args.models:
        worst = convert(name, args.from_dir)
        print(f"{name}: {SHIPPED[name][0]}.pt2 written; largest difference from the TorchScript: {worst:.3g}")


if __name__ == "__main__":
    main()
