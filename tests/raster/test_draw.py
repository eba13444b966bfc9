"""The scan conversion against OpenCV itself (when the l5kit oracle venv is there), and without numba."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from pytest_driveeval.raster import draw

ORACLE_PYTHON = Path.home() / ".cache" / "driveeval-bench" / "l5kit" / "bin" / "python"
SIZE = (40, 48)


def random_polygons(seed: int, cases: int):
    """Per case 1-3 polygons of 2-7 vertices in 1/512 px, some far outside the image."""
    rng = np.random.default_rng(seed)
    verts, starts, bounds = [], [0], [0]
    for _ in range(cases):
        for _ in range(rng.integers(1, 4)):
            n = rng.integers(2, 8)
            centre = rng.uniform(-60, 110, 2)
            points = centre + rng.uniform(-1, 1, (n, 2)) * rng.choice([3, 20, 60, 400]) * rng.uniform(0.05, 1)
            verts.append((points * 512).astype(np.int64))
            starts.append(starts[-1] + n)
        bounds.append(len(starts) - 1)
    return np.concatenate(verts), np.array(starts), np.array(bounds)


def ours(verts, starts, bounds):
    fills, lines, lanes = [], [], []
    for k in range(bounds.size - 1):
        s = starts[bounds[k]:bounds[k + 1] + 1]
        v, s = verts[s[0]:s[-1]], s - s[0]
        im = np.zeros(SIZE + (1,), np.uint8)
        draw.fill_polygons(im, v, s, np.array([255]))
        fills.append(im[..., 0])
        im = np.full(SIZE + (3,), 255, np.uint8)
        draw.polylines(im, v, s, False, np.array([255, 117, 69]))
        lines.append(im)
        im = np.full(SIZE + (3,), 255, np.uint8)
        for p in range(s.size - 1):
            draw.fill_polygons(im, v, s[p:p + 2], np.array([17, 17, 31]))
        draw.polylines(im, v, s, True, np.array([0, 255, 0]))
        lanes.append(im)
    return np.array(fills), np.array(lines), np.array(lanes)


OPENCV = textwrap.dedent("""
    import sys, numpy as np, cv2
    d = np.load(sys.argv[1]); v, s, c = d["verts"], d["starts"], d["bounds"]
    fills, lines, lanes = [], [], []
    for k in range(len(c) - 1):
        polys = [v[s[p]:s[p + 1]].astype(np.int32) for p in range(c[k], c[k + 1])]
        im = np.zeros(%(size)r, np.uint8)
        cv2.fillPoly(im, polys, color=255, shift=9, lineType=cv2.LINE_AA); fills.append(im)
        im = np.full(%(size)r + (3,), 255, np.uint8)
        cv2.polylines(im, polys, False, (255, 117, 69), shift=9, lineType=cv2.LINE_AA); lines.append(im)
        im = np.full(%(size)r + (3,), 255, np.uint8)
        for p in polys:
            cv2.fillPoly(im, [p], color=(17, 17, 31), shift=9, lineType=cv2.LINE_AA)
        cv2.polylines(im, polys, True, (0, 255, 0), shift=9, lineType=cv2.LINE_AA); lanes.append(im)
    np.savez(sys.argv[2], fills=np.array(fills), lines=np.array(lines), lanes=np.array(lanes))
""") % {"size": SIZE}


def test_pixels_equal_opencvs(tmp_path):
    if not ORACLE_PYTHON.is_file():
        pytest.skip(f"l5kit oracle venv absent: no {ORACLE_PYTHON} (python benchmarks/l5kit_oracle/oracle_venv.py builds it)")
    verts, starts, bounds = random_polygons(3, 300)
    np.savez(tmp_path / "cases.npz", verts=verts, starts=starts, bounds=bounds)
    subprocess.run([str(ORACLE_PYTHON), "-c", OPENCV, str(tmp_path / "cases.npz"), str(tmp_path / "cv.npz")],
                   check=True, timeout=300)
    expected = np.load(tmp_path / "cv.npz")
    fills, lines, lanes = ours(verts, starts, bounds)
    assert expected["fills"].any() and expected["lines"].min() < 255
    np.testing.assert_array_equal(fills, expected["fills"])
    np.testing.assert_array_equal(lines, expected["lines"])
    np.testing.assert_array_equal(lanes, expected["lanes"])


WITHOUT_NUMBA = textwrap.dedent("""
    import sys
    sys.modules["numba"] = None  # import numba fails: the plain-Python path
    sys.path.insert(0, sys.argv[3])
    import numpy as np
    from pytest_driveeval.raster import draw
    assert not draw.AVAILABLE
    from test_draw import ours, random_polygons
    np.savez(sys.argv[1], *ours(*random_polygons(int(sys.argv[2]), 25)))
""")


def test_the_plain_python_path_draws_the_same(tmp_path):
    pytest.importorskip("numba")
    out = tmp_path / "plain.npz"
    subprocess.run([sys.executable, "-c", WITHOUT_NUMBA, str(out), "5", str(Path(__file__).parent)], check=True,
                   timeout=600)
    plain = np.load(out)
    for got, expected in zip(ours(*random_polygons(5, 25)), (plain[f"arr_{i}"] for i in range(3))):
        assert expected.any()
        np.testing.assert_array_equal(got, expected)


def test_subpixel_truncates_toward_zero_like_astype_int():
    np.testing.assert_array_equal(draw.subpixel(np.array([[1.0015, -1.0015]])), [[512, -512]])
