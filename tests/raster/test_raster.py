"""box_debug and py_semantic rasters: matrices, boxes, channels, filter, map layers, batching."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")  # a Python without torch skips the file

from pytest_driveeval.raster import (ActiveFaces, RasterParams, Rasterizer, active_faces, agent_keep,  # noqa: E402
                                     raster_from_local, raster_from_world, rasterize)
from pytest_driveeval.raster.boxes import box_corners  # noqa: E402
from raster_helpers import make_log, make_map  # noqa: E402

# 16 x 16 pixels of 0.5 m with the ego in the middle: raster = (8 + 2 x, 8 - 2 y) for a local (x, y).
SMALL = dict(raster_size=(16, 16), pixel_size=(0.5, 0.5), ego_center=(0.5, 0.5))


def boxes(history=0, **kw) -> RasterParams:
    return RasterParams(map_type="box_debug", history_num_frames=history, **{**SMALL, **kw})


def test_raster_from_local_is_l5kits_default():
    # scale 1/0.5, origin at (0.25 * 224, 0.5 * 224), y flipped and moved down by the height.
    np.testing.assert_array_equal(raster_from_local(RasterParams()), [[2, 0, 56], [0, -2, 112], [0, 0, 1]])
    unflipped = RasterParams(set_origin_to_bottom=False)
    np.testing.assert_array_equal(raster_from_local(unflipped), [[2, 0, 56], [0, 2, 112], [0, 0, 1]])


def test_raster_from_world_puts_the_ego_frame_where_expected():
    m = raster_from_world(RasterParams(), np.array([[10.0, 5.0]]), np.array([np.pi / 2]))[0]
    # Facing +y: one metre ahead is world (10, 6) -> local (1, 0) -> pixel (58, 112);
    # one metre to the left is world (9, 5) -> local (0, 1) -> pixel (56, 110).
    for world, pixel in [((10, 5), (56, 112)), ((10, 6), (58, 112)), ((9, 5), (56, 110))]:
        np.testing.assert_allclose(m[:2, :2] @ world + m[:2, 2], pixel, atol=1e-12)


def test_box_corners_follow_l5kits_order_and_rotation():
    corners = box_corners(np.array([[1.0, 2.0]]), np.array([np.pi / 2], np.float32), np.array([[4.0, 2.0]], np.float32))
    # (-l/2, -w/2), (-l/2, w/2), (l/2, w/2), (l/2, -w/2), turned a quarter left.
    np.testing.assert_allclose(corners[0], [[2, 0], [0, 0], [0, 4], [2, 4]], atol=1e-6)


def draw(params, log, frame=0, **kw):
    return Rasterizer(params, log, **kw)(np.array([0]), np.array([frame]), log.ego_xy, log.ego_yaw)[0]


def test_an_agent_box_lands_on_the_hand_computed_pixels():
    # Local x in [1, 3] m, y in [-0.5, 0.5] m: pixels x 10..14, rows 7..9 (row edges at 7 and 9).
    log = make_log(1, [dict(frames=[0], xy=(2.0, 0.0), extent=(2.0, 1.0))])
    image = draw(boxes(), log)
    agents = image[0]
    # The fill covers rows [7, 9) and columns ceil(10)..floor(14); the outline only adds around it.
    assert np.all(agents[7:9, 10:15] == 1.0)
    lit = np.argwhere(agents > 0)
    assert lit[:, 0].min() >= 5 and lit[:, 0].max() <= 11 and lit[:, 1].min() >= 8 and lit[:, 1].max() <= 15
    centre = (np.argwhere(agents > 0) * agents[agents > 0][:, None]).sum(0) / agents.sum()
    np.testing.assert_allclose(centre, (8, 12), atol=0.6)
    # The anti-aliased edge gives values between 0 and 1, as cv2's LINE_AA does.
    assert np.any((agents > 0) & (agents < 1))


def test_the_ego_box_is_l5kits_rasterizer_ego():
    image = draw(boxes(), make_log(1, []))
    assert not image[0].any()
    ego = image[1]
    # 4.87 m x 1.85 m around the ego at pixel (8, 8): columns ceil(3.13)..floor(12.87), rows [7, 10) after rounding 6.15 and 9.85.
    assert np.all(ego[7:10, 4:13] == 1.0)
    assert not ego[:, :2].any() and not ego[:, 15:].any() and not ego[:4].any() and not ego[13:].any()


def test_history_channels_run_from_the_current_frame_back_agents_then_ego():
    # The agent is seen only at frame 3; the ego drives +x one metre a frame.
    log = make_log(6, [dict(frames=[3], xy=(30.0, 0.0), extent=(2.0, 1.0))])
    log.ego_xy[0, :, 0] = 25.0 + np.arange(6)
    params = boxes(history=3, raster_size=(40, 16))
    image = draw(params, log, frame=5)
    assert image.shape == (8, 16, 40)
    lit = [bool(image[c].any()) for c in range(4)]
    assert lit == [False, False, True, False]  # channel k is frame 5 - k
    # Ego channels 4..7: the ego k frames back sits k metres (2k pixels) further left.
    centres = [np.argwhere(image[4 + k] == 1.0)[:, 1].mean() for k in range(4)]
    np.testing.assert_allclose(np.diff(centres), [-2, -2, -2], atol=0.01)
    only_now = draw(boxes(history=3, raster_size=(40, 16), render_ego_history=False), log, frame=5)
    assert only_now[4].any() and not only_now[5:].any()


def test_frames_before_the_scene_leave_their_channels_empty():
    log = make_log(3, [dict(frames=[0, 1, 2], xy=(2.0, 0.0), extent=(2.0, 1.0))])
    image = draw(boxes(history=4), log, frame=1)
    assert [bool(image[c].any()) for c in range(10)] == [True, True, False, False, False] * 2


def test_agents_outside_the_label_filter_are_not_drawn():
    log = make_log(1, [dict(frames=[0], xy=(2.0, 0.0), extent=(2.0, 1.0), keep=False),
                       dict(frames=[0], xy=(-3.0, 0.0), extent=(2.0, 1.0))])
    image = draw(boxes(), log)
    assert image[0][:, 9:].sum() == 0 and image[0][:, :6].sum() > 0
    keep = np.ones(log.shape, bool)
    assert draw(boxes(), log, keep=keep)[0][:, 9:].sum() > 0


def test_overlapping_boxes_of_a_channel_cancel_like_one_fillpoly():
    one = make_log(1, [dict(frames=[0], xy=(2.0, 0.0), extent=(2.0, 1.0))])
    two = make_log(1, [dict(frames=[0], xy=(2.0, 0.0), extent=(2.0, 1.0))] * 2)
    assert draw(boxes(), one)[0][7:9, 10:15].min() == 1.0
    assert draw(boxes(), two)[0][7:9, 11:14].max() < 1.0  # even-odd: the doubled inside is not filled


def lane_map(face_colour=None):
    left = [(-20.0, 1.5), (20.0, 1.5)]
    right = [(-20.0, -1.5), (20.0, -1.5)]
    faces = [("face", face_colour)] if face_colour is not None else []
    return make_map(lanes=[(left, right)], faces=faces, lane_faces=[["face"] if faces else []],
                    crosswalks=[[(4.0, 3.5), (6.0, 3.5), (6.0, 6.0), (4.0, 6.0)]])


def semantic(face_colour=None, active=True):
    log = make_log(1, [])
    faces = ActiveFaces(1, np.array([0, 1 if active else 0]), np.array(["face"] if active else [], "<U16"))
    params = RasterParams(map_type="py_semantic", raster_size=(32, 32), pixel_size=(0.5, 0.5), ego_center=(0.5, 0.5))
    image = draw(params, log, semantic_map=lane_map(face_colour), faces=faces)
    return (image[2:] * 255).round().astype(int)  # R, G, B; raster = (16 + 2 x, 16 - 2 y)


def test_semantic_fills_the_lane_in_road_colour_on_white():
    rgb = semantic()
    assert rgb.shape == (3, 32, 32)
    assert rgb[:, 16, 16].tolist() == [17, 17, 31]  # inside the lane, between its boundaries at rows 13 and 19
    assert rgb[:, 28, 16].tolist() == [255, 255, 255]  # off the map


def blended(start, colour) -> set[tuple[int, ...]]:
    """Every value cv2's anti-aliased line leaves on a pixel of colour ``start``: two blends
    ``c += ((colour - c) * a + 127) >> 8`` with one weight a."""
    out = set()
    for a in range(1, 256):
        c = np.array(start)
        for _ in range(2):
            c = c + (((np.array(colour) - c) * a + 127) >> 8)
        out.add(tuple(int(v) for v in c))
    return out


@pytest.mark.parametrize("colour, expected", [(None, (255, 217, 82)), (1, (255, 0, 0)), (2, (255, 255, 0)),
                                              (3, (0, 255, 0)), (0, (255, 217, 82))])
def test_lane_boundaries_take_the_active_faces_colour(colour, expected):
    rgb = semantic(colour)
    # The left boundary y = 1.5 m runs along row 13, over the road colour.
    assert tuple(rgb[:, 13, 6]) in blended((17, 17, 31), expected)
    others = {(255, 217, 82), (255, 0, 0), (255, 255, 0), (0, 255, 0)} - {expected}
    assert all(tuple(rgb[:, 13, 6]) not in blended((17, 17, 31), o) for o in others)


def test_an_inactive_face_leaves_the_lane_uncoloured():
    assert tuple(semantic(1, active=False)[:, 13, 6]) in blended((17, 17, 31), (255, 217, 82))


def test_crosswalks_are_outlined():
    rgb = semantic()
    # Crosswalk x 4..6 m, y 3.5..6 m: its left edge at column 24, rows 4..9, on white.
    assert tuple(rgb[:, 6, 24]) in blended((255, 255, 255), (255, 117, 69))
    assert rgb[:, 6, 24].tolist() != [255, 255, 255]
    assert rgb[:, 6, 26].tolist() == [255, 255, 255]  # inside the outline stays white


def test_semantic_needs_a_map_and_faces():
    log = make_log(1, [])
    with pytest.raises(ValueError, match="semantic_map"):
        Rasterizer(RasterParams(), log)
    with pytest.raises(ValueError, match="faces"):
        Rasterizer(RasterParams(), log, semantic_map=lane_map())


@pytest.mark.parametrize("field, value, match", [
    ("map_type", "py_satellite", "map_type"), ("raster_size", (0, 16), "raster_size"),
    ("pixel_size", (0.5, 0.25), "square"), ("history_num_frames", -1, "history_num_frames"),
    ("ego_center", (np.nan, 0.5), "ego_center"), ("raster_size", (16.5, 16), "raster_size")])
def test_bad_params_name_the_value(field, value, match):
    with pytest.raises(ValueError, match=match):
        RasterParams(**{field: value})


def test_rows_and_frames_are_checked():
    log = make_log(3, [])
    raster = Rasterizer(boxes(), log)
    with pytest.raises(IndexError, match="scene 7: frame 3"):
        raster(np.array([0]), np.array([3]), log.ego_xy, log.ego_yaw)
    with pytest.raises(ValueError, match="ego_xy"):
        raster(np.array([0]), np.array([0]), log.ego_xy[:, :2], log.ego_yaw)


@pytest.fixture(scope="module")
def real(shared_data):
    from pytest_driveeval.io.l5.l5kit_zarr import L5Dataset
    from pytest_driveeval.sim.logreplay.logarrays import stack_scenes
    path = shared_data / "l5kit" / "single_scene.zarr"
    if not path.is_dir():
        pytest.skip(f"real sample data absent: {path} is not there")
    scene = L5Dataset.open(path).scene(0)
    return scene, stack_scenes([scene])


def test_agent_keep_is_l5kits_row_filter(real):
    scene, log = real
    keep = agent_keep([scene], log, 0.5)
    t = 40
    start, end = scene.frames["agent_index_interval"][t]
    rows = scene.agents[start:end]
    expected = np.sum(rows["label_probabilities"][:, 3:16], axis=1) > 0.5
    drawn = keep[0, t][log.available[0, t]]
    assert drawn.sum() == expected.sum() > 0
    assert keep.sum() != log.relevant.sum() or np.array_equal(keep, log.relevant)


def test_real_scene_batched_equals_one_at_a_time_and_repeats(real):
    scene, log = real
    params = RasterParams(map_type="box_debug", raster_size=(112, 112), history_num_frames=10)
    frames = np.array([0, 5, 60, 200, int(log.num_frames[0]) - 1])
    big = log.take(np.zeros(frames.size, np.int64))
    # Driven poses differ from the log's: shift every copy's ego sideways by its own amount.
    ego_xy = big.ego_xy + np.arange(frames.size)[:, None, None] * np.array([0.0, 0.7])
    raster = Rasterizer(params, big, scenes=[scene] * frames.size)
    batch = raster(np.arange(frames.size), frames, ego_xy, big.ego_yaw)
    assert batch.shape == (5, 22, 112, 112) and batch.dtype == np.float32
    assert batch.min() >= 0 and batch.max() == 1 and batch[:, 0].any(axis=(1, 2)).all()
    for b, f in enumerate(frames):
        alone = rasterize(params, big, [b], [f], ego_xy, big.ego_yaw, scenes=[scene] * frames.size)
        np.testing.assert_array_equal(alone[0], batch[b])
    np.testing.assert_array_equal(raster(np.arange(frames.size), frames, ego_xy, big.ego_yaw), batch)


def test_real_scene_faces_are_read_per_frame(real):
    scene, log = real
    faces = active_faces([scene], log.shape[1])
    assert faces.offsets.size == log.shape[1] + 1
    start, end = scene.frames["traffic_light_faces_index_interval"][10]
    on = scene.traffic_light_faces[start:end]
    expected = sorted(on["face_id"][on["traffic_light_face_status"][:, 0] > 0].tolist())
    assert sorted(faces.ids[faces.offsets[10]:faces.offsets[11]].tolist()) == expected


PLAIN = """
import sys
sys.modules["numba"] = None  # the plain-Python path
sys.path.insert(0, sys.argv[2])
import numpy as np
import test_raster
from pytest_driveeval.raster import draw
assert not draw.AVAILABLE
np.savez(sys.argv[1], semantic=test_raster.semantic(1), boxes=test_raster.moving_boxes())
"""


def moving_boxes():
    log = make_log(4, [dict(frames=[0, 1, 2, 3], xy=(2.0, 0.3), yaw=0.4, extent=(2.0, 1.0)),
                       dict(frames=[1, 2], xy=(-3.0, 1.0), yaw=-1.0, extent=(4.5, 1.9))])
    log.ego_xy[0, :, 0] = np.arange(4) * 0.8
    return draw(boxes(history=2), log, frame=3)


def test_without_numba_the_rasters_are_the_same(tmp_path):
    import subprocess
    import sys
    from pathlib import Path
    pytest.importorskip("numba")
    out = tmp_path / "plain.npz"
    subprocess.run([sys.executable, "-c", PLAIN, str(out), str(Path(__file__).parent)], check=True, timeout=600)
    plain = np.load(out)
    assert plain["boxes"][:3].any() and (plain["semantic"] != 255).any()
    np.testing.assert_array_equal(semantic(1), plain["semantic"])
    np.testing.assert_array_equal(moving_boxes(), plain["boxes"])


def test_each_drawing_kernel_is_compiled_for_values_not_for_literals():
    """numba compiles a kernel again for literal arguments (``0``, ``True``) where another caller passes
    values of the same type; each such copy costs a cold start seconds.  The box channels and the
    semantic map reach their kernels with values only."""
    from pytest_driveeval.raster import boxes as box_kernels, draw as draw_kernels

    if not draw_kernels.AVAILABLE:
        pytest.skip("numba is not installed: the kernels run as Python")
    from numba import types

    draw(boxes(history=1), make_log(2, [dict(frames=[0, 1], xy=(2.0, 0.0), extent=(2.0, 1.0))]), frame=1)
    semantic()
    assert len(box_kernels._channel.signatures) == 1, box_kernels._channel.signatures
    for kernel in (box_kernels._channel, draw_kernels.polylines, draw_kernels.fill_polygons, draw_kernels.line_aa):
        for signature in kernel.signatures:
            assert not any(isinstance(t, types.Literal) for t in signature), (kernel, signature)
