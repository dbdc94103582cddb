"""Sim-to-real gap, part 1: **where** does the nominal simulator disagree with the recordings?

:func:`locate_gap` replays the recorded duty cycle through the nominal rig and compares, per
recording (all on the recording's uniform grid, :func:`aeropend_ident.greybox.uniform.uniform_data`):

1. **Free run** — the model driven by the duty cycle alone from the first samples' state
   (:func:`aeropend_ident.greybox.fit.free_run_theta`); residual e_k = θ_sim − θ_meas [rad], NRMSE as in
   :func:`aeropend_ident.greybox.fit.error_metrics`. θ(0) and θ̇(0) are refined by least squares over
   the first :data:`INIT_WINDOW` seconds (a noisy first sample would otherwise start a spurious
   oscillation that colours the whole residual).
2. **Short-horizon prediction** — the model restarted every ``horizon`` seconds from the
   *measured* state (θ, θ̇ measured or Savitzky-Golay estimated; i_a, ω₁ measured when
   recorded, else taken from the nominal free run, which is exact for the motor because the
   motor does not depend on the pendulum). A model whose free run drifts but whose
   short-horizon prediction is good has a slow (steady-state) gap; a bad short-horizon
   prediction means the fast dynamics are wrong.
3. **Equation errors** — each state equation of :mod:`aeropend_sim.model` evaluated on the
   measured signals (one-step, derivative form), so the gap is located in a subsystem:

   ======== ============ ======================================================= ============
   equation subsystem    residual                                                needs
   ======== ============ ======================================================= ============
   actuator actuator     v_a,meas − v_a(τ) (dead zone, Eq. 4.3 map or ideal)     v_a
   armature electrical   v_a − R_a·i_a − K_ω·ω₁ − L_a·di_a/dt [V]                 i_a, ω₁
   rotor    motor        K_t·i_a − B_m·ω₁ − T_c·sgn ω₁ − K_d·ω₁|ω₁| − J_m·ω̇₁ [N·m] ω₁
                         (ESC: (ω_ss(τ) − ω₁)/T_m − ω̇₁ [rad/s²])
   pendulum pendulum /   θ̈ − (−(mgd/J)sin θ − (c/J)θ̇ − (T_f/J)sgn θ̇ + (L/J)f) [rad/s²] θ
            aerodynamic
   ======== ============ ======================================================= ============

   The right-hand sides are not written here: each is the sum of the nominal rig's active terms of
   that slot (:meth:`aeropend_sim.components.assembly.Assembly.slot_values`), the actuator chain
   from :meth:`~aeropend_sim.components.assembly.Assembly.point`; the table shows them for the
   thesis rig. A check the rig's family does not have (the actuator and armature checks of an ESC,
   which has no armature voltage or current) is reported "not applicable to family esc".

   Derivatives are Savitzky-Golay (cubic, window :data:`SG_WINDOW` s, at least 7 samples);
   the model side is smoothed by the same window so both sides have the same phase. Each
   residual is reported relative to the equation's **driving term** (v_a, K_t·i_a, (L/J)·f):
   the fraction of the input the nominal equation does not account for. The residual is then
   regressed on the equation's term groups (e.g. gravity/offset, friction, thrust for the
   pendulum) and the R² of each group alone says which term is mis-modelled. With θ only, the
   pendulum equation uses the thrust of the *simulated* rotor speed, so a motor or actuator
   error shows there as a "thrust" term; the report says which equations could not be checked
   and why.
4. **Regions** — the free-run residual per bin of measured θ, duty cycle and |θ̇| and transient
   vs steady state (:func:`aeropend_ident.greybox.baseline.residual_regions`), steady-state error per
   constant-duty hold, and per frequency band (Welch PSD of the residual vs the measured θ).
5. **Residual tests** (Ljung & Box 1978; Ljung, *System Identification* §16.6):
   Ljung-Box portmanteau test of the free-run residual's whiteness; cross-correlation between
   the prewhitened input and the residual (χ² test and the lag of its peak); the lag that best
   aligns the simulated with the measured θ̇ (a pure input delay shows up exactly there).

A gap is **significant** when the free-run residual is not white (Ljung-Box p < :data:`ALPHA`)
and its RMS exceeds both 3× the measurement noise (:func:`aeropend_ident.gap.effects.measurement_noise`:
white noise, at least the rounding noise of a detected quantum)
and :data:`MIN_NRMSE` of the measured range. An equation is flagged when its relative residual
exceeds :data:`MIN_RELATIVE`, its RMS exceeds the measurement-noise floor by three standard
errors of an RMS estimate, and the part of its RMS not explained by noise exceeds 1.5× its
method floor (the same equation error on the nominal model's own simulation of the input).

No rclpy import. Units SI, angles in the recording's frame unless said otherwise.
"""


