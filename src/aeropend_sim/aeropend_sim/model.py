"""Aeropendulum plant model: the rig's components and effects as one state-space model.

State vector ``x``, SI units: the state layout of the rig (:attr:`PlantModel.states`,
:mod:`aeropend_sim.components.states`): the signal chain's five states in fixed positions,

====  ==========  =========  ===============================================================
idx   symbol      unit       meaning
====  ==========  =========  ===============================================================
0     θ           rad        pendulum angle from the vertical (0 = hanging down)
1     θ̇           rad/s      pendulum angular velocity Ω
2     i_a         A          armature current (≡ 0 on a family without an armature: esc)
3     ω₁          rad/s      rotor speed (motor side of the gearbox)
4     τ_f         1          duty cycle after the first-order actuator lag (= τ without lag)
====  ==========  =========  ===============================================================

then the own states of the effects acting on the rig, in their order (``motor_heating``: the
winding's temperature rise T_m [K]). Indices come from the layout (``model.states.index("i_a")``);
the constants :data:`THETA` … :data:`TAU_F` are the chain's fixed positions.

Input ``u``: duty-cycle command τ ∈ [0, 1] (after the input delay, which the simulator applies
by shifting the zero-order-hold input in time).

The equations are not written here: each component and effect declares its own terms in
``aeropend_sim.components`` (one module each), and :class:`aeropend_sim.components.assembly.Assembly`
composes the active ones along the signal chain duty → drive (armature voltage or ESC speed
set-point) → armature → rotor → gearbox → thrust → rod. ``docs/model.md`` lists them (generated
from the registry). For the thesis rig the chain is thesis Eqs. 3.1-3.10 with the measured
H-bridge map (Eq. 4.3); substituting Eq. 3.6 into Eq. 3.8 gives the thesis' Eq. 3.10, while this
model keeps ω₁ as a state so the armature inductance, propeller drag and rotor inertia can be
switched on.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable
from functools import cached_property

import numpy as np

from aeropend_sim.components.assembly import Assembly, AssemblyError
from aeropend_sim.components.pendulum.rod import G
from aeropend_sim.components.states import I_A, OMEGA, TAU_F, THETA, THETA_DOT, StateLayout
from aeropend_sim.components.xp import MATH, NUMPY
from aeropend_sim.params import Rig

__all__ = [
    "I_A",
    "OMEGA",
    "TAU_F",
    "THETA",
    "THETA_DOT",
    "G",
    "ModelError",
    "PlantModel",
    "plant_model",
]

#: Short attribute names of earlier versions -> (parameter key, effective value?). An effective
#: value is the parameter's absent value when its effect is off, 0 when the rig's family has no
#: such effect (an ESC has no B_m: no such torque); otherwise the rig's value. Read by
#: aeropend_control and aeropend_ident where they still compute with the model's numbers directly.
_LEGACY_ATTRS: dict[str, tuple[str, bool]] = {
    "T_a": ("actuator.lag_time_constant", False), "tau_dz": ("actuator.dead_zone", True),
    "v_supply": ("actuator.v_supply", False), "R": ("motor.R_a", False), "L": ("motor.L_a", False),
    "K_w": ("motor.K_omega", True), "K_t": ("motor.K_t", False), "J_m": ("motor.J_m", False),
    "B_m": ("motor.B_m", True), "K_d": ("motor.K_d", True),
    "n": ("motor.gear_ratio", False), "K_q": ("thrust.K_q", False), "alpha": ("thrust.exponent", True),
    "a_g": ("pendulum.mgd_over_J", False), "a_c": ("pendulum.c_over_J", True),
    "a_f": ("pendulum.coulomb_over_J", True), "v_eps": ("pendulum.friction_velocity", False),
    "a_s": ("pendulum.stribeck_over_J", True), "v_s": ("pendulum.stribeck_velocity", False),
    "b_f": ("pendulum.L_over_J", False), "th_min": ("pendulum.theta_min", False),
    "th_max": ("pendulum.theta_max", False), "k_s": ("pendulum.stop_stiffness", False),
    "c_s": ("pendulum.stop_damping", False),
}


class ModelError(ValueError):
    """A request the model cannot satisfy (e.g. an unreachable equilibrium)."""


class PlantModel:
    """Continuous-time aeropendulum model built from a :class:`~aeropend_sim.params.Rig`.

    The right-hand side is generated once per rig from the active terms (no branches on the
    effect switches at run time); :attr:`rhs_source` shows it.

    Parameters
    ----------
    rig : Rig
        Parameter set, actuator family and effect switches.

    Attributes
    ----------
    assembly : Assembly
        The active components and effects, effective parameter values, terms per slot.
    lag, dynamic_current, hbridge, stops : bool
        Actuator lag active; armature current a state; H-bridge map on; end stops on.
    states : StateLayout
        The state vector (module doc): ``states.size`` entries, ``states.index(name)``.
    delay : float
        Input delay T_d [s] (0 when off), applied by the simulator.
    """

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        e = rig.effects
        self.assembly = a = Assembly(rig.family, rig.values(), {f: getattr(e, f) for f in vars(e)})
        self.family = rig.family
        self.lag = a.lag
        self.dynamic_current = a.dynamic_current
        self.states: StateLayout = a.states
        self.hbridge = a.has("hbridge_map")
        self.stops = a.has("end_stops")
        self.delay = a.values["actuator.input_delay"]
        raw = rig.values()
        for attr, (key, effective) in _LEGACY_ATTRS.items():
            if key in raw:
                setattr(self, attr, a.values[key] if effective else raw[key])
            elif effective:
                setattr(self, attr, 0.0)
        if "actuator.hbridge_k0" in raw:
            self.k = tuple(raw[f"actuator.hbridge_k{j}"] for j in range(4))

    def __reduce__(self) -> tuple[type, tuple[Rig]]:
        """Pickle and deep-copy as the rig (the generated right-hand side is rebuilt from it)."""
        return (PlantModel, (self.rig,))

    @property
    def rhs_source(self) -> str:
        """Python source of the generated :meth:`rhs`."""
        return self.assembly.rhs_source

    # ------------------------------------------------------------------ actuator chain
    def effective_duty(self, tau: float) -> float:
        """Duty cycle after the duty transforms (dead zone), τ_e = max(0, τ − τ_dz)/(1 − τ_dz)."""
        return float(self.assembly.duty_chain(MATH, tau))

    def drive(self, tau: float) -> float:
        """Drive quantity for a duty cycle τ already past the lag: v_a [V] (voltage families) or
        the ESC's rotor-speed set-point ω_ss [rad/s] (``esc``)."""
        return float(self.assembly.drive(MATH, tau))

    def _voltage_family(self, what: str) -> None:
        if self.assembly.drive_name != "v_a":
            raise ModelError(f"{what}: the {self.family} family has no armature voltage (its drive quantity "
                             f"is {self.assembly.drive_name})")

    def armature_voltage(self, tau: float) -> float:
        """Armature voltage v_a [V] for a duty cycle τ already past the actuator lag.

        Ideal map v_a = v_supply·τ_e, the H-bridge map of thesis Eq. 4.3 clipped at 0 V, or an
        amplifier's v_offset + v_max·τ_e.

        Raises
        ------
        ModelError
            On a family without an armature voltage (``esc``).
        """
        self._voltage_family("armature_voltage")
        return self.drive(tau)

    def duty_for_drive(self, q: float) -> float:
        """Inverse of :meth:`drive` (steady state, no lag): duty τ for a drive quantity q.

        Raises
        ------
        ModelError
            If ``q`` is negative or beyond what τ = 1 delivers.
        """
        unit = "V" if self.assembly.drive_name == "v_a" else "rad/s"
        what = "armature voltage" if unit == "V" else "rotor-speed set-point"
        if q < 0.0:
            raise ModelError(f"{what} {q:g} {unit} < 0 is not reachable with τ >= 0")
        tau = self.assembly.duty_for_drive(q)
        if tau > 1.0 + 1e-12:
            raise ModelError(
                f"{what} {q:.4g} {unit} needs duty cycle {tau:.4g} > 1 "
                f"(max {self.drive(1.0):.4g} {unit})"
            )
        return min(tau, 1.0)

    def duty_for_voltage(self, v_a: float) -> float:
        """Inverse of :meth:`armature_voltage` (steady state, no lag): duty τ for a voltage v_a.

        Raises
        ------
        ModelError
            If ``v_a`` is negative or beyond what τ = 1 delivers, or the family has no armature
            voltage.
        """
        self._voltage_family("duty_for_voltage")
        return self.duty_for_drive(v_a)

    def thrust(self, omega_rotor: float) -> float:
        """Thrust f [N] = K_q·|ω₂|^α·sign(ω₂) with ω₂ = ω₁/n (thesis Eqs. 3.3-3.4)."""
        return float(self.assembly.thrust_scalar(float(omega_rotor)))

    def current(self, x: np.ndarray | list[float], u: float) -> float:
        """Armature current i_a [A]: the state, algebraic in quasi-static mode (Eq. 3.6), 0 without
        an armature (``esc``)."""
        if self.dynamic_current:
            return float(x[I_A])
        if not self.assembly.armature:
            return 0.0
        return float(self.assembly.point(MATH, [float(v) for v in x], float(u))["i_a"])

    def outputs(self, x: np.ndarray, u: np.ndarray) -> dict[str, np.ndarray]:
        """Noise-free channels of the family for states x (N, n) and actuator-side inputs u (N,).

        Keys: ``theta``, ``theta_dot``, ``omega_rotor``, ``omega_prop``, ``thrust``, for the
        voltage-driven families ``i_a`` and ``v_a`` (absent on an ESC, not zeros), and each effect
        state by name (``T_m``).
        """
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        p = self.assembly.point(NUMPY, x, u)
        out = {"theta": x[:, THETA].copy(), "theta_dot": x[:, THETA_DOT].copy(),
               "omega_rotor": x[:, OMEGA].copy(), "omega_prop": np.asarray(p["omega_prop"], dtype=float),
               "thrust": np.asarray(p["thrust"], dtype=float)}
        if self.assembly.armature:
            out["i_a"] = x[:, I_A].copy() if self.dynamic_current else np.asarray(p["i_a"], dtype=float)
            out["v_a"] = np.asarray(p["v_a"], dtype=float) + 0.0 * u
        for st in self.states.extra:
            out[st.name] = x[:, self.states.index(st.name)].copy()
        return out

    # ------------------------------------------------------------------ dynamics
    @cached_property
    def rhs(self) -> Callable[[float, np.ndarray | list[float], float], list[float]]:
        """The state derivative function ``rhs(t, x, u)`` -> dx/dt (list of ``states.size`` floats; see
        module doc), generated for this rig on first use (:attr:`Assembly.rhs`) and then an attribute of the
        instance (no property call per evaluation: ODE solvers call it directly).

        Its arguments: ``t`` [s], the time (unused: the model is time invariant; kept for ODE
        solvers); ``x``, array_like of shape (n,), the state; ``u``, the duty cycle τ in [0, 1]
        reaching the actuator (after the input delay).
        """
        return self.assembly.rhs

    def dry_friction(self, thd: float) -> float:
        """Rod dry friction over inertia [rad/s²] at rate θ̇ [rad/s] (0 when off): Coulomb plus
        Stribeck part, (T_f/J + ((T_s − T_f)/J)·exp(−(θ̇/v_s)²))·tanh(θ̇/v_ε)."""
        point = {"theta": 0.0, "theta_dot": float(thd), "thrust": 0.0}
        values = self.assembly.slot_values("rod", MATH, point)
        terms = [t for t in self.assembly.slots.get("rod", ()) if t.regularised_sign]
        return -sum((values[t.label] for t in terms), 0.0)

    def jacobian(self, x: np.ndarray | list[float], u: float,
                 dry_friction: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Linearisation A = ∂f/∂x (n×n), B = ∂f/∂u (n×1) at (x, u), n = ``states.size``.

        The chain rule over each active term's partial derivatives (declared with the term, or a
        documented central difference of it). Used for small-signal design (thesis Eq. 6.3);
        checked against finite differences of :meth:`rhs` in the tests. Non-smooth points
        (dead-zone edge, map clip at 0 V, stop contact onset) take the one-sided derivative of the
        active branch.

        ``dry_friction=False`` leaves out the slope of the rod's dry friction (:meth:`dry_friction`).
        Its sign is regularised over v_ε only for simulation, so at rest the slope is
        (T_f/J)/v_ε, hundreds of 1/s: damping that the rod has only for motions slower than v_ε.
        A controller designed on it would count on damping that is gone as soon as the rod moves
        (a Coulomb force has constant size), so controller design omits it.
        """
        return self.assembly.jacobian(x, u, dry_friction=dry_friction)

    # ------------------------------------------------------------------ steady state
    def equilibrium(self, theta: float) -> tuple[np.ndarray, float]:
        """Equilibrium state and duty cycle that hold the rod at angle θ.

        Solves the rod's balance for the thrust (L·f = m·g·d·sin θ), inverts the thrust law and
        the gearbox, then the rotor's steady state (DC motor: the torque balance
        K_t·i_a = B_m·ω₁ + T_c + K_d·ω₁² and v_a = R_a·i_a + K_ω·ω₁; ESC: ω_ss = ω₁), then the
        drive map (Eq. 4.3, ideal, amplifier or the ESC's throttle map) and the dead zone.

        Parameters
        ----------
        theta : float
            Angle [rad], in [0, π): past π/2 the thrust that holds the rod falls again with sin θ
            (the rod leans over its pivot and gravity pulls it back, as on rigs that hold 1-2.2 rad).

        Returns
        -------
        x_eq : ndarray, shape (n,)
            The effects' own states at their initial values (:meth:`Assembly.steady_state`).
        tau_eq : float

        Raises
        ------
        ModelError
            If θ is outside [0, π) or needs a duty cycle above 1.
        """
        x, q = self._steady_state(theta)
        tau = self.duty_for_drive(q) if q > 0.0 else 0.0
        x[TAU_F] = tau
        return np.array(x), tau

    def holding_duty(self, theta: float) -> float:
        """The duty cycle τ that holds the rod at angle θ, not limited to 1: :meth:`equilibrium`'s
        τ where that is at most 1, and past the actuator's reach the τ > 1 it would take (a smooth
        function of θ up to π/2, whose root τ(θ) = 1 is the reach).

        Raises
        ------
        ModelError
            If θ is outside [0, π) or the chain has no steady state there.
        """
        _, q = self._steady_state(theta)
        return self.assembly.duty_for_drive(q) if q > 0.0 else 0.0

    def _steady_state(self, theta: float) -> tuple[list[float], float]:
        """:meth:`Assembly.steady_state` at θ (its state and drive quantity q), θ checked."""
        if not (0.0 <= theta < math.pi):
            raise ModelError(f"equilibrium angle {theta!r} rad outside [0, π) "
                             "(the thrust can only lift the rod)")
        try:
            return self.assembly.steady_state(theta)
        except (AssemblyError, ZeroDivisionError) as exc:
            raise ModelError(f"no steady state at θ = {theta:g} rad: {exc}") from exc

    def pendulum_energy(self, x: np.ndarray | list[float]) -> float:
        """Rod mechanical energy per unit inertia, ½θ̇² + (mgd/J)(1 − cos θ) [rad²/s²]."""
        return 0.5 * x[THETA_DOT] ** 2 + self.a_g * (1.0 - math.cos(x[THETA]))

    def motor_energy(self, x: np.ndarray | list[float]) -> float:
        """Stored armature + rotor energy ½L_a·i_a² + ½J_m·ω₁² [J] (DC motor families).

        Raises
        ------
        ModelError
            On a family without an armature (``esc``: its rotor inertia is not a parameter).
        """
        if not self.assembly.armature:
            raise ModelError(f"motor_energy: the {self.family} family has no armature or rotor inertia")
        return 0.5 * self.L * x[I_A] ** 2 + 0.5 * self.J_m * x[OMEGA] ** 2


#: Plant models kept by :func:`plant_model`: the most recent rigs (a fit makes thousands of trial
#: rigs; each model keeps its rig alive, so an unbounded cache would keep them all).
PLANT_MODELS_KEPT = 64
_MODELS: OrderedDict[int, PlantModel] = OrderedDict()
_MODELS_LOCK = threading.Lock()


def plant_model(rig: Rig) -> PlantModel:
    """The :class:`PlantModel` of ``rig``, built once per rig object: the one place models are made.

    A rig is frozen, and so is its model (its assembly, its generated right-hand side, the values it
    read); every module that needs the model of a rig asks here, so a run that passes one rig down
    builds its model once (issue 64) instead of once per call. Kept for the
    :data:`PLANT_MODELS_KEPT` most recently asked rigs, keyed by the rig object's identity (the
    cached model holds its rig, so an identity is not reused while cached).

    Parameters
    ----------
    rig : Rig

    Returns
    -------
    PlantModel
        Shared: do not set attributes on it.

    Raises
    ------
    aeropend_sim.params.RigFileError, ModelError
        As :class:`PlantModel` does for a rig it cannot model.
    """
    key = id(rig)
    with _MODELS_LOCK:
        model = _MODELS.get(key)
        if model is not None and model.rig is rig:
            _MODELS.move_to_end(key)
            return model
    model = PlantModel(rig)
    with _MODELS_LOCK:
        _MODELS[key] = model
        _MODELS.move_to_end(key)
        while len(_MODELS) > PLANT_MODELS_KEPT:
            _MODELS.popitem(last=False)
    return model

