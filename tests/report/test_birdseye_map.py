"""The bird's-eye GIF's map under the boxes, its legend, and the markers of failed score terms:
read back pixel by pixel from the GIF's frames, where the world says they must be."""
from __future__ import annotations

import numpy as np
import pytest

PIL = pytest.importorskip("PIL.Image")

from pytest_driveeval.report.birdseye import (  # noqa: E402
    AGENT_FILL, BACKGROUND, EGO, LEGEND_OUTLINE, render_unroll_gif)
from pytest_driveeval.report.map_layers import CROSSWALK, LANE, ROAD_EDGE, ROAD_LINE, DrawnMap  # noqa: E402
from pytest_driveeval.report.markers import KINDS  # noqa: E402

SIZE, METERS = 320, 60.0
SCALE = SIZE / METERS
ORANGE = KINDS["off_drivable_area"][1]


def frames(path) -> list[np.ndarray]:
    from PIL import ImageSequence

    with PIL.open(path) as image:
        return [np.asarray(f.convert("RGB")).copy() for f in ImageSequence.Iterator(image)]


def pixel(ego: np.ndarray, world) -> tuple[int, int]:
    """(row, column) of a world point in the frame centred on ``ego``."""
    x = SIZE / 2 + (world[0] - ego[0]) * SCALE
    y = SIZE / 2 - (world[1] - ego[1]) * SCALE
    return int(round(y)), int(round(x))


def is_colour(rgb: np.ndarray, colour) -> np.ndarray:
    return (rgb == np.asarray(colour)).all(-1)


def gif(tmp_path, T=20, drawn_map=None, markers=None, frame_numbers=None, max_frames=80, name="u.gif", step=1.7):
    """The ego drives along +x at ``step`` m per frame (the view moves across the map's tiles); one
    agent rides 8 m ahead of it, another stands far away."""
    ego = np.stack([np.arange(T) * step + 3.0, np.full(T, 1.0)], -1)
    agents = np.stack([ego + [8.0, 0.0], np.tile([[500.0, 500.0]], (T, 1))], 1)
    return render_unroll_gif(tmp_path / name, ego, np.zeros(T), np.array([4.9, 1.9]), ego, agents,
                             np.zeros((T, 2)), np.array([4.5, 1.9]), np.ones((T, 2), bool), np.zeros(T, bool),
                             title="scene 0", frame_numbers=frame_numbers, max_frames=max_frames,
                             drawn_map=drawn_map, markers=markers), ego


def strip_map() -> DrawnMap:
    """A lane strip along y in [-20, 10], a road line across it at x = 21.3, a road edge along
    y = 12, a crosswalk at x in [40, 44] (below the boxes)."""
    lane = np.array([[-200.0, -20], [300, -20], [300, 10], [-200, 10]])
    line = np.array([[21.3, -19.0], [21.3, -6.0]])
    edge = np.array([[-200.0, 12.0], [300, 12.0]])
    walk = np.array([[40.0, -19], [44, -19], [44, -8], [40, -8]])
    return DrawnMap([lane], [line], [edge], [walk])


def test_the_map_lies_under_the_boxes_where_the_world_puts_it_on_every_frame(tmp_path):
    path, ego = gif(tmp_path, drawn_map=strip_map())
    shown = frames(path)
    assert len(shown) == len(ego)
    line_seen = 0
    for t, rgb in enumerate(shown):
        e = ego[t]
        # Lane where nothing else is drawn; plain background beyond the lane, past the road edge.
        assert is_colour(rgb[pixel(e, (e[0] - 12, -12))], LANE)
        assert is_colour(rgb[pixel(e, (e[0] + 3, 20))], BACKGROUND)
        # A box wins over the map: the ego and the agent ahead stand on the lane.
        assert is_colour(rgb[pixel(e, e)], EGO)
        assert is_colour(rgb[pixel(e, e + [8.0, 0.0])], AGENT_FILL)
        # The road edge's row, wherever the view has moved (the tiles join without a shift).
        row, column = pixel(e, (e[0] - 20, 12.0))
        assert is_colour(rgb[row - 1:row + 2, column], ROAD_EDGE).any()
        # The road line's column, while it is in view.
        if abs(21.3 - e[0]) < METERS / 2 - 2:
            row, column = pixel(e, (21.3, -12.0))
            assert is_colour(rgb[row, column - 1:column + 2], ROAD_LINE).any(), t
            assert not is_colour(rgb[row, column - 6:column - 2], ROAD_LINE).any()
            line_seen += 1
        if abs(42.0 - e[0]) < METERS / 2 - 3:
            assert is_colour(rgb[pixel(e, (42.0, -10.0))], CROSSWALK)
    assert line_seen >= 5


