"""Aeropendulum plant model: thesis Eqs. 3.1-3.10 as one state-space model with optional effects.

State vector ``x`` (shape (5,)), SI units:

====  ==========  =========  ===============================================================
idx   symbol      unit       meaning
====  ==========  =========  ===============================================================
0     θ           rad        pendulum angle from the vertical (0 = hanging down)
1     θ̇           rad/s      pendulum angular velocity Ω
2     i_a         A          armature current
3     ω₁          rad/s      rotor speed (motor side of the gearbox)
4     τ_f         1          duty cycle after the first-order actuator lag (= τ without lag)
====  ==========  =========  ===============================================================

Input ``u``: duty-cycle command τ ∈ [0, 1] (after the input delay, which the simulator applies
by shifting the zero-order-hold input in time).

Equations (each optional term is switched by :class:`aeropend_sim.params.Effects`):

* actuator lag: τ̇_f = (τ − τ_f)/T_a                                   (``actuator_lag``)
* dead zone: τ_e = max(0, τ_f − τ_dz)/(1 − τ_dz)                       (``dead_zone``)
* voltage: v_a = v_supply·τ_e (ideal) or v_a = max(0, k0 + k1·sqrt(k2·τ_e + k3)) (thesis
  Eq. 4.3, ``hbridge_map``)
* armature (thesis Eq. 3.5): L_a·di_a/dt = v_a − R_a·i_a − K_ω·ω₁ (``back_emf``); with
  ``armature_inductance: quasi_static`` the current is algebraic, i_a = (v_a − K_ω·ω₁)/R_a
  (thesis Eq. 3.6)
* rotor: J_m·ω̇₁ = K_t·i_a − B_m·ω₁ − T_c·sgn(ω₁) − K_d·ω₁·|ω₁|
  (``viscous_friction``, ``coulomb_friction``, ``propeller_drag``)
* gearbox (thesis Eq. 3.4): ω₂ = ω₁ / n
* thrust (thesis Eq. 3.3): f = K_q·|ω₂|^α·sign(ω₂), α = 2 unless ``thrust_exponent``
* pendulum (thesis Eqs. 3.1-3.2): θ̈ = −(mgd/J)·sin θ − (c/J)·θ̇ − (T_f/J)·sgn(θ̇) + (L/J)·f
  + end-stop contact (``end_stops``: one-sided spring-damper beyond θ_min/θ_max that never pulls);
  with ``coulomb_friction`` the dry friction may carry a Stribeck part, T_f/J → T_f/J +
  ((T_s − T_f)/J)·exp(−(θ̇/v_s)²) (``pendulum.stribeck_over_J``, ``stribeck_velocity``; 0 = none):
  the static friction exceeds the sliding one and falls off over the Stribeck velocity v_s

``sgn(v)`` is regularised as ``tanh(v/v_ε)`` (v_ε = ``pendulum.friction_velocity`` for the rod,
:data:`ROTOR_FRICTION_VELOCITY` for the rotor) so the ODE stays Lipschitz for the integrator.
Substituting Eq. 3.6 into Eq. 3.8 gives the thesis' Eq. 3.10; this model keeps ω₁ as a state so
the armature inductance, propeller drag and rotor inertia can be switched on.
"""

from __future__ import annotations

import math

import numpy as np

from aeropend_sim.params import Rig

N_STATES = 5
THETA, THETA_DOT, I_A, OMEGA, TAU_F = range(N_STATES)
STATE_NAMES: tuple[str, ...] = ("theta", "theta_dot", "i_a", "omega_rotor", "tau_f")
STATE_UNITS: tuple[str, ...] = ("rad", "rad/s", "A", "rad/s", "1")

#: Regularisation width [rad/s] of sign(ω₁) in the rotor Coulomb friction.
ROTOR_FRICTION_VELOCITY = 1.0
#: Standard gravity [m/s²] (for converting physical pendulum data in rig files).
G = 9.80665


class ModelError(ValueError):
    """A request the model cannot satisfy (e.g. an unreachable equilibrium)."""


