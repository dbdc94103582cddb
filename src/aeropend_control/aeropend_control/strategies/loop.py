"""Shared plumbing of the I-PD position loops (FL and small-signal): θ̇ estimate, PID, allocation.

Both loops measure **θ only** (the thesis rig has no θ̇ sensor) and run once per sample.

θ̇ estimate (``estimator``): by default the Kalman observer of :mod:`aeropend_control.observer`
(stationary gain, state [θ, θ̇, d], the model thrust predicted from the applied duty as known
input; the loop then uses θ̂ and θ̂̇ throughout, the PID's derivative via its external-derivative
input); alternatively (``estimator="difference"``) a first-order low-pass filtered backward
difference (:class:`VelocityEstimator`, θ̇_k = (T_f·θ̇_{k-1} + θ_k − θ_{k-1})/(T_f + h), i.e.
s/(T_f·s + 1) by backward Euler, T_f = 10 ms), the same filter the PID's derivative on
measurement uses.
"""

from __future__ import annotations

import math
from dataclasses import replace

from aeropend_control.allocation import Allocation, ModelAllocator, ThesisAllocator
from aeropend_control.drive_design import default_thrust_gain
from aeropend_control.observer import ObserverSpec, PendulumObserver
from aeropend_control.pid import PID, PIDGains
from aeropend_control.strategies.base import ControlOutput, Strategy, StrategyError
from aeropend_sim.model import plant_model
from aeropend_sim.params import Rig

#: Default derivative / velocity filter time constant [s].
DEFAULT_TF = 0.01
#: Allocation chains accepted by the position loops.
ALLOCATORS = ("model", "thesis")
#: θ̇ estimators: filtered difference (:class:`VelocityEstimator`) or Kalman observer
#: (:class:`aeropend_control.observer.PendulumObserver`).
ESTIMATORS = ("difference", "observer")


class VelocityEstimator:
    """θ̇ from θ: backward-Euler discretised s/(T_f·s + 1) (filtered difference; see module doc).

    Parameters
    ----------
    dt : float
        Sample period h [s].
    tf : float
        Filter time constant T_f [s] (0 = raw difference).
    """

    def __init__(self, dt: float, tf: float = DEFAULT_TF) -> None:
        if not (dt > 0.0 and tf >= 0.0 and math.isfinite(tf)):
            raise StrategyError(f"velocity estimator needs dt > 0 and tf >= 0, got dt = {dt!r}, tf = {tf!r}")
        self.dt, self.tf = dt, tf
        self.reset()

    def reset(self) -> None:
        """Forget the history (the next update returns 0)."""
        self._prev: float | None = None
        self.value = 0.0

    def update(self, theta: float) -> float:
        """New θ [rad] in, θ̇ estimate [rad/s] out."""
        if self._prev is not None:
            self.value = (self.tf * self.value + theta - self._prev) / (self.tf + self.dt)
        self._prev = theta
        return self.value


def _allocator(rig: Rig, name: str) -> ModelAllocator | ThesisAllocator:
    if name == "model":
        return ModelAllocator(rig)
    if name == "thesis":
        return ThesisAllocator(rig)
    raise StrategyError(f"allocator = {name!r}; expected one of {ALLOCATORS}")


