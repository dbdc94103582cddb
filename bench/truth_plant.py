"""Independent truth plant for blind benchmarks: an aeropendulum written as a lab writes its own.

This module shares **no code** with ``aeropend_sim`` or ``aeropend_ident`` (it imports neither:
checked by ``test/test_truth_plant.py``). It is the thesis' simulated plant (equations printed with
thesis Figs. 5.3/5.4) written directly from its equations, integrated by a fixed-step classical
Runge-Kutta scheme with the duty cycle held over each 2.048 ms sample::

    θ̈       = −(mgd/J)·sin θ − (c/J)·θ̇ + (L/J)·f                      (thesis Eqs. 3.1-3.2)
    f        = K_q·|ω₂|^α·sgn ω₂,  ω₂ = (N₁/N₂)·ω₁,  α = 2               (thesis Eqs. 3.3-3.4)
    L_a·i̇_a  = v_a − R_a·i_a − K_ω·ω₁                                  (thesis Eq. 3.5)
    J_m·ω̇₁   = K_t·i_a − B_m·ω₁                                         (thesis Eq. 3.8)
    v_a      = V_s·τ  (ideal drive)

with the Fig. 5.3 numbers (di_a/dt = −8.6957 i_a − 1.0217 ω₁ + 4.3478 v_a, dω₁/dt = 4519.2 i_a −
192.31 ω₁, θ̈ = −13.82 θ̇ − 131.75 sin θ + 1.7285 ω₁²) split into physical parameters (R_a = 2 Ω,
L_a = 0.23 H, K_ω = K_t = 0.235, J_m = K_t/4519.2, B_m = 192.31·J_m, K_q = 1e-4 N·s², N₁/N₂ =
55/9, L/J = 1.7285/(K_q·(55/9)²)).

Every unmodelled effect is implemented from its physics, in physical units
(:data:`EFFECT_DOCS` gives the equation of each):

* drive: H-bridge voltage drop, dead zone, first-order lag of the armature voltage, transport
  delay of the duty command (a FIFO buffer of whole samples);
* motor: back-EMF constant, armature resistance and inductance, torque constant, rotor
  viscous friction, rotor inertia, propeller drag torque K_d·ω₁|ω₁|;
* aerodynamics: thrust coefficient, thrust-law exponent;
* pendulum: gravity torque, inertia, viscous and Coulomb friction, stiction with a Stribeck
  curve (the friction at rest above the sliding one), a hard end stop (restitution);
* sensor: angle offset and gain;
* effects outside aeropend's catalog: a thrust loss that grows with the rod angle, an
  angle-sensor offset that drifts slowly in time, quadratic aerodynamic drag on the rod.

Sensor noise: zero-mean Gaussian with σ = RMS(channel)/10^(SNR/20) on θ, i_a, v_a and ω₁.
Excitations (own implementations): Latin-hypercube duty steps (thesis §5.1) and an
amplitude-modulated PRBS (APRBS).

Nothing here knows how aeropend parameterises its effects; the benches map a truth to the
diagnosis' vocabulary only when they score (``bench/bench_gap_independent.py``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import qmc

#: Sample period of the Arduino acquisition [s] (Timer1 overflow at 490 Hz, thesis §4.3.2).
DT = 2.048e-3
#: Runge-Kutta substeps per sample.
SUBSTEPS = 4
#: Gear ratio N₁/N₂ of the propeller over the rotor speed (ω₂ = GEAR·ω₁).
GEAR = 55.0 / 9.0
#: Restitution coefficient of the hard end stop.
RESTITUTION = 0.3
#: Regularisation speed [rad/s] of sgn θ̇ in the rod's Coulomb friction (stiff, resolved by the
#: substeps; a lab's simulator would use the same kind of smooth sign).
COULOMB_VELOCITY = 2e-3
#: Stribeck velocity [rad/s] of the rod's stiction (``stiction``): the friction's excess over the
#: sliding level falls to 1/e at this rate (Armstrong-Hélouvry's Gaussian Stribeck curve).
STRIBECK_VELOCITY = 0.15


@dataclass(frozen=True)
class PlantParams:
    """Physical parameters of the truth plant (SI).

    Defaults: the thesis' simulated plant (Figs. 5.3/5.4 equations, ideal 2.32 V drive).
    """

    v_supply: float = 2.32          # V: drive voltage at τ = 1
    R_a: float = 2.0                # Ω: 8.6957 s⁻¹ × L_a
    L_a: float = 0.23               # H: 1/4.3478
    K_omega: float = 0.235          # V·s/rad: 1.0217 × L_a
    K_t: float = 0.235              # N·m/A
    J_m: float = 0.235 / 4519.2     # kg·m²: K_t/4519.2
    B_m: float = 192.31 * 0.235 / 4519.2  # N·m·s/rad: 192.31 s⁻¹ × J_m
    K_q: float = 1.0e-4             # N·s²: thrust coefficient (propeller side)
    L_over_J: float = 1.7285 / (1.0e-4 * GEAR**2)  # 1/(kg·m): lever over rod inertia
    mgd_over_J: float = 131.75      # 1/s²
    c_over_J: float = 13.82         # 1/s

    def scaled(self, **factors: float) -> PlantParams:
        """Copy with some parameters multiplied by factors (e.g. ``scaled(mgd_over_J=0.8)``)."""
        return dataclasses.replace(self, **{k: getattr(self, k) * v for k, v in factors.items()})


#: Effects the truth plant implements, with their physics (the magnitude's unit in brackets).
EFFECT_DOCS: dict[str, str] = {
    "hbridge_drop": "v_a = max(0, V_s·τ − V_d)  [V_d, V]: constant drop across the conducting switches",
    "dead_zone": "v_a = V_s·max(0, τ − τ_dz)/(1 − τ_dz)  [τ_dz, 1]: driver output starts at τ_dz, full "
                 "scale kept",
    "actuator_lag": "T_a·v̇_a = v_a,cmd − v_a  [T_a, s]: first-order lag of the drive output",
    "input_delay": "τ(t − T_d) reaches the drive, T_d a whole number of samples  [T_d, s]",
    "back_emf": "K_ω ← K_ω·k  [K_ω, V·s/rad]",
    "armature_resistance": "R_a ← R_a·k  [R_a, Ω]",
    "armature_inductance": "L_a ← L_a·k  [L_a, H]",
    "torque_constant": "K_t ← K_t·k  [K_t, N·m/A]",
    "rotor_friction": "B_m ← B_m·k  [B_m, N·m·s/rad]",
    "motor_time_constant": "J_m ← J_m·k  [J_m, kg·m²]: rotor + gear + propeller inertia",
    "propeller_drag": "J_m·ω̇₁ −= K_d·ω₁|ω₁|  [K_d, N·m·s²]: aerodynamic drag torque of the propeller",
    "thrust_coefficient": "K_q ← K_q·k  [K_q, N·s²]",
    "thrust_law": "f = K_q·N²·|ω₁|^α (the thrust law fitted on the rotor speed ω₁ as a lab measures it; "
                  "α = 2 nominal, its coefficient unchanged)  [α, 1]",
    "gravity": "mgd/J ← k·mgd/J  [mgd/J, 1/s²]",
    "inertia": "J ← k·J: mgd/J, c/J, L/J all divided by k  [k, 1]",
    "viscous_friction": "c/J ← k·c/J  [c/J, 1/s]",
    "coulomb_friction": "θ̈ −= (T_f/J)·sgn θ̇  [T_f/J, rad/s²]",
    "stiction": "θ̈ −= ((T_s − T_f)/J)·exp(−(θ̇/v_s)²)·sgn θ̇, v_s = STRIBECK_VELOCITY  [(T_s − T_f)/J, "
                "rad/s²]: static friction above the sliding (Coulomb) level, the Stribeck curve",
    "end_stops": "hard stop at θ_max: the rod cannot pass it, impacts with restitution 0.3  [θ_max, rad]",
    "sensor_offset": "θ_recorded = θ + δ  [δ, rad]",
    "sensor_scale": "θ_recorded = s·θ  [s, 1]",
    # outside aeropend's catalog
    "angle_thrust_loss": "f ← f·(1 − κ·sin²θ)  [κ, 1]: inflow blocked as the rod swings up "
                         "(not in aeropend's catalog)",
    "offset_drift": "θ_recorded = θ + r·t  [r, rad/s]: sensor offset drifting in time (not in the catalog)",
    "rod_air_drag": "θ̈ −= k_d·θ̇|θ̇|  [k_d, 1/rad]: quadratic aerodynamic drag on the rod "
                    "(not in the catalog)",
}
#: Effects that aeropend's gap catalog does not contain (must be reported as unexplained).
OUT_OF_CATALOG = ("angle_thrust_loss", "offset_drift", "rod_air_drag")
#: Parameters changed by a multiplicative factor: effect -> PlantParams field.
SCALE_EFFECTS = {
    "back_emf": "K_omega", "armature_resistance": "R_a", "armature_inductance": "L_a",
    "torque_constant": "K_t", "rotor_friction": "B_m", "motor_time_constant": "J_m",
    "thrust_coefficient": "K_q", "gravity": "mgd_over_J", "viscous_friction": "c_over_J",
}


class TruthError(ValueError):
    """An unknown effect or an impossible magnitude for the truth plant."""



def _recorded_angle(theta: Any, t: Any, e: Mapping[str, float]) -> Any:
    """The angle sensor's reading of the true θ at time t (sensor scale, offset, drift)."""
    if "sensor_scale" in e:
        theta = e["sensor_scale"] * theta
    if "sensor_offset" in e:
        theta = theta + e["sensor_offset"]
    if "offset_drift" in e:
        theta = theta + e["offset_drift"] * t
    return theta


