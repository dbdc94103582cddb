"""Static parameter estimators of thesis §4.4 (armature, back-EMF, H-bridge map, thrust law).

Every estimator takes plain arrays in SI units (or the thesis' units where a conversion is part
of the estimate, e.g. rotor speed in RPM for Table 4.2) and returns a frozen dataclass with the
estimate, its spread and the per-row values, so the thesis' tables can be reproduced row by row:

* :func:`armature_resistance` — R_a = v_a / i_a at stall (thesis Eq. 4.2, Table 4.1);
* :func:`armature_time_constant` — τ_e from a current step (63 % rule or an exponential fit),
  L_a = R_a·τ_e (thesis §4.4.2);
* :func:`back_emf_constant` — K_ω = (v_a − R_a·i_a)/ω at steady state (thesis §4.4.3,
  Table 4.2), in V/RPM and V·s/rad;
* :func:`fit_hbridge_map` — v_a(τ) = k0 + k1·sqrt(k2·τ + k3) (thesis Eq. 4.3) and its inverse;
* :func:`fit_thrust_law` — f = a·v_a² + b·v_a + c (thesis Eq. 4.4) and its inverse (Eq. 4.5).

No rclpy, no plotting: pure NumPy/SciPy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import curve_fit

from aeropend_ident.errors import StaticEstimationError

#: 1 RPM in rad/s (2π/60).
RPM_TO_RAD_S = 2.0 * math.pi / 60.0


def rpm_to_rad_s(rpm: np.ndarray | float) -> np.ndarray:
    """Speed in RPM -> rad/s (× 2π/60)."""
    return np.asarray(rpm, dtype=float) * RPM_TO_RAD_S


def v_per_rpm_to_si(k_v_per_rpm: float) -> float:
    """Back-EMF constant in V/RPM -> V·s/rad (÷ 2π/60 = × 60/(2π))."""
    return float(k_v_per_rpm) / RPM_TO_RAD_S


def _vec(name: str, x: np.ndarray | list[float], n_min: int = 1) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 1:
        raise StaticEstimationError(f"{name} must be 1-D, got shape {a.shape}")
    if a.size < n_min:
        raise StaticEstimationError(f"{name} needs at least {n_min} value(s), got {a.size}")
    bad = ~np.isfinite(a)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise StaticEstimationError(f"{name}[{k}] = {float(a[k])!r} is not finite")
    return a


def _same_length(**arrays: np.ndarray) -> None:
    sizes = {k: v.size for k, v in arrays.items()}
    if len(set(sizes.values())) != 1:
        raise StaticEstimationError(f"arrays must have the same length, got {sizes}")


@dataclass(frozen=True)
class Estimate:
    """A parameter estimated from several rows.

    Attributes
    ----------
    value : float
        Mean of the per-row estimates.
    std : float
        Sample standard deviation (ddof = 1) of the per-row estimates (0 for one row).
    rows : ndarray, shape (M,)
        Per-row estimates.
    unit : str
        Unit of ``value``/``std``/``rows``.
    """

    value: float
    std: float
    rows: np.ndarray
    unit: str

    @classmethod
    def from_rows(cls, rows: np.ndarray, unit: str) -> Estimate:
        std = float(np.std(rows, ddof=1)) if rows.size > 1 else 0.0
        return cls(value=float(np.mean(rows)), std=std, rows=rows, unit=unit)


def armature_resistance(v_a: np.ndarray | list[float], i_a: np.ndarray | list[float]) -> Estimate:
    """Armature resistance from stall measurements, R_a = v_a/i_a (thesis Eq. 4.2).

    With the rotor blocked there is no back-EMF and, at steady state, no inductive drop, so each
    (v_a, i_a) row gives one R_a; the estimate is their mean and σ their sample standard
    deviation (thesis Table 4.1: R̂_a = 1.08 Ω, σ = 0.04 Ω from 21 rows).

    Parameters
    ----------
    v_a : array_like, shape (M,)
        Armature voltage [V].
    i_a : array_like, shape (M,)
        Armature current [A], > 0.

    Returns
    -------
    Estimate
        R_a [ohm].

    Raises
    ------
    StaticEstimationError
        On non-finite values, different lengths or a current <= 0.
    """
    v = _vec("v_a", v_a)
    i = _vec("i_a", i_a)
    _same_length(v_a=v, i_a=i)
    if (i <= 0).any():
        k = int(np.flatnonzero(i <= 0)[0])
        raise StaticEstimationError(f"i_a[{k}] = {float(i[k])!r} A: stall current must be > 0 to divide by")
    return Estimate.from_rows(v / i, "ohm")


@dataclass(frozen=True)
class TimeConstant:
    """Electrical time constant from a current step (thesis §4.4.2).

    Attributes
    ----------
    tau_e : float
        Time constant [s].
    i_ss : float
        Steady-state current [A] used for the 63 % level (mean of the last samples, or fitted).
    L_a : float or None
        Armature inductance R_a·τ_e [H] when a resistance was given.
    method : str
        ``"63"`` (first crossing of 63.2 % of the step, linear interpolation between samples)
        or ``"fit"`` (least-squares fit of i_0 + Δi·(1 − exp(−(t − t_step)/τ_e))).
    """

    tau_e: float
    i_ss: float
    L_a: float | None
    method: str


def armature_time_constant(
    t: np.ndarray | list[float],
    i_a: np.ndarray | list[float],
    t_step: float = 0.0,
    R_a: float | None = None,
    method: str = "63",
    tail_fraction: float = 0.2,
) -> TimeConstant:
    """Electrical time constant τ_e = L_a/R_a from the current response to a voltage step.

    Thesis §4.4.2: the time for i_a to reach 63 % of its steady-state value after a voltage step
    at stall gave τ̂_e = 2 ms and, with R̂_a = 1.08 Ω, L̂_a = 2.2 mH. The steady state is the mean
    of the last ``tail_fraction`` of the samples; the current before the step is the mean of the
    samples at t < t_step (0 if there are none).

    Parameters
    ----------
    t : array_like, shape (N,)
        Sample times [s], increasing.
    i_a : array_like, shape (N,)
        Armature current [A].
    t_step : float
        Instant of the voltage step [s].
    R_a : float, optional
        Armature resistance [ohm]; if given, ``L_a = R_a·τ_e`` is returned too.
    method : {"63", "fit"}
        ``"63"``: 63.2 % crossing, linear interpolation between samples (its error grows with the
        sample period relative to τ_e: at 490 Hz a 2 ms constant spans one sample); ``"fit"``:
        exponential least squares (scipy ``curve_fit``), unbiased on coarse grids.
    tail_fraction : float
        Fraction of the record (at its end) taken as steady state, in (0, 0.5].

    Raises
    ------
    StaticEstimationError
        On bad arrays, an unknown method, no samples after the step, a step smaller than 5 % of
        the final current, or a response that never crosses 63 %.
    """
    tt = _vec("t", t, 3)
    i = _vec("i_a", i_a, 3)
    _same_length(t=tt, i_a=i)
    if method not in ("63", "fit"):
        raise StaticEstimationError(f"method = {method!r}; expected '63' or 'fit'")
    if not 0.0 < tail_fraction <= 0.5:
        raise StaticEstimationError(f"tail_fraction = {tail_fraction!r} must be in (0, 0.5]")
    if R_a is not None and not R_a > 0:
        raise StaticEstimationError(f"R_a = {R_a!r} ohm must be > 0")
    before = tt < t_step
    after = ~before
    if after.sum() < 3:
        raise StaticEstimationError(f"need >= 3 samples at t >= t_step = {t_step} s, got {int(after.sum())}")
    i0 = float(np.mean(i[before])) if before.any() else 0.0
    n_tail = max(1, round(tail_fraction * tt.size))
    i_ss = float(np.mean(i[-n_tail:]))
    step = i_ss - i0
    if abs(step) < 0.05 * max(abs(i_ss), 1e-12):
        raise StaticEstimationError(
            f"current step {step:.4g} A (from {i0:.4g} to {i_ss:.4g} A) is too small to time"
        )
    ta, ia = tt[after] - t_step, i[after]
    if method == "63":
        level = i0 + (1.0 - math.exp(-1.0)) * step
        frac = (ia - level) * np.sign(step)
        k = np.flatnonzero(frac >= 0)
        if k.size == 0:
            raise StaticEstimationError(f"current never reaches 63 % of the step ({level:.4g} A)")
        k0 = int(k[0])
        if k0 == 0:
            tau = float(ta[0])
        else:
            y0, y1 = ia[k0 - 1], ia[k0]
            tau = float(ta[k0 - 1] + (level - y0) / (y1 - y0) * (ta[k0] - ta[k0 - 1]))
    else:
        def model(x: np.ndarray, d: float, tau_: float) -> np.ndarray:
            return i0 + d * (1.0 - np.exp(-x / tau_))

        guess = max(float(ta[min(np.searchsorted(np.abs(ia - i0), 0.632 * abs(step)), ta.size - 1)]), 1e-6)
        popt, _ = curve_fit(model, ta, ia, p0=(step, guess), bounds=([-np.inf, 1e-9], [np.inf, np.inf]))
        tau = float(popt[1])
        i_ss = i0 + float(popt[0])
    return TimeConstant(tau_e=tau, i_ss=i_ss, L_a=None if R_a is None else R_a * tau, method=method)


@dataclass(frozen=True)
class BackEmfEstimate:
    """Back-EMF constant from steady-state rows (thesis §4.4.3, Table 4.2).

    Attributes
    ----------
    per_rpm : Estimate
        K_ω [V/RPM] (the thesis' unit: ω₁ in RPM).
    si : float
        Mean K_ω [V·s/rad].
    si_std : float
        Its standard deviation [V·s/rad].
    """

    per_rpm: Estimate
    si: float
    si_std: float


def back_emf_constant(
    v_a: np.ndarray | list[float],
    i_a: np.ndarray | list[float],
    omega: np.ndarray | list[float],
    R_a: float,
    omega_unit: str = "rpm",
) -> BackEmfEstimate:
    """K_ω = (v_a − R_a·i_a)/ω₁ per row at steady speed (thesis §4.4.3; L_a·di/dt = 0).

    Thesis Table 4.2 uses ω₁ in RPM (strobe speed through the gear ratio) and R̂_a = 1.08 Ω:
    K̂_ω = 6.606e-4 V/RPM, σ = 1.38e-5, i.e. 6.3085e-3 V·s/rad.

    Parameters
    ----------
    v_a, i_a : array_like, shape (M,)
        Armature voltage [V] and current [A] at steady state.
    omega : array_like, shape (M,)
        Rotor speed ω₁, in RPM (``omega_unit="rpm"``) or rad/s (``"rad/s"``), > 0.
    R_a : float
        Armature resistance [ohm], > 0.
    omega_unit : {"rpm", "rad/s"}

    Raises
    ------
    StaticEstimationError
        On bad arrays, a speed <= 0, R_a <= 0 or an unknown unit.
    """
    v = _vec("v_a", v_a)
    i = _vec("i_a", i_a)
    w = _vec("omega", omega)
    _same_length(v_a=v, i_a=i, omega=w)
    if not R_a > 0:
        raise StaticEstimationError(f"R_a = {R_a!r} ohm must be > 0")
    if (w <= 0).any():
        k = int(np.flatnonzero(w <= 0)[0])
        raise StaticEstimationError(f"omega[{k}] = {float(w[k])!r} {omega_unit}: steady speed must be > 0")
    if omega_unit == "rpm":
        w_rpm = w
    elif omega_unit == "rad/s":
        w_rpm = w / RPM_TO_RAD_S
    else:
        raise StaticEstimationError(f"omega_unit = {omega_unit!r}; expected 'rpm' or 'rad/s'")
    est = Estimate.from_rows((v - R_a * i) / w_rpm, "V/RPM")
    return BackEmfEstimate(per_rpm=est, si=v_per_rpm_to_si(est.value), si_std=v_per_rpm_to_si(est.std))


@dataclass(frozen=True)
class HBridgeMap:
    """v_a(τ) = k0 + k1·sqrt(k2·τ + k3) (thesis Eq. 4.3), τ as a fraction.

    The four constants are not identifiable from data (k1·sqrt(k2·τ + k3) =
    k1·sqrt(k2)·sqrt(τ + k3/k2)): the fit estimates k0, a = k1·sqrt(k2) and b = k3/k2 and reports
    k2, k3 for the chosen k1 (the thesis' 6.8e-4 by default).

    Attributes
    ----------
    k0, k1, k2, k3 : float
        Eq. 4.3 constants ([V], [V], [1], [1]).
    mse : float
        Mean squared fit error [V²] (thesis: 2.6e-5).
    """

    k0: float
    k1: float
    k2: float
    k3: float
    mse: float

    def voltage(self, tau: np.ndarray | float) -> np.ndarray:
        """v_a [V] for duty cycle τ (fraction)."""
        return self.k0 + self.k1 * np.sqrt(self.k2 * np.asarray(tau, dtype=float) + self.k3)

    def duty(self, v_a: np.ndarray | float) -> np.ndarray:
        """Inverse of :meth:`voltage`: τ = (((v_a − k0)/k1)² − k3)/k2."""
        v = np.asarray(v_a, dtype=float)
        if (v < self.k0).any():
            raise StaticEstimationError(f"v_a below k0 = {self.k0:.4g} V is outside the map's range")
        return (((v - self.k0) / self.k1) ** 2 - self.k3) / self.k2


def fit_hbridge_map(
    tau: np.ndarray | list[float], v_a: np.ndarray | list[float], k1: float = 6.8e-4
) -> HBridgeMap:
    """Least-squares fit of thesis Eq. 4.3 to (τ, v_a) pairs (scipy ``curve_fit``).

    Parameters
    ----------
    tau : array_like, shape (M,)
        Duty cycle (fraction in [0, 1]).
    v_a : array_like, shape (M,)
        Armature voltage [V].
    k1 : float
        Value of k1 used to split the identifiable product (see :class:`HBridgeMap`).

    Raises
    ------
    StaticEstimationError
        On bad arrays, fewer than 4 rows, τ outside [0, 1] or k1 <= 0.
    """
    x = _vec("tau", tau, 4)
    v = _vec("v_a", v_a, 4)
    _same_length(tau=x, v_a=v)
    if (x < 0).any() or (x > 1).any():
        raise StaticEstimationError(f"tau must be a fraction in [0, 1], got range [{x.min()}, {x.max()}]")
    if not k1 > 0:
        raise StaticEstimationError(f"k1 = {k1!r} must be > 0")

    def model(t: np.ndarray, k0: float, a: float, b: float) -> np.ndarray:
        return k0 + a * np.sqrt(np.maximum(t + b, 0.0))

    lower, upper = [-np.inf, 0.0, 0.0], [np.inf, np.inf, np.inf]
    popt, _ = curve_fit(model, x, v, p0=(-0.3, 2.5, 0.01), bounds=(lower, upper))
    k0, a, b = (float(p) for p in popt)
    k2 = (a / k1) ** 2
    mse = float(np.mean((model(x, *popt) - v) ** 2))
    return HBridgeMap(k0=k0, k1=k1, k2=k2, k3=b * k2, mse=mse)


@dataclass(frozen=True)
class ThrustLaw:
    """f = a·v_a² + b·v_a + c (thesis Eq. 4.4) with its inverse (Eq. 4.5).

    Attributes
    ----------
    a, b, c : float
        [N/V²], [N/V], [N] (thesis: 0.054, 0.0435, 0.0029).
    mse : float
        Mean squared fit error [N²].
    """

    a: float
    b: float
    c: float
    mse: float

    def thrust(self, v_a: np.ndarray | float) -> np.ndarray:
        """Thrust f [N] at armature voltage v_a [V] (Eq. 4.4)."""
        v = np.asarray(v_a, dtype=float)
        return self.a * v**2 + self.b * v + self.c

    def inverse_constants(self) -> tuple[float, float, float, float]:
        """Constants (p, q, r, s) of v_a = p + q·sqrt(r + s·f) (thesis Eq. 4.5).

        p = −b/(2a), q = 1/(2a), r = b² − 4ac, s = 4a. For the thesis' Eq. 4.4 this gives
        (−0.4028, 9.2593, 0.0013, 0.2160): the thesis prints p as +0.4028 and drops the
        brackets, a typesetting slip (with +0.4028 the inverse does not invert Eq. 4.4).
        """
        return -self.b / (2 * self.a), 1.0 / (2 * self.a), self.b**2 - 4 * self.a * self.c, 4 * self.a

    def voltage(self, f: np.ndarray | float) -> np.ndarray:
        """Armature voltage [V] that produces thrust f [N] (Eq. 4.5, the root on the rising branch).

        Raises
        ------
        StaticEstimationError
            If a thrust lies below the parabola's minimum (no real root).
        """
        p, q, r, s = self.inverse_constants()
        arg = r + s * np.asarray(f, dtype=float)
        if (arg < 0).any():
            raise StaticEstimationError(
                f"thrust {float(np.min(f)):.4g} N is below the fitted law's minimum {-r / s:.4g} N"
            )
        return p + q * np.sqrt(arg)


def fit_thrust_law(v_a: np.ndarray | list[float], f: np.ndarray | list[float]) -> ThrustLaw:
    """Quadratic least-squares fit of thrust vs armature voltage (thesis Eq. 4.4, load cell §4.4.5).

    Parameters
    ----------
    v_a : array_like, shape (M,)
        Armature voltage [V].
    f : array_like, shape (M,)
        Measured thrust [N].

    Raises
    ------
    StaticEstimationError
        On bad arrays, fewer than 3 rows or a fit whose a <= 0 (no invertible rising branch).
    """
    v = _vec("v_a", v_a, 3)
    y = _vec("f", f, 3)
    _same_length(v_a=v, f=y)
    a, b, c = (float(p) for p in np.polyfit(v, y, 2))
    if not a > 0:
        raise StaticEstimationError(f"fitted quadratic coefficient a = {a:.4g} N/V² must be > 0")
    mse = float(np.mean((a * v**2 + b * v + c - y) ** 2))
    return ThrustLaw(a=a, b=b, c=c, mse=mse)