from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from aeropend_ident.errors import GapInputError, IdentificationError
from aeropend_ident.gap.effects import measurement_noise
from aeropend_ident.gap.residual_tests import (
    SG_WINDOW,
    _deriv_gain,
    _group_r2,
    _sg_window,
    _smooth,
    alignment_lag,
    constant_holds,
    frequency_bands,
    input_cross_correlation,
    ljung_box,
    repeatability,
)
from aeropend_ident.gap.where_report import (
    MIN_NRMSE,
    MIN_RELATIVE,
    EquationCheck,
    RecordingWhere,
    WhereReport,
)
from aeropend_ident.greybox.baseline import measured_rate, residual_bins, residual_regions
from aeropend_ident.greybox.fit import error_metrics, initial_velocity
from aeropend_ident.greybox.uniform import UniformData, rod_stiffness, uniform_data
from aeropend_ident.io.resampling import uniform_recording
from aeropend_sim.compiled.plant import CompiledPlant
from aeropend_sim.components import registry
from aeropend_sim.components.xp import NUMPY
from aeropend_sim.model import I_A, OMEGA, TAU_F, THETA, THETA_DOT, ModelError, PlantModel, plant_model
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import SimulationError, simulate_plant

#: Window [s] over which the free run's initial θ, θ̇ are refined by least squares.
INIT_WINDOW = 2.0


#: Fewest samples locate_gap accepts per recording.
MIN_SAMPLES = 50


EQUATIONS: tuple[str, ...] = ("actuator", "armature", "rotor", "pendulum")


SUBSYSTEM = {"actuator": "actuator", "armature": "electrical", "rotor": "motor", "pendulum": "pendulum"}


#: Subsystem each term group points to when it explains the residual.
GROUP_SUBSYSTEM = {
    "offset": "actuator",
    "gain": "actuator",
    "dead_zone": "actuator",
    "voltage": "electrical",
    "resistance": "electrical",
    "back_emf": "electrical",
    "inductance": "electrical",
    "torque": "motor",
    "viscous": "motor",
    "coulomb": "motor",
    "drag": "aerodynamic",
    "gravity_offset": "pendulum",
    "friction": "pendulum",
    "thrust": "aerodynamic",
    "set_point": "actuator",
    "response": "motor",
}


#: Subsystem label of the pendulum equation's thrust group when the rotor speed is not recorded.
THETA_ONLY_CHAIN = "actuator chain (actuator, motor or aerodynamic: not separable from θ alone)"


def _flag(e: EquationCheck, n_eff: float) -> bool:
    """Flag rule: relative > MIN_RELATIVE; RMS above the noise floor by 3 standard errors of an
    RMS estimate over ``n_eff`` independent samples; and the part of the RMS not due to noise
    above 1.5× the method floor."""
    if not (e.relative > MIN_RELATIVE):
        return False
    if e.rms <= e.noise_floor * (1.0 + 3.0 / math.sqrt(2.0 * n_eff)):
        return False
    excess = math.sqrt(max(e.rms**2 - e.noise_floor**2, 0.0))
    return bool(excess > 1.5 * e.method_floor)


def _check(
    eq: str,
    residual: np.ndarray,
    driving: np.ndarray,
    unit: str,
    noise_floor: float,
    note: str,
    groups: dict[str, list[np.ndarray]],
    trim: int,
) -> EquationCheck:
    core = slice(trim, residual.size - trim) if residual.size > 2 * trim + 10 else slice(None)
    r, d = residual[core], driving[core]
    rms = float(np.sqrt(np.mean(r**2)))
    drms = float(np.sqrt(np.mean(d**2)))
    rel = rms / drms if drms > 0.0 else math.nan  # no driving term (a free decay): no relative size
    flagged = bool(rel > MIN_RELATIVE and rms > 3.0 * noise_floor)
    return EquationCheck(
        equation=eq,
        subsystem=SUBSYSTEM[eq],
        checked=True,
        note=note,
        unit=unit,
        rms=rms,
        mean=float(np.mean(r)),
        driving_rms=drms,
        relative=rel,
        noise_floor=noise_floor,
        flagged=flagged,
        groups=_group_r2(r, {k: [c[core] for c in v] for k, v in groups.items()}),
        residual=residual,
        group_subsystems={g: GROUP_SUBSYSTEM[g] for g in groups},
    )


