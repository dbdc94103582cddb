"""Discrete two-degree-of-freedom PID controller (no rclpy).

Continuous law (Åström & Hägglund, *Advanced PID Control*, §3.5; the form of ros2_control's
``control_toolbox::Pid`` and of the Arduino PID library the thesis used, thesis §6.4)::

    v(t) = kp·(b·r − y) + ki·∫(r − y)dt + kd·D,   T_f·dD/dt + D = d(c·r − y)/dt
    u(t) = sat(v(t), u_min, u_max)

* **setpoint weighting** ``b`` (proportional) and ``c`` (derivative); ``c = 0`` (default) is
  derivative on measurement, so a setpoint step gives no derivative kick;
* **derivative filter**: first-order low-pass with time constant ``T_f`` [s] (``tf``);
* **anti-windup**: ``"back_calculation"`` (tracking, dI/dt += k_t·(u − v), ``k_t`` in 1/s),
  ``"conditional"`` (conditional integration / clamping: the integrator is frozen while the
  output is saturated and the error would drive it further into saturation) or ``"none"``;
* **discretisation** (sample period h), stated per method:

  ``backward_euler`` (default): I_k = I_{k-1} + h·ki·e_k (+ implicit back-calculation),
  D_k = T_f/(T_f + h)·D_{k-1} + 1/(T_f + h)·(ed_k − ed_{k-1});
  ``forward_euler`` (the Arduino PID library's form, thesis §6.4): I_k = I_{k-1} + h·ki·e_{k-1}
  (+ explicit back-calculation with the previous saturation error),
  D_k = (1 − h/T_f)·D_{k-1} + 1/T_f·(ed_k − ed_{k-1}) (needs T_f > h/2 for stability; the
  first update does not integrate);
  ``tustin``: I_k = I_{k-1} + h·ki·(e_k + e_{k-1})/2,
  D_k = (2T_f − h)/(2T_f + h)·D_{k-1} + 2/(2T_f + h)·(ed_k − ed_{k-1}),

  where e = r − y and ed = c·r − y; the derivative part of the output is kd·D_k. On the first
  update the previous values are taken equal to the current ones (no start-up kick);
* **bumpless** gain changes (:meth:`PID.set_gains` moves the jump of the proportional term into
  the integrator) and manual/automatic switching (:meth:`PID.set_manual` /
  :meth:`PID.set_auto`: in manual mode the integrator tracks the manual output);
* **NaN-safe**: a non-finite ``r`` or ``y`` leaves the state unchanged, returns the last output
  and sets :attr:`PID.nan_flag` (counted in :attr:`PID.nan_count`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Anti-windup schemes.
ANTI_WINDUP = ("back_calculation", "conditional", "none")
#: Discretisation methods.
METHODS = ("backward_euler", "forward_euler", "tustin")


class PIDConfigError(ValueError):
    """Invalid PID gains, limits or options (the message names the bad value)."""


def check_limits(u_min: float, u_max: float) -> None:
    """Raise :class:`PIDConfigError` unless the output limits satisfy u_min < u_max (NaN refused)."""
    if math.isnan(u_min) or math.isnan(u_max) or not u_min < u_max:
        raise PIDConfigError(f"PID output limits u_min = {u_min!r} >= u_max = {u_max!r}")


@dataclass(frozen=True)
class PIDGains:
    """Gains and options of :class:`PID` (SI; the output unit is the actuator's).

    Attributes
    ----------
    kp : float
        Proportional gain [u/rad for an angle loop].
    ki : float
        Integral gain [u/(rad·s)].
    kd : float
        Derivative gain [u·s/rad].
    b : float
        Proportional setpoint weight (1 = error feedback, 0 = I-PD).
    c : float
        Derivative setpoint weight (0 = derivative on measurement).
    tf : float
        Derivative filter time constant T_f [s] (0 = unfiltered; not allowed with forward Euler).
    u_min, u_max : float
        Output limits (``-inf``/``inf`` = unlimited).
    anti_windup : str
        One of :data:`ANTI_WINDUP`.
    kt : float
        Back-calculation tracking gain k_t [1/s] (default when ``None``: 1/T_t with the
        Åström-Hägglund rule T_t = sqrt(T_i·T_d), or ki/kp if kd = 0, or 1/h if kp = 0).
    method : str
        One of :data:`METHODS`.
    """

    kp: float = 0.0
    ki: float = 0.0
    kd: float = 0.0
    b: float = 1.0
    c: float = 0.0
    tf: float = 0.0
    u_min: float = -math.inf
    u_max: float = math.inf
    anti_windup: str = "back_calculation"
    kt: float | None = None
    method: str = "backward_euler"

    def validate(self, dt: float) -> None:
        """Raise :class:`PIDConfigError` naming the first invalid field."""
        for name in ("kp", "ki", "kd", "b", "c", "tf"):
            val = getattr(self, name)
            if not math.isfinite(val):
                raise PIDConfigError(f"PID {name} = {val!r} is not finite")
        if self.tf < 0.0:
            raise PIDConfigError(f"PID derivative filter tf = {self.tf!r} s must be >= 0")
        check_limits(self.u_min, self.u_max)
        if self.anti_windup not in ANTI_WINDUP:
            raise PIDConfigError(f"PID anti_windup = {self.anti_windup!r}; expected one of {ANTI_WINDUP}")
        if self.method not in METHODS:
            raise PIDConfigError(f"PID method = {self.method!r}; expected one of {METHODS}")
        if self.kt is not None and not (math.isfinite(self.kt) and self.kt >= 0.0):
            raise PIDConfigError(f"PID back-calculation gain kt = {self.kt!r} 1/s must be finite and >= 0")
        if self.method == "forward_euler" and self.kd != 0.0 and not self.tf > dt / 2.0:
            raise PIDConfigError(
                f"PID tf = {self.tf!r} s: forward Euler derivative needs tf > h/2 = {dt / 2:g} s"
            )

    def tracking_gain(self, dt: float) -> float:
        """Back-calculation gain k_t [1/s] actually used (see the attribute doc)."""
        if self.kt is not None:
            return self.kt
        if self.kp > 0.0 and self.ki > 0.0:
            ti = self.kp / self.ki
            if self.kd > 0.0:
                return 1.0 / math.sqrt(ti * self.kd / self.kp)
            return 1.0 / ti
        return 1.0 / dt


class PID:
    """Discrete 2-DOF PID with limits, anti-windup, filtered derivative, modes, NaN safety.

    Parameters
    ----------
    gains : PIDGains
    dt : float
        Sample period h [s] (> 0).

    Attributes
    ----------
    p, i, d : float
        Proportional, integral and derivative parts of the last unsaturated output v.
    output : float
        Last (saturated) output u.
    saturated : int
        +1 / −1 if the last output hit u_max / u_min, else 0.
    nan_flag : bool
        True if the last update got a non-finite input (output held).
    nan_count : int
        Number of updates with non-finite input.
    manual : bool
        Manual mode (output = the manual value, integrator tracks it).
    """

    def __init__(self, gains: PIDGains, dt: float) -> None:
        if not (math.isfinite(dt) and dt > 0.0):
            raise PIDConfigError(f"PID sample period dt = {dt!r} s must be finite and > 0")
        gains.validate(dt)
        self.gains = gains
        self.dt = float(dt)
        self.nan_count = 0
        self.manual = False
        self._manual_u = 0.0
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self, integral: float = 0.0) -> None:
        """Clear the state (first update afterwards has no kick); set the integrator value."""
        self.p = 0.0
        self.i = float(integral)
        self.d = 0.0
        self._dstate = 0.0
        self.output = 0.0
        self.saturated = 0
        self.nan_flag = False
        self._prev: tuple[float, float] | None = None  # (r, y) of the last valid update
        self._prev_e = 0.0
        self._prev_sat_err = 0.0  # u − v of the last update (forward-Euler back-calculation)

    def _p_term(self, g: PIDGains, r: float, y: float) -> float:
        return g.kp * (g.b * r - y)

    def set_gains(self, gains: PIDGains) -> None:
        """Change gains/options without a bump in the output (for the last r, y).

        The integrator absorbs the change of the proportional term, kp_old·(b_old·r − y) −
        kp_new·(b_new·r − y); the derivative filter state is kept.
        """
        gains.validate(self.dt)
        if self._prev is not None:
            r, y = self._prev
            self.i += self._p_term(self.gains, r, y) - self._p_term(gains, r, y)
        self.gains = gains

    def set_limits(self, u_min: float, u_max: float) -> None:
        """Change the output limits (bumpless as far as the limits allow); the same limits change nothing
        (a loop that sets them every sample does not rebuild its gains every sample)."""
        g = self.gains
        if u_min == g.u_min and u_max == g.u_max:
            return
        check_limits(u_min, u_max)
        # only the limits change (a feedback-linearising loop moves them every sample): the other
        # fields were validated with these gains, and set_gains' bumpless correction of the
        # proportional term would add kp·(b·r − y) − kp·(b·r − y) = 0 to the integrator
        new = object.__new__(PIDGains)  # dataclasses.replace without its per-call cost
        new.__dict__.update(g.__dict__, u_min=u_min, u_max=u_max)
        self.gains = new

    def set_manual(self, u: float) -> None:
        """Switch to manual mode with output ``u`` (clamped to the limits)."""
        if not math.isfinite(u):
            raise PIDConfigError(f"manual PID output {u!r} is not finite")
        self.manual = True
        self._manual_u = min(max(float(u), self.gains.u_min), self.gains.u_max)
        self.output = self._manual_u

    def set_auto(self) -> None:
        """Switch back to automatic mode; the first automatic output continues from the manual one."""
        if self.manual:
            self.i = self.output - self.p - self.d
        self.manual = False

    # ------------------------------------------------------------------ update
    def _derivative(self, ed: float, ed_prev: float) -> float:
        g, h = self.gains, self.dt
        delta = ed - ed_prev
        if g.tf == 0.0:
            self._dstate = delta / h
        elif g.method == "backward_euler":
            self._dstate = (g.tf * self._dstate + delta) / (g.tf + h)
        elif g.method == "forward_euler":
            self._dstate = (1.0 - h / g.tf) * self._dstate + delta / g.tf
        else:
            self._dstate = ((2 * g.tf - h) * self._dstate + 2.0 * delta) / (2 * g.tf + h)
        return g.kd * self._dstate

    def update(self, r: float, y: float, dy: float | None = None) -> float:
        """One sample: setpoint ``r`` and measurement ``y`` in, saturated output ``u`` out.

        Parameters
        ----------
        r, y : float
            Setpoint and measurement.
        dy : float, optional
            Externally estimated derivative dy/dt (e.g. an observer's θ̂̇). When given, the
            derivative part is kd·(−dy) and the internal filtered difference is bypassed; this
            needs derivative on measurement (c = 0).

        Returns
        -------
        float
            u_k in [u_min, u_max]; the last output if ``r`` or ``y`` is not finite.
        """
        if not (math.isfinite(r) and math.isfinite(y)) or (dy is not None and not math.isfinite(dy)):
            self.nan_flag = True
            self.nan_count += 1
            return self.output
        self.nan_flag = False
        g, h = self.gains, self.dt
        r, y = float(r), float(y)
        first = self._prev is None
        r0, y0 = (r, y) if first else self._prev
        e = r - y
        e_prev = self._prev_e if self._prev is not None else e
        self.p = self._p_term(g, r, y)
        if dy is None:
            self.d = self._derivative(g.c * r - y, g.c * r0 - y0)
        else:
            if g.c != 0.0:
                raise PIDConfigError(f"PID with an external derivative dy needs c = 0, got c = {g.c!r}")
            self._dstate = -float(dy)
            self.d = g.kd * self._dstate
        self._prev = (r, y)
        self._prev_e = e
        if self.manual:  # integrator tracks the manual output: bumpless return to auto
            self.i = self._manual_u - self.p - self.d
            self.output = self._manual_u
            self.saturated = 0
            return self.output
        if g.method == "backward_euler":
            di = h * g.ki * e
        elif g.method == "forward_euler":
            di = 0.0 if first else h * g.ki * e_prev  # I_0 = initial value
        else:
            di = 0.5 * h * g.ki * (e + e_prev)
        i_prev = self.i
        i_tent = i_prev + di
        v = self.p + i_tent + self.d
        u = min(max(v, g.u_min), g.u_max)
        if g.anti_windup == "back_calculation":
            kt = g.tracking_gain(h)
            if g.method == "forward_euler":  # explicit: previous saturation error
                i_new = i_tent + h * kt * self._prev_sat_err
                v = self.p + i_new + self.d
                u = min(max(v, g.u_min), g.u_max)
            elif u != v:  # implicit: I = I_tent + h·kt·(u − p − d − I)
                i_new = (i_tent + h * kt * (u - self.p - self.d)) / (1.0 + h * kt)
                v = self.p + i_new + self.d
            else:
                i_new = i_tent
            self._prev_sat_err = u - v
        elif g.anti_windup == "conditional":
            pushing = (v > g.u_max and di > 0.0) or (v < g.u_min and di < 0.0)
            i_new = i_prev if pushing else i_tent
            v = self.p + i_new + self.d
            u = min(max(v, g.u_min), g.u_max)
        else:
            i_new = i_tent
        self.i = i_new
        self.saturated = 1 if v > g.u_max else (-1 if v < g.u_min else 0)
        self.output = u
        return u
