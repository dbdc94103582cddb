"""Free decay of the rod: swing frequency and the envelope's shape (exponential vs linear decay).

With the input constant (motor off, or a held command) the rod swings about its equilibrium θ_eq
and decays. Per half swing the peak-to-peak half amplitude h_k falls as

    h_{k+1} = q·h_k − d,    q = exp(−σ·T/2),  d = 2·(T_f/J)/ω_n²

(viscous friction c/J = 2σ shrinks it by a constant factor: an exponential envelope; dry friction
T_f/J by a constant step: a linear envelope). A least-squares line through (h_k, h_{k+1}) gives q
and d with their standard errors; the period T from the extrema gives ω_d = 2π/T and
ω_n² = ω_d² + σ². Linearised about θ_eq, ω_n² = (mgd/J)·cos θ_eq; the amplitude correction of the
pendulum's period (T ≈ T₀·(1 + A²/16)) is applied with the mean amplitude. These are the starting
values and the structure (is there dry friction?) for ``rig fit``, whose output-error fit of the
same recording then gives the final values and uncertainties.

No rclpy, pure NumPy/SciPy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import find_peaks

from aeropend_ident.errors import StaticEstimationError

#: Fewest extrema (half swings + 1) the analysis needs.
MIN_EXTREMA = 4
#: Dry friction is reported when its step d exceeds this many standard errors.
SIGNIFICANCE = 3.0


@dataclass(frozen=True)
class DecayEnvelope:
    """What a free decay says about the rod.

    Attributes
    ----------
    period : float
        Mean swing period T [s].
    omega_n : float
        Undamped natural frequency about θ_eq [rad/s].
    theta_eq : float
        Equilibrium angle [rad] (mean of the swing midpoints).
    mgd_over_J : float
        Gravity term [1/s²]: ω_n²/cos θ_eq with the amplitude correction.
    c_over_J : float
        Viscous friction 2σ [1/s] (0 when the envelope is linear).
    coulomb_over_J, coulomb_std : float
        Dry friction T_f/J [rad/s²] from the linear step d, and its standard error.
    ratio, step : float
        q and d of the half-swing recursion (d in rad).
    envelope : str
        ``"exponential"``, ``"linear"`` or ``"exponential + linear"``.
    extrema : int
        Number of extrema used.
    """

    period: float
    omega_n: float
    theta_eq: float
    mgd_over_J: float
    c_over_J: float
    coulomb_over_J: float
    coulomb_std: float
    ratio: float
    step: float
    envelope: str
    extrema: int

    @property
    def dry_friction(self) -> bool:
        """Whether the envelope shows dry friction (its step is significant)."""
        return "linear" in self.envelope


def _extrema(theta: np.ndarray, noise: float) -> np.ndarray:
    """Indices of alternating maxima and minima (the more extreme kept of two of a kind)."""
    k = 5
    smooth = np.convolve(theta, np.ones(k) / k, mode="same")
    smooth[: k // 2] = theta[: k // 2]
    smooth[-(k // 2):] = theta[-(k // 2):]
    prom = max(5.0 * noise, 1e-6 * max(float(np.ptp(theta)), 1e-12))
    hi, _ = find_peaks(smooth, prominence=prom)
    lo, _ = find_peaks(-smooth, prominence=prom)
    marks = sorted([(int(i), 1) for i in hi] + [(int(i), -1) for i in lo])
    out: list[tuple[int, int]] = []
    for i, s in marks:
        if out and out[-1][1] == s:
            if s * smooth[i] > s * smooth[out[-1][0]]:
                out[-1] = (i, s)
            continue
        out.append((i, s))
    return np.array([i for i, _ in out], dtype=int)


def analyse_decay(t: np.ndarray, theta: np.ndarray, noise: float = 0.0) -> DecayEnvelope:
    """Swing frequency and envelope of a free decay (module docstring).

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample times [s], increasing.
    theta : ndarray, shape (N,)
        Angle [rad], model frame (0 = hanging).
    noise : float
        Measurement noise σ of θ [rad] (extrema must stand out by 5σ).

    Raises
    ------
    StaticEstimationError
        On arrays of different lengths, non-finite values, or fewer than :data:`MIN_EXTREMA`
        extrema (the rod hardly swings: release it from a larger angle).
    """
    t = np.asarray(t, dtype=float)
    th = np.asarray(theta, dtype=float)
    if t.shape != th.shape or t.ndim != 1:
        raise StaticEstimationError(f"free decay: t {t.shape} and θ {th.shape} must be 1-D of one length")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(th))):
        raise StaticEstimationError("free decay: t and θ must be finite")
    idx = _extrema(th, noise)
    if idx.size < MIN_EXTREMA:
        raise StaticEstimationError(
            f"free decay: only {idx.size} swing extrema stand out of the noise ({noise:.2g} rad); "
            f"the analysis needs {MIN_EXTREMA}: release the rod from a larger angle and record longer")
    p, tp = th[idx], t[idx]
    half = 0.5 * np.abs(np.diff(p))            # h_k, one per half swing
    mids = 0.5 * (p[1:] + p[:-1])
    period = 2.0 * float(np.mean(np.diff(tp)))
    theta_eq = float(np.mean(mids))
    x, y = half[:-1], half[1:]
    design = np.column_stack([x, -np.ones_like(x)])
    if x.size >= 3:
        coef, *_ = np.linalg.lstsq(design, y, rcond=None)
        q, d = float(coef[0]), float(coef[1])
        res = y - design @ coef
        s2 = float(res @ res) / max(x.size - 2, 1)
        cov = s2 * np.linalg.pinv(design.T @ design)
        d_std = math.sqrt(max(cov[1, 1], 0.0))
    else:
        q, d, d_std = float(np.mean(y / x)), 0.0, math.inf
    dry = d > SIGNIFICANCE * d_std and d > 0.0
    if not dry:
        q = float(np.exp(np.mean(np.log(np.maximum(y, 1e-12) / np.maximum(x, 1e-12)))))
        d = 0.0
    q = min(max(q, 1e-6), 1.0)
    sigma = -2.0 * math.log(q) / period
    omega_d = 2.0 * math.pi / period
    omega_n2 = omega_d**2 + sigma**2
    amp = float(np.mean(half))
    omega_0 = math.sqrt(omega_n2) * (1.0 + amp**2 / 16.0)
    mgd = omega_0**2 / max(math.cos(theta_eq), 1e-3)
    viscous = sigma > 0.0 and (not dry or q < 0.999)
    kind = "exponential + linear" if dry and viscous else ("linear" if dry else "exponential")
    return DecayEnvelope(
        period=period, omega_n=math.sqrt(omega_n2), theta_eq=theta_eq, mgd_over_J=mgd,
        c_over_J=2.0 * sigma, coulomb_over_J=0.5 * d * omega_n2 if dry else 0.0,
        coulomb_std=0.5 * d_std * omega_n2, ratio=q, step=d, envelope=kind, extrema=int(idx.size),
    )