def _grid(rec: Recording, data: UniformData) -> dict[str, np.ndarray]:
    """Every recorded channel on the uniform grid of ``data`` (the one resampling of the tools,
    :func:`aeropend_ident.io.resampling.uniform_recording`)."""
    for name, y in rec.channels.items():
        if not np.all(np.isfinite(y)):
            raise GapInputError(
                f"{rec.source or '<recording>'}: channel {name} has "
                f"{int((~np.isfinite(y)).sum())} NaN/inf value(s); expected finite values"
            )
    grid = uniform_recording(rec, dt=data.dt)
    return {name: y[: data.t.size].copy() for name, y in grid.channels.items()}


def _plant(model: PlantModel, data: UniformData) -> CompiledPlant:
    """The nominal rig's compiled plant at the recording's sample period: one for every replay of
    the recording (free run, initial-state refinement, short-horizon windows, method floor)."""
    try:
        return CompiledPlant(model, data.dt)
    except (ValueError, ModelError) as exc:
        raise GapInputError(f"simulation of {data.source or 'the recording'} failed: {exc}") from exc


def _simulate(plant: CompiledPlant, data: UniformData, x0: np.ndarray) -> Any:
    """:func:`aeropend_sim.simulation.simulate` of the recorded duty from ``x0`` (the same trajectory
    bit for bit, on the kept plant)."""
    try:
        return simulate_plant(plant, data.duty, x0=x0)
    except (SimulationError, ModelError) as exc:
        raise GapInputError(f"simulation of {data.source or 'the recording'} failed: {exc}") from exc


def _refine_initial_state(
    plant: CompiledPlant, data: UniformData, x0: np.ndarray, offset: float, window: float = INIT_WINDOW
) -> np.ndarray:
    """Least-squares correction of θ(0), θ̇(0) over the first ``window`` seconds of free run.

    A noisy first sample starts a spurious free oscillation that colours the whole residual; the
    correction (Gauss-Newton, finite-difference sensitivities, two iterations) removes it. The
    motor states are left as they are.
    """
    k = int(min(data.t.size, max(10, round(window / data.dt))))
    part = UniformData(
        t=data.t[:k],
        duty=data.duty[:k],
        theta=data.theta[:k],
        dt=data.dt,
        resampled=False,
        decimate=1,
        source=data.source,
    )
    x = x0.copy()
    steps = (1e-4, 1e-3)
    for _ in range(2):
        base = _simulate(plant, part, x).x[:, THETA] - offset
        r = data.theta[:k] - base
        jac = np.empty((k, 2))
        for j, h in enumerate(steps):
            xp = x.copy()
            xp[(THETA, THETA_DOT)[j]] += h
            jac[:, j] = (_simulate(plant, part, xp).x[:, THETA] - offset - base) / h
        delta, *_ = np.linalg.lstsq(jac, r, rcond=None)
        if not np.all(np.isfinite(delta)):
            break
        x[THETA] += delta[0]
        x[THETA_DOT] += delta[1]
    return x


def _short_horizon(
    plant: CompiledPlant,
    data: UniformData,
    theta_rate: np.ndarray,
    states: np.ndarray,
    ch: dict[str, np.ndarray],
    offset: float,
    horizon: float,
    omega: np.ndarray | None,
) -> np.ndarray:
    n = data.t.size
    h = max(2, round(horizon / data.dt))
    pred = np.empty(n)
    model = plant.model  # the recording's plant serves every window (a replay equals simulate()'s)
    for k in range(0, n, h):
        stop = min(n, k + h)
        x0 = states[k].copy()
        x0[THETA] = data.theta[k] + offset
        x0[THETA_DOT] = theta_rate[k]
        if omega is not None:
            x0[OMEGA] = omega[k]
        if "i_a" in ch and model.dynamic_current:
            x0[I_A] = ch["i_a"][k]
        if stop - k < 2:
            pred[k] = x0[THETA]
            continue
        x, _u, failed = plant.replay(np.ascontiguousarray(data.duty[k:stop]), x0,
                                     float(data.duty[k - 1]) if k else 0.0)
        if failed >= 0:
            raise GapInputError(
                f"short-horizon simulation of {data.source} at t = {data.t[k]:.3f} s failed: the replay "
                f"diverged at sample {failed} of the window (a state is not finite)")
        pred[k:stop] = x[:, THETA]
    return pred - offset