class _Dynamics:
    """Drive map and right-hand side of the truth plant for given parameters and effects.

    State s = [θ, θ̇, i_a, ω₁, v_a] (v_a is the lagged drive output; unused without lag).
    """

    def __init__(self, p: PlantParams, e: Mapping[str, float]) -> None:
        self.p = p
        self.dz = e.get("dead_zone", 0.0)
        self.v_d = e.get("hbridge_drop", 0.0)
        self.t_lag = e.get("actuator_lag", 0.0)
        self.alpha = e.get("thrust_law", 2.0)
        self.k_drag = e.get("propeller_drag", 0.0)
        self.coul = e.get("coulomb_friction", 0.0)
        self.stick = e.get("stiction", 0.0)
        self.kappa = e.get("angle_thrust_loss", 0.0)
        self.k_air = e.get("rod_air_drag", 0.0)
        self.th_max = e.get("end_stops", math.inf)

    def drive(self, tau: float) -> float:
        """Drive output v_a,cmd [V] for the duty τ reaching the drive."""
        if self.dz > 0.0:
            tau = max(0.0, tau - self.dz) / (1.0 - self.dz)
        return max(0.0, self.p.v_supply * tau - self.v_d)

    def rhs(self, s: list[float], v_cmd: float) -> list[float]:
        """ds/dt [rad/s, rad/s², A/s, rad/s², V/s] at state s under drive command v_cmd [V]."""
        p, t_lag, kappa = self.p, self.t_lag, self.kappa
        th, thd, i, w, v = s
        v_a = v if t_lag > 0.0 else v_cmd
        di = (v_a - p.R_a * i - p.K_omega * w) / p.L_a
        dw = (p.K_t * i - p.B_m * w - self.k_drag * w * abs(w)) / p.J_m
        f = p.K_q * GEAR**2 * abs(w) ** self.alpha * (1.0 if w >= 0.0 else -1.0)
        if kappa:
            f *= 1.0 - kappa * math.sin(th) ** 2
        dthd = -p.mgd_over_J * math.sin(th) - p.c_over_J * thd + p.L_over_J * f
        if self.coul or self.stick:
            level = self.coul + self.stick * math.exp(-((thd / STRIBECK_VELOCITY) ** 2))
            dthd -= level * math.tanh(thd / COULOMB_VELOCITY)
        if self.k_air:
            dthd -= self.k_air * thd * abs(thd)
        dv = (v_cmd - v) / t_lag if t_lag > 0.0 else 0.0
        return [thd, dthd, di, dw, dv]

    def advance(self, s: list[float], v_cmd: float, h: float, substeps: int) -> list[float]:
        """``substeps`` classical RK4 steps of length h [s] with v_cmd held (end stop applied)."""
        rhs, th_max = self.rhs, self.th_max
        for _ in range(substeps):
            k1 = rhs(s, v_cmd)
            s2 = [a + 0.5 * h * b for a, b in zip(s, k1, strict=True)]
            k2 = rhs(s2, v_cmd)
            s3 = [a + 0.5 * h * b for a, b in zip(s, k2, strict=True)]
            k3 = rhs(s3, v_cmd)
            s4 = [a + h * b for a, b in zip(s, k3, strict=True)]
            k4 = rhs(s4, v_cmd)
            s = [a + h / 6.0 * (b + 2.0 * c + 2.0 * d + g)
                 for a, b, c, d, g in zip(s, k1, k2, k3, k4, strict=True)]
            if s[0] > th_max:  # hard stop: the rod is put back on the stop and rebounds
                s[0] = th_max
                if s[1] > 0.0:
                    s[1] = -RESTITUTION * s[1]
        return s