def test_without_a_map_the_frames_are_as_before(tmp_path):
    path, ego = gif(tmp_path)
    for t, rgb in enumerate(frames(path)):
        assert is_colour(rgb[pixel(ego[t], (ego[t][0] - 12, -12))], BACKGROUND)
        assert not is_colour(rgb[40:], LANE).any()  # (below the caption: its text's soft edges take the nearest shade)


def legend_pixels(rgb: np.ndarray) -> int:
    """The legend's frame in the bottom-left corner."""
    return int(is_colour(rgb[SIZE // 2:, :SIZE // 2], LEGEND_OUTLINE).sum())


def test_the_legend_names_what_is_drawn_and_is_absent_when_nothing_is(tmp_path):
    bare, _ = gif(tmp_path, name="bare.gif")
    full, _ = gif(tmp_path, drawn_map=strip_map(), name="full.gif")
    lanes, _ = gif(tmp_path, drawn_map=DrawnMap(lane_surfaces=strip_map().lane_surfaces), name="lanes.gif")
    marked, _ = gif(tmp_path, markers=[(3, 0.0, 0.0, "wrong_direction")], name="marked.gif")
    assert legend_pixels(frames(bare)[0]) == 0
    assert legend_pixels(frames(full)[0]) > 100 and legend_pixels(frames(marked)[0]) > 100

    def height(path) -> int:
        rows = np.flatnonzero(is_colour(frames(path)[0][SIZE // 2:, :SIZE // 2], LEGEND_OUTLINE).any(1))
        return int(rows.max() - rows.min())

    # four layers take four rows of the key, a map of lanes only one
    assert height(full) > 3 * height(lanes) - 10


def test_a_marker_shows_from_its_frame_on_and_its_caption_names_the_term(tmp_path):
    # The log's frame numbers start at 10: the marker's frame 18 is the animation's ninth row.
    T = 20
    place = (3.0 + 8 * 1.7 - 6.0, 1.0 + 10.0)  # up and behind the ego at frame 18, away from the legend
    path, ego = gif(tmp_path, drawn_map=strip_map(), markers=[(18, *place, "off_drivable_area")],
                    frame_numbers=np.arange(T) + 10)
    for t, rgb in enumerate(frames(path)):
        row, column = pixel(ego[t], place)
        ring = rgb[max(0, row - 20):row + 20, max(0, column - 20):column + 20]
        caption = rgb[17:30, :SIZE // 2]  # the caption's second line
        if t < 8:
            assert not is_colour(ring, ORANGE).any() and not is_colour(caption, ORANGE).any(), t
        else:
            assert is_colour(ring, ORANGE).sum() > 30 and is_colour(caption, ORANGE).sum() > 10, t


def test_a_markers_frame_is_shown_though_subsampling_would_skip_it(tmp_path):
    place = (18.0, 9.0)
    path, ego = gif(tmp_path, T=100, max_frames=10, markers=[(37, *place, "collision")], step=0.0)
    red = KINDS["collision"][1]
    shown = frames(path)
    assert len(shown) == 11
    row, column = pixel(ego[0], place)
    marked = [bool(is_colour(rgb[row - 20:row + 20, column - 20:column + 20], red).any()) for rgb in shown]
    # rows 0, 10, 20, 30 unmarked; 37, then 40 .. 90 marked
    assert marked == [False] * 4 + [True] * 7


def test_a_marker_of_an_unknown_kind_is_refused(tmp_path):
    with pytest.raises(ValueError, match="'offroad' is not one of off_drivable_area, wrong_direction"):
        gif(tmp_path, markers=[(3, 0.0, 0.0, "offroad")])