@dataclass
class _Signals:
    """What the equation checks of one recording share: the nominal model, its actuator chain on the
    recorded input, the derivative filters and the noise of every channel."""

    rig: Rig
    model: PlantModel
    chain: dict[str, Any]
    ch: dict[str, np.ndarray]
    noise: dict[str, float]
    n: int
    dt: float
    w: int
    trim: int
    omega: np.ndarray | None
    omega_note: str

    def sm(self, y: np.ndarray) -> np.ndarray:
        return _smooth(y, self.w)

    def d1(self, y: np.ndarray) -> np.ndarray:
        return _smooth(y, self.w, 1, self.dt)

    @property
    def assembly(self) -> Any:
        return self.model.assembly

    def value(self, key: str) -> float:
        """Effective value of parameter ``key`` in the nominal model."""
        return float(self.assembly.values[key])

    def slot(self, slot: str, inputs: dict[str, Any]) -> dict[str, np.ndarray]:
        """Each active term of ``slot`` on the recorded signals (label -> array)."""
        return {k: np.broadcast_to(np.asarray(v, dtype=float), (self.n,))
                for k, v in self.assembly.slot_values(slot, NUMPY, inputs).items()}

    def summed(self, slot: str, inputs: dict[str, Any]) -> np.ndarray:
        return np.sum(list(self.slot(slot, inputs).values()) or [np.zeros(self.n)], axis=0)

    def driving(self, slot: str, name: str, inputs: dict[str, Any]) -> np.ndarray:
        """The part of a slot that its input ``name`` drives: Σ ∂term/∂name · name (the motor torque
        K_t·i_a, the thrust torque (L/J)·f, the set-point term ω_ss/T_m)."""
        vals = {**self.assembly.by_name, **inputs}
        out = np.zeros(self.n)
        for t in self.assembly.slots.get(slot, ()):
            if name in t.inputs:
                out = out + t.partial(NUMPY, name, vals) * inputs[name]
        return out

    def shape(self, part: str, slot: str, inputs: dict[str, Any], partial: str = "") -> np.ndarray:
        """The shape of a component's or effect's ``slot`` term on the recorded signals, whether the
        rig models it or not: the term at its first parameter 1, settings (regularisation widths) at
        the rig's values, the other parameters absent (``partial``: its derivative by that input).
        A term-error group regresses the residual on these shapes."""
        decl = next(p for p in registry.parts() if p.name == part)
        term = next(t for t in decl.terms if t.slot == slot)
        raw = self.rig.values()
        vals: dict[str, Any] = {}
        for k, p in enumerate(decl.params):
            if k == 0:
                vals[p.name] = 1.0
            elif p.setting or p.absent is None:
                vals[p.name] = raw.get(p.key, p.absent)
            else:
                vals[p.name] = p.absent
        vals.update(inputs)
        y = term.partial(NUMPY, partial, vals) if partial else term(NUMPY, vals)
        return np.broadcast_to(np.asarray(y, dtype=float), (self.n,))


def _not_applicable(eq: str, s: _Signals, why: str) -> EquationCheck:
    return EquationCheck(eq, SUBSYSTEM[eq], False, f"not applicable to family {s.rig.family}: {why}")


def _actuator_check(s: _Signals) -> tuple[EquationCheck, np.ndarray, str]:
    """Measured v_a against the duty → v_a map; returns the check and the v_a the later checks use."""
    a = s.assembly
    if a.drive_name != "v_a":
        why = (f"its drive quantity is {a.drive_name}, a set-point inside the drive, not a measured "
               "armature voltage")
        return _not_applicable("actuator", s, why), np.zeros(s.n), ""
    v_map = np.broadcast_to(np.asarray(s.chain["v_a"], dtype=float), (s.n,))
    if "v_a" not in s.ch:
        return (EquationCheck("actuator", SUBSYSTEM["actuator"], False, "needs v_a, not recorded"), v_map,
                "v_a from the duty→v_a map")
    tau = np.asarray(s.chain["tau"], dtype=float)
    te = np.broadcast_to(np.asarray(s.chain["tau_e"], dtype=float), (s.n,))
    r = s.sm(s.ch["v_a"] - v_map)
    groups = {"offset": [np.ones(s.n)], "gain": [s.sm(v_map)], "dead_zone": [s.sm(np.clip(tau, 0,
                                                                                          None) - te)]}
    g0 = _deriv_gain(s.w, s.dt, 0)
    check = _check("actuator", r, s.ch["v_a"], "V", s.noise["v_a"] * g0, "measured v_a vs the duty→v_a map",
                   groups, s.trim)
    return check, s.ch["v_a"], "measured v_a"