@dataclass
class TruthPlant:
    """The hidden plant: nominal parameters plus effects ``{name: magnitude}``.

    Magnitudes are in the units of :data:`EFFECT_DOCS`; scale effects take the factor k.

    Raises
    ------
    TruthError
        On an unknown effect name or a non-finite magnitude.
    """

    params: PlantParams = field(default_factory=PlantParams)
    effects: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for k, v in self.effects.items():
            if k not in EFFECT_DOCS:
                raise TruthError(f"unknown truth effect {k!r}; known: {sorted(EFFECT_DOCS)}")
            if not math.isfinite(v):
                raise TruthError(f"truth effect {k!r} magnitude {v!r} is not finite")

    def physical(self) -> PlantParams:
        """The plant's actual parameters (scale effects and inertia applied)."""
        p = self.params
        e = self.effects
        factors = {SCALE_EFFECTS[k]: v for k, v in e.items() if k in SCALE_EFFECTS}
        p = p.scaled(**factors) if factors else p
        if "inertia" in e:
            k = e["inertia"]
            p = dataclasses.replace(p, mgd_over_J=p.mgd_over_J / k, c_over_J=p.c_over_J / k,
                                    L_over_J=p.L_over_J / k)
        return p

    def simulate(self, duty: np.ndarray, dt: float = DT, substeps: int = SUBSTEPS) -> dict[str, np.ndarray]:
        """Noise-free response to a duty sequence, from rest (rod hanging, motor stopped).

        Parameters
        ----------
        duty : ndarray, shape (N,)
            Duty cycle τ_k ∈ [0, 1] held over [k·dt, (k+1)·dt).

        Returns
        -------
        dict
            ``t`` (N,) [s], ``duty``, true ``theta`` [rad], ``theta_dot`` [rad/s], ``i_a`` [A],
            ``v_a`` [V], ``omega_rotor`` [rad/s] at the sample instants (sample k before τ_k acts),
            and ``theta_recorded`` (the angle sensor's reading before noise).

        Raises
        ------
        TruthError
            On duty values outside [0, 1] or NaN.
        """
        duty = np.asarray(duty, dtype=float)
        if duty.ndim != 1 or not np.all(np.isfinite(duty)) or duty.min() < 0.0 or duty.max() > 1.0:
            raise TruthError("duty must be a finite 1-D sequence in [0, 1]")
        p = self.physical()
        e = self.effects
        n = duty.size
        d_samples = round(e.get("input_delay", 0.0) / dt)
        delayed = np.concatenate([np.zeros(d_samples), duty])[:n] if d_samples else duty
        dyn = _Dynamics(p, e)
        h = dt / substeps
        s = [0.0, 0.0, 0.0, 0.0, 0.0]
        out = np.empty((n, 5))
        v_out = np.empty(n)
        for k in range(n):
            v_cmd = dyn.drive(float(delayed[k]))
            out[k] = s
            v_out[k] = s[4] if dyn.t_lag > 0.0 else v_cmd
            s = dyn.advance(s, v_cmd, h, substeps)
        t = np.arange(n) * dt
        theta_rec = _recorded_angle(out[:, 0].copy(), t, e)
        return {"t": t, "duty": duty, "theta": out[:, 0], "theta_dot": out[:, 1], "i_a": out[:, 2],
                "omega_rotor": out[:, 3], "v_a": v_out, "theta_recorded": theta_rec}


#: Measured channels of a fully instrumented rig (what the Arduino acquisition samples).
CHANNELS = ("theta", "i_a", "v_a", "omega_rotor")


def add_noise(true: Mapping[str, np.ndarray], snr_db: float, seed: int,
              channels: Sequence[str] = CHANNELS) -> dict[str, np.ndarray]:
    """Measured channels: true values plus Gaussian noise σ = RMS/10^(SNR/20) (θ: the sensor reading).

    Returns
    -------
    dict
        channel -> (N,) array; the angle is the recorded one (offset/scale/drift applied).
    """
    rng = np.random.default_rng(seed)
    out = {}
    for c in channels:
        y = np.asarray(true["theta_recorded" if c == "theta" else c], dtype=float)
        sigma = float(np.sqrt(np.mean(y**2))) / 10.0 ** (snr_db / 20.0)
        out[c] = y + sigma * rng.standard_normal(y.size)
    return out


