"""Pre-processing for identification: outliers, smoothing and derivatives (thesis §5.3.1).

* :func:`hampel` — outlier rejection (median ± k·MAD in a sliding window), e.g. potentiometer
  drop-outs;
* :func:`moving_average` — the thesis' moving-average filter (40 samples in §5.3.1);
* :func:`differentiate` — derivatives by finite differences (``pysindy.FiniteDifference``),
  Savitzky-Golay (``scipy.signal.savgol_filter``) with the window chosen automatically by
  leave-every-other-sample-out cross-validation of the smoother, total-variation
  regularisation (Chartrand's iterative TVRegDiff, ``pynumdiff``'s ``iterative_velocity``,
  which needs no convex solver) with the weight γ chosen by the same cross-validation, or the
  smoothers of the
  ``derivative`` package through ``pysindy.SINDyDerivative`` (``spline``, ``kalman``,
  ``trend_filtered`` with their parameters given);
* :func:`add_derivatives` — the same for every target state of an :class:`IdentData`.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pysindy as ps
from scipy.ndimage import median_filter, uniform_filter1d
from scipy.signal import savgol_filter

from aeropend_ident.errors import IdentificationError
from aeropend_ident.sindy.model import IdentData

DERIVATIVE_METHODS = ("finite_difference", "savgol", "tv", "spline", "kalman", "trend_filtered")
#: Candidate TV weights γ (pynumdiff ``iterative_velocity``, on the signal's own scale).
TV_GAMMAS = (1e-4, 1e-3, 1e-2, 1e-1)


def _signal(name: str, y: np.ndarray) -> np.ndarray:
    a = np.asarray(y, dtype=float)
    if a.ndim != 1 or a.size < 5:
        raise IdentificationError(f"{name} must be 1-D with >= 5 samples, got shape {a.shape}")
    bad = ~np.isfinite(a)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise IdentificationError(f"{name} has {int(bad.sum())} non-finite value(s), first at sample {first}")
    return a


def hampel(y: np.ndarray, window: int = 7, k: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Replace outliers by the local median (Hampel filter).

    A sample is an outlier when |y − median| > k·σ̂, with σ̂ = 1.4826·MAD of the deviations
    from the running median over a centred window of ``window`` samples, floored at 1.4826·median|Δy|
    over the whole record (so smooth extrema of noise-free data, where the local MAD vanishes,
    are not flagged).

    Returns
    -------
    cleaned : ndarray, shape (N,)
    outliers : ndarray of bool, shape (N,)
    """
    a = _signal("y", y)
    if window < 3 or window % 2 == 0:
        raise IdentificationError(f"window = {window!r} must be an odd integer >= 3")
    med = median_filter(a, size=window, mode="nearest")
    mad = median_filter(np.abs(a - med), size=window, mode="nearest") * 1.4826
    dev = np.abs(a - med)
    floor = 1.4826 * float(np.median(np.abs(np.diff(a)))) + 1e-12 * (float(np.max(np.abs(a))) + 1.0)
    out = dev > k * np.maximum(mad, floor)
    cleaned = np.where(out, med, a)
    return cleaned, out


def moving_average(y: np.ndarray, window: int = 40) -> np.ndarray:
    """Centred moving average over ``window`` samples (thesis §5.3.1 uses 40)."""
    a = _signal("y", y)
    if window < 1:
        raise IdentificationError(f"window = {window!r} must be >= 1")
    return uniform_filter1d(a, size=window, mode="nearest")


@dataclass(frozen=True)
class Derivative:
    """A derivative estimate and how it was made.

    Attributes
    ----------
    dydt : ndarray, shape (N,)
    smooth : ndarray, shape (N,)
        The smoothed signal (the input for finite differences).
    method : str
    params : dict
        Parameters used (e.g. the chosen Savitzky-Golay window and its CV score).
    """

    dydt: np.ndarray
    smooth: np.ndarray
    method: str
    params: dict[str, Any]