def _armature_check(s: _Signals, v_a: np.ndarray, v_note: str) -> EquationCheck:
    """Voltage balance v_a − R_a·i_a + Σ armature terms(ω₁) − L_a·di_a/dt [V]."""
    a = s.assembly
    if not a.armature:
        return _not_applicable("armature", s, a.family.lacks.get("armature", "no armature circuit"))
    reads_omega = bool(a.slots.get("armature"))
    if "i_a" not in s.ch or (s.omega is None and reads_omega):
        need = [c for c, ok in (("i_a", "i_a" in s.ch), ("omega_rotor",
                                                         s.omega is not None or not reads_omega))
                if not ok]
        return EquationCheck("armature", SUBSYSTEM["armature"], False,
                             f"needs {' and '.join(need)}, not recorded")
    i_a = s.ch["i_a"]
    w1 = s.omega if s.omega is not None else np.zeros(s.n)
    didt = s.d1(i_a) if a.dynamic_current else np.zeros(s.n)
    r_a, l_a = s.value("motor.R_a"), float(s.rig.values()["motor.L_a"])
    r = s.sm(v_a) + s.sm(s.summed("armature", {"omega": w1})) - r_a * s.sm(i_a) - l_a * didt
    g0, g1 = _deriv_gain(s.w, s.dt, 0), _deriv_gain(s.w, s.dt, 1)
    floor = math.hypot(r_a * s.noise["i_a"] * g0, l_a * s.noise["i_a"] * g1)
    groups = {"voltage": [s.sm(v_a)], "resistance": [s.sm(i_a)],
              "back_emf": [s.sm(s.shape("back_emf", "armature", {"omega": w1}))], "inductance": [didt],
              "offset": [np.ones(s.n)]}
    note = f"{v_note}, measured i_a, {s.omega_note or 'no back-EMF'}"
    return _check("armature", r, v_a, "V", floor, note, groups, s.trim)


def _rotor_check(s: _Signals, v_a: np.ndarray) -> EquationCheck:
    """Rotor torque balance Σ rotor-torque terms − J_m·ω̇₁ [N·m] (DC motor), or the speed response
    Σ rotor-response terms − ω̇₁ [rad/s²] (ESC)."""
    a = s.assembly
    if s.omega is None:
        return EquationCheck("rotor", SUBSYSTEM["rotor"], False,
                             "needs omega_rotor (or omega_prop), not recorded")
    omega = s.omega
    g1 = _deriv_gain(s.w, s.dt, 1)
    noise_w = s.noise.get("omega_rotor", s.noise.get("omega_prop", 0.0) * s.value("motor.gear_ratio"))
    if not a.armature:
        sp = np.broadcast_to(np.asarray(s.chain[a.drive_name], dtype=float), (s.n,))
        inputs = {a.drive_name: sp, "omega": omega}
        response = s.summed("rotor_response", inputs)
        r = s.sm(response) - s.d1(omega)
        # a wrong response time scales the response term itself; a wrong map, the set-point
        groups = {"response": [s.sm(response)], "set_point": [s.sm(sp)], "offset": [np.ones(s.n)]}
        note = f"{s.omega_note}, set-point {a.drive_name} of the throttle map"
        return _check("rotor", r, s.driving("rotor_response", a.drive_name, inputs), "rad/s^2", noise_w * g1,
                      note,
                      groups, s.trim)
    if "i_a" in s.ch:
        i_a, i_note = s.ch["i_a"], "measured i_a"
    else:
        i_a = (v_a + s.summed("armature", {"omega": omega})) / s.value("motor.R_a")
        i_note = "i_a = (v_a − K_ω·ω₁)/R_a (quasi-static, i_a not recorded)"
    inputs = {"i_a": i_a, "omega": omega}
    r = s.sm(s.summed("rotor_torque", inputs)) - s.value("motor.J_m") * s.d1(omega)
    groups = {"torque": [s.sm(i_a)]}
    for group, effect in (("viscous", "rotor_viscous_friction"), ("coulomb", "rotor_coulomb_friction"),
                          ("drag", "propeller_drag")):
        groups[group] = [s.sm(s.shape(effect, "rotor_torque", {"omega": omega}))]
    return _check("rotor", r, s.driving("rotor_torque", "i_a", inputs), "N*m",
                  s.value("motor.J_m") * noise_w * g1,
                  f"{s.omega_note}, {i_note}", groups, s.trim)