class PlantModel:
    """Continuous-time aeropendulum model built from a :class:`~aeropend_sim.params.Rig`.

    Parameters of switched-off effects are zeroed once here, so :meth:`rhs` has no branches
    on the effect switches beyond the structural ones (lag, inductance mode, map).

    Parameters
    ----------
    rig : Rig
        Parameter set and effect switches.
    """

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        e, a, m, th, p = rig.effects, rig.actuator, rig.motor, rig.thrust, rig.pendulum
        self.lag = e.actuator_lag and a.lag_time_constant > 0.0
        self.T_a = a.lag_time_constant
        self.tau_dz = a.dead_zone if e.dead_zone else 0.0
        self.hbridge = e.hbridge_map
        self.v_supply = a.v_supply
        self.k = (a.hbridge_k0, a.hbridge_k1, a.hbridge_k2, a.hbridge_k3)
        self.delay = a.input_delay if e.input_delay else 0.0
        self.dynamic_current = e.armature_inductance == "dynamic"
        self.R, self.L = m.R_a, m.L_a
        self.K_w = m.K_omega if e.back_emf else 0.0
        self.K_t, self.J_m = m.K_t, m.J_m
        self.B_m = m.B_m if e.viscous_friction else 0.0
        self.T_cm = m.T_c if e.coulomb_friction else 0.0
        self.K_d = m.K_d if e.propeller_drag else 0.0
        self.n = m.gear_ratio
        self.K_q = th.K_q
        self.alpha = th.exponent if e.thrust_exponent else 2.0
        self.a_g = p.mgd_over_J
        self.a_c = p.c_over_J if e.viscous_friction else 0.0
        self.a_f = p.coulomb_over_J if e.coulomb_friction else 0.0
        self.v_eps = p.friction_velocity
        self.a_s = p.stribeck_over_J if e.coulomb_friction else 0.0
        self.v_s = p.stribeck_velocity
        self.b_f = p.L_over_J
        self.stops = e.end_stops
        self.th_min, self.th_max = p.theta_min, p.theta_max
        self.k_s, self.c_s = p.stop_stiffness, p.stop_damping

    # ------------------------------------------------------------------ actuator chain
    def effective_duty(self, tau: float) -> float:
        """Duty cycle after the dead zone, τ_e = max(0, τ − τ_dz)/(1 − τ_dz)."""
        if self.tau_dz > 0.0:
            return max(0.0, tau - self.tau_dz) / (1.0 - self.tau_dz)
        return tau

    def armature_voltage(self, tau: float) -> float:
        """Armature voltage v_a [V] for a duty cycle τ already past the actuator lag.

        Ideal map v_a = v_supply·τ_e, or the H-bridge map of thesis Eq. 4.3 clipped at 0 V.
        """
        te = self.effective_duty(tau)
        if self.hbridge:
            k0, k1, k2, k3 = self.k
            return max(0.0, k0 + k1 * math.sqrt(max(k2 * te + k3, 0.0)))
        return self.v_supply * te

    def duty_for_voltage(self, v_a: float) -> float:
        """Inverse of :meth:`armature_voltage` (steady state, no lag): duty τ for a voltage v_a.

        Raises
        ------
        ModelError
            If ``v_a`` is negative or beyond what τ = 1 delivers.
        """
        if v_a < 0.0:
            raise ModelError(f"armature voltage {v_a:g} V < 0 is not reachable with τ >= 0")
        if self.hbridge:
            k0, k1, k2, k3 = self.k
            te = (((v_a - k0) / k1) ** 2 - k3) / k2 if v_a > 0.0 else 0.0
            te = max(te, 0.0)
        else:
            te = v_a / self.v_supply
        tau = te * (1.0 - self.tau_dz) + self.tau_dz if te > 0.0 else 0.0
        if tau > 1.0 + 1e-12:
            raise ModelError(
                f"armature voltage {v_a:.4g} V needs duty cycle {tau:.4g} > 1 "
                f"(max {self.armature_voltage(1.0):.4g} V)"
            )
        return min(tau, 1.0)

    def thrust(self, omega_rotor: float) -> float:
        """Thrust f [N] = K_q·|ω₂|^α·sign(ω₂) with ω₂ = ω₁/n (thesis Eqs. 3.3-3.4)."""
        w2 = omega_rotor / self.n
        return self.K_q * math.copysign(abs(w2) ** self.alpha, w2)

    def current(self, x: np.ndarray | list[float], u: float) -> float:
        """Armature current i_a [A]: the state, or algebraic in quasi-static mode (Eq. 3.6)."""
        if self.dynamic_current:
            return float(x[I_A])
        tau = x[TAU_F] if self.lag else u
        return (self.armature_voltage(tau) - self.K_w * x[OMEGA]) / self.R

    # ------------------------------------------------------------------ dynamics
    def rhs(self, t: float, x: np.ndarray | list[float], u: float) -> list[float]:
        """State derivative dx/dt (shape (5,)) for a duty-cycle input u (see module doc).

        Parameters
        ----------
        t : float
            Time [s] (unused: the model is time invariant; kept for ODE solvers).
        x : array_like, shape (5,)
            State.
        u : float
            Duty cycle τ in [0, 1] reaching the actuator (after the input delay).
        """
        th, thd, i, w, tf = x[0], x[1], x[2], x[3], x[4]
        if self.lag:
            dtf = (u - tf) / self.T_a
            tau = tf
        else:
            dtf = 0.0
            tau = u
        v = self.armature_voltage(tau)
        if self.dynamic_current:
            di = (v - self.R * i - self.K_w * w) / self.L
        else:
            i = (v - self.K_w * w) / self.R
            di = 0.0
        dw = self.K_t * i - self.B_m * w - self.K_d * w * abs(w)
        if self.T_cm > 0.0:
            dw -= self.T_cm * math.tanh(w / ROTOR_FRICTION_VELOCITY)
        dw /= self.J_m
        w2 = w / self.n
        f = self.K_q * math.copysign(abs(w2) ** self.alpha, w2)
        dthd = -self.a_g * math.sin(th) - self.a_c * thd + self.b_f * f
        if self.a_f > 0.0 or self.a_s > 0.0:
            dthd -= self.dry_friction(thd)
        if self.stops:
            dthd += self._stop_accel(th, thd)
        return [thd, dthd, di, dw, dtf]

    def dry_friction(self, thd: float) -> float:
        """Rod dry friction over inertia [rad/s²] at rate θ̇ [rad/s]: Coulomb plus Stribeck part,
        (T_f/J + ((T_s − T_f)/J)·exp(−(θ̇/v_s)²))·tanh(θ̇/v_ε)."""
        level = self.a_f
        if self.a_s > 0.0:
            level += self.a_s * math.exp(-((thd / self.v_s) ** 2))
        return level * math.tanh(thd / self.v_eps)

    def _dry_friction_slope(self, thd: float) -> float:
        """d(:meth:`dry_friction`)/dθ̇ [1/s]."""
        x = thd / self.v_eps
        slope = self.a_f / self.v_eps / math.cosh(x) ** 2
        if self.a_s > 0.0:
            ex = math.exp(-((thd / self.v_s) ** 2))
            slope += self.a_s * ex * (1.0 / self.v_eps / math.cosh(x) ** 2
                                      - 2.0 * thd / self.v_s**2 * math.tanh(x))
        return slope

    def _stop_accel(self, th: float, thd: float) -> float:
        if th > self.th_max:
            return min(0.0, -self.k_s * (th - self.th_max) - self.c_s * thd)
        if th < self.th_min:
            return max(0.0, -self.k_s * (th - self.th_min) - self.c_s * thd)
        return 0.0

    def jacobian(self, x: np.ndarray | list[float], u: float,
                 dry_friction: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Analytic linearisation A = ∂f/∂x (5×5), B = ∂f/∂u (5×1) at (x, u).

        Used for small-signal design (thesis Eq. 6.3); checked against finite differences in
        the tests. Non-smooth points (dead-zone edge, map clip at 0 V, stop contact onset) take
        the one-sided derivative of the active branch.

        ``dry_friction=False`` leaves out the slope of the rod's dry friction (:meth:`dry_friction`).
        Its sign is regularised over v_ε only for simulation, so at rest the slope is
        (T_f/J)/v_ε, hundreds of 1/s: damping that the rod has only for motions slower than v_ε.
        A controller designed on it would count on damping that is gone as soon as the rod moves
        (a Coulomb force has constant size), so controller design omits it.
        """
        A = np.zeros((N_STATES, N_STATES))
        B = np.zeros((N_STATES, 1))
        th, thd, w = x[THETA], x[THETA_DOT], x[OMEGA]
        tau = x[TAU_F] if self.lag else u
        # d v_a / d tau
        te = self.effective_duty(tau)
        dte = (1.0 / (1.0 - self.tau_dz)) if (self.tau_dz == 0.0 or tau > self.tau_dz) else 0.0
        if self.hbridge:
            k0, k1, k2, k3 = self.k
            root = math.sqrt(max(k2 * te + k3, 1e-300))
            dv = (k1 * k2 / (2.0 * root)) if (k0 + k1 * root) > 0.0 else 0.0
        else:
            dv = self.v_supply
        dv_dtau = dv * dte
        # d(rhs)/d(τ) of the actuator-side duty: routed to A[:, TAU_F] (lag) or to B (no lag)
        b_tau = np.zeros(N_STATES)
        if self.lag:
            A[TAU_F, TAU_F] = -1.0 / self.T_a
            B[TAU_F, 0] = 1.0 / self.T_a
        # armature / rotor
        if self.dynamic_current:
            A[I_A, I_A] = -self.R / self.L
            A[I_A, OMEGA] = -self.K_w / self.L
            b_tau[I_A] = dv_dtau / self.L
            A[OMEGA, I_A] = self.K_t / self.J_m
            di_dw, di_dtau = 0.0, 0.0
        else:
            di_dw, di_dtau = -self.K_w / self.R, dv_dtau / self.R
        dw_dw = -self.B_m - 2.0 * self.K_d * abs(w)
        if self.T_cm > 0.0:
            dw_dw -= self.T_cm / ROTOR_FRICTION_VELOCITY / math.cosh(w / ROTOR_FRICTION_VELOCITY) ** 2
        A[OMEGA, OMEGA] = (dw_dw + self.K_t * di_dw) / self.J_m
        b_tau[OMEGA] = self.K_t * di_dtau / self.J_m
        # pendulum
        A[THETA, THETA_DOT] = 1.0
        dth = -self.a_g * math.cos(th)
        dthd = -self.a_c
        if dry_friction and (self.a_f > 0.0 or self.a_s > 0.0):
            dthd -= self._dry_friction_slope(thd)
        if self.stops:
            for lim, sign in ((self.th_max, 1.0), (self.th_min, -1.0)):
                pen = (th - lim) * sign
                if pen > 0.0:
                    force = -self.k_s * (th - lim) - self.c_s * thd
                    if force * sign < 0.0:
                        dth -= self.k_s
                        dthd -= self.c_s
        A[THETA_DOT, THETA] = dth
        A[THETA_DOT, THETA_DOT] = dthd
        w2 = w / self.n
        df_dw = self.K_q * self.alpha * abs(w2) ** (self.alpha - 1.0) / self.n if w2 != 0.0 else (
            self.K_q / self.n if self.alpha == 1.0 else 0.0
        )
        A[THETA_DOT, OMEGA] = self.b_f * df_dw
        if self.lag:
            A[:, TAU_F] += b_tau
        else:
            B[:, 0] += b_tau
        return A, B

    # ------------------------------------------------------------------ steady state
    def equilibrium(self, theta: float) -> tuple[np.ndarray, float]:
        """Equilibrium state and duty cycle that hold the rod at angle θ.

        Solves L·f = m·g·d·sin θ (thrust balances gravity), then the rotor torque balance
        K_t·i_a = B_m·ω₁ + T_c + K_d·ω₁² and v_a = R_a·i_a + K_ω·ω₁, then inverts the
        voltage map (Eq. 4.3 or ideal) and the dead zone.

        Parameters
        ----------
        theta : float
            Angle [rad], in [0, π/2] (thrust can only lift).

        Returns
        -------
        x_eq : ndarray, shape (5,)
        tau_eq : float

        Raises
        ------
        ModelError
            If θ is outside [0, π/2] or needs a duty cycle above 1.
        """
        if not (0.0 <= theta <= math.pi / 2):
            raise ModelError(f"equilibrium angle {theta!r} rad outside [0, π/2]")
        f = self.a_g * math.sin(theta) / self.b_f
        w2 = (f / self.K_q) ** (1.0 / self.alpha) if f > 0.0 else 0.0
        w1 = self.n * w2
        torque = self.B_m * w1 + self.K_d * w1 * w1
        if self.T_cm > 0.0 and w1 > 0.0:
            torque += self.T_cm * math.tanh(w1 / ROTOR_FRICTION_VELOCITY)
        i = torque / self.K_t
        v = self.R * i + self.K_w * w1
        tau = self.duty_for_voltage(v) if v > 0.0 else 0.0
        x = np.array([theta, 0.0, i, w1, tau])
        return x, tau

    def pendulum_energy(self, x: np.ndarray | list[float]) -> float:
        """Rod mechanical energy per unit inertia, ½θ̇² + (mgd/J)(1 − cos θ) [rad²/s²]."""
        return 0.5 * x[THETA_DOT] ** 2 + self.a_g * (1.0 - math.cos(x[THETA]))

    def motor_energy(self, x: np.ndarray | list[float]) -> float:
        """Stored armature + rotor energy ½L_a·i_a² + ½J_m·ω₁² [J]."""
        return 0.5 * self.L * x[I_A] ** 2 + 0.5 * self.J_m * x[OMEGA] ** 2
