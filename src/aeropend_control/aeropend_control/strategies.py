"""Position-control strategies of thesis chapter 6 as per-sample controllers (no rclpy).

Every strategy measures **θ only** (the thesis rig has no θ̇ sensor) and runs once per sample:
``step(r, theta) -> ControlOutput`` with the duty cycle τ ∈ [0, 1] for the next sample period.

θ̇ estimate (``estimator``): by default the Kalman observer of :mod:`aeropend_control.observer`
(stationary gain, state [θ, θ̇, d], the model thrust predicted from the applied duty as known
input; the loop then uses θ̂ and θ̂̇ throughout, the PID's derivative via its external-derivative
input); alternatively (``estimator="difference"``) a first-order low-pass filtered backward
difference (:class:`VelocityEstimator`, θ̇_k = (T_f·θ̇_{k-1} + θ_k − θ_{k-1})/(T_f + h), i.e.
s/(T_f·s + 1) by backward Euler, T_f = 10 ms), the same filter the PID's derivative on
measurement uses.

Strategies
----------
:class:`FeedbackLinearizationPID` (thesis §6.6, Eqs. 6.4-6.7)
    v = I-PD(r, θ) (the pseudo-control θ̈_desired), thrust
    f = (v + (mgd/J)·sin θ + (c/J)·θ̂̇)/(L/J) (damping cancelled too; with
    ``cancel_damping=False`` the thesis' Eq. 6.4 without the damping term), then thrust →
    duty allocation (:mod:`aeropend_control.allocation`). The PID's output limits are the
    thrust limits [f_min, f_max] mapped through the law at the current θ, θ̂̇, so back-calculation
    anti-windup sees the real actuator saturation.
:class:`SmallSignalPID` (thesis §6.5, Eqs. 6.1-6.3)
    f = f₀(θ_op) + Δf, Δf = I-PD(r, θ) designed on the linearisation at θ_op; with gain
    scheduling the operating point is the reference (θ_op = r, gains and f₀ interpolated in a
    table of designs); a change of operating point is bumpless (the integrator absorbs the
    jumps of f₀ and of kp), as in the linear design where the thrust is continuous.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from aeropend_control.allocation import Allocation, ModelAllocator, ThesisAllocator
from aeropend_control.design import (
    DEFAULT_GRID,
    LAG_CURRENT_RATIO,
    CascadeDesign,
    LoopDesign,
    PoleSpec,
    design_cascade,
    design_fl,
    design_small_signal,
    reachable_grid,
    schedule,
)
from aeropend_control.drive_design import (
    CASCADE_STRATEGIES,
    DEFAULT_SPECS,
    DriveSpec,
    default_spec,
    default_thrust_gain,
    design_drive,
    design_small_signal_on_drive,
    fl_design,
)
from aeropend_control.observer import ObserverSpec, PendulumObserver
from aeropend_control.oscillation import OscillationMonitor
from aeropend_control.pid import PID, PIDGains
from aeropend_sim.model import PlantModel
from aeropend_sim.params import Rig

#: Default derivative / velocity filter time constant [s].
DEFAULT_TF = 0.01
#: Strategy names accepted by :func:`make_strategy`.
STRATEGIES = ("fl_pid", "small_signal", "small_signal_fixed", "cascade", "fl_cascade")
#: Strategies that need the measured rotor speed ω₁ and armature current i_a.
NEEDS_MOTOR = CASCADE_STRATEGIES
#: Allocation chains accepted by the strategies.
ALLOCATORS = ("model", "thesis")
#: θ̇ estimators: filtered difference (:class:`VelocityEstimator`) or Kalman observer
#: (:class:`aeropend_control.observer.PendulumObserver`).
ESTIMATORS = ("difference", "observer")
class StrategyError(ValueError):
    """Invalid strategy configuration (the message names the value)."""


@dataclass(frozen=True)
class ControlOutput:
    """One controller sample.

    Attributes
    ----------
    duty : float
        Duty cycle τ ∈ [0, 1] to apply.
    error : float
        r − θ [rad].
    v : float
        Loop output: pseudo-control θ̈_desired [rad/s²] (FL) or thrust deviation Δf [N] (small-signal).
    thrust : float
        Requested thrust f [N] (before allocation saturation).
    theta_dot : float
        Estimated θ̇ [rad/s].
    saturated : int
        Allocation saturation (+1 high, −1 low, 0 none).
    nan_input : bool
        True if θ or r was not finite (previous duty held).
    """

    duty: float
    error: float
    v: float
    thrust: float
    theta_dot: float
    saturated: int
    nan_input: bool = False


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


class _Base:
    """Shared plumbing: estimator, PID, allocation, NaN handling, bumpless start."""

    def __init__(self, rig: Rig, gains: PIDGains, allocator: str, tf: float, dt: float | None,
                 f_init: float, estimator: str = "observer",
                 observer_spec: ObserverSpec | None = None) -> None:
        if estimator not in ESTIMATORS:
            raise StrategyError(f"estimator = {estimator!r}; expected one of {ESTIMATORS}")
        self.rig = rig
        self.model = PlantModel(rig)
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


class FeedbackLinearizationPID(_Base):
    """Input-output feedback linearisation + I-PD (thesis §6.6; see module doc).

    Parameters
    ----------
    rig : Rig
        Model parameters used by the linearising law (mgd/J, c/J, L/J) and the allocation.
    design : LoopDesign, optional
        Outer-loop gains (default :func:`fl_design` with :func:`default_spec` of ``fl_pid`` on the drive
        :func:`design_drive` names).
    cancel_damping : bool
        Include (c/J)·θ̂̇ in the law (default True).
    allocator : {"model", "thesis"}
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

    name = "fl_pid"

    def __init__(self, rig: Rig, design: LoopDesign | None = None, cancel_damping: bool = True,
                 allocator: str = "model", tf: float = DEFAULT_TF, dt: float | None = None,
                 f_init: float = 0.0, estimator: str = "observer",
                 observer_spec: ObserverSpec | None = None) -> None:
        if design is None:
            design = (fl_design(rig, default_spec(self.name, rig), design_drive(rig, self.name))
                      if cancel_damping else design_fl(rig, DEFAULT_SPECS[self.name], cancel_damping=False))
        self.design = design
        self.cancel_damping = cancel_damping
        super().__init__(rig, self.design.pid_gains(), allocator, tf, dt, f_init, estimator, observer_spec)

    def retune(self, other: FeedbackLinearizationPID) -> None:
        """Take ``other``'s design (gains) while running: bumpless (:meth:`PID.set_gains`), the
        observer, filters and integrator state kept; the output limits stay as they are."""
        if not isinstance(other, FeedbackLinearizationPID):
            raise StrategyError(f"cannot retune {self.name} with a {type(other).__name__} design")
        self.design = other.design
        g = self.pid.gains
        self.pid.set_gains(replace(other.pid.gains, u_min=g.u_min, u_max=g.u_max))

    def law(self, theta: float, theta_dot: float, v: float) -> float:
        """Thrust f [N] for pseudo-control v [rad/s²] (thesis Eq. 6.4, plus damping if cancelled)."""
        m = self.model
        damp = m.a_c * theta_dot if self.cancel_damping else 0.0
        return (v + m.a_g * math.sin(theta) + damp) / m.b_f

    def v_for_thrust(self, theta: float, theta_dot: float, f: float) -> float:
        """Inverse of :meth:`law`: the pseudo-control a thrust f realises."""
        m = self.model
        damp = m.a_c * theta_dot if self.cancel_damping else 0.0
        return m.b_f * f - m.a_g * math.sin(theta) - damp

    def step(self, r: float, theta: float) -> ControlOutput:
        """One sample: reference r [rad], measured θ [rad] → duty (see :class:`ControlOutput`)."""
        bad = self._nan(r, theta)
        if bad is not None:
            return bad
        y, thd = self._estimate(theta)
        lo = self.v_for_thrust(y, thd, self.f_min)
        hi = self.v_for_thrust(y, thd, self.f_max)
        self.pid.set_limits(lo, hi)
        v = self._pid_update(r, y, self.v_for_thrust(y, thd, self.f_init), thd)
        return self._finish(r, theta, thd, v, self.law(y, thd, v))