# ------------------------------------------------------------------------------ excitations
def lhs_steps(duration: float, seed: int, lo: float = 0.25, hi: float = 0.95, n_steps: int = 8,
              rest: float = 0.5, dt: float = DT) -> np.ndarray:
    """Latin-hypercube duty steps (thesis §5.1): levels and hold lengths from one LH sample.

    ``rest`` seconds at τ = 0 first; the holds fill the rest of ``duration`` in proportion to
    their Latin-hypercube lengths (each between 0.5 and 1.5 times the mean hold).
    """
    sample = qmc.LatinHypercube(d=2, seed=seed).random(n_steps)
    levels = lo + (hi - lo) * sample[:, 0]
    holds = 0.5 + sample[:, 1]
    holds = holds / holds.sum() * (duration - rest)
    n_rest = round(rest / dt)
    parts = [np.zeros(n_rest)] + [np.full(max(round(hd / dt), 1), lv) for lv, hd in
                                  zip(levels, holds, strict=True)]
    duty = np.concatenate(parts)
    n = round(duration / dt)
    return np.pad(duty, (0, max(n - duty.size, 0)), mode="edge")[:n]


def aprbs(duration: float, seed: int, lo: float = 0.25, hi: float = 0.95, min_hold: float = 0.15,
          max_hold: float = 1.2, rest: float = 0.5, dt: float = DT) -> np.ndarray:
    """Amplitude-modulated PRBS: uniform random levels held for uniform random times."""
    rng = np.random.default_rng(seed)
    n = round(duration / dt)
    duty = np.zeros(n)
    k = round(rest / dt)
    while k < n:
        m = round(rng.uniform(min_hold, max_hold) / dt)
        duty[k:k + m] = rng.uniform(lo, hi)
        k += m
    return duty


@dataclass
class TruthRecording:
    """What a lab's logger writes: time, duty and the measured channels (plus the hidden truth)."""

    t: np.ndarray
    duty: np.ndarray
    channels: dict[str, np.ndarray]
    true: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)

    def to_csv(self, path: Any) -> None:
        """Write a CSV log (columns ``time_s, duty, theta_rad, i_a_A, v_a_V, omega_rad_s``)."""
        units = {"theta": "theta_rad", "i_a": "i_a_A", "v_a": "v_a_V", "omega_rotor": "omega_rad_s"}
        cols = ["time_s", "duty"] + [units[c] for c in self.channels]
        data = np.column_stack([self.t, self.duty, *self.channels.values()])
        np.savetxt(path, data, delimiter=",", header=",".join(cols), comments="", fmt="%.9g")


def record(plant: TruthPlant, duty: np.ndarray, snr_db: float, seed: int,
           channels: Sequence[str] = CHANNELS) -> TruthRecording:
    """Simulate the plant under ``duty`` and measure ``channels`` at ``snr_db``."""
    true = plant.simulate(duty)
    meas = add_noise(true, snr_db, seed, channels)
    return TruthRecording(t=true["t"], duty=true["duty"], channels=meas, true=true,
                          meta={"snr_db": snr_db, "effects": dict(plant.effects)})


# ------------------------------------------------------------------------------ sample by sample
class TruthStepper:
    """The truth plant stepped one sample at a time, for closed loops (a controller in between).

    Same equations, drive map, integration (``substeps`` RK4 steps per sample with the duty held)
    and effects as :meth:`TruthPlant.simulate`: a duty sequence fed through :meth:`step` gives the
    same states, bit for bit. The transport delay is a FIFO of whole samples (zeros first).

    Parameters
    ----------
    plant : TruthPlant
    sigma : mapping, optional
        Noise std per measured channel (``theta`` [rad], ``i_a`` [A], ``v_a`` [V],
        ``omega_rotor`` [rad/s]); channels not given are noise-free. Closed-loop runs have no
        recording to take an RMS from, so the caller states σ (e.g. RMS of a typical run /
        10^(SNR/20)).
    seed : int
        Seed of the noise generator.
    dt : float
        Sample period [s].
    substeps : int
        RK4 steps per sample.

    Attributes
    ----------
    k : int
        Index of the current sample.
    state : list of float
        True [θ, θ̇, i_a, ω₁, v_a] at the current sample.
    """

    def __init__(self, plant: TruthPlant, sigma: Mapping[str, float] | None = None, seed: int = 0,
                 dt: float = DT, substeps: int = SUBSTEPS) -> None:
        self.plant = plant
        self.effects = dict(plant.effects)
        self.dyn = _Dynamics(plant.physical(), self.effects)
        self.dt, self.substeps, self.h = dt, substeps, dt / substeps
        self.sigma = {c: float(v) for c, v in (sigma or {}).items()}
        bad = set(self.sigma) - set(CHANNELS)
        if bad or any(not (math.isfinite(v) and v >= 0.0) for v in self.sigma.values()):
            raise TruthError(f"noise sigma {sigma!r}: channels must be among {CHANNELS}, values finite >= 0")
        self.rng = np.random.default_rng(seed)
        self.fifo = [0.0] * round(self.effects.get("input_delay", 0.0) / dt)
        self.k = 0
        self.state = [0.0, 0.0, 0.0, 0.0, 0.0]
        self._v_cmd = self.dyn.drive(0.0)

    @property
    def t(self) -> float:
        """Time of the current sample [s]."""
        return self.k * self.dt

    def true(self) -> dict[str, float]:
        """True values at the current sample: θ, θ̇, i_a, ω₁ and v_a (the drive output)."""
        th, thd, i, w, v = self.state
        return {"theta": th, "theta_dot": thd, "i_a": i, "omega_rotor": w,
                "v_a": v if self.dyn.t_lag > 0.0 else self._v_cmd}

    def sample(self) -> dict[str, float]:
        """Measured channels at the current sample (θ as the sensor records it, plus noise)."""
        tr = self.true()
        out = {c: tr[c] for c in CHANNELS}
        out["theta"] = float(_recorded_angle(tr["theta"], self.t, self.effects))
        for c, s in self.sigma.items():
            if s > 0.0:
                out[c] += s * float(self.rng.standard_normal())
        return out

    def step(self, duty: float) -> dict[str, float]:
        """Apply duty τ ∈ [0, 1] over one sample period; return the next sample's measurement.

        Raises
        ------
        TruthError
            If τ is not finite or outside [0, 1].
        """
        duty = float(duty)
        if not (math.isfinite(duty) and 0.0 <= duty <= 1.0):
            raise TruthError(f"duty {duty!r} must be finite and in [0, 1]")
        if self.fifo:
            self.fifo.append(duty)
            duty = self.fifo.pop(0)
        self._v_cmd = self.dyn.drive(duty)
        self.state = self.dyn.advance(self.state, self._v_cmd, self.h, self.substeps)
        self.k += 1
        return self.sample()