def _pendulum_check(s: _Signals, theta: np.ndarray, states: np.ndarray, offset: float,
                    theta_rate: np.ndarray) -> EquationCheck:
    """θ̈ against the sum of the rod's terms at the recorded θ, θ̇ and the thrust of ω₁ [rad/s²]."""
    th = theta + offset
    w1 = s.omega if s.omega is not None else states[:, OMEGA]
    wp, thrust = s.assembly.propeller(NUMPY, w1)
    thd = s.ch["theta_dot"] if "theta_dot" in s.ch else theta_rate
    inputs = {"theta": th, "theta_dot": thd, "thrust": np.asarray(thrust, dtype=float)}
    w2 = _sg_window(s.n, s.dt, 2.0 * SG_WINDOW)
    lhs = s.d1(thd) if "theta_dot" in s.ch else _smooth(theta, w2, 2, s.dt)
    r = lhs - s.sm(s.summed("rod", inputs))
    floor = (s.noise["theta_dot"] * _deriv_gain(s.w, s.dt, 1) if "theta_dot" in s.ch
             else s.noise["theta"] * _deriv_gain(w2, s.dt, 2))
    groups = {
        "gravity_offset": [s.sm(s.shape("rod", "rod", {"theta": th})),
                           s.sm(s.shape("rod", "rod", {"theta": th}, partial="theta")), np.ones(s.n)],
        "friction": [s.sm(s.shape("rod_viscous_friction", "rod", {"theta_dot": thd})),
                     s.sm(s.shape("rod_coulomb_friction", "rod", {"theta_dot": thd}))],
        "thrust": [s.sm(np.asarray(thrust, dtype=float)), s.sm(np.asarray(wp, dtype=float))],
    }
    note = (
        f"θ̈ from {'measured θ̇' if 'theta_dot' in s.ch else 'θ (Savitzky-Golay)'}; thrust from "
        + (s.omega_note if s.omega is not None else "the simulated ω₁ (motor/actuator errors show as thrust)")
    )
    pend = _check("pendulum", r, s.driving("rod", "thrust", inputs), "rad/s^2", floor, note, groups, s.trim)
    if s.omega is None:
        pend.group_subsystems["thrust"] = THETA_ONLY_CHAIN
    return pend


def _equations(
    model: PlantModel,
    theta: np.ndarray,
    duty: np.ndarray,
    dt: float,
    ch: dict[str, np.ndarray],
    states: np.ndarray,
    offset: float,
    theta_rate: np.ndarray,
) -> list[EquationCheck]:
    """The equation checks of one recording (module doc, step 3), every term from the nominal rig's
    components (:meth:`aeropend_sim.components.assembly.Assembly.point` and ``slot_values``): the
    actuator-side input is the simulation's (``states[:, TAU_F]``: the delayed command, or the lag
    state), so the chain sees what the nominal simulator's actuator saw."""
    rig = model.rig
    n = theta.size
    w = _sg_window(n, dt)
    omega, omega_note = None, ""
    if "omega_rotor" in ch:
        omega, omega_note = ch["omega_rotor"], "measured ω₁"
    elif "omega_prop" in ch:
        omega, omega_note = ch["omega_prop"] * rig.motor.gear_ratio, "ω₁ = n·measured ω₂"
    chain = model.assembly.point(NUMPY, states, states[:, TAU_F])
    s = _Signals(rig=rig, model=model, chain=chain, ch=ch, noise={k: measurement_noise(v) for k,
                                                                  v in ch.items()},
                 n=n, dt=dt, w=w, trim=w, omega=omega, omega_note=omega_note)
    actuator, v_a, v_note = _actuator_check(s)
    return [actuator, _armature_check(s, v_a, v_note), _rotor_check(s, v_a),
            _pendulum_check(s, theta, states, offset, theta_rate)]


def _free_run_start(plant: CompiledPlant, data: Any, ch: dict[str, np.ndarray], theta_offset: float
                    ) -> np.ndarray:
    """The free run's initial state (n,) of the rig's state layout: from the first samples, the
    motor at the steady state of the first duty, the recorded rate, rotor speed and (dynamic
    armature) current where logged, then θ, θ̇ refined over :data:`INIT_WINDOW`."""
    from aeropend_ident.greybox.fit import initial_state

    rig = plant.rig
    x0 = initial_state(rig, data.theta, data.duty, data.dt, theta_offset)
    x0[THETA_DOT] = ch["theta_dot"][0] if "theta_dot" in ch else initial_velocity(data.theta, data.dt)
    if "omega_rotor" in ch or "omega_prop" in ch:
        x0[OMEGA] = (
            ch["omega_rotor"][0] if "omega_rotor" in ch else ch["omega_prop"][0] * rig.motor.gear_ratio
        )
    if "i_a" in ch and rig.effects.armature_inductance == "dynamic":
        x0[I_A] = ch["i_a"][0]
    return _refine_initial_state(plant, data, x0, theta_offset)


