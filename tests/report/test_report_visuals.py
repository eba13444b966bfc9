"""The bird's-eye GIF and the bar chart are real images of the right content."""
from __future__ import annotations

import numpy as np
import pytest

PIL = pytest.importorskip("PIL.Image")

from pytest_driveeval.report.birdseye import COLLISION, render_unroll_gif  # noqa: E402
from pytest_driveeval.report.plots import bar_chart  # noqa: E402


def straight_scene(T=120, A=6):
    t = np.arange(T)
    ego = np.stack([t * 1.0, np.zeros(T)], -1)
    agents = np.stack([ego[:, None, 0] + 10 * np.arange(1, A + 1), np.full((T, A), 3.5)], -1)
    return ego, agents


def test_gif_is_subsampled_small_and_marks_collisions(tmp_path):
    ego, agents = straight_scene()
    collision = np.zeros(len(ego), bool)
    collision[37] = True  # not on the subsampling grid: must still be shown
    path = render_unroll_gif(tmp_path / "u.gif", ego, np.zeros(len(ego)), np.array([4.9, 1.9]), ego,
                             agents, np.zeros(agents.shape[:2]), np.array([4.5, 1.9]),
                             np.ones(agents.shape[:2], bool), collision, title="scene 0", max_frames=40)
    with PIL.open(path) as image:
        assert image.format == "GIF"
        assert 40 <= image.n_frames <= 41
        assert path.stat().st_size < 300_000
        red_frames = 0
        for index in range(image.n_frames):
            image.seek(index)
            rgb = np.asarray(image.convert("RGB"))
            red_frames += bool((rgb == COLLISION).all(-1).sum() > 50)
    assert red_frames == 1


def test_bar_chart_is_a_png(tmp_path):
    path = bar_chart(tmp_path / "c.png", {"front": 2, "side": 0, "rear": 1, "drift resets": 4}, "scene 0")
    with PIL.open(path) as image:
        assert image.format == "PNG" and image.size == (480, 320)
        assert len(np.unique(np.asarray(image.convert("RGB")).reshape(-1, 3), axis=0)) > 10
