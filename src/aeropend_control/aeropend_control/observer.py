"""θ̇ observer for a rig that measures θ only: steady-state Kalman filter with a model input (no rclpy).

The thesis rig measures the angle θ (and, for the cascades, ω₁ and i_a) but not θ̇, which the
PID's derivative and the feedback-linearising law need. :class:`PendulumObserver` estimates
x = [θ, θ̇, d] from θ and the **known input**:

* pendulum (thesis Eq. 3.1) with a lumped acceleration disturbance d (random walk):
  θ̈ = −(c/J)·θ̇ + u + d,  u = (L/J)·f̂ − (mgd/J)·sin θ̂ (the gravity term evaluated at the
  estimate, i.e. the nonlinearity is injected as a known input);
* thrust f̂ from a **motor predictor** (:class:`ThrustPredictor`): the rotor equation of the
  plant model (thesis Eqs. 3.3-3.6, quasi-static current i_a = (v_a(τ) − K_ω·ω₁)/R_a, Eq. 4.3
  voltage map) integrated over each sample period from the duty cycle the controller applied
  (RK4, one step per sample; rotor time constant ≈ 21 ms ≫ h = 2.048 ms); when the rig also
  measures ω₁ (cascades), the predictor is re-anchored to the measured ω₁ every sample.

The gain is the stationary Kalman gain of the linear part discretised with a zero-order hold
(python-control ``c2d`` and ``dlqe``), filter form: correct with θ_k, then predict to k+1.
Measurement noise σ_θ defaults to 1.5 mrad (the rig's 10-bit angle quantum 6.1 mrad/√12 =
1.8 mrad and the 50 dB noise σ ≈ 1.3 mrad are of that size); process noise: white acceleration
σ_a on θ̇ and a random-walk step σ_d on d per sample. d absorbs what the model does not know
(motor lag that the steady-state allocation ignores, dead zone, friction, thrust error), so
the estimate has no steady-state bias; the PID's integrator, not d, removes the set-point error.

Why this observer: the input is known and the model is good (the pendulum law is the one the
FL controller inverts), so a model-based estimator has far less lag than a differentiator of
the same noise rejection; the disturbance state makes it an *extended-state* observer that
stays unbiased under model error; a fixed gain keeps the per-sample cost to a few scalar
operations (no allocation in the hot path, no matrix inverse).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

# python-control is imported inside the functions that use it: importing it costs ~2 s
# (scipy.signal, matplotlib.pyplot), which `controller --help` and every importer would pay.
from aeropend_sim.compiled.source import family_module, layout
from aeropend_sim.model import PlantModel, plant_model


class ObserverError(ValueError):
    """Invalid observer parameters (the message names the value)."""


@dataclass(frozen=True)
class ObserverSpec:
    """Noise model of :class:`PendulumObserver` (sets the Kalman gain).

    Attributes
    ----------
    sigma_theta : float
        Angle measurement noise std [rad].
    sigma_accel : float
        White acceleration noise std [rad/s²] (unmodelled fast effects on θ̈).
    sigma_dist : float
        Random-walk step of the disturbance d per sample [rad/s²].
    """

    sigma_theta: float = 1.5e-3
    sigma_accel: float = 2.0
    sigma_dist: float = 0.5

    def validate(self) -> None:
        """Raise :class:`ObserverError` naming the first non-positive or non-finite field."""
        for name in ("sigma_theta", "sigma_accel", "sigma_dist"):
            val = getattr(self, name)
            if not (math.isfinite(val) and val > 0.0):
                raise ObserverError(f"observer {name} = {val!r} must be finite and > 0")


def kalman_gain(a_c: float, dt: float, spec: ObserverSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZOH model (Ad, Bd) of [θ, θ̇, d] and the stationary Kalman filter gain M (filter form).

    Parameters
    ----------
    a_c : float
        Viscous damping c/J [1/s].
    dt : float
        Sample period h [s].
    spec : ObserverSpec

    Returns
    -------
    Ad : ndarray, shape (3, 3)
    Bd : ndarray, shape (3,)
        Input vector of the acceleration input u [rad/s²].
    M : ndarray, shape (3,)
        Correction gain: x̂ₖ = x̂ₖ⁻ + M·(θₖ − θ̂ₖ⁻), M = P·Cᵀ/(C·P·Cᵀ + R) with P the a-priori
        covariance solving the discrete Riccati equation (``control.dlqe``).
    """
    import control
    spec.validate()
    A = np.array([[0.0, 1.0, 0.0], [0.0, -a_c, 1.0], [0.0, 0.0, 0.0]])
    B = np.array([[0.0], [1.0], [0.0]])
    C = np.array([[1.0, 0.0, 0.0]])
    sysd = control.c2d(control.ss(A, B, C, 0.0), dt, method="zoh")
    Ad, Bd = np.asarray(sysd.A), np.asarray(sysd.B).ravel()
    G = np.array([[0.0, 0.0], [dt, 0.0], [0.0, 1.0]])
    Q = np.diag([spec.sigma_accel**2, spec.sigma_dist**2])
    R = np.array([[spec.sigma_theta**2]])
    _, P, _ = control.dlqe(Ad, G, C, Q, R)
    P = np.asarray(P)
    M = P[:, 0] / (P[0, 0] + R[0, 0])
    return Ad, Bd, M