class SmallSignalPID(_Base):
    """Small-signal I-PD on thrust at an operating point, optionally gain-scheduled (thesis §6.5).

    Parameters
    ----------
    rig : Rig
    theta_op : float, optional
        Fixed operating point [rad] (no scheduling). If None, gains are scheduled on the
        reference over ``grid``.
    grid : sequence of float
        Scheduling grid [rad] (designs by :func:`aeropend_control.design.schedule`), cut to the
        rig's reach (:func:`aeropend_control.design.reachable_grid`): a rig with less thrust
        than the thesis rig is scheduled up to what it can hold.
    spec : PoleSpec, optional
        Default :func:`default_spec` of ``small_signal`` for ``rig``.
    allocator, tf, dt, f_init, estimator, observer_spec
        As for :class:`FeedbackLinearizationPID`.
    drive : DriveSpec, None or "auto"
        Drive chain the gains are placed on (None: the pendulum alone; default "auto":
        :func:`design_drive`).
    """

    name = "small_signal"

    def __init__(self, rig: Rig, theta_op: float | None = None, grid: tuple[float, ...] = DEFAULT_GRID,
                 spec: PoleSpec | None = None, allocator: str = "model", tf: float = DEFAULT_TF,
                 dt: float | None = None, f_init: float = 0.0, estimator: str = "observer",
                 observer_spec: ObserverSpec | None = None, drive: DriveSpec | str | None = "auto") -> None:
        spec = spec or default_spec("small_signal", rig)
        if isinstance(drive, str):
            if drive != "auto":
                raise StrategyError(f"drive = {drive!r}; expected a DriveSpec, None or 'auto'")
            drive = design_drive(rig, self.name)
        thetas = [float(theta_op)] if theta_op is not None else list(reachable_grid(rig, grid))
        if drive is not None:
            self.table = [design_small_signal_on_drive(rig, t, spec, drive) for t in thetas]
        elif theta_op is None:  # scheduled over the part of the grid the rig can hold (with headroom)
            self.table = schedule(rig, thetas, spec)
        else:
            self.table = [design_small_signal(rig, thetas[0], spec)]
        self.scheduled = theta_op is None
        self._grid = np.array([d.theta_op for d in self.table])
        first = self.table[0]
        super().__init__(rig, first.pid_gains(), allocator, tf, dt, f_init, estimator, observer_spec)
        self._op_r: float | None = None
        self.f0 = first.u_op
        self.gains_now = first.pid_gains(tf)

    def retune(self, other: SmallSignalPID) -> None:
        """Take ``other``'s design table (gains per operating point) while running; the gains of
        the current operating point change at the next sample, bumpless (:meth:`PID.set_gains`)."""
        if not isinstance(other, SmallSignalPID) or other.scheduled != self.scheduled:
            raise StrategyError(f"cannot retune {self.name} with a {type(other).__name__} design")
        self.table, self._grid = other.table, other._grid
        self._op_r = None  # re-read the gains at the next sample (same r: f0 unchanged)

    def _interp(self, r: float) -> tuple[PIDGains, float]:
        if not self.scheduled:
            d = self.table[0]
            return d.pid_gains(self.estimator.tf), d.u_op
        g = self._grid

        def at(key: str) -> float:
            return float(np.interp(r, g, [getattr(d, key) for d in self.table]))

        f0 = self.model.a_g * math.sin(min(max(r, 0.0), math.pi / 2)) / self.model.b_f
        gains = PIDGains(kp=at("kp"), ki=at("ki"), kd=at("kd"), b=0.0, c=0.0, tf=self.estimator.tf)
        return gains, f0

    def step(self, r: float, theta: float) -> ControlOutput:
        """One sample: reference r [rad], measured θ [rad] → duty (see :class:`ControlOutput`)."""
        bad = self._nan(r, theta)
        if bad is not None:
            return bad
        y, thd = self._estimate(theta)
        if r != self._op_r:  # new operating point (scheduled) / first sample
            gains, f0 = self._interp(r)
            if self._started:
                self.pid.i -= f0 - self.f0  # keep f = f0 + Δf continuous
            self.f0 = f0
            self.pid.set_gains(replace(gains, u_min=self.pid.gains.u_min, u_max=self.pid.gains.u_max))
            self.gains_now = gains
            self._op_r = r
        self.pid.set_limits(self.f_min - self.f0, self.f_max - self.f0)
        df = self._pid_update(r, y, self.f_init - self.f0, thd)
        return self._finish(r, theta, thd, df, self.f0 + df)