def _method_floor(model: PlantModel, data: Any, ch: dict[str, np.ndarray], traj: Any, theta_free: np.ndarray,
                  theta_offset: float, eqs: list[EquationCheck]) -> None:
    """Each checked equation's method floor (the same equation errors on the nominal simulation of
    this input: what the derivative filters alone leave on a perfect model) and its flag, in place."""
    dt = data.dt
    sim_ch = {k: (traj.true[k] - (theta_offset if k == "theta" else 0.0)) for k in ch if k in traj.true}
    sim_rate = sim_ch["theta_dot"] if "theta_dot" in sim_ch else measured_rate(theta_free, dt)
    n_eff = max(data.t.size / _sg_window(data.t.size, dt, 2.0 * SG_WINDOW), 1.0)
    for e, f in zip(
        eqs, _equations(model, theta_free, data.duty, dt, sim_ch, traj.x, theta_offset, sim_rate), strict=True
    ):
        if e.checked:
            e.method_floor = f.rms
            e.flagged = _flag(e, n_eff)


def locate_recording(
    rig: Rig, recording: Recording, *, horizon: float = 0.2, theta_offset: float = 0.0, n_bins: int = 5
) -> RecordingWhere:
    """Where-analysis of one recording (module doc, steps 1-5).

    Parameters
    ----------
    rig : Rig
        Nominal model.
    recording : Recording
        Needs ``theta`` [rad] and the duty cycle; uses ``theta_dot``, ``i_a``, ``v_a``,
        ``omega_rotor`` / ``omega_prop`` when present.
    horizon : float
        Short-horizon prediction length [s].
    theta_offset : float
        θ_model − θ_recorded [rad].
    n_bins : int
        Bins per operating-region variable.

    Raises
    ------
    GapInputError
        No θ, NaNs, constant input, fewer than :data:`MIN_SAMPLES` samples, bad horizon, or a
        failed simulation.
    """
    if not (math.isfinite(horizon) and horizon > 0.0):
        raise GapInputError(f"horizon = {horizon!r}; expected a finite value > 0 s")
    try:
        data = uniform_data(recording, min_samples=MIN_SAMPLES)
    except IdentificationError as exc:
        raise GapInputError(str(exc)) from exc
    ch = _grid(recording, data)
    dt = data.dt
    rate = measured_rate(data.theta, dt)
    plant = _plant(plant_model(rig), data)
    traj = _simulate(plant, data, _free_run_start(plant, data, ch, theta_offset))
    states = traj.x
    theta_free = states[:, THETA] - theta_offset
    omega = ch.get("omega_rotor")
    if omega is None and "omega_prop" in ch:
        omega = ch["omega_prop"] * rig.motor.gear_ratio
    theta_rate = ch["theta_dot"] if "theta_dot" in ch else rate
    theta_short = _short_horizon(plant, data, theta_rate, states, ch, theta_offset, horizon, omega)
    resid = theta_free - data.theta
    free = error_metrics(data.theta, theta_free)
    all_holds = constant_holds(data.t, data.duty, data.theta, theta_free, limit=100_000)
    # a free run that leaves the measured angle range by more than π has flipped over the pivot:
    # its NRMSE only says "diverged"
    free["diverged"] = bool(
        np.max(np.abs(theta_free - np.clip(theta_free, data.theta.min(), data.theta.max()))) > math.pi
    )
    short = error_metrics(data.theta, theta_short)
    regions = residual_regions(data.theta, data.duty, resid, dt, n_bins)
    regions["rate_bins"] = residual_bins(np.abs(rate), resid, n_bins, "rad/s")
    regions["short_horizon"] = residual_regions(data.theta, data.duty, theta_short - data.theta, dt, n_bins)
    eqs = _equations(plant.model, data.theta, data.duty, dt, ch, states, theta_offset, theta_rate)
    _method_floor(plant.model, data, ch, traj, theta_free, theta_offset, eqs)
    pend = next(e for e in eqs if e.equation == "pendulum")
    if pend.residual is not None:
        regions["pendulum_equation"] = {
            "theta_bins": residual_bins(data.theta, pend.residual, n_bins, "rad"),
            "duty_bins": residual_bins(data.duty, pend.residual, n_bins, "1"),
            "rate_bins": residual_bins(np.abs(rate), pend.residual, n_bins, "rad/s"),
            "unit": "rad/s^2",
        }
    th_mean = float(np.mean(data.theta)) + theta_offset
    k_lin = rod_stiffness(rig, th_mean)
    if k_lin <= 0.0:
        k_lin = rod_stiffness(rig, 0.0)
    f_n = math.sqrt(max(k_lin, 1e-6)) / (2 * math.pi)
    # at least the rounding noise of the rig's angle sensor: a stretch that sits on one or two lattice
    # values (a decay come to rest) shows no lattice of its own, and its noise read 0 made any residual
    # "significant" (an effect-free H-bridge rig at held-out NRMSE 0.00034)
    q = rig.sensors.theta_quantum if rig.effects.quantisation else 0.0
    noise = max(measurement_noise(data.theta), q / math.sqrt(12.0))
    wb = ljung_box(resid)
    rms = free["rms_error"]
    significant = bool((not wb["white"]) and rms > 3.0 * noise and free["nrmse"] > MIN_NRMSE)
    return RecordingWhere(
        source=recording.source or "<recording>",
        dt=dt,
        channels=sorted(recording.channels),
        t=data.t,
        duty=data.duty,
        theta=data.theta,
        theta_free=theta_free,
        theta_short=theta_short,
        free_run=free,
        short_horizon=short,
        horizon=horizon,
        equations=eqs,
        regions=regions,
        holds=all_holds[:60],
        repeats=repeatability(all_holds),
        bands=[*frequency_bands(resid, data.theta, dt, f_n), {"band": "nominal f_n", "f_hz": f_n}],
        whiteness=wb,
        input_xcorr=input_cross_correlation(data.duty, resid, dt),
        alignment=alignment_lag(data.theta, theta_free, dt),
        noise_rms=noise,
        significant=significant,
    )