class ThrustPredictor:
    """Rotor speed ω̂₁ and mean thrust over a sample period from the applied duty (see module doc).

    The drive chain of the rig file, sample by sample: the input delay (a FIFO of whole samples,
    when the rig enables it), then the model's own right-hand side for the actuator lag (when
    enabled), the dead zone and drive map and the rotor (J_m·ω̇₁ = K_t·i − B_m·ω₁ − K_d·ω₁|ω₁| − …
    with the armature current quasi-static, i = (v_a − K_ω·ω₁)/R_a; an ESC's speed response);
    RK4 over one period, the thrust averaged by Simpson's rule on the stages, in one call of the
    compiled kernel :func:`aeropend_sim.compiled.kernels.rotor_step` (the plant simulator's equations
    of the rig's family; 3 µs a sample where the same arithmetic in Python took 27 µs). A rig that
    knows its lag or delay thus predicts the thrust the plant really produces. (The armature current
    as a state, for thesis_sim's L_a/R_a = 115 ms, was tried: on the independent benchmark the
    cascades then limit-cycled in 24 instead of 18 of 48 runs, FL/small-signal unchanged;
    docs/control.md.)

    Parameters
    ----------
    model : PlantModel
        Nominal model (its actuator, motor and thrust parameters and effect switches).
    dt : float
        Sample period [s].
    """

    def __init__(self, model: PlantModel, dt: float) -> None:
        self._rotor = plant_model(model.rig.with_effects(armature_inductance="quasi_static"))
        self._rest = self._rotor.states.initial()  # an effect's own state held at its initial value
        self._p = layout(self._rotor.family).vector(self._rotor.assembly)
        self._step = self._kernel()  # loaded here, not on the loop's first sample
        self.dt = dt
        self.n_delay = round(model.delay / dt) if model.delay > 0.0 else 0
        self.reset()

    def _kernel(self) -> Any:
        """The compiled rotor step of the rotor model's family module
        (:func:`aeropend_sim.compiled.kernels.rotor_step`, the model's right-hand side)."""
        rotor = self._rotor
        return family_module(rotor.family, rotor.states.extra_names).rotor_step

    def __getstate__(self) -> dict[str, Any]:
        """Pickled without the compiled kernel (a function of a module generated at run time, which
        pickle cannot name): :meth:`__setstate__` loads it again for the rotor model, which is
        pickled as its rig (:meth:`aeropend_sim.model.PlantModel.__reduce__`)."""
        return {k: v for k, v in self.__dict__.items() if k != "_step"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._step = self._kernel()

    def reset(self) -> None:
        """Motor at rest, delay line empty (zeros)."""
        self.omega = 0.0
        self.tau_f = 0.0
        self._fifo = [0.0] * self.n_delay

    def advance(self, duty: float) -> float:
        """Integrate the motor over one period at duty τ (after the delay line); return the mean
        thrust [N] over the period."""
        h = self.dt
        tau = min(max(duty, 0.0), 1.0)
        if self._fifo:
            self._fifo.append(tau)
            tau = self._fifo.pop(0)
        # RK4 of (ω₁, τ_f), τ_f clipped to [0, 1] at each stage, and Simpson's mean thrust, compiled:
        # the rotor's equations of the rig's family module (the plant simulator's), one call instead
        # of four Python evaluations of the right-hand side and three of the thrust
        self.omega, self.tau_f, f = self._step(self._rest, self.omega, self.tau_f, tau, h, self._p)
        return f


class PendulumObserver:
    """Stationary Kalman filter for [θ, θ̇, d] with the model thrust as known input (see module doc).

    Use per sample: :meth:`correct` (θ measured) → control law → :meth:`predict` (duty applied,
    optionally the measured ω₁).

    Parameters
    ----------
    model : PlantModel
        Nominal model: c/J, mgd/J, L/J and the rotor chain of the thrust predictor.
    dt : float
        Sample period h [s].
    spec : ObserverSpec, optional

    Attributes
    ----------
    theta, theta_dot, dist : float
        Current estimates [rad], [rad/s], [rad/s²] (a posteriori after :meth:`correct`, a priori
        for the next sample after :meth:`predict`).
    theta_k, dist_k : float
        A-posteriori θ̂ and d̂ of the last :meth:`correct` (kept through :meth:`predict`).
    gain : ndarray, shape (3,)
        Correction gain M.
    """

    def __init__(self, model: PlantModel, dt: float, spec: ObserverSpec | None = None) -> None:
        if not (math.isfinite(dt) and dt > 0.0):
            raise ObserverError(f"observer sample period dt = {dt!r} s must be finite and > 0")
        self.spec = spec or ObserverSpec()
        self.model = model
        self.dt = float(dt)
        Ad, Bd, M = kalman_gain(model.a_c, self.dt, self.spec)
        self.gain = M
        # scalars for the hot path (no array allocation per sample)
        (self._a00, self._a01, self._a02), (self._a10, self._a11, self._a12), _ = Ad.tolist()
        self._b0, self._b1, _ = Bd.tolist()
        self._m0, self._m1, self._m2 = M.tolist()
        self.thrust = ThrustPredictor(model, self.dt)
        self.reset()

    def reset(self) -> None:
        """Forget the state; the next :meth:`correct` initialises θ̂ = θ, θ̂̇ = 0, d̂ = 0, ω̂₁ = 0."""
        self.theta = self.theta_dot = self.dist = 0.0
        self.theta_k = self.dist_k = math.nan
        self.thrust.reset()
        self._init = False

    def correct(self, theta: float) -> float:
        """Measurement update with θₖ [rad]; returns θ̂̇ₖ [rad/s]."""
        if not self._init:
            self.theta, self.theta_dot, self.dist = theta, 0.0, 0.0
            self.theta_k, self.dist_k = theta, 0.0
            self._init = True
            return 0.0
        e = theta - self.theta
        self.theta += self._m0 * e
        self.theta_dot += self._m1 * e
        self.dist += self._m2 * e
        self.theta_k, self.dist_k = self.theta, self.dist
        return self.theta_dot

    def predict(self, duty: float, omega: float = math.nan) -> None:
        """Time update to the next sample with duty τ applied over the period.

        Parameters
        ----------
        duty : float
            Duty cycle applied until the next sample.
        omega : float
            Measured rotor speed ω₁ [rad/s] at this sample (re-anchors the thrust predictor);
            NaN if not measured.
        """
        if not self._init:
            return
        if math.isfinite(omega):
            self.thrust.omega = max(omega, 0.0)
        m = self.model
        u = m.b_f * self.thrust.advance(duty) - m.a_g * math.sin(self.theta)
        th, thd, d = self.theta, self.theta_dot, self.dist
        self.theta = self._a00 * th + self._a01 * thd + self._a02 * d + self._b0 * u
        self.theta_dot = self._a10 * th + self._a11 * thd + self._a12 * d + self._b1 * u
        # d: random walk, unchanged by the prediction
