"""A demo point-cloud filter, as a team might write a first obstacle-segmentation stage.

Raw lidar points in base_link (ground near z = 0) in, obstacle points out:

1. ground removal: drop what lies within ``ground_z`` of the flat ground plane;
2. height band: drop what is above ``max_z`` (overhanging trees, bridges, signs);
3. sparse-return removal: drop points whose 3 x 3 neighbourhood of ``cell`` x
   ``cell`` grid cells holds fewer than ``min_neighbours`` points (rain, dust,
   stray returns), the cheap cousin of radius outlier removal.

Step 3 is where it is fragile: a far, small object is only a handful of
returns, so when some of them go missing the rest look like noise and are
removed too, and the object's box ends up short of points.  The robustness
demo (scenario_tests/obstacle_segmentation/robustness) searches for the
dropout at which that happens.
"""
from __future__ import annotations

import numpy as np


def ground_height_filter(points: np.ndarray, ground_z: float = 0.3, max_z: float = 2.5, cell: float = 0.5,
                         min_neighbours: int = 5) -> np.ndarray:
    """Obstacle points of ``points`` (structured with x, y, z fields, or (N, >=3)), same dtype."""
    if points.dtype.names:
        x, y, z = (np.asarray(points[c], dtype=np.float64) for c in "xyz")
    else:
        x, y, z = (np.asarray(points[:, k], dtype=np.float64) for k in range(3))
    band = np.flatnonzero((z > ground_z) & (z < max_z))
    if not len(band):
        return points[band]
    i = np.floor(x[band] / cell).astype(np.int64)
    j = np.floor(y[band] / cell).astype(np.int64)
    i -= i.min() - 1  # one empty cell of margin on every side, so neighbours are never negative
    j -= j.min() - 1
    width = int(j.max()) + 2
    keys = i * width + j
    cells, counts = np.unique(keys, return_counts=True)
    around = np.zeros(len(band), dtype=np.int64)
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            neighbour = keys + di * width + dj
            at = np.clip(np.searchsorted(cells, neighbour), 0, len(cells) - 1)
            around += np.where(cells[at] == neighbour, counts[at], 0)
    return points[band[around >= min_neighbours]]