class PositionLoop(Strategy):
    """Shared plumbing of the I-PD position loops: estimator, PID, allocation, NaN handling,
    bumpless start (abstract: :class:`~aeropend_control.strategies.fl_pid.FeedbackLinearizationPID`
    and :class:`~aeropend_control.strategies.small_signal.SmallSignalPID` add the law).

    Parameters
    ----------
    rig : Rig
    gains : PIDGains
        Initial I-PD gains.
    allocator : {"model", "thesis"}
        Thrust → duty chain (:mod:`aeropend_control.allocation`).
    tf : float
        Velocity/derivative filter time constant [s] (``estimator="difference"``).
    dt : float, optional
        Sample period [s] (default ``rig.sample_period``).
    f_init : float
        Thrust [N] the first sample continues from (0 = motor off).
    estimator : {"observer", "difference"}
        θ̇ from :class:`~aeropend_control.observer.PendulumObserver` (default; the loop then also
        uses the observer's θ̂ instead of the raw θ) or from the filtered difference.
    observer_spec : ObserverSpec, optional
        Noise model of the observer.
    """

    drive_kind = "duty"

    def __init__(self, rig: Rig, gains: PIDGains, allocator: str, tf: float, dt: float | None,
                 f_init: float, estimator: str = "observer",
                 observer_spec: ObserverSpec | None = None) -> None:
        if estimator not in ESTIMATORS:
            raise StrategyError(f"estimator = {estimator!r}; expected one of {ESTIMATORS}")
        self.rig = rig
        self.model = plant_model(rig)
        self.dt = float(rig.sample_period if dt is None else dt)
        self.alloc = _allocator(rig, allocator)
        self.f_min = getattr(self.alloc, "f_min", 0.0)
        self.f_max = self.alloc.f_max
        self.estimator = VelocityEstimator(self.dt, tf)
        self.observer = (PendulumObserver(self.model, self.dt, observer_spec) if estimator == "observer"
                         else None)
        #: True when an enclosing cascade applies another duty and calls :meth:`advance` itself.
        self.defer_predict = False
        self.pid = PID(replace(gains, tf=tf), self.dt)
        self.f_init = float(f_init)
        #: Gain K of the model-based thrust loop f_cmd = f + K·(f − f̂), f̂ the thrust the observer's
        #: motor model predicts (:func:`default_thrust_gain`: on when the rig declares a drive lag).
        self.thrust_gain = default_thrust_gain(rig)
        self.last: ControlOutput | None = None
        self._started = False

    def reset(self) -> None:
        """Back to the initial state (next sample starts bumpless from ``f_init``)."""
        self.estimator.reset()
        if self.observer is not None:
            self.observer.reset()
        self.pid.reset()
        self.last = None
        self._started = False

    @property
    def nan_count(self) -> int:
        """Samples with a non-finite reference or θ (counted by the PID)."""
        return self.pid.nan_count

    def _estimate(self, theta: float) -> tuple[float, float]:
        """(angle the loop uses, θ̇ estimate): (θ, filtered difference) or the observer's (θ̂, θ̂̇)."""
        if self.observer is None:
            return theta, self.estimator.update(theta)
        thd = self.observer.correct(theta)
        return self.observer.theta, thd

    def advance(self, duty: float, omega: float = math.nan) -> None:
        """Tell the observer (if any) the duty applied until the next sample (and the measured ω₁)."""
        if self.observer is not None:
            self.observer.predict(duty, omega)

    def _finish(self, r: float, theta: float, thd: float, v: float, f: float) -> ControlOutput:
        f_alloc = f
        if self.thrust_gain > 0.0 and self.observer is not None:
            f_alloc = f + self.thrust_gain * (f - self.model.thrust(self.observer.thrust.omega))
        a: Allocation = self.alloc.allocate(f_alloc)
        sat = a.saturated if a.saturated else self.pid.saturated  # PID clamps at the mapped limits
        out = ControlOutput(a.duty, r - theta, v, f, thd, sat)
        self.last = out
        if not self.defer_predict:
            self.advance(out.duty)
        return out

    def _nan(self, r: float, theta: float) -> ControlOutput | None:
        if math.isfinite(r) and math.isfinite(theta):
            return None
        prev = self.last
        duty = prev.duty if prev is not None else 0.0
        out = ControlOutput(duty, math.nan, math.nan, math.nan, math.nan, 0, True)
        self.pid.nan_count += 1
        if not self.defer_predict:
            self.advance(duty)
        return out

    def _pid_update(self, r: float, theta: float, u_start: float, thd: float) -> float:
        """PID update; on the very first sample the output is forced to ``u_start`` (bumpless start).

        With the observer the PID's derivative is the observer's θ̂̇ (``thd``), else its own
        filtered difference of ``theta``.
        """
        dy = thd if self.observer is not None else None
        if not self._started:
            self.pid.set_manual(u_start)
            u = self.pid.update(r, theta, dy)
            self.pid.set_auto()
            self._started = True
            return u
        return self.pid.update(r, theta, dy)