def make_strategy(
    name: str, rig: Rig, **options: object
) -> FeedbackLinearizationPID | SmallSignalPID | CascadeStrategy:
    """Build a strategy by name (:data:`STRATEGIES`); ``options`` go to its constructor.

    ``small_signal`` is gain-scheduled; ``small_signal_fixed`` needs ``theta_op``; ``cascade``
    and ``fl_cascade`` take ``cascade_design`` (a :class:`CascadeDesign`) and pass the other
    options to their outer loop (scheduled small-signal / FL). ``spec`` (a :class:`PoleSpec`) is
    accepted by every strategy: the FL ones turn it into their ``design`` (:func:`fl_design` on
    the drive :func:`design_drive` names) unless a ``design`` is given.

    Raises
    ------
    StrategyError
        On an unknown name or a missing ``theta_op``.
    """
    cdesign = (options.pop("cascade_design", None) or design_cascade(rig)) if name in NEEDS_MOTOR else None
    if name in ("fl_pid", "fl_cascade"):
        spec = options.pop("spec", None)
        if options.get("design") is None:  # fl_cascade's outer fl_pid gets its design, not a spec
            spec = spec or default_spec(name, rig, cdesign)
            options["design"] = fl_design(rig, spec, design_drive(rig, name, cdesign))  # type: ignore[arg-type]
    if name in NEEDS_MOTOR:
        if name == "cascade":
            options.setdefault("drive", design_drive(rig, name, cdesign))  # type: ignore[arg-type]
            if options.get("spec") is None:
                options["spec"] = default_spec(name, rig, cdesign)
        outer = make_strategy("fl_pid" if name == "fl_cascade" else "small_signal", rig, **options)
        return CascadeStrategy(outer, rig, cdesign)  # type: ignore[arg-type]
    if name == "fl_pid":
        return FeedbackLinearizationPID(rig, **options)  # type: ignore[arg-type]
    if name == "small_signal":
        return SmallSignalPID(rig, **options)  # type: ignore[arg-type]
    if name == "small_signal_fixed":
        if options.get("theta_op") is None:
            raise StrategyError("strategy 'small_signal_fixed' needs theta_op (operating point in rad)")
        return SmallSignalPID(rig, **options)  # type: ignore[arg-type]
    raise StrategyError(f"strategy = {name!r}; expected one of {STRATEGIES}")


