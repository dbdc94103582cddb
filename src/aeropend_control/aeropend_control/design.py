"""Gain design with python-control from a rig file (thesis §6.3, §6.5, §6.6; no rclpy).

Both position loops use an **I-PD** law (PID with setpoint weights b = 0, c = 0: the
reference enters only through the integral, so a set-point step gives neither a proportional
nor a derivative kick and the closed loop has no zeros)::

    u = ki·∫(r − θ)dt − kp·θ − kd·θ̇

designed by pole placement (:func:`control.place`) on the plant augmented with the integral
state z = ∫(r − θ)dt. The closed-loop poles are a complex pair ω_n·(−ζ ± j·sqrt(1 − ζ²)) and a
real pole −ρ·ω_n; the default ω_n = 9 rad/s, ζ = 0.7, ρ = 1 gives (python-control
``step_info`` of the linear loop) tr 0.33 s, tp 0.69 s, ts 0.53 s, Mp 1.5 %: inside Table 6.1
and the issue's goal (ts ≤ 1 s, Mp ≤ 5 %). Its peak angular acceleration is ≈ 22·Δθ rad/s² per
rad of step; the thesis rig delivers at most 16.7 rad/s² minus gravity (θ̈ ≥ −(mgd/J)·sin θ
with thrust ≥ 0), so steps beyond ≈ 0.5 rad touch the duty limits briefly (back-calculation
anti-windup). On the nominal rig (motor dynamics, 2.048 ms sampling, θ̇ filter) the simulated
metrics are within ≈ 0.1 s of the prediction (tp ≈ 0.79 s).

Plants (second order, θ̈ = −a0·θ − a1·θ̇ + g·u):

* **feedback linearisation** (thesis Eqs. 6.4-6.7): u = v, θ̈ = v − (c/J)·θ̇ (Eq. 6.6; a0 = 0,
  a1 = c/J, g = 1), or with the damping cancelled too, θ̈ = v (a1 = 0);
* **small-signal** (thesis Eqs. 6.1-6.3): u = Δf thrust [N], a0 = (mgd/J)·cos θ₀ and
  a1 = c/J read from :meth:`PlantModel.jacobian` at :meth:`PlantModel.equilibrium` (θ₀), g = L/J.

The predicted metrics are computed on the linear closed loop with the motor dynamics included
where they exist (small-signal: the full 4-state Jacobian with the thrust allocation linearised
at θ₀), so they show what the neglected actuator dynamics cost.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from aeropend_control.allocation import ModelAllocator
from aeropend_control.metrics import StepMetrics, step_metrics
from aeropend_control.pid import PIDGains
from aeropend_sim.model import OMEGA, TAU_F, THETA, THETA_DOT, PlantModel, plant_model
from aeropend_sim.params import Rig

# python-control is imported inside the functions that use it: importing it costs ~2 s
# (scipy.signal, matplotlib.pyplot), which `controller --help` and every importer would pay.
if TYPE_CHECKING:
    import control


class DesignError(ValueError):
    """Invalid design specification (the message names the value)."""


@dataclass(frozen=True)
class PoleSpec:
    """Closed-loop pole pattern: pair ω_n(−ζ ± j√(1−ζ²)) and real pole −ρ·ω_n.

    Attributes
    ----------
    omega_n : float
        Natural frequency [rad/s].
    zeta : float
        Damping ratio of the pair, in (0, 1).
    rho : float
        Real pole as a multiple of ω_n.
    """

    omega_n: float = 9.0
    zeta: float = 0.7
    rho: float = 1.0

    def poles(self) -> np.ndarray:
        """The three closed-loop poles [rad/s], shape (3,)."""
        for name in ("omega_n", "rho"):
            val = getattr(self, name)
            if not (math.isfinite(val) and val > 0.0):
                raise DesignError(f"pole spec {name} = {val!r} must be finite and > 0")
        if not 0.0 < self.zeta < 1.0:
            raise DesignError(f"pole spec zeta = {self.zeta!r} must be in (0, 1)")
        w, z = self.omega_n, self.zeta
        wd = w * math.sqrt(1.0 - z * z)
        return np.array([complex(-z * w, wd), complex(-z * w, -wd), -self.rho * w])


@dataclass(frozen=True)
class LoopDesign:
    """Result of one I-PD design.

    Attributes
    ----------
    kp, ki, kd : float
        Gains in the plant's input unit (v [rad/s²] for FL, thrust [N] for small-signal).
    a0, a1, g : float
        Design plant θ̈ = −a0·θ − a1·θ̇ + g·u [1/s², 1/s, unit⁻¹·rad/s²].
    theta_op : float
        Operating point [rad] (nan for FL).
    u_op : float
        Plant input at the operating point (thrust f₀ [N] for small-signal; 0 for FL).
    duty_op : float
        Equilibrium duty cycle at θ_op (nan for FL).
    predicted : StepMetrics
        Predicted unit-step metrics (python-control ``step_info``) of the linear closed loop.
    drive : str
        ``"static"``: poles placed on the pendulum alone (thrust taken as instantaneous);
        ``"duty"`` / ``"cascade"``: placed on the loop with the drive chain the rig file declares
        (:mod:`aeropend_control.drive_design`).
    """

    kp: float
    ki: float
    kd: float
    a0: float
    a1: float
    g: float
    theta_op: float
    u_op: float
    duty_op: float
    predicted: StepMetrics
    drive: str = "static"

    def pid_gains(self, tf: float = 0.0, method: str = "backward_euler") -> PIDGains:
        """I-PD :class:`PIDGains` (b = c = 0) with derivative filter ``tf`` [s]; no limits."""
        return PIDGains(kp=self.kp, ki=self.ki, kd=self.kd, b=0.0, c=0.0, tf=tf, method=method)


def place_ipd(a0: float, a1: float, g: float, spec: PoleSpec) -> tuple[float, float, float]:
    """I-PD gains (kp, ki, kd) placing the poles of θ̈ = −a0·θ − a1·θ̇ + g·u at ``spec``.

    Uses :func:`control.place` on the augmented state [z, θ, θ̇], ż = r − θ; u = −K·x gives
    ki = −K₀, kp = K₁, kd = K₂. Analytically: kd = (Σp − a1)/g, kp = (Σpᵢpⱼ − a0)/g, ki = Πp/g
    (with p = −poles).
    """
    import control
    if not (math.isfinite(g) and g != 0.0):
        raise DesignError(f"input gain g = {g!r} must be finite and non-zero")
    A = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, -a0, -a1]])
    B = np.array([[0.0], [0.0], [g]])
    K = np.asarray(control.place(A, B, spec.poles())).ravel()
    return float(K[1]), float(-K[0]), float(K[2])


def _closed_loop_2nd(
    a0: float, a1: float, g: float, kp: float, ki: float, kd: float
) -> control.TransferFunction:
    """r → θ of the I-PD loop on the 2nd-order plant: g·ki/(s³ + (a1 + g·kd)s² + (a0 + g·kp)s + g·ki)."""
    import control
    return control.tf([g * ki], [1.0, a1 + g * kd, a0 + g * kp, g * ki])


def step_samples(sys: control.LTI, n: int, dt: float) -> np.ndarray:
    """Unit-step response of a continuous SISO loop at t = k·dt, k = 0 … n − 1, from rest.

    The same samples as :func:`control.step_response` (its state-space realisation, zero initial
    state, y(0) = D), computed without its per-sample Python loop: a constant input makes the
    zero-order-hold discretisation exact, z[k+1] = E·z[k] with z = [x; u], u = 1 and
    E = expm([[A, B], [0, 0]]·dt) (Van Loan's block exponential, :func:`scipy.linalg.expm`), and
    the samples are filled by doubling, z[m … 2m − 1] = E^m·z[0 … m − 1] with E^m by repeated
    squaring: 13 matrix products for 5 001 samples instead of 5 000 steps (python-control's loop
    took 17-46 ms per 5 s response at 1 ms, half of ``design_gains``' time on a ``rig new`` rig
    file; this 0.2-0.4 ms, ``bench/results/step_response.json``). The samples agree with
    python-control's to rounding (``test/control/test_strategies.py`` checks 1e-9 relative).

    Parameters
    ----------
    sys : control.LTI
        Continuous-time single-input single-output loop (transfer function or state space).
    n : int
        Number of samples (≥ 1).
    dt : float
        Sample period [s] (> 0).

    Returns
    -------
    ndarray, shape (n,)
        y(k·dt) for a unit step of the input at t = 0.
    """
    import control
    from scipy.linalg import expm
    s = control.ss(sys)
    a, b, c, d = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (s.A, s.B, s.C, s.D))
    nx = a.shape[0]
    block = np.zeros((nx + 1, nx + 1))
    block[:nx, :nx] = a
    block[:nx, nx:] = b[:, :1]
    e = expm(block * dt)
    z = np.zeros((nx + 1, n))
    z[nx, 0] = 1.0
    m, power = 1, e
    while m < n:
        k = min(m, n - m)
        z[:, m:m + k] = power @ z[:, :k]
        m += k
        power = power @ power
    return (c[:1] @ z[:nx]).ravel() + d[0, 0]


def predict_step(sys: control.LTI, horizon: float = 5.0, dt: float = 1e-3) -> StepMetrics:
    """Unit-step metrics (:func:`aeropend_control.metrics.step_metrics`) of a linear loop r → θ,
    sampled every ``dt`` [s] over ``horizon`` [s] (:func:`step_samples`)."""
    t = np.arange(0.0, horizon + dt / 2, dt)
    return step_metrics(t, step_samples(sys, t.size, dt), 1.0)


def design_fl(rig: Rig, spec: PoleSpec | None = None, cancel_damping: bool = True) -> LoopDesign:
    """I-PD for the feedback-linearised pendulum (thesis Eq. 6.7, or θ̈ = v if the damping is cancelled).

    Parameters
    ----------
    rig : Rig
        Supplies c/J (only needed when ``cancel_damping`` is False).
    spec : PoleSpec, optional
        Closed-loop poles (default :class:`PoleSpec`).
    cancel_damping : bool
        True: f = (v + (mgd/J)·sin θ + (c/J)·θ̇)/(L/J), linear plant 1/s²;
        False: thesis Eq. 6.4, plant 1/(s(s + c/J)).
    """
    spec = spec or PoleSpec()
    a1 = 0.0 if cancel_damping else plant_model(rig).a_c
    kp, ki, kd = place_ipd(0.0, a1, 1.0, spec)
    pred = predict_step(_closed_loop_2nd(0.0, a1, 1.0, kp, ki, kd))
    return LoopDesign(kp, ki, kd, 0.0, a1, 1.0, math.nan, 0.0, math.nan, pred)


def linearise(rig: Rig, theta: float) -> tuple[PlantModel, np.ndarray, float, np.ndarray, np.ndarray]:
    """The rig's model linearised at the equilibrium that holds angle θ [rad].

    The rod's dry (Coulomb, Stribeck) friction is left out (``PlantModel.jacobian(...,
    dry_friction=False)``): its regularised sign has a slope of (T_f/J)/v_ε at rest, damping the
    rod does not have once it moves; designed on it, the small-signal loop oscillates on a rig
    file that declares Coulomb friction (a `gap`-corrected one that names it).

    Returns
    -------
    model, x_eq, tau_eq, A, B
        :class:`PlantModel`, equilibrium state (shape (n,)) and duty cycle, Jacobians (n×n, n×1)
        of :meth:`PlantModel.jacobian` there.

    Raises
    ------
    DesignError
        If θ is not a reachable equilibrium.
    """
    m = plant_model(rig)
    try:
        x_eq, tau_eq = m.equilibrium(theta)
    except ValueError as exc:
        raise DesignError(f"operating point theta_op = {theta!r} rad: {exc}") from exc
    A, B = m.jacobian(x_eq, tau_eq, dry_friction=False)
    return m, x_eq, tau_eq, A, B


def design_small_signal(rig: Rig, theta_op: float, spec: PoleSpec | None = None) -> LoopDesign:
    """I-PD on the small-signal model at θ₀ (thesis Eq. 6.3), thrust as the plant input.

    The pendulum coefficients come from :meth:`PlantModel.jacobian` at
    :meth:`PlantModel.equilibrium` (θ₀): a0 = −A[θ̇, θ] = (mgd/J)·cos θ₀, a1 = −A[θ̇, θ̇] = c/J.
    The predicted metrics use the full linearised model (pendulum + armature + rotor) with the
    thrust → duty allocation linearised at θ₀, i.e. the loop the controller really closes.

    Raises
    ------
    DesignError
        If θ₀ is not a reachable equilibrium.
    """
    import control
    spec = spec or PoleSpec()
    m, _, tau_eq, A, B = linearise(rig, theta_op)
    a0, a1 = -A[THETA_DOT, THETA], -A[THETA_DOT, THETA_DOT]
    g = m.b_f
    kp, ki, kd = place_ipd(a0, a1, g, spec)
    f0 = m.a_g * math.sin(theta_op) / m.b_f
    # full loop: states without the (inert, lag-free) duty state; duty = τ_eq + Δf·dτ/df
    keep = [i for i in range(A.shape[0]) if m.lag or i != TAU_F]
    Af, Bf = A[np.ix_(keep, keep)], B[keep, :]
    k_tau = dtau_df(m, f0)
    n = len(keep)
    it, id_ = keep.index(THETA), keep.index(THETA_DOT)
    K = np.zeros((1, n))
    K[0, it], K[0, id_] = kp, kd
    # closed loop, state [x, z]: Δτ = dτ/df·(ki·z − kp·θ − kd·θ̇); ż = r − θ
    Acl = np.zeros((n + 1, n + 1))
    Acl[:n, :n] = Af - Bf @ K * k_tau
    Acl[:n, n] = Bf[:, 0] * k_tau * ki
    Acl[n, it] = -1.0
    Bcl = np.zeros((n + 1, 1))
    Bcl[n, 0] = 1.0
    Ccl = np.zeros((1, n + 1))
    Ccl[0, it] = 1.0
    pred = predict_step(control.ss(Acl, Bcl, Ccl, 0.0))
    return LoopDesign(kp, ki, kd, float(a0), float(a1), g, float(theta_op), f0, float(tau_eq), pred)


def dtau_df(m: PlantModel, f0: float, rel: float = 1e-6) -> float:
    """Slope dτ/df [1/N] of the steady-state allocation at thrust f0 (central difference)."""
    from aeropend_control.allocation import ModelAllocator

    alloc = ModelAllocator(m.rig)
    h = max(abs(f0), 1e-3) * rel
    lo, hi = alloc.allocate(max(f0 - h, 0.0)), alloc.allocate(f0 + h)
    return (hi.duty - lo.duty) / (hi.requested - lo.requested)


def schedule(rig: Rig, thetas: np.ndarray | list[float], spec: PoleSpec | None = None) -> list[LoopDesign]:
    """Small-signal designs over a grid of operating points (gain scheduling table)."""
    th = np.asarray(thetas, dtype=float)
    if th.ndim != 1 or th.size < 1 or np.any(np.diff(th) <= 0.0):
        raise DesignError(f"schedule grid {thetas!r} must be a non-empty increasing 1-D list of angles")
    return [design_small_signal(rig, float(t), spec) for t in th]


#: Default gain-scheduling grid [rad] (cut to the rig's reach by :func:`reachable_grid`).
DEFAULT_GRID = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1)
#: Duty-cycle headroom kept above an equilibrium for control authority: a set point is reachable
#: when holding it needs τ ≤ 1 − REACH_DUTY_MARGIN (the loop can still push up by this much).
REACH_DUTY_MARGIN = 0.05
#: Largest angle considered [rad] without end stops: past π/2 the rod leans over its pivot, the thrust
#: that holds it falls with sin θ and only gravity pulls it back; near π that pull vanishes.
REACH_ANGLE_MAX = math.pi - 0.05
#: Margin [rad] kept below an upper end stop the rig file declares.
REACH_STOP_MARGIN = 0.05
#: Past π/2 a set point is held while gravity pulls the rod back (thrust off) with at least this share of
#: the full-command thrust's torque: below it the loop can push the rod over faster than it can bring it
#: back (a choice, not a measurement: 0.2 keeps a rig with twice the thrust it needs for π/2 below 2.94
#: rad and one with three times below 2.5 rad).
REACH_LEAN_FLOOR = 0.2


def reachable_angle(rig: Rig, duty_margin: float = REACH_DUTY_MARGIN, tol: float = 1e-4) -> float:
    """Largest set point θ [rad] the rig holds with control authority both ways, from its thrust,
    gravity and command range.

    Up to π/2 the holding thrust L·f = m·g·d·sin θ grows with θ: a set point is held when its
    equilibrium duty (:meth:`PlantModel.equilibrium`) is τ_eq ≤ 1 − ``duty_margin`` (bisection to
    ``tol``). When the rig holds π/2 that way it can lean past it, where the holding thrust falls
    again with sin θ and gravity is the only pull back: a set point past π/2 is held while the
    holding thrust is at least :data:`REACH_LEAN_FLOOR` × the full-command thrust f_max. At most
    :data:`REACH_ANGLE_MAX`, and
    :data:`REACH_STOP_MARGIN` below an upper end stop the rig file declares.

    Raises
    ------
    DesignError
        If not even a small angle (0.01 rad) is reachable (the actuator cannot lift the rod).
    """
    m = plant_model(rig)
    top = 1.0 - duty_margin
    cap = REACH_ANGLE_MAX
    if m.stops:
        cap = min(cap, float(m.assembly.values["pendulum.theta_max"]) - REACH_STOP_MARGIN)

    def ok(theta: float) -> bool:
        try:
            return m.equilibrium(theta)[1] <= top
        except ValueError:
            return False

    def bisect(lo: float, hi: float, good: Callable[[float], bool]) -> float:
        while hi - lo > tol:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if good(mid) else (lo, mid)
        return lo

    half = min(math.pi / 2, cap)
    if not ok(0.01):
        raise DesignError(f"rig {rig.name!r}: holding even 0.01 rad needs a duty cycle above {top:g}: "
                          "the actuator cannot lift the rod")
    if not ok(half):
        return bisect(0.01, half, ok)
    if cap <= half:
        return half
    f_floor = REACH_LEAN_FLOOR * ModelAllocator(rig).f_max

    def leans(theta: float) -> bool:  # past π/2: the holding thrust falls with θ
        return m.assembly.thrust_to_hold(theta) >= f_floor

    return cap if leans(cap) else bisect(half, cap, leans)


#: Spacing [rad] of the scheduling points added past the default grid up to a larger reach.
GRID_EXTENSION_STEP = 0.2


def reachable_grid(rig: Rig, grid: tuple[float, ...] | list[float] = DEFAULT_GRID,
                   duty_margin: float = REACH_DUTY_MARGIN) -> tuple[float, ...]:
    """The scheduling grid fitted to the rig's reach (:func:`reachable_angle`): cut there, with the
    reach itself as the last point, when the grid goes beyond it; extended by points every
    :data:`GRID_EXTENSION_STEP` rad up to the reach (the last point) when the rig holds more, e.g.
    past π/2. Every design point is an equilibrium the actuator holds with headroom, whatever the rig."""
    reach = reachable_angle(rig, duty_margin)
    kept = [float(t) for t in grid if t < reach - 1e-3]
    if kept and max(grid) < reach:
        t = kept[-1] + GRID_EXTENSION_STEP
        while t < reach - 0.5 * GRID_EXTENSION_STEP:
            kept.append(round(t, 6))
            t += GRID_EXTENSION_STEP
    if not kept or abs(kept[-1] - reach) > 1e-3:
        kept.append(reach)
    return tuple(kept)




# ---------------------------------------------------------------------------------- cascade
@dataclass(frozen=True)
class CascadeDesign:
    """Gains and limits of the motor speed/current cascade (thesis §6.7, Fig. 6.10).

    Attributes
    ----------
    kp_w, ki_w : float
        Speed PI [A·s/rad, A/rad]: i_ref = PI(ω₁,ref − ω₁).
    kp_i, ki_i : float
        Current PI [V/A, V/(A·s)]: v_a = PI(i_ref − i_a).
    i_max : float
        Current-reference limit [A].
    v_max : float
        Voltage limit [V] (the H-bridge at τ = 1).
    omega_speed, omega_current : float
        Design bandwidths of the speed and current loops [rad/s].
    predicted : StepMetrics
        Unit step of ω₁,ref → ω₁ of the linear cascade at the design speed (python-control).
    """

    kp_w: float
    ki_w: float
    kp_i: float
    ki_i: float
    i_max: float
    v_max: float
    omega_speed: float
    omega_current: float
    predicted: StepMetrics


#: Phase margin [deg] the speed loop keeps against a drive lag + delay the rig file declares
#: (T = T_a + T_d treated as one first-order lag: atan(ω_s·T) ≤ 90° − margin).
LAG_PHASE_MARGIN_DEG = 35.0
#: Current-loop bandwidth as a multiple of the speed loop's when a drive lag limits the latter.
LAG_CURRENT_RATIO = 2.5


def design_cascade(rig: Rig, omega_speed: float = 45.0, omega_current: float = 120.0,
                   theta_op: float = 0.4, i_max: float = 2.0) -> CascadeDesign:
    """PI gains of the speed and current loops by pole-zero cancellation (IMC / technical optimum).

    Current loop, plant 1/(L_a·s + R_a) (back-EMF treated as a disturbance; Eq. 3.5):
    kp_i = L_a·ω_c, ki_i = R_a·ω_c, closed loop ω_c/(s + ω_c); on a rig whose armature is
    quasi-static (L_a not modelled, e.g. a fitted voltage-amplifier rig) the plant is 1/R_a and the
    loop is integral only (kp_i = 0, ki_i = R_a·ω_c), with the same closed loop.
    Speed loop, plant K_t/(J_m·s + B_eff) (the back-EMF acts inside the current loop) with
    B_eff = B_m + 2·K_d·ω₁₀ linearised at the rotor speed ω₁₀ of the equilibrium θ_op:
    kp_w = J_m·ω_s/K_t, ki_w = B_eff·ω_s/K_t. ω_s < ω_c keeps the loops separated.
    Defaults ω_c = 120 rad/s, ω_s = 45 rad/s: robust to an unmodelled 10 ms actuator lag plus
    5 ms delay (ω_c = 200 rad/s, ω_s = 60 rad/s, the sample-rate limit ω_c·T_s ≈ 0.4, is faster
    on the nominal rig but the current loop then limit-cycles under that lag + delay; below
    ω_s ≈ 30 rad/s the speed loop is too slow for the 9 rad/s position loop and the step
    overshoots; sweep in docs/control.md). A rig file that declares a drive lag T_a and/or
    delay T_d (``effects.actuator_lag`` / ``input_delay``, e.g. the ``corrected_rig.yaml`` of
    ``gap``) limits ω_s ≤ tan(90° − :data:`LAG_PHASE_MARGIN_DEG`)/(T_a + T_d) and
    ω_c ≤ :data:`LAG_CURRENT_RATIO`·ω_s (issue 19: at ω_s = 45 rad/s an unmodelled 40-60 ms lag
    makes the loops limit-cycle, at 30 rad/s not). The predicted metrics
    are those of the full linear cascade including the back-EMF coupling.

    Raises
    ------
    DesignError
        On non-positive bandwidths or a current limit ≤ 0, or a rig without an armature (``esc``:
        the message names the strategies that need θ only).
    """
    import control
    for name, val in (("omega_speed", omega_speed), ("omega_current", omega_current), ("i_max", i_max)):
        if not (math.isfinite(val) and val > 0.0):
            raise DesignError(f"cascade {name} = {val!r} must be finite and > 0")
    m = plant_model(rig)
    if not m.assembly.armature:
        raise DesignError(f"rig {rig.name!r}: a motor cascade (cascade, fl_cascade) closes loops "
                          "on the armature current i_a and the rotor speed ω₁ of a DC motor; the "
                          f"{rig.family} family has no armature (its ESC runs its own speed loop): use "
                          "fl_pid or small_signal, which need the angle θ only")
    lag = (m.T_a if m.lag else 0.0) + m.delay
    if lag > 0.0:  # the rig file knows a drive lag/delay: keep the speed loop's phase margin
        omega_speed = min(omega_speed, math.tan(math.radians(90.0 - LAG_PHASE_MARGIN_DEG)) / lag)
        omega_current = min(omega_current, LAG_CURRENT_RATIO * omega_speed)
    x_eq, _ = m.equilibrium(min(theta_op, reachable_angle(rig)))
    w0 = float(x_eq[OMEGA])
    b_eff = m.B_m + 2.0 * m.K_d * w0
    kp_w, ki_w = m.J_m * omega_speed / m.K_t, b_eff * omega_speed / m.K_t
    ki_i = m.R * omega_current
    if m.dynamic_current:
        kp_i = m.L * omega_current
        # full linear loop with back-EMF: states (i_a, ω₁, z_i, z_w)
        A = np.array([
            [-(m.R + kp_i) / m.L, -(m.K_w + kp_i * kp_w) / m.L, ki_i / m.L, kp_i * ki_w / m.L],
            [m.K_t / m.J_m, -b_eff / m.J_m, 0.0, 0.0],
            [-1.0, -kp_w, 0.0, ki_w],
            [0.0, -1.0, 0.0, 0.0],
        ])
        B = np.array([[kp_i * kp_w / m.L], [0.0], [kp_w], [1.0]])
        C = np.array([[0.0, 1.0, 0.0, 0.0]])
    else:
        # quasi-static armature (L_a not modelled: i_a = (v_a − K_ω·ω₁)/R_a): the current plant is
        # the gain 1/R_a, so an integral current loop v_a = ki_i·∫(i_ref − i_a) with ki_i = R_a·ω_c
        # gives i_a/i_ref = ω_c/(s + ω_c) (kp_i = 0). Linear loop with back-EMF: states (ω₁, z_i, z_w),
        # i_a = (ki_i·z_i − K_ω·ω₁)/R_a.
        kp_i = 0.0
        i_z, i_w = ki_i / m.R, -m.K_w / m.R  # ∂i_a/∂z_i, ∂i_a/∂ω₁
        A = np.array([
            [m.K_t * i_w / m.J_m - b_eff / m.J_m, m.K_t * i_z / m.J_m, 0.0],
            [-kp_w - i_w, -i_z, ki_w],
            [-1.0, 0.0, 0.0],
        ])
        B = np.array([[0.0], [kp_w], [1.0]])
        C = np.array([[1.0, 0.0, 0.0]])
    pred = predict_step(control.ss(A, B, C, 0.0), horizon=0.5, dt=1e-4)
    return CascadeDesign(kp_w, ki_w, kp_i, ki_i, i_max, m.armature_voltage(1.0), omega_speed, omega_current,
                         pred)