# ============================================================================== other actuator families
# Two more hidden plants for the per-family benchmarks: a brushless motor behind an ESC (hobby rigs)
# and a DC motor on a voltage amplifier (Quanser-Aero style). Both are written as a lab writes its
# own simulator, in the quantities it measures (masses and lengths, torques, a motor's K_v in
# rpm/V, the ESC's pulse widths in µs, propeller coefficients C_T and C_Q), not in aeropend's
# per-inertia ratios or its throttle-map parameters; the benchmark converts them into the lab's rig
# file (bench/bench_gap_independent.py). Physics:
#
#   rod        J·θ̈ = −m·g·d·sin θ − c·θ̇ + L·f − J·(T_f/J)·sgn θ̇ − ...      (torques about the pivot)
#   propeller  f = C_T·ρ·n²·D⁴,  Q = C_Q·ρ·n²·D⁵,  n = ω/(2π) [rev/s]     (momentum-theory coefficients)
#   ESC        pulse p = p_min + τ·(p_max − p_min) [µs]; the ESC sets the motor voltage
#              V_bat·max(0, (p − p_idle)/(p_max − p_idle)) and the unloaded-K_v speed follows,
#              ω_ss = K_v·V; ω̇ = (ω_ss − ω)/T_r (the ESC's speed loop, motor and propeller); dead time
#   amplifier  v_a = K_amp·V_ref·τ + V_os; L_a·i̇_a = v_a − R_a·i_a − k_e·ω;
#              J_r·ω̇ = k_t·i_a − B·ω − Q − T_c·sgn ω   (direct drive: the propeller on the shaft)
#
# The armature's electrical time constant L_a/R_a (0.14 ms on a Quanser Aero) is far below the
# integration step, so the current is integrated exactly for the speed held over each substep
# (exponential integrator): i(s) = i_ss(ω(s)) + (i₀ − i_ss(ω₀))·exp(−s·R_a/L_a).

#: Standard gravity [m/s²] (CGPM 1901).
G_STANDARD = 9.80665
#: Air density [kg/m³] of the International Standard Atmosphere at sea level, 15 °C.
RHO_AIR = 1.225
#: Regularisation speed [rad/s] of sgn ω in the amplifier motor's brush friction.
BRUSH_VELOCITY = 0.5


@dataclass(frozen=True)
class RodParams:
    """The rod as a lab measures it (SI): masses, lengths and torques, not per-inertia ratios.

    Attributes
    ----------
    mass : kg, moving part (rod, motor, propeller).
    com : m, pivot to centre of mass.
    arm : m, pivot to the thrust line.
    inertia : kg·m², about the pivot.
    damping : N·m·s/rad, viscous pivot friction.
    """

    mass: float
    com: float
    arm: float
    inertia: float
    damping: float

    def scaled(self, **factors: float) -> RodParams:
        """Copy with some fields multiplied by factors."""
        return dataclasses.replace(self, **{k: getattr(self, k) * v for k, v in factors.items()})


@dataclass(frozen=True)
class EscParams:
    """A brushless motor behind an ESC (hobby rig, 100 Hz logger), in a lab's units.

    Attributes
    ----------
    kv_rpm : rpm/V, the motor's velocity constant K_v.
    battery : V, battery voltage under load (2-cell LiPo).
    pulse_min, pulse_max : µs, the throttle range the ESC is calibrated to (command τ = 0 and 1).
    pulse_idle : µs, the arming/idle pulse: the ESC holds the motor still below it.
    response : s, time constant T_r of the speed response (ESC speed loop, motor, propeller).
    dead_time : s, ESC frame and signal latency (whole samples).
    diameter : m, propeller diameter D.
    c_t : 1, propeller thrust coefficient C_T.
    rod : RodParams
    """

    kv_rpm: float = 1400.0
    battery: float = 7.4
    pulse_min: float = 1000.0
    pulse_max: float = 2000.0
    pulse_idle: float = 1080.0
    response: float = 0.05
    dead_time: float = 0.02
    diameter: float = 0.127
    c_t: float = 0.10
    rod: RodParams = field(default_factory=lambda: RodParams(mass=0.12, com=0.18, arm=0.15,
                                                             inertia=0.12 * 0.18**2 * 1.4, damping=4.4e-3))

    def scaled(self, **factors: float) -> EscParams:
        """Copy with some (non-rod) fields multiplied by factors."""
        return dataclasses.replace(self, **{k: getattr(self, k) * v for k, v in factors.items()})


