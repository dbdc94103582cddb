"""Pre-processing: outlier rejection, moving average, derivatives with automatic regularisation."""

from __future__ import annotations

import numpy as np
import pytest

from aeropend_ident.errors import IdentificationError
from aeropend_ident.sindy.preprocess import differentiate, hampel, moving_average

T = np.arange(0.0, 4.0, 2.048e-3)
Y = np.sin(2.0 * T) + 0.3 * np.sin(5.0 * T)
DY = 2.0 * np.cos(2.0 * T) + 1.5 * np.cos(5.0 * T)


def test_hampel_removes_dropouts() -> None:
    y = Y.copy()
    y[[100, 700, 1500]] = 0.0 - 3.0  # potentiometer drop-outs
    cleaned, out = hampel(y, window=7, k=5.0)
    assert set(np.flatnonzero(out)) == {100, 700, 1500}
    assert np.max(np.abs(cleaned - Y)) < 0.01


def test_moving_average_thesis_window() -> None:
    assert np.allclose(moving_average(np.ones(100), 40), 1.0)
    assert moving_average(Y, 40).shape == Y.shape


def test_savgol_window_chosen_by_cross_validation() -> None:
    rng = np.random.default_rng(0)
    noisy = Y + rng.normal(0.0, 0.01, Y.size)
    d = differentiate(T, noisy, method="savgol")
    assert d.params["window"] > 21  # noise pushes the CV choice to a wide window
    core = slice(200, -200)
    assert np.sqrt(np.mean((d.dydt - DY)[core] ** 2)) < 0.05
    clean = differentiate(T, Y, method="savgol")
    assert clean.params["window"] >= 5
    assert np.max(np.abs((clean.dydt - DY)[core])) < 1e-3
    fd = differentiate(T, Y, method="finite_difference")
    assert np.max(np.abs((fd.dydt - DY)[5:-5])) < 1e-4
    sp = differentiate(T, Y, method="spline", s=1e-6)
    assert np.max(np.abs((sp.dydt - DY)[core])) < 1e-2


def test_errors() -> None:
    with pytest.raises(IdentificationError, match="method = 'magic'"):
        differentiate(T, Y, method="magic")
    with pytest.raises(IdentificationError, match="non-finite"):
        differentiate(T[:10], np.r_[np.nan, Y[1:10]])
    with pytest.raises(IdentificationError, match="odd integer"):
        hampel(Y, window=4)
