"""Catalog of candidate unmodelled effects for the sim-to-real gap diagnosis (issue 5, "which").

Each :class:`Effect` is a small group of physically meaningful parameters that, added to a
nominal rig, changes the simulated response in one characteristic way: an H-bridge voltage drop,
a duty-cycle dead zone, a misscaled back-EMF, a wrong armature inductance, Coulomb friction on
the rod, a viscous-friction error, a thrust-law exponent other than 2, a propeller-drag error, an
actuator lag, a motor mechanical time constant (rotor inertia J_m), an input (transport) delay,
a gravity-torque error, an inertia error, end stops, a sensor offset or scale on θ, and angle
quantisation. Every entry says

* how to switch it on in a :class:`aeropend_sim.params.Rig` and which parameters to fit, with
  units, physical bounds, the value meaning "absent" and a typical magnitude (``probe``) used for
  screening and as the start of a fit (:meth:`Effect.apply`);
* its discrepancy-SINDy term group: the named candidate columns it adds to each state equation
  (``terms``), built by :mod:`aeropend_ident.gap_which` as the change of the model's right-hand
  side when the effect is switched on at the probe magnitude;
* which recorded channels are needed to identify it (``needs_channels``): an armature-inductance
  or back-EMF error hides inside the thrust gain when only θ is recorded, propeller drag needs the
  rotor speed;
* effects it is easily confused with (``confusable_with``).

Effects that the plant model cannot express (an offset or scale of the angle sensor) are
**measurement transforms** implemented here (:class:`MeasurementMap`):
θ_recorded = s·(θ_model − θ_offset), the offset with the sign convention of the rig files'
``recording_frame.theta_offset`` (θ_model = θ_recorded + θ_offset for s = 1).

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeropend_sim.model import PlantModel
from aeropend_sim.params import Rig, RigFileError
from aeropend_sim.recording import Recording


class GapError(ValueError):
    """Input the gap diagnosis cannot use (missing channel, NaNs, too short, unknown effect)."""


#: Operating angle [rad] at which the thrust-exponent effect keeps the thrust unchanged.
THRUST_REFERENCE_ANGLE = 0.5
#: Fewest samples a recording must have for the gap diagnosis.
MIN_RECORDING_SAMPLES = 200


@dataclass(frozen=True)
class MeasurementMap:
    """Angle-sensor transform θ_recorded = scale·(θ_model − theta_offset).

    Attributes
    ----------
    theta_offset : float
        θ_model − θ_recorded at scale 1 [rad] (sign convention of ``recording_frame``).
    theta_scale : float
        Sensor gain [1] (1 = exact).
    """

    theta_offset: float = 0.0
    theta_scale: float = 1.0

    def to_recorded(self, theta_model: np.ndarray) -> np.ndarray:
        """Recorded angle [rad] of a model angle [rad] (any shape)."""
        return self.theta_scale * (np.asarray(theta_model, dtype=float) - self.theta_offset)

    def to_model(self, theta_recorded: np.ndarray) -> np.ndarray:
        """Model angle [rad] of a recorded angle [rad] (inverse of :meth:`to_recorded`)."""
        return np.asarray(theta_recorded, dtype=float) / self.theta_scale + self.theta_offset

    @property
    def identity(self) -> bool:
        """True when the map changes nothing."""
        return self.theta_offset == 0.0 and self.theta_scale == 1.0


@dataclass(frozen=True)
class EffectParameter:
    """One fitted parameter of an effect.

    Attributes
    ----------
    name : str
        Parameter name within the effect (e.g. ``"dead_zone"``, ``"K_omega_scale"``).
    unit : str
        SI unit ("1" for scale factors and duty fractions).
    lower, upper : float
        Physical bounds.
    off : float
        Value at which the effect is absent (0 for additive terms, 1 for scale factors).
    probe : float
        Typical magnitude: the screening column is the model change from ``off`` to ``probe``,
        and fits start there.
    log : bool
        Fitted as a logarithm (strictly positive parameters).
    rig_field : str
        Where the value ends up: ``"section.field"`` of the rig, or ``"measurement.<attr>"``.
    doc : str
        Meaning.
    """

    name: str
    unit: str
    lower: float
    upper: float
    off: float
    probe: float
    log: bool
    rig_field: str
    doc: str


@dataclass(frozen=True)
class Effect:
    """One catalog entry (see the module docstring).

    Attributes
    ----------
    name : str
        Catalog key, e.g. ``"dead_zone"``.
    subsystem : str
        ``"electrical" | "motor" | "aerodynamic" | "pendulum" | "actuator" | "sensor"``.
    description : str
        What the effect is, with its equation.
    needs_channels : tuple of str
        Channels that must be recorded (besides the duty cycle) to identify it.
    parameters : tuple of EffectParameter
        The fitted group.
    terms : dict
        Discrepancy-SINDy term group: equation (``"theta_dot"``, ``"i_a"``, ``"omega_rotor"``,
        ``"v_a"``) -> named candidate columns.
    model_switch : str
        The :class:`aeropend_sim.params.Effects` switch it turns on ("" for parameter errors and
        measurement transforms).
    confusable_with : tuple of str
        Effects with a similar signature on the channels named in ``needs_channels``.
    kind : str
        ``"model"`` (changes the plant), ``"measurement"`` (θ transform) or ``"direct"``
        (detected from the data itself, e.g. quantisation).
    data_probe : callable, optional
        Recorded angle -> probe values, for effects whose typical magnitude depends on the data
        (the end-stop angle must lie inside the recorded range).
    screened : bool
        Part of the discrepancy-SINDy screening (default). False: always confirmed by a grey-box
        fit instead (the motor time constant, whose θ̈ column is nearly collinear with the damping
        term and would crowd it out of the group selection).
    """

    name: str
    subsystem: str
    description: str
    needs_channels: tuple[str, ...]
    parameters: tuple[EffectParameter, ...]
    terms: dict[str, tuple[str, ...]]
    model_switch: str
    confusable_with: tuple[str, ...] = ()
    kind: str = "model"
    _apply: Callable[[Rig, Mapping[str, float]], Rig] | None = field(default=None, repr=False, compare=False)
    data_probe: Callable[[np.ndarray], dict[str, float]] | None = field(
        default=None, repr=False, compare=False)
    screened: bool = True

    def probe_for(self, theta_model: np.ndarray) -> dict[str, float]:
        """Probe values for data whose model-frame angle is ``theta_model`` [rad].

        Most effects use their fixed ``probe``; an end stop must sit inside the recorded range
        to change anything, so its probe is taken just below the largest recorded angles (0.02 rad
        under the 99.5 % quantile: on a stop, the rod rests there for a while).
        """
        vals = {p.name: p.probe for p in self.parameters}
        if self.data_probe is not None and np.size(theta_model):
            for k, v in self.data_probe(np.asarray(theta_model, dtype=float)).items():
                p = next(q for q in self.parameters if q.name == k)
                vals[k] = float(min(max(v, p.lower), p.upper))
        return vals

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the fitted parameters, in order."""
        return tuple(p.name for p in self.parameters)

    def values(self, values: Mapping[str, float] | None = None, which: str = "probe") -> dict[str, float]:
        """Complete parameter values: ``values`` filled up with ``probe`` (or ``off``) values.

        Raises
        ------
        GapError
            On an unknown parameter name or a value outside the bounds.
        """
        out = {p.name: float(getattr(p, which)) for p in self.parameters}
        for k, v in (values or {}).items():
            if k not in out:
                raise GapError(f"effect {self.name!r} has no parameter {k!r}; expected some of {list(out)}")
            out[k] = float(v)
        for p in self.parameters:
            v = out[p.name]
            if p.name not in (values or {}):
                continue
            if not math.isfinite(v) or not (p.lower <= v <= p.upper):
                raise GapError(
                    f"effect {self.name!r}: {p.name} = {v!r} {p.unit} outside [{p.lower}, {p.upper}]"
                )
        return out

    def apply(self, rig: Rig, values: Mapping[str, float] | None = None) -> Rig:
        """The rig with this effect switched on at the given (default: probe) magnitude.

        Measurement transforms and directly detected effects return the rig unchanged (see
        :meth:`measurement`, :func:`apply_effects`).

        Raises
        ------
        GapError
            On unknown parameters, values outside the bounds, or values the rig format rejects.
        """
        vals = self.values(values)
        if self._apply is None:
            return rig
        try:
            return self._apply(rig, vals)
        except RigFileError as exc:
            raise GapError(f"effect {self.name!r} with {vals}: rejected by the rig format: {exc}") from exc

    def measurement(self, current: MeasurementMap,
                    values: Mapping[str, float] | None = None) -> MeasurementMap:
        """The measurement map with this effect's θ transform composed in (model effects: unchanged)."""
        if self.kind != "measurement":
            return current
        vals = self.values(values)
        return dataclasses.replace(current, **{k.split(".", 1)[1]: vals[p]
                                               for p, k in ((q.name, q.rig_field) for q in self.parameters)})

    def rig_values(self, rig: Rig, values: Mapping[str, float] | None = None) -> dict[str, float]:
        """Physical values the effect writes (``"section.field"`` or ``"measurement.*"`` -> value)."""
        vals = self.values(values)
        new = self.apply(rig, vals)
        out: dict[str, float] = {}
        for p in self.parameters:
            section, _, name = p.rig_field.partition(".")
            if section == "measurement":
                out[p.rig_field] = vals[p.name]
            else:
                out[p.rig_field] = float(getattr(getattr(new, section), name))
        return out