@dataclass(frozen=True)
class AmplifierParams:
    """A DC motor on a voltage amplifier (Quanser-Aero-style rig, 500 Hz), SI.

    Attributes
    ----------
    gain : V/V, amplifier gain K_amp.
    v_ref : V, the command's full scale at the amplifier input (τ = 1).
    R_a : Ω, L_a : H, k_t : N·m/A, k_e : V·s/rad (k_t = k_e in SI for one motor).
    J_r : kg·m², rotor and propeller.
    B : N·m·s/rad, rotor viscous friction.
    diameter : m; c_t, c_q : 1, propeller thrust and torque coefficients.
    rod : RodParams
    """

    gain: float = 2.4
    v_ref: float = 10.0
    R_a: float = 8.4
    L_a: float = 1.16e-3
    k_t: float = 0.042
    k_e: float = 0.042
    J_r: float = 2.0e-5
    B: float = 2.0e-6
    diameter: float = 0.127
    c_t: float = 0.10
    c_q: float = 0.008
    rod: RodParams = field(default_factory=lambda: RodParams(mass=0.25, com=0.024, arm=0.16, inertia=2.5e-3,
                                                             damping=2.0e-3))

    def scaled(self, **factors: float) -> AmplifierParams:
        """Copy with some (non-rod) fields multiplied by factors."""
        return dataclasses.replace(self, **{k: getattr(self, k) * v for k, v in factors.items()})


def prop_thrust(c_t: float, diameter: float, omega: float, exponent: float = 2.0,
                n_ref: float = 1.0) -> float:
    """Thrust f [N] = C_T·ρ·n_ref²·D⁴·(|n|/n_ref)^α·sgn n of a propeller at shaft speed ω [rad/s]
    (n = ω/2π rev/s; α = 2 is momentum theory and n_ref then drops out)."""
    n = omega / (2.0 * math.pi)
    return c_t * RHO_AIR * diameter**4 * n_ref**2 * (abs(n) / n_ref) ** exponent * (1.0 if n >= 0.0 else -1.0)


#: Effects of the ESC plant: name -> physics [magnitude, unit].
ESC_EFFECT_DOCS: dict[str, str] = {
    "esc_idle": "p_idle ← magnitude  [p_idle, µs]: the ESC's idle/arming pulse (recalibrated throttle range)",
    "esc_speed_range": "V_bat ← k·V_bat  [k, 1]: battery voltage under load (charge state): ω_ss scales",
    "esc_response": "T_r ← k·T_r  [k, 1]: speed response of ESC, motor and propeller",
    "input_delay": "dead time += magnitude (whole samples)  [s]",
    "actuator_lag": "T_a·τ̇_f = τ − τ_f  [T_a, s]: a first-order filter of the throttle in the ESC",
    "thrust_coefficient": "C_T ← k·C_T  [k, 1]",
    "thrust_law": "f = C_T·ρ·n_h²·D⁴·(n/n_h)^α, n_h the speed at half throttle  [α, 1]",
    "gravity": "m·d ← k·m·d  [k, 1]: a counterweight moved (the inertia unchanged)",
    "inertia": "J ← k·J  [k, 1]",
    "viscous_friction": "c ← k·c  [k, 1]",
    "coulomb_friction": "J·θ̈ −= J·(T_f/J)·sgn θ̇  [T_f/J, rad/s²]",
    "end_stops": EFFECT_DOCS["end_stops"],
    "sensor_offset": EFFECT_DOCS["sensor_offset"],
    "sensor_scale": EFFECT_DOCS["sensor_scale"],
    "angle_thrust_loss": EFFECT_DOCS["angle_thrust_loss"],
    "offset_drift": EFFECT_DOCS["offset_drift"],
    "rod_air_drag": EFFECT_DOCS["rod_air_drag"],
}
#: Effects of the amplifier plant: name -> physics [magnitude, unit].
AMPLIFIER_EFFECT_DOCS: dict[str, str] = {
    "amplifier_offset": "v_a += V_os  [V_os, V]: the amplifier's output offset",
    "input_delay": "the command reaches the amplifier whole samples later  [T_d, s]",
    "actuator_lag": "T_a·v̇_a = v_cmd − v_a  [T_a, s]: amplifier slew/filter",
    "back_emf": "k_e ← k·k_e  [k, 1]",
    "armature_resistance": "R_a ← k·R_a  [k, 1]",
    "torque_constant": "k_t ← k·k_t  [k, 1]",
    "rotor_friction": "B ← k·B  [k, 1]",
    "motor_time_constant": "J_r ← k·J_r  [k, 1]",
    "propeller_drag": "C_Q ← k·C_Q  [k, 1]: the propeller's drag torque",
    "rotor_brush_friction": "J_r·ω̇ −= T_c·sgn ω  [T_c, N·m]: brush friction",
    "thrust_coefficient": "C_T ← k·C_T  [k, 1]",
    "thrust_law": ESC_EFFECT_DOCS["thrust_law"],
    "gravity": ESC_EFFECT_DOCS["gravity"],
    "inertia": ESC_EFFECT_DOCS["inertia"],
    "viscous_friction": ESC_EFFECT_DOCS["viscous_friction"],
    "coulomb_friction": ESC_EFFECT_DOCS["coulomb_friction"],
    "end_stops": EFFECT_DOCS["end_stops"],
    "sensor_offset": EFFECT_DOCS["sensor_offset"],
    "sensor_scale": EFFECT_DOCS["sensor_scale"],
    "angle_thrust_loss": EFFECT_DOCS["angle_thrust_loss"],
    "offset_drift": EFFECT_DOCS["offset_drift"],
    "rod_air_drag": EFFECT_DOCS["rod_air_drag"],
}
#: Factor effects of the two plants: effect -> field (of the plant, or ``rod.<field>``).
ESC_SCALE = {"esc_speed_range": "battery", "esc_response": "response", "thrust_coefficient": "c_t",
             "inertia": "rod.inertia", "viscous_friction": "rod.damping"}
AMPLIFIER_SCALE = {"back_emf": "k_e", "armature_resistance": "R_a", "torque_constant": "k_t",
                   "rotor_friction": "B",
                   "motor_time_constant": "J_r", "propeller_drag": "c_q", "thrust_coefficient": "c_t",
                   "inertia": "rod.inertia", "viscous_friction": "rod.damping"}


