"""Feedback linearisation + I-PD (thesis §6.6, Eqs. 6.4-6.7).

v = I-PD(r, θ) (the pseudo-control θ̈_desired), thrust f = (v + (mgd/J)·sin θ + (c/J)·θ̂̇)/(L/J)
(damping cancelled too; with ``cancel_damping=False`` the thesis' Eq. 6.4 without the damping
term), then thrust → duty allocation (:mod:`aeropend_control.allocation`). The PID's output limits
are the thrust limits [f_min, f_max] mapped through the law at the current θ, θ̂̇, so
back-calculation anti-windup sees the real actuator saturation.
"""

from __future__ import annotations

import math
from dataclasses import replace

from aeropend_control.design import LoopDesign, PoleSpec, design_fl
from aeropend_control.drive_design import fl_design
from aeropend_control.observer import ObserverSpec
from aeropend_control.strategies.base import ControlOutput, Measurement, Strategy, StrategyError
from aeropend_control.strategies.loop import DEFAULT_TF, PositionLoop
from aeropend_control.strategies.registry import register
from aeropend_sim.params import Rig


@register
class FeedbackLinearizationPID(PositionLoop):
    """Input-output feedback linearisation + I-PD (thesis §6.6; see module doc).

    Parameters
    ----------
    rig : Rig
        Model parameters used by the linearising law (mgd/J, c/J, L/J) and the allocation.
    design : LoopDesign, optional
        Outer-loop gains (default :func:`fl_design` with :meth:`default_spec_for` the rig on the
        drive :meth:`drive_for` names).
    cancel_damping : bool
        Include (c/J)·θ̂̇ in the law (default True).
    allocator, tf, dt, f_init, estimator, observer_spec
        As for :class:`~aeropend_control.strategies.loop.PositionLoop`.
    """

    name = "fl_pid"
    listed = 0
    default = True
    description = "feedback linearisation + I-PD on θ (thesis §6.6)"
    #: ω_n = 9.5 rad/s: within 1.5× the time-optimal bound in every bench scenario (docs/control.md).
    default_spec = PoleSpec(9.5)
    linearising = True

    def __init__(self, rig: Rig, design: LoopDesign | None = None, cancel_damping: bool = True,
                 allocator: str = "model", tf: float = DEFAULT_TF, dt: float | None = None,
                 f_init: float = 0.0, estimator: str = "observer",
                 observer_spec: ObserverSpec | None = None) -> None:
        if design is None:
            design = (fl_design(rig, self.default_spec_for(rig), self.drive_for(rig))
                      if cancel_damping else design_fl(rig, self.default_spec, cancel_damping=False))
        self.design = design
        self.cancel_damping = cancel_damping
        super().__init__(rig, self.design.pid_gains(), allocator, tf, dt, f_init, estimator, observer_spec)

    @classmethod
    def build(cls, rig: Rig, spec: PoleSpec | None = None, design: LoopDesign | None = None,
              **options: object) -> FeedbackLinearizationPID:
        """Instance with ``design`` or, if None, :func:`fl_design` of ``spec`` (default
        :meth:`default_spec_for` the rig) on the drive :meth:`drive_for` names; ``options`` go to
        the constructor."""
        if design is None:
            design = fl_design(rig, spec or cls.default_spec_for(rig), cls.drive_for(rig))
        return cls(rig, design=design, **options)  # type: ignore[arg-type]

    def retune(self, other: Strategy) -> None:
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

    def step(self, r: float, y: Measurement) -> ControlOutput:
        """One sample: reference r [rad], measured θ [rad] (``y.theta``) → duty (:class:`ControlOutput`)."""
        theta = y.theta
        bad = self._nan(r, theta)
        if bad is not None:
            return bad
        y_hat, thd = self._estimate(theta)
        lo = self.v_for_thrust(y_hat, thd, self.f_min)
        hi = self.v_for_thrust(y_hat, thd, self.f_max)
        self.pid.set_limits(lo, hi)
        v = self._pid_update(r, y_hat, self.v_for_thrust(y_hat, thd, self.f_init), thd)
        return self._finish(r, theta, thd, v, self.law(y_hat, thd, v))