def locate_gap(
    rig: Rig,
    recordings: Sequence[Recording],
    *,
    horizon: float = 0.2,
    theta_offset: float = 0.0,
    n_bins: int = 5,
) -> WhereReport:
    """Locate the sim-to-real gap of a nominal rig on recordings (see the module doc).

    Parameters
    ----------
    rig : Rig
        The nominal simulator.
    recordings : sequence of Recording
        Recorded runs (duty cycle + θ at least).
    horizon : float
        Short-horizon prediction length [s].
    theta_offset : float
        θ_model − θ_recorded [rad] (:func:`aeropend_ident.greybox.parameters.rig_theta_offset` of a rig file).
    n_bins : int
        Bins per operating-region variable.

    Returns
    -------
    WhereReport

    Raises
    ------
    GapInputError
        No recordings, or a recording :func:`locate_recording` refuses.
    """
    if not recordings:
        raise GapInputError("no recordings given; expected at least one with theta and duty")
    per = [
        locate_recording(rig, r, horizon=horizon, theta_offset=theta_offset, n_bins=n_bins)
        for r in recordings
    ]
    located, not_checked = [], []
    for eq in EQUATIONS:
        rows = [(r.equation(eq), r.t.size) for r in per if r.equation(eq).checked]
        if not rows:
            not_checked.append({"equation": eq, "reason": per[0].equation(eq).note})
            continue
        wsum = sum(nw for _, nw in rows)
        # pooled: the residual's mean square over the driving term's, both sample-weighted (a free
        # decay's near-zero driving term does not blow the ratio up)
        pooled = sum(e.driving_rms**2 * nw for e, nw in rows)
        rel = math.sqrt(sum(e.rms**2 * nw for e, nw in rows) / pooled) if pooled > 0.0 else math.nan
        groups: dict[str, float] = {}
        for e, nw in rows:
            for g, v in e.groups.items():
                groups[g] = groups.get(g, 0.0) + v * nw / wsum
        top = max(groups, key=groups.__getitem__) if groups else None
        gsub = {}
        for e, _ in rows:
            gsub.update(e.group_subsystems)
        located.append(
            {
                "equation": eq,
                "subsystem": SUBSYSTEM[eq],
                "relative": rel,
                "flagged": any(e.flagged for e, _ in rows),
                "top_group": top,
                "top_group_subsystem": gsub.get(top or "", None),
                "groups": groups,
                "n_recordings": len(rows),
            }
        )
    # flagged equations first, in causal order (an upstream error also shows downstream where the
    # downstream equation uses a simulated, not a measured, upstream signal); then by size
    located.sort(
        key=lambda r: (
            not r["flagged"],
            EQUATIONS.index(r["equation"]) if r["flagged"] else 0,
            -r["relative"] if math.isfinite(r["relative"]) else 0.0,
        )
    )
    return WhereReport(
        rig=rig.name,
        theta_offset=theta_offset,
        recordings=per,
        significant=any(r.significant for r in per),
        located=located,
        not_checked=not_checked,
    )