def _apply_scales(p: Any, effects: Mapping[str, float], table: Mapping[str, str]) -> Any:
    rod = p.rod
    for eff, fld in table.items():
        if eff in effects:
            if fld.startswith("rod."):
                rod = rod.scaled(**{fld[4:]: effects[eff]})
            else:
                p = p.scaled(**{fld: effects[eff]})
    if "gravity" in effects:  # m·d scaled, J kept: the mass moved, not added
        rod = dataclasses.replace(rod, com=rod.com * effects["gravity"])
    return dataclasses.replace(p, rod=rod)


class _RodPlant:
    """The rod, the sensor and the integration shared by the ESC and amplifier plants.

    Subclasses give :meth:`drive_state` (the actuator and rotor states' derivatives and the
    propeller speed) and the state layout [θ, θ̇, *actuator states]."""

    dt: float
    substeps: int
    effects: dict[str, float]
    rod: RodParams
    n_hover: float

    def _rod_accel(self, th: float, thd: float, f: float) -> float:
        r, e = self.rod, self.effects
        if "angle_thrust_loss" in e:
            f *= 1.0 - e["angle_thrust_loss"] * math.sin(th) ** 2
        torque = -r.mass * G_STANDARD * r.com * math.sin(th) - r.damping * thd + r.arm * f
        acc = torque / r.inertia
        if "coulomb_friction" in e:
            acc -= e["coulomb_friction"] * math.tanh(thd / COULOMB_VELOCITY)
        if "rod_air_drag" in e:
            acc -= e["rod_air_drag"] * thd * abs(thd)
        return acc

    def _thrust(self, omega: float) -> float:
        alpha = self.effects.get("thrust_law", 2.0)
        return prop_thrust(self.c_t, self.diameter, omega, alpha, self.n_hover)  # type: ignore[attr-defined]

    def simulate(self, duty: np.ndarray) -> dict[str, np.ndarray]:
        """Noise-free response to a duty sequence (τ_k held over [k·dt, (k+1)·dt)), from rest.

        Returns ``t``, ``duty``, ``theta``, ``theta_dot``, ``omega_rotor``, ``theta_recorded`` and
        the family's own channels (``i_a``, ``v_a`` of the amplifier plant).

        Raises
        ------
        TruthError
            On duty values outside [0, 1] or NaN.
        """
        duty = np.asarray(duty, dtype=float)
        if duty.ndim != 1 or not np.all(np.isfinite(duty)) or duty.min() < 0.0 or duty.max() > 1.0:
            raise TruthError("duty must be a finite 1-D sequence in [0, 1]")
        n = duty.size
        lag = round((self.base_dead_time + self.effects.get("input_delay", 0.0)) / self.dt)  # type: ignore[attr-defined]
        delayed = np.concatenate([np.zeros(lag), duty])[:n] if lag else duty
        s = self.rest_state()  # type: ignore[attr-defined]
        h = self.dt / self.substeps
        rows = []
        th_max = self.effects.get("end_stops", math.inf)
        for k in range(n):
            rows.append(self.outputs(s, float(delayed[k])))  # type: ignore[attr-defined]
            for _ in range(self.substeps):
                s = self.step(s, float(delayed[k]), h)  # type: ignore[attr-defined]
                if s[0] > th_max:  # hard stop: the rod is put back on the stop and rebounds
                    s[0] = th_max
                    if s[1] > 0.0:
                        s[1] = -RESTITUTION * s[1]
        t = np.arange(n) * self.dt
        out = {key: np.array([r[key] for r in rows]) for key in rows[0]}
        out.update(t=t, duty=duty, theta_recorded=_recorded_angle(out["theta"].copy(), t, self.effects))
        return out


def _rk4(f: Any, s: list[float], h: float) -> list[float]:
    k1 = f(s, 0.0)
    k2 = f([a + 0.5 * h * b for a, b in zip(s, k1, strict=True)], 0.5 * h)
    k3 = f([a + 0.5 * h * b for a, b in zip(s, k2, strict=True)], 0.5 * h)
    k4 = f([a + h * b for a, b in zip(s, k3, strict=True)], h)
    return [a + h / 6.0 * (b + 2.0 * c + 2.0 * d + g)
            for a, b, c, d, g in zip(s, k1, k2, k3, k4, strict=True)]


class EscPlant(_RodPlant):
    """The hidden ESC rig: :class:`EscParams` plus effects ``{name: magnitude}``
    (:data:`ESC_EFFECT_DOCS`). State [θ, θ̇, ω, τ_f] (τ_f: the throttle filter of ``actuator_lag``).

    Raises
    ------
    TruthError
        On an unknown effect or a non-finite magnitude.
    """

    dt = 0.01
    substeps = 8
    channels = ("theta", "omega_rotor")

    def __init__(self, params: EscParams | None = None, effects: Mapping[str, float] | None = None) -> None:
        self.params = params or EscParams()
        self.effects = _checked(effects, ESC_EFFECT_DOCS)
        p = _apply_scales(self.params, self.effects, ESC_SCALE)
        if "esc_idle" in self.effects:
            p = dataclasses.replace(p, pulse_idle=self.effects["esc_idle"])
        self.p, self.rod, self.c_t, self.diameter = p, p.rod, p.c_t, p.diameter
        self.base_dead_time = p.dead_time
        self.n_hover = self.omega_ss(0.5) / (2.0 * math.pi)

    def omega_ss(self, tau: float) -> float:
        """Steady rotor speed [rad/s] the ESC sets for throttle τ: K_v·V_bat·(share of the range
        above the idle pulse)."""
        p = self.p
        pulse = p.pulse_min + tau * (p.pulse_max - p.pulse_min)
        share = max(0.0, (pulse - p.pulse_idle) / (p.pulse_max - p.pulse_idle))
        return p.kv_rpm * 2.0 * math.pi / 60.0 * p.battery * share

    def rest_state(self) -> list[float]:
        return [0.0, 0.0, 0.0, 0.0]

    def step(self, s: list[float], tau: float, h: float) -> list[float]:
        t_a = self.effects.get("actuator_lag", 0.0)

        def f(x: list[float], _t: float) -> list[float]:
            th, thd, w, tf = x
            w_ss = self.omega_ss(min(max(tf, 0.0), 1.0) if t_a > 0.0 else tau)
            return [thd, self._rod_accel(th, thd, self._thrust(w)), (w_ss - w) / self.p.response,
                    (tau - tf) / t_a if t_a > 0.0 else 0.0]

        return _rk4(f, s, h)

    def outputs(self, s: list[float], tau: float) -> dict[str, float]:
        return {"theta": s[0], "theta_dot": s[1], "omega_rotor": s[2]}


