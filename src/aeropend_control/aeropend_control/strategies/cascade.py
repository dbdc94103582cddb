"""Position loop + motor cascade (thesis §6.7-6.8): the cascades' shared machinery and ``cascade``.

The outer position loop (scheduled small-signal I-PD here, :class:`SmallSignalCascade`; feedback
linearisation in :mod:`aeropend_control.strategies.fl_cascade`) computes the thrust f; the
rotor-speed reference is ω₁,ref = n·(f/K_q)^(1/α) (inverse of Eqs. 3.3-3.4) and the motor cascade
(:class:`MotorCascade`: speed and current PI loops) turns it into the duty cycle. Needs the
measured rotor speed ω₁ and armature current i_a (thesis §4.2: SNS current, IR speed sensor);
non-finite values hold the last duty.
"""

from __future__ import annotations

import math
from abc import abstractmethod
from dataclasses import replace

from aeropend_control.design import LAG_CURRENT_RATIO, CascadeDesign, PoleSpec, design_cascade
from aeropend_control.drive_design import once_per_rig
from aeropend_control.oscillation import OscillationMonitor
from aeropend_control.pid import PID, PIDGains
from aeropend_control.strategies.base import ControlOutput, Measurement, Strategy, StrategyError
from aeropend_control.strategies.loop import PositionLoop
from aeropend_control.strategies.registry import register
from aeropend_control.strategies.small_signal import SmallSignalPID
from aeropend_sim.model import plant_model
from aeropend_sim.params import Rig

#: Factor on the speed-loop bandwidth per detected limit cycle of the motor cascade.
DETUNE_FACTOR = 2.0 / 3.0
#: Lowest speed-loop bandwidth the detuning goes to [rad/s] (below ≈ 20 rad/s the position loop
#: overshoots > 30 %, docs/control.md).
MIN_OMEGA_SPEED = 20.0


def _detuned_speed(design: CascadeDesign) -> float:
    """The speed-loop bandwidth [rad/s] one detuning step below ``design``'s (at least
    :data:`MIN_OMEGA_SPEED`)."""
    return max(design.omega_speed * DETUNE_FACTOR, MIN_OMEGA_SPEED)


@once_per_rig
def detune_chain(rig: Rig, design: CascadeDesign) -> tuple[CascadeDesign, ...]:
    """Each design :class:`MotorCascade`'s detuning moves to in turn from ``design``, down to the floor
    (once per rig and design: every cascade built on the rig shares them)."""
    chain = [design]
    while (w_s := _detuned_speed(chain[-1])) < chain[-1].omega_speed:
        d = chain[-1]
        w_c = min(d.omega_current, LAG_CURRENT_RATIO * w_s)
        chain.append(design_cascade(rig, omega_speed=w_s, omega_current=w_c, i_max=d.i_max))
    return tuple(chain[1:])


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
    down to :data:`MIN_OMEGA_SPEED`. Those designs are made when the cascade is built, so the
    sample that detects the cycle only switches gains (a design took 1.4-1.7 ms on 2026-12-01's
    machine, 7.5-8 ms on a slower one: up to four samples at 490 Hz). A rig without such dynamics
    never cycles, so its design is never changed. ``detune=False`` keeps the design fixed.

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
        self.model = plant_model(rig)
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
        #: The designs the detuning steps through after :attr:`design`, made here rather than in the
        #: per-sample call that detects the cycle (a design takes 1.4-8 ms: up to four samples at 490 Hz).
        self._detuned_designs = detune_chain(rig, self.design) if detune else ()

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
        """Move both PIs to the next lower speed-loop bandwidth, bumplessly (see the class docstring)."""
        d = self.design
        w_s = _detuned_speed(d)
        self.detune_event = (d.omega_speed, w_s)
        if w_s >= d.omega_speed:
            return
        new = self._detuned_designs[len(self.detuned)]
        self.speed.set_gains(replace(self.speed.gains, kp=new.kp_w, ki=new.ki_w))
        self.current.set_gains(replace(self.current.gains, kp=new.kp_i, ki=new.ki_i))
        self.design = new
        self.detuned.append(w_s)

    @property
    def saturated(self) -> int:
        """+1/−1 if a loop hit its upper/lower limit in the last sample, else 0."""
        return self.current.saturated or self.speed.saturated


