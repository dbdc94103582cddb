"""Partial-state identification: the pendulum equation from the angle and the duty cycle only.

Most real logs have only θ and τ (issue 4, item 4). What such data supports is the pendulum
equation with an *estimated* θ̇ and a *static* thrust map:

    θ̈ = −(c/J)·θ̇ − (mgd/J)·sin θ + (L/J)·f(v_a),   f(v_a) = a·v_a² + b·v_a + c  (thesis Eq. 4.4)

with v_a = v_a(τ) from a duty -> voltage map (thesis Eq. 4.3, e.g. ``PlantModel(rig).armature_voltage``).
The library is therefore {1, θ̇, sin θ, v_a, v_a²}; its v_a², v_a and 1 coefficients are
(L/J)·(a, b, c). The map is static, i.e. it assumes the motor is fast compared with the
pendulum: true for ``thesis_rig`` (τ_e 2 ms, rotor 20-40 ms against a 1.6 s pendulum period),
not for ``thesis_sim`` (rotor modes of 26 ms and 6 ms next to ω_n = 11.5 rad/s), where the
static map makes the identified c/J and mgd/J 20-50 % too small (measured; see
``docs/identification.md``). The current and rotor equations need i_a and ω₁ and are refused
by :func:`aeropend_ident.sindy.fit`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from aeropend_ident.libraries import Candidate, CandidateLibrary, constant
from aeropend_ident.preprocess import differentiate
from aeropend_ident.sindy import IdentData, IdentificationError


def angle_only_data(
    t: np.ndarray, theta: np.ndarray, duty: np.ndarray,
    voltage_map: Callable[[float], float] | None = None, source: str = "angle-only",
) -> IdentData:
    """Identification data from θ and τ: smoothed θ, θ̇ and θ̈ estimated, v_a from the map.

    θ̇ and θ̈ are Savitzky-Golay derivatives with the window chosen by cross-validation
    (:func:`aeropend_ident.preprocess.differentiate`), θ̈ from the estimated θ̇.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Uniform sample times [s].
    theta : ndarray, shape (N,)
        Angle [rad].
    duty : ndarray, shape (N,)
        Duty cycle τ ∈ [0, 1] held over each sample period.
    voltage_map : callable, optional
        τ -> v_a [V] (e.g. ``PlantModel(rig).armature_voltage``); default v_a = τ (then the
        coefficients are per unit duty instead of per volt).

    Returns
    -------
    IdentData
        Variables ``theta``, ``theta_dot`` (estimated), ``v_a``, ``duty``; derivative
        ``theta_dot`` (θ̈, estimated).

    Raises
    ------
    IdentificationError
        On shape mismatch, NaNs or a duty cycle outside [0, 1].
    """
    th = np.asarray(theta, dtype=float)
    u = np.asarray(duty, dtype=float)
    if th.shape != u.shape or th.shape != np.shape(t):
        raise IdentificationError(
            f"{source}: t, theta, duty shapes differ: {np.shape(t)}, {th.shape}, {u.shape}"
        )
    if not np.isfinite(u).all() or (u < 0).any() or (u > 1).any():
        raise IdentificationError(f"{source}: duty must be finite fractions in [0, 1]")
    d1 = differentiate(t, th, method="savgol")
    d2 = differentiate(t, d1.dydt, method="savgol")
    v_a = u.copy() if voltage_map is None else np.array([voltage_map(float(x)) for x in u])
    return IdentData(
        t=np.asarray(t, dtype=float),
        variables={"theta": d1.smooth, "theta_dot": d1.dydt, "v_a": v_a, "duty": u},
        derivatives={"theta_dot": d2.dydt}, source=source,
    )


def static_thrust_library() -> CandidateLibrary:
    """{1, θ̇, sin θ, v_a, v_a²}: pendulum terms plus the thesis Eq. 4.4 thrust law in v_a."""
    return CandidateLibrary((
        constant(),
        Candidate("θ̇", ("theta_dot",), lambda d: np.asarray(d["theta_dot"], dtype=float)),
        Candidate("sin(θ)", ("theta",), lambda d: np.sin(np.asarray(d["theta"], dtype=float))),
        Candidate("v_a", ("v_a",), lambda d: np.asarray(d["v_a"], dtype=float)),
        Candidate("v_a²", ("v_a",), lambda d: np.asarray(d["v_a"], dtype=float) ** 2),
    ))