def _par(name: str, unit: str, lower: float, upper: float, off: float, probe: float, log: bool,
         rig_field: str, doc: str) -> EffectParameter:
    return EffectParameter(name, unit, lower, upper, off, probe, log, rig_field, doc)


# ------------------------------------------------------------------------------ appliers
def _hbridge_drop(rig: Rig, v: Mapping[str, float]) -> Rig:
    drop = v["V_drop"]
    a = rig.actuator
    if rig.effects.hbridge_map:
        return rig.with_params("actuator", hbridge_k0=a.hbridge_k0 - drop)
    # ideal map v_a = v_s·τ: a drop V with the 0 V clip equals a dead zone V/v_s at a supply v_s − V
    if drop <= 0.0:
        return rig.with_params("actuator", v_supply=a.v_supply - drop)
    if drop >= a.v_supply:
        raise GapError(f"H-bridge drop {drop} V >= supply {a.v_supply} V")
    base_dz = a.dead_zone if rig.effects.dead_zone else 0.0
    te0 = drop / a.v_supply
    dz = base_dz + te0 * (1.0 - base_dz)
    return rig.with_params("actuator", v_supply=a.v_supply - drop, dead_zone=dz).with_effects(dead_zone=True)


def _dead_zone(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("actuator", dead_zone=v["dead_zone"]).with_effects(dead_zone=True)


def _back_emf(rig: Rig, v: Mapping[str, float]) -> Rig:
    m = rig.motor
    base = m.K_omega if rig.effects.back_emf else m.K_t
    return rig.with_params("motor", K_omega=base * v["K_omega_scale"]).with_effects(back_emf=True)


def _inductance(rig: Rig, v: Mapping[str, float]) -> Rig:
    new = rig.with_params("motor", L_a=rig.motor.L_a * v["L_a_scale"])
    return new.with_effects(armature_inductance="dynamic")


def _coulomb(rig: Rig, v: Mapping[str, float]) -> Rig:
    base = rig.pendulum.coulomb_over_J if rig.effects.coulomb_friction else 0.0
    return rig.with_params("pendulum", coulomb_over_J=base + v["coulomb_over_J"]).with_effects(
        coulomb_friction=True)


def _viscous(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("pendulum", c_over_J=rig.pendulum.c_over_J * v["c_scale"]).with_effects(
        viscous_friction=True)


def thrust_reference_speed(rig: Rig) -> float:
    """Propeller speed ω₂ [rad/s] holding the rod at :data:`THRUST_REFERENCE_ANGLE` with α = 2.

    The thrust-exponent effect rescales K_q so that the thrust at this speed stays the nominal
    one: f = K_q·ω_ref^(2−α)·|ω₂|^α (only the shape of the thrust law changes, not its level at
    the operating point).
    """
    p = rig.pendulum
    f = p.mgd_over_J * math.sin(THRUST_REFERENCE_ANGLE) / p.L_over_J
    return math.sqrt(f / rig.thrust.K_q)


def _thrust_exponent(rig: Rig, v: Mapping[str, float]) -> Rig:
    alpha = v["exponent"]
    base_alpha = rig.thrust.exponent if rig.effects.thrust_exponent else 2.0
    w_ref = thrust_reference_speed(rig)
    k_q = rig.thrust.K_q * w_ref ** (base_alpha - alpha)
    return rig.with_params("thrust", exponent=alpha, K_q=k_q).with_effects(thrust_exponent=True)


def _drag(rig: Rig, v: Mapping[str, float]) -> Rig:
    m = rig.motor
    base = m.K_d if (rig.effects.propeller_drag and m.K_d > 0.0) else 1e-8
    return rig.with_params("motor", K_d=base * v["K_d_scale"]).with_effects(propeller_drag=True)


def _lag(rig: Rig, v: Mapping[str, float]) -> Rig:
    new = rig.with_params("actuator", lag_time_constant=v["lag_time_constant"])
    return new.with_effects(actuator_lag=True)


def _motor_time_constant(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("motor", J_m=rig.motor.J_m * v["J_m_scale"])


def _delay(rig: Rig, v: Mapping[str, float]) -> Rig:
    base = rig.actuator.input_delay if rig.effects.input_delay else 0.0
    return rig.with_params("actuator", input_delay=base + v["input_delay"]).with_effects(input_delay=True)


def _gravity(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("pendulum", mgd_over_J=rig.pendulum.mgd_over_J * v["mgd_scale"])


def _inertia(rig: Rig, v: Mapping[str, float]) -> Rig:
    s = v["J_scale"]
    p = rig.pendulum
    return rig.with_params("pendulum", mgd_over_J=p.mgd_over_J / s, c_over_J=p.c_over_J / s,
                           L_over_J=p.L_over_J / s, coulomb_over_J=p.coulomb_over_J / s)


def _end_stops(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("pendulum", theta_max=v["theta_max"]).with_effects(end_stops=True)


def _quantisation(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("sensors", theta_quantum=v["theta_quantum"]).with_effects(quantisation=True)


_TH = "theta_dot"
CATALOG: tuple[Effect, ...] = (
    Effect(
        "hbridge_drop", "electrical",
        "H-bridge voltage drop V_d: v_a = max(0, k0 − V_d + k1·sqrt(k2·τ + k3)) (Eq. 4.3 map) or "
        "max(0, v_supply·τ − V_d) (ideal map)",
        ("theta",),
        (_par("V_drop", "V", -0.5, 1.0, 0.0, 0.15, False, "actuator.hbridge_k0",
              "voltage lost across the bridge switches"),),
        {_TH: ("L/J·Δf(V_d)",), "i_a": ("Δv_a(V_d)/L_a",), "v_a": ("Δv_a(V_d)",)},
        "hbridge_map", ("dead_zone",), _apply=_hbridge_drop,
    ),
    Effect(
        "dead_zone", "actuator",
        "duty-cycle dead zone τ_dz: τ_e = max(0, τ − τ_dz)/(1 − τ_dz)",
        ("theta",),
        (_par("dead_zone", "1", 0.0, 0.5, 0.0, 0.05, False, "actuator.dead_zone", "dead-zone width τ_dz"),),
        {_TH: ("L/J·Δf(τ_dz)",), "i_a": ("Δv_a(τ_dz)/L_a",), "v_a": ("Δv_a(τ_dz)",)},
        "dead_zone", ("hbridge_drop",), _apply=_dead_zone,
    ),
    Effect(
        "back_emf", "motor",
        "back-EMF omitted or misscaled: L_a·di_a/dt = v_a − R_a·i_a − k·K_ω·ω₁",
        ("i_a",),
        (_par("K_omega_scale", "1", 0.05, 20.0, 1.0, 1.5, True, "motor.K_omega", "K_ω true / K_ω nominal"),),
        {_TH: ("L/J·Δf(K_ω)",), "i_a": ("−ΔK_ω·ω₁/L_a",), "omega_rotor": ("K_t·Δi_a(K_ω)/J_m",)},
        "back_emf", (), _apply=_back_emf,
    ),
    Effect(
        "armature_inductance", "electrical",
        "armature inductance misscaled: L_a → k·L_a (electrical time constant L_a/R_a)",
        ("i_a",),
        (_par("L_a_scale", "1", 0.05, 200.0, 1.0, 5.0, True, "motor.L_a", "L_a true / L_a nominal"),),
        {_TH: ("L/J·Δf(L_a)",), "i_a": ("(1/k − 1)·di_a/dt",), "omega_rotor": ("K_t·Δi_a(L_a)/J_m",)},
        "armature_inductance", (), _apply=_inductance,
    ),
    Effect(
        "coulomb_friction", "pendulum",
        "Coulomb/stiction friction on the rod: θ̈ −= (T_f/J)·sgn(θ̇) (tanh-regularised)",
        ("theta",),
        (_par("coulomb_over_J", "rad/s^2", 0.0, 20.0, 0.0, 0.5, False, "pendulum.coulomb_over_J",
              "friction torque over inertia T_f/J"),),
        {_TH: ("−tanh(θ̇/v_ε)",)},
        "coulomb_friction", ("viscous_friction",), _apply=_coulomb,
    ),
    Effect(
        "viscous_friction", "pendulum",
        "viscous friction error on the rod: c/J → k·c/J",
        ("theta",),
        (_par("c_scale", "1", 0.05, 20.0, 1.0, 1.5, True, "pendulum.c_over_J", "c/J true / c/J nominal"),),
        {_TH: ("−θ̇",)},
        "viscous_friction", ("coulomb_friction",), _apply=_viscous,
    ),
    Effect(
        "thrust_exponent", "aerodynamic",
        "thrust law f = K_q·|ω₂|^α with α ≠ 2 (K_q rescaled to keep the thrust at the operating point "
        f"θ = {THRUST_REFERENCE_ANGLE} rad)",
        ("theta",),
        (_par("exponent", "1", 1.0, 3.5, 2.0, 2.2, False, "thrust.exponent", "thrust-law exponent α"),),
        {_TH: ("L/J·f·ln(ω₂/ω_ref)",)},
        "thrust_exponent", ("propeller_drag", "gravity"), _apply=_thrust_exponent,
    ),
    Effect(
        "propeller_drag", "aerodynamic",
        "propeller drag torque misscaled or omitted: K_d → k·K_d in J_m·ω̇₁ = … − K_d·ω₁|ω₁|",
        ("omega_rotor",),
        (_par("K_d_scale", "1", 0.05, 50.0, 1.0, 1.5, True, "motor.K_d", "K_d true / K_d nominal"),),
        {_TH: ("L/J·Δf(K_d)",), "omega_rotor": ("−ΔK_d·ω₁|ω₁|/J_m",)},
        "propeller_drag", ("thrust_exponent",), _apply=_drag,
    ),
    Effect(
        "actuator_lag", "actuator",
        "first-order actuator lag T_a: τ̇_f = (τ − τ_f)/T_a",
        ("theta",),
        (_par("lag_time_constant", "s", 1e-3, 2.0, 0.0, 0.05, True, "actuator.lag_time_constant",
              "lag time constant T_a"),),
        {_TH: ("L/J·Δf(T_a)",), "i_a": ("Δv_a(T_a)/L_a",), "v_a": ("Δv_a(T_a)",)},
        "actuator_lag", ("input_delay", "motor_time_constant"), _apply=_lag,
    ),
    Effect(
        "motor_time_constant", "motor",
        "rotor-side inertia error J_m → k·J_m (rotor + gear + propeller): the motor's mechanical time "
        "constant J_m/(B_m + 2·K_d·ω₁ + K_t·K_ω/R_a) scales with k, the thrust follows the duty cycle "
        "more slowly (k > 1) or faster (k < 1)",
        ("theta",),
        (_par("J_m_scale", "1", 0.05, 20.0, 1.0, 2.0, True, "motor.J_m", "J_m true / J_m nominal"),),
        {_TH: ("L/J·Δf(J_m)",), "omega_rotor": ("−ΔJ_m·ω̇₁/J_m",)},
        "", ("actuator_lag", "input_delay"), _apply=_motor_time_constant, screened=False,
    ),
    Effect(
        "input_delay", "actuator",
        "input/transport delay T_d: the actuator sees τ(t − T_d)",
        ("theta",),
        (_par("input_delay", "s", 0.0, 0.5, 0.0, 0.04, False, "actuator.input_delay", "delay T_d"),),
        {_TH: ("L/J·Δf(T_d)",), "i_a": ("Δv_a(T_d)/L_a",), "v_a": ("Δv_a(T_d)",)},
        "input_delay", ("actuator_lag", "motor_time_constant"), _apply=_delay,
    ),
    Effect(
        "gravity", "pendulum",
        "gravity-torque (mass · lever) error: mgd/J → k·mgd/J",
        ("theta",),
        (_par("mgd_scale", "1", 0.2, 5.0, 1.0, 1.2, True, "pendulum.mgd_over_J", "mgd/J true / nominal"),),
        {_TH: ("−sin θ",)},
        "", ("inertia", "sensor_scale"), _apply=_gravity,
    ),
    Effect(
        "inertia", "pendulum",
        "rod inertia error J → k·J: every /J term (mgd/J, c/J, L/J, T_f/J) divided by k",
        ("theta",),
        (_par("J_scale", "1", 0.2, 5.0, 1.0, 1.2, True, "pendulum.L_over_J", "J true / J nominal"),),
        {_TH: ("θ̈_model",)},
        "", ("gravity",), _apply=_inertia,
    ),
    Effect(
        "end_stops", "pendulum",
        "mechanical end stop at θ_max: one-sided spring-damper contact beyond it",
        ("theta",),
        (_par("theta_max", "rad", 0.1, 1.5707963, 1.5707963, 0.8, False, "pendulum.theta_max",
              "upper stop angle"),),
        {_TH: ("contact(θ − θ_max)",)},
        "end_stops", (), _apply=_end_stops,
        data_probe=lambda th: {"theta_max": float(np.quantile(th, 0.995)) - 0.02},
    ),
    Effect(
        "sensor_offset", "sensor",
        "angle-sensor offset: θ_recorded = θ − θ_offset",
        ("theta",),
        (_par("theta_offset", "rad", -0.6, 0.6, 0.0, 0.05, False, "measurement.theta_offset",
              "θ_model − θ_recorded"),),
        {_TH: ("−(mgd/J)·cos θ",)},
        "", (), kind="measurement",
    ),
    Effect(
        "sensor_scale", "sensor",
        "angle-sensor gain error: θ_recorded = s·θ",
        ("theta",),
        (_par("theta_scale", "1", 0.5, 2.0, 1.0, 1.1, True, "measurement.theta_scale", "sensor gain s"),),
        {_TH: ("s·θ̈_model(θ/s)",)},
        "", ("gravity", "inertia"), kind="measurement",
    ),
    Effect(
        "quantisation", "sensor",
        "angle quantisation: θ_recorded = q·round(θ/q) (ADC/encoder LSB q)",
        ("theta",),
        (_par("theta_quantum", "rad", 0.0, 0.2, 0.0, 0.006, False, "sensors.theta_quantum", "angle LSB q"),),
        {},
        "quantisation", (), kind="direct", _apply=_quantisation,
    ),
)

#: Catalog keyed by effect name.
EFFECTS: dict[str, Effect] = {e.name: e for e in CATALOG}


def get_effect(name: str) -> Effect:
    """Catalog entry by name.

    Raises
    ------
    GapError
        If ``name`` is not in :data:`CATALOG` (the message lists the known names).
    """
    try:
        return EFFECTS[name]
    except KeyError:
        raise GapError(f"unknown effect {name!r}; the catalog has {list(EFFECTS)}") from None


def apply_effects(rig: Rig, chosen: Mapping[str, Mapping[str, float]],
                  measurement: MeasurementMap | None = None) -> tuple[Rig, MeasurementMap]:
    """Rig and measurement map with several effects applied in catalog order.

    Parameters
    ----------
    rig : Rig
        Nominal rig.
    chosen : mapping
        ``{effect name: {parameter: value}}`` (missing parameters take their probe values).
    measurement : MeasurementMap, optional
        Starting measurement map (default identity).

    Returns
    -------
    (Rig, MeasurementMap)

    Raises
    ------
    GapError
        On an unknown effect or parameter, or a value out of bounds.
    """
    for name in chosen:
        get_effect(name)
    meas = measurement or MeasurementMap()
    for eff in CATALOG:
        if eff.name in chosen:
            rig = eff.apply(rig, chosen[eff.name])
            meas = eff.measurement(meas, chosen[eff.name])
    return rig, meas


def identifiable(effect: Effect, channels: set[str] | frozenset[str]) -> str | None:
    """None if the effect can be identified from these recorded channels, else the reason."""
    missing = [c for c in effect.needs_channels if c not in channels]
    if missing:
        return (f"needs {', '.join(missing)}, not recorded (has {', '.join(sorted(channels)) or 'nothing'}); "
                "with the angle alone its signature is absorbed by the thrust gain")
    return None


def check_recordings(recordings: Any, what: str = "recordings",
                     min_samples: int = MIN_RECORDING_SAMPLES) -> frozenset[str]:
    """Validate recordings for the gap diagnosis; return the channels every one of them has.

    Parameters
    ----------
    recordings : sequence of Recording
    what : str
        Name used in messages (``"fit recordings"``, ``"held-out recordings"``).
    min_samples : int
        Fewest samples per recording.

    Raises
    ------
    GapError
        Empty sequence; an item that is not a Recording; no ``theta`` channel; NaN/inf in θ, the
        duty cycle or another channel; duty outside [0, 1]; too few samples; a constant duty cycle.
    """
    recs = list(recordings) if recordings is not None else []
    if not recs:
        raise GapError(f"no {what} given; expected at least one Recording with theta and duty")
    common: set[str] | None = None
    for k, r in enumerate(recs):
        if not isinstance(r, Recording):
            raise GapError(f"{what}[{k}] is a {type(r).__name__}; expected aeropend_sim.recording.Recording")
        src = r.source or f"{what}[{k}]"
        if "theta" not in r.channels:
            raise GapError(f"{src}: no 'theta' channel (has {sorted(r.channels)}); the gap diagnosis "
                           "compares recorded and simulated angles")
        if len(r) < min_samples:
            raise GapError(f"{src}: only {len(r)} samples; the gap diagnosis needs at least {min_samples}")
        for name, y in [("duty", r.duty), *r.channels.items()]:
            bad = ~np.isfinite(y)
            if bad.any():
                raise GapError(f"{src}: {name} has {int(bad.sum())} NaN/inf value(s), first at sample "
                               f"{int(np.flatnonzero(bad)[0])}; repair or cut the recording")
        if (r.duty < 0.0).any() or (r.duty > 1.0).any():
            k_bad = int(np.flatnonzero((r.duty < 0.0) | (r.duty > 1.0))[0])
            raise GapError(f"{src}: duty[{k_bad}] = {r.duty[k_bad]!r} outside [0, 1] (a fraction)")
        if np.ptp(r.duty) == 0.0:
            raise GapError(f"{src}: constant duty cycle {r.duty[0]:g}: the input is unexcited")
        dt = np.diff(r.t)
        if np.ptp(dt) > 1e-3 * np.median(dt):
            raise GapError(f"{src}: non-uniform sampling (dt from {dt.min():.4g} to {dt.max():.4g} s); "
                           "resample first (aeropend_ident.greybox.uniform_data)")
        ch = set(r.channels) & {"theta", "i_a", "v_a", "omega_rotor"}
        common = ch if common is None else common & ch
    return frozenset(common or set())


def nominal_model_check(rig: Rig) -> None:
    """Raise :class:`GapError` if the nominal rig cannot be simulated (e.g. no motor steady state)."""
    try:
        PlantModel(rig).equilibrium(0.1)
    except Exception as exc:
        raise GapError(f"nominal rig {rig.name!r} is not usable: {exc}") from exc