class CascadeStrategy(Strategy):
    """Position loop + motor cascade (thesis §6.7-6.8; see module doc): the base of the cascades.

    A subclass names its outer loop's design in :meth:`build_outer`; :meth:`build` adds the motor
    loops.

    Parameters
    ----------
    outer : PositionLoop
        The position loop (its observer sees the duty the cascade applies).
    rig : Rig
    design : CascadeDesign, optional
        The motor loops (default :func:`aeropend_control.design.design_cascade`).
    dt : float, optional
        Sample period [s].
    """

    needs = ("theta", "omega", "i_a")
    #: ω_n = 9 rad/s: the speed loop (ω_s = 45 rad/s) adds lag; a faster outer loop overshoots
    #: > 5 % at 0.7 rad (docs/control.md).
    default_spec = PoleSpec(9.0)
    drive_kind = "cascade"

    def __init__(self, outer: PositionLoop, rig: Rig, design: CascadeDesign | None = None,
                 dt: float | None = None) -> None:
        self.outer = outer
        outer.defer_predict = True  # the observer must see the duty the cascade applies
        self.inner = MotorCascade(rig, design, dt)
        self.model = self.inner.model
        self.observer = outer.observer
        self.pid = outer.pid
        self.last: ControlOutput | None = None

    @classmethod
    def build(cls, rig: Rig, spec: PoleSpec | None = None, cascade_design: CascadeDesign | None = None,
              **options: object) -> CascadeStrategy:
        """Instance with the motor loops ``cascade_design`` (default
        :func:`~aeropend_control.design.design_cascade`) and the outer loop :meth:`build_outer`
        designs with ``spec`` and ``options``."""
        cdesign = cascade_design or design_cascade(rig)
        return cls(cls.build_outer(rig, spec, cdesign, **options), rig, cdesign)

    @classmethod
    @abstractmethod
    def build_outer(cls, rig: Rig, spec: PoleSpec | None, cascade: CascadeDesign,
                    **options: object) -> PositionLoop:
        """The outer position loop, designed with ``spec`` (default :meth:`default_spec_for` the rig
        and ``cascade``) on the drive :meth:`drive_for` names; ``options`` go to its constructor."""

    def reset(self) -> None:
        """Back to the initial state: outer loop, motor loops (their design kept), held duty."""
        self.outer.reset()
        self.inner.reset()
        self.last = None

    def retune(self, other: Strategy) -> None:
        """Take ``other``'s outer-loop design while running (the motor loops depend on the rig only)."""
        if not isinstance(other, CascadeStrategy):
            raise StrategyError(f"cannot retune {self.name} with a {type(other).__name__} design")
        self.outer.retune(other.outer)

    @property
    def nan_count(self) -> int:
        """Samples with a non-finite reference, θ, ω₁ or i_a."""
        return self.pid.nan_count

    @property
    def detune_event(self) -> tuple[float, float] | None:
        """The motor loops' :attr:`MotorCascade.detune_event` of the last sample."""
        return self.inner.detune_event

    def omega_ref(self, f: float) -> float:
        """Rotor speed [rad/s] whose thrust is f [N] (0 for f ≤ 0)."""
        m = self.model
        return m.n * (f / m.K_q) ** (1.0 / m.alpha) if f > 0.0 else 0.0

    def step(self, r: float, y: Measurement) -> ControlOutput:
        """One sample: reference, θ, ω₁, i_a → duty (see :class:`ControlOutput`)."""
        o = self.outer.step(r, y)
        held = self.last.duty if self.last is not None else 0.0
        if o.nan_input:
            self.outer.advance(held)
            return replace(o, duty=held)
        omega, i_a = y.omega, y.i_a
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


@register
class SmallSignalCascade(CascadeStrategy):
    """Scheduled small-signal I-PD (:class:`~aeropend_control.strategies.small_signal.SmallSignalPID`)
    commanding the motor cascade (thesis §6.7)."""

    name = "cascade"
    listed = 3
    description = "gain-scheduled small-signal I-PD over the motor speed/current PI cascade (§6.7)"

    @classmethod
    def build_outer(cls, rig: Rig, spec: PoleSpec | None, cascade: CascadeDesign,
                    **options: object) -> SmallSignalPID:
        """:class:`SmallSignalPID` with ``spec`` (default :meth:`default_spec_for`) on the cascade drive."""
        options.setdefault("drive", cls.drive_for(rig, cascade))
        if spec is None:
            spec = cls.default_spec_for(rig, cascade)
        return SmallSignalPID(rig, spec=spec, **options)  # type: ignore[arg-type]