# ---------------------------------------------------------------------------------- cascade
#: Factor on the speed-loop bandwidth per detected limit cycle of the motor cascade.
DETUNE_FACTOR = 2.0 / 3.0
#: Lowest speed-loop bandwidth the detuning goes to [rad/s] (below ≈ 20 rad/s the position loop
#: overshoots > 30 %, docs/control.md).
MIN_OMEGA_SPEED = 20.0


class MotorCascade:
    """Speed and current PI loops of the motor (thesis §6.7, Fig. 6.10), per sample.

    i_ref = PI_ω(ω₁,ref − ω₁) limited to [0, i_max]; v_a = PI_I(i_ref − i_a) limited to
    [0, v_max]; τ = inverse voltage map (Eq. 4.3 or ideal, :meth:`PlantModel.duty_for_voltage`).
    Both PIs use back-calculation anti-windup, so the limits are the thesis' current and voltage
    saturations.

    **Detuning on a limit cycle** (issue 19): a drive lag or delay the rig file does not know
    (40-60 ms) leaves the 45 rad/s speed loop without phase margin and the duty cycles between
    its limits at 6-8 Hz. An :class:`~aeropend_control.oscillation.OscillationMonitor` on the duty
    detects that cycle (a relay-feedback experiment run by accident) and the loops are redesigned
    with ω_s × :data:`DETUNE_FACTOR` (ω_c = :data:`~aeropend_control.design.LAG_CURRENT_RATIO`·ω_s,
    the rule of a rig file that declares its lag), bumplessly (:meth:`PID.set_gains`), at most
    down to :data:`MIN_OMEGA_SPEED`. A rig without such dynamics never cycles, so its design is
    never changed. ``detune=False`` keeps the design fixed.

    Parameters
    ----------
    rig : Rig
    design : CascadeDesign, optional
        Default :func:`aeropend_control.design.design_cascade`.
    dt : float, optional
        Sample period [s].
    detune : bool
        Detune the loops when the duty limit-cycles (default True).
    """

    def __init__(self, rig: Rig, design: CascadeDesign | None = None, dt: float | None = None,
                 detune: bool = True) -> None:
        self.rig = rig
        self.design = design or design_cascade(rig)
        d = self.design
        self.model = PlantModel(rig)
        self.dt = float(rig.sample_period if dt is None else dt)
        self.speed = PID(PIDGains(kp=d.kp_w, ki=d.ki_w, u_min=0.0, u_max=d.i_max), self.dt)
        self.current = PID(PIDGains(kp=d.kp_i, ki=d.ki_i, u_min=0.0, u_max=d.v_max), self.dt)
        self.i_ref = 0.0
        self.v_a = 0.0
        self.monitor = OscillationMonitor(self.dt) if detune else None
        #: Speed-loop bandwidths [rad/s] the loops were detuned to, in order (empty: as designed).
        self.detuned: list[float] = []
        #: Set for the one sample at which a limit cycle was detected: (ω_s before, ω_s after) [rad/s];
        #: equal values mean the floor was reached and nothing changed.
        self.detune_event: tuple[float, float] | None = None

    def reset(self) -> None:
        """Clear both integrators and the limit-cycle monitor (the design is kept)."""
        self.speed.reset()
        self.current.reset()
        if self.monitor is not None:
            self.monitor.reset()

    def step(self, omega_ref: float, omega: float, i_a: float) -> float:
        """Speed reference ω₁,ref [rad/s], measured ω₁ [rad/s] and i_a [A] → duty τ."""
        self.i_ref = self.speed.update(omega_ref, omega)
        self.v_a = self.current.update(self.i_ref, i_a)
        duty = self.model.duty_for_voltage(min(max(self.v_a, 0.0), self.design.v_max))
        self.detune_event = None
        if self.monitor is not None and self.monitor.update(duty):
            self._detune()
        return duty

    def _detune(self) -> None:
        """Redesign both PIs at a lower speed-loop bandwidth, bumplessly (see the class docstring)."""
        d = self.design
        w_s = max(d.omega_speed * DETUNE_FACTOR, MIN_OMEGA_SPEED)
        self.detune_event = (d.omega_speed, w_s)
        if w_s >= d.omega_speed:
            return
        w_c = min(d.omega_current, LAG_CURRENT_RATIO * w_s)
        new = design_cascade(self.rig, omega_speed=w_s, omega_current=w_c, i_max=d.i_max)
        self.speed.set_gains(replace(self.speed.gains, kp=new.kp_w, ki=new.ki_w))
        self.current.set_gains(replace(self.current.gains, kp=new.kp_i, ki=new.ki_i))
        self.design = new
        self.detuned.append(w_s)

    @property
    def saturated(self) -> int:
        """+1/−1 if a loop hit its upper/lower limit in the last sample, else 0."""
        return self.current.saturated or self.speed.saturated