class AmplifierPlant(_RodPlant):
    """The hidden amplifier rig: :class:`AmplifierParams` plus effects ``{name: magnitude}``
    (:data:`AMPLIFIER_EFFECT_DOCS`). State [θ, θ̇, i_a, ω, v_a] (v_a: the lagged amplifier output).

    Raises
    ------
    TruthError
        On an unknown effect or a non-finite magnitude.
    """

    dt = 2e-3
    substeps = 4
    channels = ("theta", "i_a", "omega_rotor")
    base_dead_time = 0.0

    def __init__(self, params: AmplifierParams | None = None,
                 effects: Mapping[str, float] | None = None) -> None:
        self.params = params or AmplifierParams()
        self.effects = _checked(effects, AMPLIFIER_EFFECT_DOCS)
        p = _apply_scales(self.params, self.effects, AMPLIFIER_SCALE)
        self.p, self.rod, self.c_t, self.diameter = p, p.rod, p.c_t, p.diameter
        self.n_hover = self.steady_speed(self.command(0.5)) / (2.0 * math.pi)

    def command(self, tau: float) -> float:
        """Amplifier output [V] for command τ: K_amp·(V_ref·τ) + V_os."""
        return self.p.gain * self.p.v_ref * tau + self.effects.get("amplifier_offset", 0.0)

    def _torque(self, i: float, w: float) -> float:
        p = self.p
        n = w / (2.0 * math.pi)
        drag = p.c_q * RHO_AIR * n * abs(n) * p.diameter**5
        brush = self.effects.get("rotor_brush_friction", 0.0) * math.tanh(w / BRUSH_VELOCITY)
        return p.k_t * i - p.B * w - drag - brush

    def steady_speed(self, v: float) -> float:
        """Rotor speed [rad/s] at which the motor torque of the steady current balances the loads."""
        p = self.p
        lo, hi = 0.0, 1.0
        while self._torque((v - p.k_e * hi) / p.R_a, hi) > 0.0:
            hi *= 2.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if self._torque((v - p.k_e * mid) / p.R_a, mid) > 0.0 else (lo, mid)
        return 0.5 * (lo + hi)

    def rest_state(self) -> list[float]:
        return [0.0, 0.0, 0.0, 0.0, self.command(0.0)]

    def step(self, s: list[float], tau: float, h: float) -> list[float]:
        """One substep of length h [s] with command τ held.

        The current is split into its slow part, the steady current of the present voltage and
        speed corrected to first order in τ_e = L_a/R_a for how fast they change (singular
        perturbation: i = (v_a − k_e·ω)/R_a − τ_e·(v̇_a − k_e·ω̇)/R_a), and a fast transient
        e(t) = e₀·exp(−t/τ_e) left by a voltage step, whose torque impulse is added exactly; the
        mechanical states are integrated by RK4 with the slow current.
        """
        p, t_a = self.p, self.effects.get("actuator_lag", 0.0)
        v_cmd = self.command(tau)
        tau_e = p.L_a / p.R_a
        c = tau_e * p.k_e / p.R_a  # ∂(slow current)/∂ω̇

        def slow(x: list[float]) -> tuple[float, float, float]:
            """(ω̇, v̇, slow current) at state x."""
            _th, _thd, _i, w, v = x
            v_a = v if t_a > 0.0 else v_cmd
            dv = (v_cmd - v) / t_a if t_a > 0.0 else 0.0
            i_ss = (v_a - p.k_e * w) / p.R_a - tau_e * dv / p.R_a
            dw = self._torque(i_ss, w) / (p.J_r - p.k_t * c)
            return dw, dv, i_ss + c * dw

        def f(x: list[float], _t: float) -> list[float]:
            th_, thd_ = x[0], x[1]
            dw, dv, _ = slow(x)
            return [thd_, self._rod_accel(th_, thd_, self._thrust(x[3])), 0.0, dw, dv]

        e0 = s[2] - slow(s)[2]
        x = _rk4(f, s, h)
        decay = math.exp(-h / tau_e)
        x[3] += p.k_t * e0 * tau_e * (1.0 - decay) / p.J_r
        x[2] = slow(x)[2] + e0 * decay
        return x

    def outputs(self, s: list[float], tau: float) -> dict[str, float]:
        v = s[4] if self.effects.get("actuator_lag", 0.0) > 0.0 else self.command(tau)
        return {"theta": s[0], "theta_dot": s[1], "i_a": s[2], "omega_rotor": s[3], "v_a": v}


def _checked(effects: Mapping[str, float] | None, docs: Mapping[str, str]) -> dict[str, float]:
    out = dict(effects or {})
    for k, v in out.items():
        if k not in docs:
            raise TruthError(f"unknown truth effect {k!r}; known: {sorted(docs)}")
        if not math.isfinite(v):
            raise TruthError(f"truth effect {k!r} magnitude {v!r} is not finite")
    return out
