"""Drawing again into one canvas (Rasterizer(..., out=canvas)) and the closed loop's reuse of it."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pytest_driveeval.raster import RasterParams, Rasterizer

SCENE = Path(__file__).resolve().parents[2] / "fixtures" / "l5kit" / "single_scene.zarr"
PARAMS = RasterParams(map_type="box_debug", raster_size=(112, 112), history_num_frames=10)


@pytest.fixture(scope="module")
def real():
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.sim.logreplay.logarrays import stack_scenes
    scene = L5Dataset.open(SCENE).scene(0)
    copies = 4
    log = stack_scenes([scene] * copies)
    # Driven poses off the log, each copy by its own amount, so boxes land in new places every step.
    rng = np.random.default_rng(2)
    xy = log.ego_xy + rng.normal(0, 1.0, log.ego_xy.shape) * np.arange(copies)[:, None, None]
    yaw = log.ego_yaw + rng.normal(0, 0.1, log.ego_yaw.shape) * np.arange(copies)[:, None]
    return scene, log, xy, yaw


def test_a_canvas_drawn_again_and_again_equals_fresh_arrays(real):
    scene, log, xy, yaw = real
    raster = Rasterizer(PARAMS, log, scenes=[scene] * 4)
    canvas = raster.canvas(4)
    n = int(log.num_frames[0])
    steps = [(np.arange(4), np.full(4, t)) for t in range(0, n, 7)]
    # Fewer rows, other rows in a slot, frames near the start (empty history channels) after full ones.
    steps += [(np.array([3, 1]), np.array([n - 1, 2])), (np.arange(4), np.array([0, 100, 1, 60])),
              (np.array([2]), np.array([150]))]
    for rows, frames in steps:
        drawn = raster(rows, frames, xy, yaw, out=canvas)
        assert drawn.base is canvas.image and drawn.shape[0] == rows.size
        np.testing.assert_array_equal(drawn, raster(rows, frames, xy, yaw))
        del drawn
    assert canvas.image[:, :11].any()


def test_the_canvas_is_busy_while_a_result_or_a_tensor_view_of_it_lives(real):
    torch = pytest.importorskip("torch")
    scene, log, xy, yaw = real
    raster = Rasterizer(PARAMS, log, scenes=[scene] * 4)
    canvas = raster.canvas(4)
    assert canvas.free
    image = raster(np.arange(2), np.full(2, 30), xy, yaw, out=canvas)
    assert not canvas.free
    del image
    assert canvas.free
    kept = torch.from_numpy(raster(np.arange(2), np.full(2, 30), xy, yaw, out=canvas))[1, 3:5]
    assert not canvas.free
    del kept
    assert canvas.free


def test_the_canvas_must_fit():
    from raster_helpers import make_log
    log = make_log(2, [])
    raster = Rasterizer(PARAMS, log)
    with pytest.raises(ValueError, match="3 rows for a canvas of 2"):
        raster(np.zeros(3, np.int64), np.zeros(3, np.int64), log.ego_xy, log.ego_yaw, out=raster.canvas(2))
    other = Rasterizer(RasterParams(map_type="box_debug", raster_size=(64, 64)), log)
    with pytest.raises(ValueError, match="make it with Rasterizer.canvas"):
        raster(np.zeros(1, np.int64), np.zeros(1, np.int64), log.ego_xy, log.ego_yaw, out=other.canvas(1))


def test_raster_inputs_reuse_the_canvas_but_never_change_what_a_policy_kept(real):
    """The closed loop's extra inputs: a step whose previous image nobody holds draws in the same
    memory; images a policy kept (whole or a view) stay as they were drawn."""
    pytest.importorskip("torch")
    from pytest_driveeval.usecases.closed_loop.raster_inputs import raster_inputs
    scene, log, xy, yaw = real
    inputs = raster_inputs(PARAMS, log, [scene] * 4)
    fresh = Rasterizer(PARAMS, log, scenes=[scene] * 4)
    kept, pointers = [], []
    for t in range(20, 60):
        rows = np.arange(4) if t < 40 else np.array([0, 2])
        image = inputs(rows, t, xy, yaw)["image"]
        pointers.append(image.data_ptr())
        if t % 5 == 0:
            kept.append((rows, t, image))
        elif t % 5 == 1:
            kept.append((rows[1:2], t, image[1:2]))
        del image
    for rows, t, image in kept:
        np.testing.assert_array_equal(image.numpy(), fresh(rows, np.full(rows.size, t), xy, yaw))
    # Steps after one whose image was let go drew in that image's memory.
    reused = [t for t in range(1, len(pointers)) if pointers[t] == pointers[t - 1]]
    assert len(reused) >= 10
