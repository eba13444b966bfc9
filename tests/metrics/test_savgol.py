"""The score's own Savitzky-Golay filter gives scipy.signal.savgol_filter's numbers (mode interp), for
the windows, orders and derivatives nuplan-devkit's comfort metrics use, even windows included."""
import numpy as np
import pytest

from pytest_driveeval.metrics.nuplan_score.savgol import savgol

scipy_signal = pytest.importorskip("scipy.signal")


@pytest.mark.parametrize("samples", [4, 5, 8, 9, 15, 16, 41, 151])
@pytest.mark.parametrize("window, order, deriv", [(8, 2, 0), (15, 2, 1), (5, 2, 1), (5, 3, 2), (7, 2, 2)])
def test_equals_scipy(samples, window, order, deriv):
    window = min(window, samples)
    if order >= window:
        pytest.skip("scipy refuses it too")
    signal = np.random.default_rng(samples * 100 + window).normal(size=samples) * 3.0
    expected = scipy_signal.savgol_filter(signal, window, order, deriv=deriv, delta=0.1)
    assert np.allclose(savgol(signal, window, order, deriv, 0.1), expected, rtol=1e-10, atol=1e-10)


def test_too_few_samples_is_refused():
    with pytest.raises(ValueError, match="polyorder < window <= samples"):
        savgol(np.zeros(3), 4, 2)
