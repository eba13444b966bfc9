"""Bird's-eye PNG of one evaluated frame: points, scaled boxes coloured by verdict, the area."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..core.atomic import atomic_path

COLOURS = {"Success": "tab:green", "Fail": "tab:red", "Warn": "tab:orange", "Other": "0.6"}
MAX_POINTS = 60_000  # enough to read the scene; keeps the PNG quick to draw


def render_frame_png(path: str | Path, points_xy: np.ndarray, footprints: np.ndarray, verdicts: Sequence[str],
                     labels: Sequence[str], area_polygons: Sequence[np.ndarray] = (),
                     area_points_xy: np.ndarray | None = None, title: str = "", extent: float | None = None) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon

    path = Path(path)
    pts = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    if len(pts) > MAX_POINTS:  # every k-th point: deterministic, spatially even for a lidar sweep
        pts = pts[:: int(np.ceil(len(pts) / MAX_POINTS))]
    fig, ax = plt.subplots(figsize=(8, 8), dpi=100)
    ax.scatter(pts[:, 1], pts[:, 0], s=0.3, c="0.35", linewidths=0, rasterized=True)
    for poly in area_polygons:
        ax.add_patch(Polygon(np.asarray(poly)[:, ::-1], closed=True, fill=True, alpha=0.15, color="tab:blue",
                             label="non-detection area"))
    if area_points_xy is not None and len(area_points_xy):
        a = np.asarray(area_points_xy)
        ax.scatter(a[:, 1], a[:, 0], s=4, c="magenta", label=f"{len(a)} point(s) in the area")
    for fp, verdict, label in zip(footprints, verdicts, labels):
        colour = COLOURS.get(verdict, COLOURS["Other"])
        ax.add_patch(Polygon(np.asarray(fp)[:, ::-1], closed=True, fill=False, lw=1.5, color=colour))
        ax.annotate(label, xy=(fp[:, 1].mean(), fp[:, 0].max()), fontsize=7, color=colour, ha="center")
    ax.plot([0], [0], marker="^", color="k", ms=8)  # base_link, x up the page
    if extent is None:
        extent = float(np.clip(np.abs(np.concatenate([np.asarray(footprints).reshape(-1, 2),
                                                     np.zeros((1, 2))])).max() + 10, 20, 120))
    ax.set_xlim(extent, -extent)  # y to the left, as seen from above
    ax.set_ylim(-extent, extent)
    ax.set_aspect("equal")
    ax.set_xlabel("y [m] (base_link, left)")
    ax.set_ylabel("x [m] (base_link, forward)")
    ax.set_title(title, fontsize=9)
    handles, names = ax.get_legend_handles_labels()
    if handles:
        unique = dict(zip(names, handles))
        ax.legend(unique.values(), unique.keys(), loc="lower right", fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path