class CascadeStrategy:
    """Position loop + motor cascade (thesis §6.7-6.8).

    The outer strategy (:class:`FeedbackLinearizationPID` for ``fl_cascade``, thesis §6.8, or the
    scheduled :class:`SmallSignalPID` for ``cascade``) computes the thrust f; the rotor-speed
    reference is ω₁,ref = n·(f/K_q)^(1/α) (inverse of Eqs. 3.3-3.4) and the motor cascade turns it
    into the duty cycle. Needs the measured rotor speed ω₁ and armature current i_a
    (thesis §4.2: SNS current, IR speed sensor); non-finite values hold the last duty.
    """

    def __init__(self, outer: FeedbackLinearizationPID | SmallSignalPID, rig: Rig,
                 design: CascadeDesign | None = None, dt: float | None = None) -> None:
        self.outer = outer
        outer.defer_predict = True  # the observer must see the duty the cascade applies
        self.name = "fl_cascade" if isinstance(outer, FeedbackLinearizationPID) else "cascade"
        self.inner = MotorCascade(rig, design, dt)
        self.model = self.inner.model
        self.observer = outer.observer
        self.pid = outer.pid
        self.last: ControlOutput | None = None

    def retune(self, other: CascadeStrategy) -> None:
        """Take ``other``'s outer-loop design while running (the motor loops depend on the rig only)."""
        if not isinstance(other, CascadeStrategy):
            raise StrategyError(f"cannot retune {self.name} with a {type(other).__name__} design")
        self.outer.retune(other.outer)  # type: ignore[arg-type]

    def omega_ref(self, f: float) -> float:
        """Rotor speed [rad/s] whose thrust is f [N] (0 for f ≤ 0)."""
        m = self.model
        return m.n * (f / m.K_q) ** (1.0 / m.alpha) if f > 0.0 else 0.0

    def step(self, r: float, theta: float, omega: float = math.nan, i_a: float = math.nan) -> ControlOutput:
        """One sample: reference, θ, ω₁, i_a → duty (see :class:`ControlOutput`)."""
        o = self.outer.step(r, theta)
        held = self.last.duty if self.last is not None else 0.0
        if o.nan_input:
            self.outer.advance(held)
            return replace(o, duty=held)
        if not (math.isfinite(omega) and math.isfinite(i_a)):
            self.pid.nan_count += 1
            self.outer.advance(held)
            return replace(o, duty=held, nan_input=True)
        f = min(max(o.thrust, self.outer.f_min), self.outer.f_max)
        duty = self.inner.step(self.omega_ref(f), omega, i_a)
        self.outer.advance(duty, omega)
        out = replace(o, duty=duty, saturated=o.saturated or self.inner.saturated)
        self.last = out
        return out
