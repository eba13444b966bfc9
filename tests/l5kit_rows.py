"""Random l5kit agent rows that the zarr reader's track table and its compiled twin in
sim/logreplay are both checked on.  A test module imports them by name
(``from l5kit_rows import random_rows``; tests/ is on the path, as for
``from conftest import REPO_ROOT``), so each test file runs on its own.
"""
from __future__ import annotations

import numpy as np


def random_rows(seed: int, sparse: bool, repeat: bool):
    """Rows frame by frame with ids dense or sparse (the lookup table or the sort), label
    probabilities with ties and NaNs, and optionally an id twice in one frame."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(0, 12, 30)
    frame = np.repeat(np.arange(counts.size), counts)
    pool = rng.choice(2**40 if sparse else 60, 40, replace=False).astype(np.uint64)
    ids = np.concatenate([rng.choice(pool, c, replace=False) for c in counts]).astype(np.uint64)
    if repeat:
        r = int(np.flatnonzero(np.diff(frame) == 0)[len(frame) // 3])
        ids[r + 1] = ids[r]
    probabilities = rng.integers(0, 3, (frame.size, 17)).astype(np.float32)  # many ties
    probabilities[rng.random(frame.size) < 0.1, rng.integers(0, 17)] = np.nan
    return ids, frame, probabilities, counts.size
