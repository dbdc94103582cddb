"""Small-signal I-PD on thrust at an operating point (thesis §6.5, Eqs. 6.1-6.3).

f = f₀(θ_op) + Δf, Δf = I-PD(r, θ) designed on the linearisation at θ_op; with gain scheduling
(:class:`SmallSignalPID`) the operating point is the reference (θ_op = r, gains and f₀
interpolated in a table of designs); a change of operating point is bumpless (the integrator
absorbs the jumps of f₀ and of kp), as in the linear design where the thrust is continuous.
:class:`SmallSignalFixedPID` keeps one operating point.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from aeropend_control.design import DEFAULT_GRID, PoleSpec, design_small_signal, reachable_grid, schedule
from aeropend_control.drive_design import DriveSpec, design_small_signal_on_drive
from aeropend_control.observer import ObserverSpec
from aeropend_control.pid import PIDGains
from aeropend_control.strategies.base import ControlOutput, Measurement, Strategy, StrategyError
from aeropend_control.strategies.loop import DEFAULT_TF, PositionLoop
from aeropend_control.strategies.registry import register
from aeropend_sim.params import Rig


@register
class SmallSignalPID(PositionLoop):
    """Small-signal I-PD on thrust, gain-scheduled on the reference unless ``theta_op`` is given
    (thesis §6.5; see module doc).

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
        Default :meth:`default_spec_for` ``rig``.
    allocator, tf, dt, f_init, estimator, observer_spec
        As for :class:`~aeropend_control.strategies.loop.PositionLoop`.
    drive : DriveSpec, None or "auto"
        Drive chain the gains are placed on (None: the pendulum alone; default "auto":
        :meth:`drive_for` the rig).
    """

    name = "small_signal"
    listed = 1
    description = "gain-scheduled small-signal I-PD on thrust (thesis §6.5)"
    #: ω_n = 9.5 rad/s: within 1.5× the time-optimal bound in every bench scenario (docs/control.md).
    default_spec = PoleSpec(9.5)

    def __init__(self, rig: Rig, theta_op: float | None = None, grid: tuple[float, ...] = DEFAULT_GRID,
                 spec: PoleSpec | None = None, allocator: str = "model", tf: float = DEFAULT_TF,
                 dt: float | None = None, f_init: float = 0.0, estimator: str = "observer",
                 observer_spec: ObserverSpec | None = None, drive: DriveSpec | str | None = "auto") -> None:
        spec = spec or self.default_spec_for(rig)
        if isinstance(drive, str):
            if drive != "auto":
                raise StrategyError(f"drive = {drive!r}; expected a DriveSpec, None or 'auto'")
            drive = self.drive_for(rig)
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

    @classmethod
    def build(cls, rig: Rig, spec: PoleSpec | None = None, **options: object) -> SmallSignalPID:
        """Instance designed with ``spec`` (default :meth:`default_spec_for` the rig); ``options``
        go to the constructor."""
        return cls(rig, spec=spec, **options)  # type: ignore[arg-type]

    def retune(self, other: Strategy) -> None:
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

    def step(self, r: float, y: Measurement) -> ControlOutput:
        """One sample: reference r [rad], measured θ [rad] (``y.theta``) → duty (:class:`ControlOutput`)."""
        theta = y.theta
        bad = self._nan(r, theta)
        if bad is not None:
            return bad
        y_hat, thd = self._estimate(theta)
        if r != self._op_r:  # new operating point (scheduled) / first sample
            gains, f0 = self._interp(r)
            if self._started:
                self.pid.i -= f0 - self.f0  # keep f = f0 + Δf continuous
            self.f0 = f0
            self.pid.set_gains(replace(gains, u_min=self.pid.gains.u_min, u_max=self.pid.gains.u_max))
            self.gains_now = gains
            self._op_r = r
        self.pid.set_limits(self.f_min - self.f0, self.f_max - self.f0)
        df = self._pid_update(r, y_hat, self.f_init - self.f0, thd)
        return self._finish(r, theta, thd, df, self.f0 + df)


@register
class SmallSignalFixedPID(SmallSignalPID):
    """:class:`SmallSignalPID` at one operating point ``theta_op`` [rad] (no scheduling; thesis §6.5).

    Raises
    ------
    StrategyError
        Without ``theta_op``.
    """

    name = "small_signal_fixed"
    listed = 2
    description = "small-signal I-PD on thrust at the fixed operating point theta_op"
    required = ("theta_op",)

    def __init__(self, rig: Rig, theta_op: float | None = None, **options: object) -> None:
        if theta_op is None:
            raise StrategyError(f"strategy {self.name!r} needs theta_op (operating point in rad)")
        super().__init__(rig, theta_op=theta_op, **options)  # type: ignore[arg-type]
