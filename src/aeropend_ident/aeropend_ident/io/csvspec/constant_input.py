"""Can a constant input explain this log? The check behind ``csv_import --input-constant``.

A log without an actuator column is imported with a constant duty cycle (``input_constant``). That
is right for a free decay or a step from rest at t = 0 and wrong for anything the actuator drove,
e.g. a closed-loop log whose only input-like column is the reference (a reference is the angle a
controller was asked to reach, not what it applied).

The physics: under a constant input the rod is an unforced, damped pendulum about the equilibrium
of that input. Its energy about the final angle θ_f never grows, so

1. **once at rest it stays at rest**: after the rod has moved, a stretch of :data:`REST_TIME_S` in
   which θ stays within its noise band is a rest (an equilibrium, or static friction holding it),
   and θ must not leave that level again; a rod held and released (a free decay started by hand)
   or a step at t = 0 moves only *before* its first rest;
2. **its swing never grows**: the turning points of θ on each side of θ_f (where θ̇ = 0 and the
   energy is all potential) shrink or stay; a later turning point farther from θ_f than an
   earlier one on the same side means energy came in;
3. **it turns back only beyond its equilibrium**: at a turning point θ̇ = 0, so only the static
   torque acts (gravity, thrust and, if the rod sticks, friction), and it points toward the
   equilibrium: θ reverses downward only above θ_f and upward only below it (with dry friction
   the rod may stop short of θ_f, and then it stays: rule 1). A rod that swings about levels
   below its final angle (a staircase of inputs, a closed loop following reference steps) breaks it.

Margins: the noise band is 6 σ of the white measurement noise (σ from the second difference,
1.4826·MAD(Δ²θ)/√6), at least 2 resolution steps (smallest change of θ); a departure or growth
counts when it exceeds 2 noise bands and :data:`RANGE_FRACTION` of θ's range (sensor drift, stick-slip
and the rig's own unsteadiness stay below it). θ is median-filtered over :data:`MEDIAN_SAMPLES`
samples first (single-sample glitches are no motion). On the recordings in ``shared/data/real`` the
free decays and steps from rest reach at most 0.5 of that margin, the driven logs (the actuator
column dropped) at least 1.65 of it (docs/csv_import.md).

The same check guards every fit (:func:`excitation_problem`): a recording that reaches ``baseline``,
``identify`` or ``gap`` with a constant duty cycle some other way (a bag, a preset) is refused with
the message ``csv_import`` gives (:func:`driven_message`) when the constant input cannot explain θ,
and as unexcited when θ does not move; a free decay or a step from rest is accepted (the rod's
dynamics are excited; the input's gain is seen at one level only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = ["MEDIAN_SAMPLES", "RANGE_FRACTION", "REST_TIME_S", "ConstantInputCheck", "check_constant_input",
           "driven_message", "excitation_problem"]

#: Shortest stretch [s] within the noise band that counts as a rest (longer than a swinging rod
#: lingers at a turning point).
REST_TIME_S = 2.0
#: A departure from a rest or a growth of the swing counts above this fraction of θ's range.
RANGE_FRACTION = 0.05
#: Noise band in white-noise standard deviations.
NOISE_SIGMAS = 6.0
#: Median filter length [samples] applied to θ before the checks.
MEDIAN_SAMPLES = 5


@dataclass(frozen=True)
class ConstantInputCheck:
    """Outcome of :func:`check_constant_input`.

    Attributes
    ----------
    driven : bool
        θ does what no constant input allows (``reason`` says what, with times and angles).
    reason : str
        The violated rule in words; "" when not driven.
    moves : bool
        θ moves beyond the margin at all (a free decay or a step does; a rod at rest does not).
    band, margin : float
        Noise band and the margin a departure or growth must exceed [rad].
    theta_final : float
        Final angle θ_f the swing is measured about [rad].
    excess : float
        Largest departure from a rest or growth of the swing, in margins (> 1: ``driven``).
    """

    driven: bool
    reason: str
    moves: bool
    band: float
    margin: float
    theta_final: float
    excess: float


def noise_band(theta: np.ndarray) -> float:
    """6 σ of white noise (second-difference MAD), at least 2 resolution steps [rad]."""
    d2 = np.diff(theta, 2)
    sigma = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0) if d2.size >= 3 else 0.0
    steps = np.abs(np.diff(theta))
    lsb = float(steps[steps > 0].min()) if np.any(steps > 0) else 0.0
    return max(NOISE_SIGMAS * sigma, 2.0 * lsb)


def _rest_then_moves(t: np.ndarray, th: np.ndarray, band: float, margin: float) -> tuple[float, str]:
    """Rule 1: after its first motion the rod rests, then leaves that level; (departure [rad], text)."""
    n = th.size
    dt = float(np.median(np.diff(t)))
    w = max(min(round(REST_TIME_S / dt), n // 4), 3)
    if n < 2 * w:
        return 0.0, ""
    first = np.flatnonzero(np.abs(th - np.median(th[:w])) > margin)
    if first.size == 0 or n - first[0] < w:  # no motion, or too little left after it for a rest
        return 0.0, ""
    rest = np.flatnonzero(np.ptp(sliding_window_view(th[first[0]:], w), axis=1) <= band)
    if rest.size == 0:
        return 0.0, ""
    i = int(first[0] + rest[0])
    level = float(np.median(th[i:i + w]))
    later = np.abs(th[i + w:] - level)
    if later.size == 0:
        return 0.0, ""
    k = i + w + int(np.argmax(later))
    return float(later.max()), (
        f"θ rests at {level:.4g} rad from t = {t[i]:.3f} s to {t[i + w - 1]:.3f} s (within "
        f"±{band / 2:.2g} rad) and then moves {later.max():.3g} rad away (to {th[k]:.4g} rad at "
        f"t = {t[k]:.3f} s), but a rod at rest under a constant input stays at rest")


def _swing_grows(t: np.ndarray, th: np.ndarray, band: float, theta_f: float) -> tuple[float, str]:
    """Rule 2: a turning point farther from θ_f than an earlier one on the same side; (growth [rad], text)."""
    # imported here, not with the module: scipy.signal costs every command 0.8 s to start
    from scipy.signal import find_peaks

    worst = (0.0, 0, 0, 1)
    for side in (1, -1):
        x = np.clip(side * (th - theta_f), 0.0, None)
        peaks, _ = find_peaks(x, prominence=band)
        if peaks.size < 2:
            continue
        heights = x[peaks]
        growth = heights[1:] - np.minimum.accumulate(heights)[:-1]
        j = int(np.argmax(growth))
        if growth[j] > worst[0]:
            earlier = int(peaks[: j + 1][np.argmin(heights[: j + 1])])
            worst = (float(growth[j]), earlier, int(peaks[j + 1]), side)
    size, a, b, side = worst
    if size <= 0.0:
        return 0.0, ""
    return size, (
        f"its swing {'above' if side > 0 else 'below'} the final angle θ_f = {theta_f:.4g} rad grows from "
        f"{abs(th[a] - theta_f):.3g} rad (turning point at t = {t[a]:.3f} s) to {abs(th[b] - theta_f):.3g} "
        f"rad (at t = {t[b]:.3f} s), but under a constant input the swing about θ_f never grows (no energy "
        "comes in)")


def _turns_short(t: np.ndarray, th: np.ndarray, band: float, theta_f: float) -> tuple[float, str]:
    """Rule 3: θ turns back before reaching the final angle; (shortfall [rad], text)."""
    from scipy.signal import find_peaks

    worst = (0.0, 0, 1)
    for side in (1, -1):  # local maxima must lie above θ_f, local minima below
        peaks, _ = find_peaks(side * th, prominence=band)
        if peaks.size == 0:
            continue
        short = side * (theta_f - th[peaks])
        j = int(np.argmax(short))
        if short[j] > worst[0]:
            worst = (float(short[j]), int(peaks[j]), side)
    size, k, side = worst
    if size <= 0.0:
        return 0.0, ""
    return size, (
        f"θ turns back {'down' if side > 0 else 'up'} at {th[k]:.4g} rad (t = {t[k]:.3f} s), {size:.3g} rad "
        f"{'below' if side > 0 else 'above'} its final angle θ_f = {theta_f:.4g} rad, but under a constant "
        "input the rod turns back only beyond its equilibrium (at a turning point θ̇ = 0 and only the static "
        "torque acts, which points toward the equilibrium)")


def check_constant_input(t: np.ndarray, theta: np.ndarray) -> ConstantInputCheck:
    """Whether a constant input can explain θ(t) (module docstring: the three rules and the margins).

    Parameters
    ----------
    t : ndarray, shape (N,)
        Increasing sample times [s] (uniform or not).
    theta : ndarray, shape (N,)
        Pendulum angle [rad], finite.

    Returns
    -------
    ConstantInputCheck
        ``driven`` with the reason when a rule is violated.
    """
    from scipy.ndimage import median_filter  # here, not with the module (as find_peaks)

    t = np.asarray(t, dtype=float)
    raw = np.asarray(theta, dtype=float)
    band = noise_band(raw)
    th = median_filter(raw, size=MEDIAN_SAMPLES, mode="nearest")
    margin = max(2.0 * band, RANGE_FRACTION * float(np.ptp(th)))
    theta_f = float(np.median(th[-max(th.size // 20, 3):]))
    moves = float(np.max(np.abs(th - th[0]))) > margin
    rules = (_rest_then_moves(t, th, band, margin), _swing_grows(t, th, band, theta_f),
             _turns_short(t, th, band, theta_f))
    size, text = max(rules, key=lambda r: r[0] / margin)
    driven = size > margin
    return ConstantInputCheck(driven, text if driven else "", moves, band, margin, theta_f, size / margin)


def driven_message(given: str, reason: str, reference: str | None = None) -> str:
    """The refusal of a log that a constant input cannot explain (``csv_import`` and every fit).

    Parameters
    ----------
    given : str
        What the constant input is, e.g. ``"input_constant = 0 counts (pwm): duty 0"``.
    reason : str
        The violated rule (:attr:`ConstantInputCheck.reason`).
    reference : str, optional
        How the log's reference is named (``"column 'theta_ref [rad]'"``, ``"channel theta_ref"``):
        the message says it is not an input.

    Returns
    -------
    str
        ``"a constant input (...) cannot explain this log: ... Log the actuator command ..."``.
    """
    stored = "" if "theta_ref" in str(reference) else ", and it is stored as the channel theta_ref"
    ref = (f" The reference {reference} is not an input: it is the angle the controller was asked to reach, "
           f"not the command it applied{stored}." if reference else "")
    return (f"a constant input ({given}) cannot explain this log: {reason}.{ref} Log the actuator command "
            "(duty, PWM, pulse width, voltage) and import it with --input-col and --input-kind; give "
            "--input-constant only for a run whose input really was constant (a free decay, a step from "
            "rest at t = 0)")


def excitation_problem(t: np.ndarray, duty: np.ndarray, theta: np.ndarray,
                       reference: str | None = None) -> tuple[str, str] | None:
    """Why a fit of the rig from θ and the duty cycle cannot use these data, or None when it can.

    Identifiability is decided on what is fitted: a changing duty cycle excites the rig (unless θ
    never changes at all); under a constant one, θ must move as a constant input allows (a free
    decay, a step from rest at t = 0: the rod's dynamics are excited, the input's gain is seen at
    one level only); a constant input that cannot explain θ is a driven log whose command was not
    logged (:func:`driven_message`, the ``csv_import`` refusal), and a θ that stays within its noise
    band is unexcited.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample times [s].
    duty : ndarray, shape (N,)
        Duty cycle τ [1].
    theta : ndarray, shape (N,)
        Angle [rad], finite.
    reference : str, optional
        How the recording's reference is named, for the message (e.g. ``"channel theta_ref"``).

    Returns
    -------
    (str, str) or None
        ``("driven", why)`` or ``("unexcited", why)`` (``why`` without the recording's name); None
        for usable data.
    """
    duty = np.asarray(duty, dtype=float)
    theta = np.asarray(theta, dtype=float)
    if np.ptp(theta) == 0.0:
        return "unexcited", (f"θ is constant ({theta[0]:g} rad) over all {theta.size} samples: the output is "
                             "unexcited")
    if np.ptp(duty) > 0.0:
        return None
    check = check_constant_input(t, theta)
    given = f"the duty cycle is {duty[0]:.4g} throughout"
    if check.driven:
        return "driven", driven_message(given, check.reason, reference)
    if not check.moves:
        return "unexcited", (
            f"the duty cycle is constant ({duty[0]:.4g}) and θ stays within {check.margin:.3g} rad of where "
            "it starts: nothing excites the rig, so no parameter is identifiable from it (a step, a free "
            "decay from a held angle or a PRBS would be)")
    return None