def _savgol_cv(a: np.ndarray, order: int, windows: Sequence[int]) -> tuple[int, dict[int, float]]:
    """Window minimising the error of predicting odd samples from the smoothed even samples."""
    even, odd = a[0::2], a[1::2]
    n = min(even.size - 1, odd.size)
    scores: dict[int, float] = {}
    for w in windows:
        half = (w // 2) | 1  # the same time span on the half-rate signal, odd
        if half <= order:
            half = (order + 1) | 1
        if half >= even.size:
            continue
        s = savgol_filter(even, half, order, mode="interp")
        pred = 0.5 * (s[:n] + s[1 : n + 1])
        scores[w] = float(np.mean((pred - odd[:n]) ** 2))
    if not scores:
        raise IdentificationError(f"signal of {a.size} samples too short for windows {list(windows)}")
    return min(scores, key=lambda w: scores[w]), scores


def _tv(a: np.ndarray, dt: float, gamma: float, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """TV-regularised derivative on the signal's unit scale (γ is dimensionless)."""
    from pynumdiff.total_variation_regularization import iterative_velocity

    scale = float(np.std(a)) or 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        x_hat, d = iterative_velocity(a / scale, dt, iterations, gamma, cg_maxiter=1000, scale="large")
    return np.asarray(x_hat) * scale, np.asarray(d) * scale


def _tv_cv(a: np.ndarray, dt: float, gammas: Sequence[float], iterations: int
           ) -> tuple[float, dict[float, float]]:
    """γ minimising the error of predicting odd samples from the TV fit of the even ones.

    The even samples are differentiated with weight γ, the derivative integrated
    (trapezoid, constant fitted) and each odd sample predicted as the mean of its two
    neighbours on that reconstruction; the score is the mean squared prediction error.
    """
    even, odd = a[0::2], a[1::2]
    n = min(even.size - 1, odd.size)
    scores: dict[float, float] = {}
    for g in gammas:
        _, d = _tv(even, 2 * dt, g, iterations)
        rec = np.concatenate(([0.0], np.cumsum(0.5 * (d[1:] + d[:-1]) * 2 * dt)))
        rec += float(np.mean(even - rec))
        pred = 0.5 * (rec[:n] + rec[1 : n + 1])
        scores[g] = float(np.mean((pred - odd[:n]) ** 2))
    return min(scores, key=lambda g: scores[g]), scores


def differentiate(t: np.ndarray, y: np.ndarray, method: str = "savgol", window: int | None = None,
                  order: int = 3, **kwargs: Any) -> Derivative:
    """Time derivative of a uniformly sampled signal.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Uniform sample times [s].
    y : ndarray, shape (N,)
    method : {"finite_difference", "savgol", "spline", "kalman", "trend_filtered"}
        ``finite_difference``: second-order centred differences (pysindy ``FiniteDifference``);
        ``savgol``: Savitzky-Golay of polynomial ``order``; with ``window=None`` the window is
        chosen among odd sizes 5…401 by cross-validation (never by hand); ``tv``: total-variation
        regularised derivative (pynumdiff ``iterative_velocity``, Chartrand 2011, no convex
        solver needed) on the signal scaled to unit standard deviation, with the weight γ chosen
        among ``gammas`` (default :data:`TV_GAMMAS`) by the same leave-every-other-sample-out
        cross-validation unless ``gamma=`` is given (``iterations=``, default 1; slow: seconds
        per thousand samples); the others go through
        ``pysindy.SINDyDerivative(kind=method, **kwargs)`` (e.g. ``s=`` for spline,
        ``alpha=`` for kalman/trend_filtered).

    Raises
    ------
    IdentificationError
        On bad input or an unknown method.
    """
    a = _signal("y", y)
    tt = _signal("t", t)
    if tt.size != a.size:
        raise IdentificationError(f"t has {tt.size} samples, y has {a.size}")
    dt = float(np.mean(np.diff(tt)))
    if method == "finite_difference":
        d = np.asarray(ps.FiniteDifference(order=2)(a, tt))
        return Derivative(d, a, method, {"order": 2})
    if method == "savgol":
        params: dict[str, Any] = {"order": order}
        if window is None:
            sizes = (5, 7, 9, 11, 15, 21, 31, 41, 61, 81, 121, 161, 241, 321, 401)
            cands = [w for w in sizes if w > order + 1]
            window, scores = _savgol_cv(a, order, cands)
            params["cv_scores"] = scores
        if window % 2 == 0 or window <= order:
            raise IdentificationError(f"savgol window = {window!r} must be odd and > order = {order}")
        params["window"] = window
        smooth = savgol_filter(a, window, order, mode="interp")
        d = savgol_filter(a, window, order, deriv=1, delta=dt, mode="interp")
        return Derivative(d, smooth, method, params)
    if method == "tv":
        iterations = int(kwargs.get("iterations", 1))
        gamma = kwargs.get("gamma")
        tv_params: dict[str, Any] = {"iterations": iterations}
        if gamma is None:
            gamma, tv_scores = _tv_cv(a, dt, kwargs.get("gammas", TV_GAMMAS), iterations)
            tv_params["cv_scores"] = tv_scores
        tv_params["gamma"] = float(gamma)
        smooth, d = _tv(a, dt, float(gamma), iterations)
        return Derivative(d, smooth, method, tv_params)
    if method in ("spline", "kalman", "trend_filtered"):
        diff = ps.SINDyDerivative(kind=method, **kwargs)
        d = np.asarray(diff(a[:, None], tt))[:, 0]
        sm = np.asarray(diff.smoothed_x_)[:, 0] if getattr(diff, "smoothed_x_", None) is not None else a
        return Derivative(d, sm, method, dict(kwargs))
    raise IdentificationError(f"derivative method = {method!r}; expected one of {DERIVATIVE_METHODS}")


def add_derivatives(data: IdentData, targets: Sequence[str] = ("theta", "theta_dot", "i_a", "omega_rotor"),
                    method: str = "savgol", smooth_variables: bool = False, **kwargs: Any) -> IdentData:
    """Copy of ``data`` with estimated derivatives of the target states.

    Parameters
    ----------
    smooth_variables : bool
        Also replace the targets' variables by the smoothed signals (the library is then
        evaluated on smoothed data, as in thesis §5.3.1).

    Raises
    ------
    IdentificationError
        If a target state is missing (named).
    """
    variables = dict(data.variables)
    derivs = dict(data.derivatives)
    for tg in targets:
        if tg not in variables:
            raise IdentificationError(
                f"{data.source}: cannot differentiate {tg}: not in the data (variables {sorted(variables)})"
            )
        r = differentiate(data.t, variables[tg], method=method, **kwargs)
        derivs[tg] = r.dydt
        if smooth_variables:
            variables[tg] = r.smooth
    src = f"{data.source}+d/dt({method})"
    return IdentData(t=data.t, variables=variables, derivatives=derivs, source=src)
