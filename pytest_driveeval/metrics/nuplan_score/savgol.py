"""Savitzky-Golay smoothing and derivatives with scipy.signal.savgol_filter's results for its default
``mode="interp"``, even windows included (nuplan-devkit smooths accelerations over 8 samples).
Written out because importing scipy.signal costs about two seconds per process, more than scoring
a hundred scenes.

Inside, each sample is the least-squares polynomial of the window around it, evaluated where scipy
evaluates it (the window's middle; for an even window, half a sample after the sample's own place,
as scipy's convolution aligns it); the first and last ``window // 2`` samples come from the
polynomial fitted to the end windows.  Both are linear in the samples: the weights are made once
per (window, order, derivative, spacing).
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np


@lru_cache(maxsize=64)
def _weights(window: int, polyorder: int, deriv: int, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """(inner weights (window,), edge weights (window, window): row j gives sample j of an end window)."""
    half = window // 2
    centre = half - 0.5 if window % 2 == 0 else float(half)
    powers = np.arange(polyorder + 1)
    design = (np.arange(window) - centre)[None, :] ** powers[:, None]
    wanted = np.zeros(polyorder + 1)
    wanted[deriv] = math.factorial(deriv) / delta ** deriv
    inner = np.linalg.lstsq(design, wanted, rcond=None)[0]
    # The end windows' polynomial, c = pinv(V) x, differentiated deriv times and evaluated at each sample.
    t = np.arange(window, dtype=np.float64)
    fit = np.linalg.pinv(t[:, None] ** powers[None, :])
    scale = np.array([math.factorial(p) / math.factorial(p - deriv) if p >= deriv else 0.0 for p in powers])
    at = np.where(powers >= deriv, t[:, None] ** np.maximum(powers - deriv, 0)[None, :], 0.0) * scale
    return inner, at @ fit / delta ** deriv


def savgol(signal: np.ndarray, window: int, polyorder: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """``signal`` (..., n) filtered along its last axis.  Each row's numbers are those it gets alone: every
    sum runs over one row's window in one order, whatever the rows beside it (several scenes' signals
    are filtered in one call)."""
    x = np.ascontiguousarray(signal, dtype=np.float64)
    n = x.shape[-1]
    if not polyorder < window <= n:
        raise ValueError(f"a Savitzky-Golay filter needs polyorder < window <= samples, got {polyorder}, {window}, {n}")
    inner, edge = _weights(window, polyorder, deriv, float(delta))
    half = window // 2
    first = half - 1 if window % 2 == 0 else half  # the window of sample i starts at i - first
    out = np.empty(x.shape)
    # Sample i's window as row i of a view over each signal (sliding_window_view's, built directly: it costs
    # several times the product here).  Such a view is no BLAS operand: numpy sums each window in order.
    rows = x.reshape(-1, n)
    windows = np.ndarray((len(rows), n - window + 1, window), dtype=np.float64, buffer=rows,
                         strides=(rows.strides[0], x.itemsize, x.itemsize))
    out.reshape(-1, n)[:, first:first + n - window + 1] = windows @ inner
    # The end windows' samples: each a sum over its window's products (a reduction along the last axis)
    out[..., :half] = (edge[:half] * x[..., None, :window]).sum(axis=-1)
    out[..., n - half:] = (edge[window - half:] * x[..., None, n - window:]).sum(axis=-1)
    return out
