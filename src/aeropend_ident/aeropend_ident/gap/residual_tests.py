"""The statistical tests of the where-analysis: is a residual white, correlated with the input, late?

Ljung-Box whiteness (:func:`ljung_box`, after AR prewhitening), the input cross-correlation
(:func:`input_cross_correlation`), the timing lag a residual shows (:func:`timing_lag_seen`,
:func:`alignment_lag`), the residual's share per frequency band (:func:`frequency_bands`), the
repeatability of repeated holds (:func:`repeatability`, :func:`constant_holds`), and the smoothing
and derivative helpers they share. Used per recording by :mod:`aeropend_ident.gap.where`. No rclpy
import: this module runs without ROS.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import signal, stats

from aeropend_ident.gap.holds import MIN_HOLD

#: Significance level of the Ljung-Box and cross-correlation tests.
ALPHA = 0.01


#: Savitzky-Golay window [s] of the equation-error derivatives (at least 7 samples).
SG_WINDOW = 0.08


#: Lags of the Ljung-Box test (capped at N/5).
LB_LAGS = 20


#: Order of the AR model that prewhitens the input for the cross-correlation test.
PREWHITEN_ORDER = 10


#: Largest lag [s] searched for the input cross-correlation peak and the alignment lag.
MAX_LAG = 1.0


def _sg_window(n: int, dt: float, seconds: float = SG_WINDOW) -> int:
    w = max(7, round(seconds / dt) | 1)
    if w > n:
        w = n if n % 2 else n - 1
    return w


def _smooth(y: np.ndarray, w: int, deriv: int = 0, dt: float = 1.0) -> np.ndarray:
    return signal.savgol_filter(y, w, 3, deriv=deriv, delta=dt, mode="interp")


def _deriv_gain(w: int, dt: float, deriv: int) -> float:
    """‖h‖₂ of the Savitzky-Golay derivative filter: noise gain per unit σ of white input noise."""
    return float(np.linalg.norm(signal.savgol_coeffs(w, 3, deriv=deriv, delta=dt)))


def _group_r2(residual: np.ndarray, groups: dict[str, list[np.ndarray]]) -> dict[str, float]:
    """R² of least squares of ``residual`` on each group's columns alone (uncentred: an offset
    must be explained by a column)."""
    ss = float(residual @ residual)
    out: dict[str, float] = {}
    if ss <= 0.0:
        return out
    for name, cols in groups.items():
        a = np.column_stack(cols)
        if not np.all(np.isfinite(a)) or np.allclose(a, 0.0):
            continue
        coef, *_ = np.linalg.lstsq(a, residual, rcond=None)
        fitted = a @ coef
        out[name] = float(np.clip(1.0 - float((residual - fitted) @ (residual - fitted)) / ss, 0.0, 1.0))
    return out


def ljung_box(residual: np.ndarray, lags: int = LB_LAGS) -> dict[str, Any]:
    """Ljung-Box portmanteau test of whiteness (Ljung & Box 1978).

    Q = N(N+2)·Σ_{k=1}^{h} ρ_k²/(N−k) ~ χ²(h) under "white".

    Parameters
    ----------
    residual : ndarray, shape (N,)
    lags : int
        h, capped at N/5.

    Returns
    -------
    dict
        ``q``, ``lags``, ``p_value``, ``white`` (p >= :data:`ALPHA`), ``acf`` (ρ_1..ρ_h),
        ``max_abs_acf``, ``max_lag`` (lag of the largest |ρ_k|).
    """
    e = np.asarray(residual, dtype=float) - float(np.mean(residual))
    n = e.size
    h = int(max(1, min(lags, n // 5)))
    c0 = float(e @ e)
    if c0 <= 0.0:
        return {
            "q": 0.0,
            "lags": h,
            "p_value": 1.0,
            "white": True,
            "acf": [0.0] * h,
            "max_abs_acf": 0.0,
            "max_lag": None,
        }
    acf = np.array([float(e[k:] @ e[:-k]) / c0 for k in range(1, h + 1)])
    q = float(n * (n + 2) * np.sum(acf**2 / (n - np.arange(1, h + 1))))
    p = float(stats.chi2.sf(q, h))
    return {
        "q": q,
        "lags": h,
        "p_value": p,
        "white": p >= ALPHA,
        "acf": acf.tolist(),
        "max_abs_acf": float(np.max(np.abs(acf))),
        "max_lag": int(np.argmax(np.abs(acf)) + 1),
    }


def _ar_prewhiten(u: np.ndarray, order: int) -> np.ndarray:
    """AR(order) coefficients a (u_k ≈ Σ a_j u_{k−j}) by least squares."""
    n = u.size
    if n <= 3 * order:
        return np.zeros(0)
    x = np.column_stack([u[order - j - 1 : n - j - 1] for j in range(order)])
    a, *_ = np.linalg.lstsq(x, u[order:], rcond=None)
    return a


def lagged_products(x: np.ndarray, y: np.ndarray, m: int) -> np.ndarray:
    """Σ_t x_t·y_{t+k} for k = −m..m (shape (2m + 1,)) of two signals of one length, by FFT
    (:func:`scipy.signal.correlate`): the same sums as a loop of dot products over the lags, to
    rounding, in O(N log N)."""
    n = x.size
    full = signal.correlate(y, x, mode="full", method="fft")
    return full[n - 1 - m: n + m]


def input_cross_correlation(
    u: np.ndarray, e: np.ndarray, dt: float, max_lag: float = MAX_LAG, order: int = PREWHITEN_ORDER
) -> dict[str, Any]:
    """Cross-correlation test between the input and the residual (Ljung, System Identification §16.6).

    The input is prewhitened by an AR(``order``) model fitted to it and the same filter is applied
    to the residual; then ρ_ue(k) = corr(u_{t−k}, e_t) for k = −M..M (M = ``max_lag``/dt) and
    S = N·Σ_{k=0}^{M} ρ_ue(k)² ~ χ²(M+1) under "residual uncorrelated with past inputs".

    Returns
    -------
    dict
        ``max_abs`` (largest |ρ_ue|), ``peak_lag_samples`` (its k; > 0: the residual follows the
        input by k samples), ``peak_lag_s``, ``bound`` (99 % band 2.58/√N), ``chi2``, ``p_value``,
        ``correlated`` (p < :data:`ALPHA`), ``lags`` and ``rho`` (for plotting).
    """
    u = np.asarray(u, dtype=float) - float(np.mean(u))
    e = np.asarray(e, dtype=float) - float(np.mean(e))
    a = _ar_prewhiten(u, order)
    if a.size:
        filt = np.concatenate(([1.0], -a))
        u = signal.lfilter(filt, [1.0], u)[order:]
        e = signal.lfilter(filt, [1.0], e)[order:]
    n = u.size
    su, se = float(np.std(u)), float(np.std(e))
    m = int(min(round(max_lag / dt), n // 4))
    if su == 0.0 or se == 0.0 or m < 1:
        return {
            "max_abs": 0.0,
            "peak_lag_samples": None,
            "peak_lag_s": None,
            "bound": 2.58 / math.sqrt(max(n, 1)),
            "chi2": 0.0,
            "p_value": 1.0,
            "correlated": False,
            "lags": [],
            "rho": [],
        }
    lags = np.arange(-m, m + 1)
    rho = lagged_products(u, e, m) / (n * su * se)
    pos = rho[m:]
    s = float(n * np.sum(pos**2))
    p = float(stats.chi2.sf(s, m + 1))
    j = int(np.argmax(np.abs(rho)))
    return {
        "max_abs": float(abs(rho[j])),
        "peak_lag_samples": int(lags[j]),
        "peak_lag_s": float(lags[j] * dt),
        "bound": 2.58 / math.sqrt(n),
        "chi2": s,
        "p_value": p,
        "correlated": p < ALPHA,
        "lags": lags.tolist(),
        "rho": rho.tolist(),
    }


def timing_lag_seen(alignment: dict[str, Any]) -> bool:
    """True when an :func:`alignment_lag` result shows a clear lead or lag (≥ 1 sample).

    Clear: peak correlation above 0.5 and not on the search limit. The effect diagnosis then also
    confirms the timing effects (motor time constant, actuator lag, input delay).
    """
    return bool(
        alignment.get("lag_samples")
        and abs(alignment["lag_samples"]) >= 1
        and alignment.get("correlation", 0) > 0.5
        and not alignment.get("at_search_limit")
    )


def alignment_lag(
    measured: np.ndarray, simulated: np.ndarray, dt: float, max_lag: float = MAX_LAG
) -> dict[str, Any]:
    """Lag that best aligns the simulated with the measured signal's rate of change.

    Correlates the Savitzky-Golay derivatives of both (the same filter, so no phase bias);
    the measured signal lagging the simulated one by d gives a peak at +d. A pure input delay
    appears here exactly; a dynamic mismatch (slower poles) also shifts it, less sharply.

    Returns
    -------
    dict
        ``lag_samples``, ``lag_s``, ``correlation`` (normalised, at the peak),
        ``correlation_at_zero``, ``at_search_limit`` (the peak lies on the ±``max_lag`` edge:
        no meaningful alignment).
    """
    n = measured.size
    w = _sg_window(n, dt)
    a = _smooth(measured, w, 1, dt)
    b = _smooth(simulated, w, 1, dt)
    a, b = a - a.mean(), b - b.mean()
    m = int(min(round(max_lag / dt), n // 4))
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na == 0.0 or nb == 0.0 or m < 1:
        return {
            "lag_samples": 0,
            "lag_s": 0.0,
            "correlation": 0.0,
            "correlation_at_zero": 0.0,
            "at_search_limit": False,
        }
    c = lagged_products(b, a, m) / (na * nb)
    j = int(np.argmax(c))
    best, best_k, c0 = float(c[j]), j - m, float(c[m])
    return {
        "lag_samples": int(best_k),
        "lag_s": float(best_k * dt),
        "correlation": float(best),
        "correlation_at_zero": float(c0),
        "at_search_limit": bool(abs(best_k) == m),
    }


def frequency_bands(
    residual: np.ndarray, measured: np.ndarray, dt: float, f_natural: float
) -> list[dict[str, Any]]:
    """Residual power per frequency band (Welch PSD), relative to the measured signal's.

    Bands: quasi-static (< 0.1 Hz), slow (0.1 Hz – f_n/2), resonance (f_n/2 – 2 f_n), fast
    (2 f_n – Nyquist), f_n = the nominal pendulum's natural frequency [Hz] (bands collapse when
    their edges cross).

    Returns
    -------
    list of dict
        ``{band, f_lo, f_hi (Hz), residual_power_fraction, residual_rms, measured_rms, ratio}``
        (``ratio`` = residual RMS / measured RMS in that band).
    """
    n = residual.size
    nper = int(min(n, max(64, 2 ** math.ceil(math.log2(max(20.0 / dt, 64))))))
    f, pe = signal.welch(residual - residual.mean(), fs=1.0 / dt, nperseg=nper)
    _, pm = signal.welch(measured - measured.mean(), fs=1.0 / dt, nperseg=nper)
    nyq = 0.5 / dt
    edges = [
        ("quasi-static", 0.0, 0.1),
        ("slow", 0.1, 0.5 * f_natural),
        ("resonance", 0.5 * f_natural, 2.0 * f_natural),
        ("fast", 2.0 * f_natural, nyq),
    ]
    df = float(f[1] - f[0]) if f.size > 1 else 1.0
    total = float(np.sum(pe)) * df
    out = []
    for name, lo, hi in edges:
        lo, hi = max(lo, 0.0), min(hi, nyq)
        if hi <= lo:
            continue
        sel = (f >= lo) & (f < hi) if hi < nyq else (f >= lo)
        p_e = float(np.sum(pe[sel])) * df
        p_m = float(np.sum(pm[sel])) * df
        out.append(
            {
                "band": name,
                "f_lo_hz": lo,
                "f_hi_hz": hi,
                "residual_power_fraction": p_e / total if total > 0 else 0.0,
                "residual_rms": math.sqrt(p_e),
                "measured_rms": math.sqrt(p_m),
                "ratio": math.sqrt(p_e / p_m) if p_m > 0 else math.inf,
            }
        )
    return out


def repeatability(holds: Sequence[dict[str, Any]], min_repeats: int = 3) -> list[dict[str, Any]]:
    """Spread and drift of the steady angle over repeated holds at the same duty cycle.

    A deterministic model repeats itself; a rig whose steady angle at the same duty wanders from
    repeat to repeat has a time-varying effect (sensor drift, temperature, battery) that no
    constant parameter can fix.

    Returns
    -------
    list of dict
        Per duty level with at least ``min_repeats`` holds: ``duty``, ``count``,
        ``measured_spread`` and ``simulated_spread`` (max − min of the steady angles [rad]),
        ``measured_drift_per_min`` (least-squares slope against the hold's end time [rad/min]).
    """
    levels: dict[float, list[dict[str, Any]]] = {}
    for h in holds:
        levels.setdefault(round(h["duty"], 9), []).append(h)
    out = []
    for duty, hs in sorted(levels.items()):
        if len(hs) < min_repeats:
            continue
        tm = np.array([h["t_end_s"] for h in hs]) / 60.0
        ym = np.array([h["theta_meas_ss"] for h in hs])
        ys = np.array([h["theta_sim_ss"] for h in hs])
        slope = float(np.polyfit(tm, ym, 1)[0]) if np.ptp(tm) > 0 else 0.0
        out.append(
            {
                "duty": duty,
                "count": len(hs),
                "measured_spread": float(np.ptp(ym)),
                "simulated_spread": float(np.ptp(ys)),
                "measured_drift_per_min": slope,
            }
        )
    return out


def constant_holds(
    t: np.ndarray,
    duty: np.ndarray,
    theta: np.ndarray,
    sim: np.ndarray,
    min_hold: float = MIN_HOLD,
    tail: float = 0.25,
    limit: int = 60,
) -> list[dict[str, Any]]:
    """Steady-state error per constant-duty hold (≥ ``min_hold`` s): means over its last ``tail``."""
    dt = float(t[1] - t[0])
    change = np.flatnonzero(np.diff(duty) != 0.0) + 1
    starts = np.concatenate(([0], change))
    stops = np.concatenate((change, [duty.size]))
    out = []
    for a, b in zip(starts, stops, strict=True):
        if (b - a) * dt < min_hold:
            continue
        c = b - max(1, round(tail * (b - a)))
        out.append(
            {
                "duty": float(duty[a]),
                "t_start_s": float(t[a]),
                "t_end_s": float(t[b - 1]),
                "theta_meas_ss": float(np.mean(theta[c:b])),
                "theta_sim_ss": float(np.mean(sim[c:b])),
                "error": float(np.mean(sim[c:b] - theta[c:b])),
            }
        )
        if len(out) >= limit:
            break
    return out

