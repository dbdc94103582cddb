"""Catalog of candidate unmodelled effects for the sim-to-real gap diagnosis ("which").

Each :class:`Effect` is a small group of **physical parameters** that, added to a nominal rig,
changes the simulated response in one characteristic way. The catalog covers what labs get
wrong (drive, motor, aerodynamics, pendulum, sensor):

=====================  ===========  ==========================================================
effect                 subsystem    fitted parameter(s), SI
=====================  ===========  ==========================================================
dead_zone              actuator     duty-cycle dead zone τ_dz [1]
hbridge_drop           electrical   voltage lost across the bridge switches V_d [V]
actuator_lag           actuator     first-order lag T_a [s]
input_delay            actuator     transport delay T_d [s]
back_emf               motor        back-EMF constant K_ω [V·s/rad]
armature_resistance    electrical   R_a [Ω]
armature_inductance    electrical   L_a [H]
torque_constant        motor        K_t [N·m/A]
rotor_friction         motor        rotor viscous friction B_m [N·m·s/rad]
motor_time_constant    motor        rotor-side inertia J_m [kg·m²]
propeller_drag         aerodynamic  drag torque coefficient K_d [N·m·s²] (J_m·ω̇₁ −= K_d·ω₁|ω₁|)
thrust_coefficient     aerodynamic  K_q [N·s²] of f = K_q·ω₂² (thesis Eq. 3.3/4.4)
thrust_law             aerodynamic  K_q [N·s^α] and exponent α of f = K_q·|ω₂|^α (level and shape)
viscous_friction       pendulum     c/J [1/s]
coulomb_friction       pendulum     T_f/J [rad/s²]
gravity                pendulum     mgd/J [1/s²]
inertia                pendulum     J/J_nominal [1] (every /J term divided by it)
end_stops              pendulum     upper stop angle θ_max [rad]
sensor_offset          sensor       θ_model − θ_recorded [rad]
sensor_scale           sensor       sensor gain s [1]
quantisation           sensor       angle LSB q [rad] (detected from the data)
=====================  ===========  ==========================================================

Every parameter is fitted in its physical unit, and its **search range is derived from the rig
and the recorded signals** (:class:`EffectContext`), not from the nominal value alone, so an
effect the nominal rig omits (K_d = 0, no dead zone, no delay, B_m = 0) is found at any
plausible size: e.g. the propeller drag spans 1e-3 to 3 times the drag that would halve the
steady rotor speed at the largest recorded duty cycle (:meth:`EffectContext.halving_drag`).
Strictly positive parameters are searched on a log scale.

Every entry also says

* how to switch it on in a :class:`aeropend_sim.params.Rig` (:meth:`Effect.apply`);
* its discrepancy-SINDy term group (``terms``): the state equations whose right-hand side it
  changes, used to screen it (:mod:`aeropend_ident.gap.which`) and to check that the where- and
  which-analyses agree;
* the channels needed to identify it (``needs_channels``): with the angle alone, a motor
  constant error hides inside the thrust gain;
* the effects it is physically confusable with (``confusable_with``); the diagnosis reports a
  confusable pair only when the data do not separate it (``ambiguous_with`` in its ranking).

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

from aeropend_ident.errors import GapError
from aeropend_sim.model import ROTOR_FRICTION_VELOCITY, PlantModel
from aeropend_sim.params import Rig, RigFileError
from aeropend_sim.recording import Recording

#: Fewest samples a recording must have for the gap diagnosis.
MIN_RECORDING_SAMPLES = 200
#: Contact stiffness of an end stop added to a rig without one, in units of mgd/J [1/rad]
#: (penetration 5 mrad under the full gravity torque).
STOP_STIFFNESS_FACTOR = 200.0


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
class EffectContext:
    """Physical scales of a rig and its recordings that set the effects' search ranges.

    Attributes
    ----------
    rig : Rig
        Nominal rig.
    duty_max : float
        Largest recorded duty cycle [1] (0.99 quantile).
    v_max : float
        Nominal armature voltage at ``duty_max`` [V].
    omega_max : float
        Nominal steady rotor speed at ``duty_max`` [rad/s].
    omega_ref : float
        Nominal steady propeller speed ω₂ at the median recorded duty cycle [rad/s] (reference of
        the thrust law's level).
    theta_hi : float
        0.995 quantile of the recorded angle in the model frame [rad] (end-stop probe).
    """

    rig: Rig
    duty_max: float
    v_max: float
    omega_max: float
    omega_ref: float
    theta_hi: float

    @classmethod
    def from_data(cls, rig: Rig, theta: np.ndarray, duty: np.ndarray) -> EffectContext:
        """Context of a nominal rig and recorded angles [rad, model frame] and duty cycles.

        Raises
        ------
        GapError
            If the nominal rig has no motor steady state (see :func:`nominal_model_check`).
        """
        from aeropend_ident.errors import IdentificationError
        from aeropend_ident.greybox.fit import motor_equilibrium

        duty = np.asarray(duty, dtype=float)
        d_max = float(np.clip(np.quantile(duty, 0.99), 0.05, 1.0))
        d_med = float(np.clip(np.median(duty[duty > 0]) if np.any(duty > 0) else d_max, 0.05, 1.0))
        model = PlantModel(rig)
        try:
            _, w_max, _ = motor_equilibrium(rig, d_max)
            _, w_med, _ = motor_equilibrium(rig, d_med)
        except IdentificationError as exc:
            raise GapError(f"nominal rig {rig.name!r} is not usable: {exc}") from exc
        th = np.asarray(theta, dtype=float)
        return cls(rig=rig, duty_max=d_max, v_max=float(model.armature_voltage(d_max)),
                   omega_max=float(abs(w_max)), omega_ref=max(abs(w_med / rig.motor.gear_ratio), 1e-9),
                   theta_hi=float(np.quantile(th, 0.995)) if th.size else 0.5)

    def _motor(self) -> PlantModel:
        return PlantModel(self.rig)

    def rotor_torque(self, omega: float) -> float:
        """Nominal net driving torque K_t·i_a − B_m·ω₁ − T_c·sgn ω₁ [N·m] at ``v_max`` and speed ω₁."""
        m = self._motor()
        i = (self.v_max - m.K_w * omega) / m.R
        return m.K_t * i - m.B_m * omega - m.T_cm * math.tanh(omega / ROTOR_FRICTION_VELOCITY)

    def halving_drag(self) -> float:
        """Propeller drag K_d [N·m·s²] that would halve the steady rotor speed at ``v_max``.

        From the rotor torque balance at ω₁ = ω_max/2 (thesis Eq. 3.8 with the drag term):
        K_d = (K_t·i_a − B_m·ω₁ − T_c − K_d,nominal·ω₁²)/ω₁² + K_d,nominal.
        """
        w = 0.5 * max(self.omega_max, 1e-9)
        return max(self.rotor_torque(w) / w**2, 1e-30)

    def halving_friction(self) -> float:
        """Rotor viscous friction B_m [N·m·s/rad] that would halve the steady rotor speed at ``v_max``."""
        w = 0.5 * max(self.omega_max, 1e-9)
        m = self._motor()
        return max((self.rotor_torque(w) - m.K_d * w * w) / w + m.B_m, 1e-30)


@dataclass(frozen=True)
class ParamRange:
    """Search range of one effect parameter for one rig and data set (physical units).

    ``off`` is the value at which the effect is absent (the nominal rig's value); ``probe`` a
    typical magnitude (screening columns are the model change from ``off`` to ``probe``);
    ``log``: searched as log(value).
    """

    lower: float
    upper: float
    off: float
    probe: float
    log: bool

    def clip(self, v: float) -> float:
        """``v`` moved inside [lower, upper]."""
        return min(max(float(v), self.lower), self.upper)


@dataclass(frozen=True)
class EffectParameter:
    """One fitted parameter of an effect.

    Attributes
    ----------
    name : str
        Parameter name within the effect, the physical symbol (e.g. ``"K_d"``, ``"dead_zone"``).
    unit : str
        SI unit.
    limits : (float, float)
        Physically valid values (a value outside raises :class:`GapError`).
    rig_field : str
        Where the value ends up: ``"section.field"`` of the rig, or ``"measurement.<attr>"``.
    doc : str
        Meaning.
    search : callable
        ``EffectContext -> (lower, upper, off, probe)``: the search range for this rig and data.
    log : bool
        Searched as log(value) (strictly positive parameters).
    """

    name: str
    unit: str
    limits: tuple[float, float]
    rig_field: str
    doc: str
    search: Callable[[EffectContext], tuple[float, float, float, float]] = field(repr=False, compare=False)
    log: bool = False

    def bind(self, ctx: EffectContext) -> ParamRange:
        """The numeric search range for a context (clipped to the physical limits)."""
        lo, hi, off, probe = (float(x) for x in self.search(ctx))
        lo = max(lo, self.limits[0])
        hi = min(hi, self.limits[1])
        if self.log:
            lo = max(lo, 1e-300)
        if not lo < hi:
            hi = lo * 10.0 if self.log else lo + 1.0
        return ParamRange(lower=lo, upper=hi, off=off, probe=min(max(probe, lo), hi), log=self.log)


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
        ``"model"`` (changes the plant), ``"measurement"`` (θ transform), ``"direct"``
        (detected from the data itself, e.g. quantisation) or ``"drift"`` (a rig quantity that
        changes between sessions rather than missing physics: fitted by the session-drift
        analysis only, never chosen by the diagnosis; :data:`DRIFT_ONLY`).
    screened : bool
        Part of the discrepancy-SINDy screening (default). False: always confirmed by a grey-box
        fit instead (the motor time constant, whose θ̈ column is nearly collinear with the damping
        term and would crowd it out of the group selection).
    exclusive_with : tuple of str
        Effects that set the same rig parameter; never chosen together with this one.
    nests : tuple of str
        Simpler effects this one contains as a special case (the thrust law with α = 2 is a
        thrust-coefficient error); it is preferred to them only when it removes clearly more.
    refines : tuple of str
        An operating-point refinement of these effects (Stribeck friction of Coulomb friction):
        never screened or confirmed on its own, only tried as a richer replacement once one of
        them is chosen, and kept only when it removes clearly more (as ``nests``).
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
    screened: bool = True
    exclusive_with: tuple[str, ...] = ()
    nests: tuple[str, ...] = ()
    refines: tuple[str, ...] = ()

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the fitted parameters, in order."""
        return tuple(p.name for p in self.parameters)

    def ranges(self, ctx: EffectContext) -> dict[str, ParamRange]:
        """Search ranges of the parameters for a rig and data set."""
        return {p.name: p.bind(ctx) for p in self.parameters}

    def probe_values(self, ctx: EffectContext) -> dict[str, float]:
        """Typical magnitudes (screening columns, fit starts) for a rig and data set."""
        return {k: r.probe for k, r in self.ranges(ctx).items()}

    def values(self, values: Mapping[str, float] | None = None,
               ctx: EffectContext | None = None) -> dict[str, float]:
        """Complete parameter values: ``values`` filled up with the probe values of ``ctx``.

        Raises
        ------
        GapError
            On an unknown parameter name, a missing value without a context, or a value outside
            the physical limits.
        """
        given = dict(values or {})
        unknown = [k for k in given if k not in self.parameter_names]
        if unknown:
            raise GapError(f"effect {self.name!r} has no parameter {unknown[0]!r}; expected some of "
                           f"{list(self.parameter_names)}")
        out: dict[str, float] = {}
        for p in self.parameters:
            if p.name in given:
                out[p.name] = float(given[p.name])
            elif ctx is not None:
                out[p.name] = p.bind(ctx).probe
            else:
                raise GapError(f"effect {self.name!r}: no value for {p.name} [{p.unit}] and no context "
                               "to take its probe value from")
        for p in self.parameters:
            v = out[p.name]
            lo, hi = p.limits
            if not math.isfinite(v) or not (lo <= v <= hi):
                raise GapError(f"effect {self.name!r}: {p.name} = {v!r} {p.unit} outside [{lo:g}, {hi:g}]")
        return out

    def apply(self, rig: Rig, values: Mapping[str, float]) -> Rig:
        """The rig with this effect switched on at the given physical values.

        Measurement transforms and directly detected effects return the rig unchanged (see
        :meth:`measurement`, :func:`apply_effects`).

        Raises
        ------
        GapError
            On unknown or missing parameters, values outside the physical limits, or values the
            rig format rejects.
        """
        vals = self.values(values)
        if self._apply is None:
            return rig
        try:
            return self._apply(rig, vals)
        except RigFileError as exc:
            raise GapError(f"effect {self.name!r} with {vals}: rejected by the rig format: {exc}") from exc

    def measurement(self, current: MeasurementMap, values: Mapping[str, float]) -> MeasurementMap:
        """The measurement map with this effect's θ transform composed in (model effects: unchanged)."""
        if self.kind != "measurement":
            return current
        vals = self.values(values)
        return dataclasses.replace(current, **{p.rig_field.split(".", 1)[1]: vals[p.name]
                                               for p in self.parameters})

    def rig_values(self, rig: Rig, values: Mapping[str, float]) -> dict[str, float]:
        """Physical values the effect writes: every rig field it changes (``"section.field"``),
        the measurement-map entries (``"measurement.*"``) and the fitted parameters themselves
        (``"<effect>.<parameter>"``, e.g. ``"hbridge_drop.V_drop"``: a voltage drop on an ideal
        drive is stored as a lower supply plus a dead zone)."""
        vals = self.values(values)
        out: dict[str, float] = {f"{self.name}.{k}": v for k, v in vals.items()}
        if self.kind == "measurement":
            out.update({p.rig_field: vals[p.name] for p in self.parameters})
            return out
        new = self.apply(rig, vals)
        for section in ("actuator", "motor", "thrust", "pendulum", "sensors"):
            a, b = getattr(rig, section), getattr(new, section)
            for f in dataclasses.fields(a):
                va, vb = getattr(a, f.name), getattr(b, f.name)
                if va != vb:
                    out[f"{section}.{f.name}"] = float(vb)
        for p in self.parameters:  # the parameter's own field, changed or not
            section, _, name = p.rig_field.partition(".")
            if section != "measurement" and p.rig_field not in out and p.rig_field != "actuator.hbridge_k0":
                out[p.rig_field] = float(getattr(getattr(new, section), name))
        return out


# ------------------------------------------------------------------------------ search ranges
def _scale_range(lo: float, hi: float, probe: float) -> Callable[[float], tuple[float, float, float, float]]:
    """Range of a nominal value v scaled by [lo, hi], probe v·probe, absent at v."""
    return lambda v: (v * lo, v * hi, v, v * probe)


def _nominal_or(value: float, switch_on: bool, fallback: float) -> float:
    return value if (switch_on and value > 0.0) else fallback


def _r_dead_zone(c: EffectContext) -> tuple[float, float, float, float]:
    off = c.rig.actuator.dead_zone if c.rig.effects.dead_zone else 0.0
    return 0.0, min(0.6, 0.9 * c.duty_max), off, off + 0.05


def _r_drop(c: EffectContext) -> tuple[float, float, float, float]:
    v = max(c.v_max, 1e-6)
    return -0.2 * v, 0.6 * v, 0.0, 0.06 * v


def _r_lag(c: EffectContext) -> tuple[float, float, float, float]:
    off = c.rig.actuator.lag_time_constant if c.rig.effects.actuator_lag else 0.0
    return 1e-3, 1.0, off, max(off * 1.5, 0.05)


def _r_delay(c: EffectContext) -> tuple[float, float, float, float]:
    off = c.rig.actuator.input_delay if c.rig.effects.input_delay else 0.0
    return 0.0, off + 0.3, off, off + 0.03


def _r_back_emf(c: EffectContext) -> tuple[float, float, float, float]:
    m, on = c.rig.motor, c.rig.effects.back_emf
    base = _nominal_or(m.K_omega, on, m.K_t)
    off = m.K_omega if on else 0.0
    return 0.1 * base, 10.0 * base, off, (1.3 if on else 0.5) * base


def _r_halving(nominal: float, on: bool, halving: float, probe: float) -> tuple[float, float, float, float]:
    """Range of a rotor load coefficient: up to 3× the value that halves the steady rotor speed
    (``halving``), and 0.05–20× a nominal value the rig has; probe ``probe``·halving if it has none."""
    if on and nominal > 0.0:
        return min(0.05 * nominal, 1e-3 * halving), max(20.0 * nominal, 3.0 * halving), nominal, 1.3 * nominal
    return 1e-3 * halving, 3.0 * halving, 0.0, probe * halving


def _r_rotor_friction(c: EffectContext) -> tuple[float, float, float, float]:
    return _r_halving(c.rig.motor.B_m, c.rig.effects.rotor_viscous_friction, c.halving_friction(), 0.2)


def _r_drag(c: EffectContext) -> tuple[float, float, float, float]:
    return _r_halving(c.rig.motor.K_d, c.rig.effects.propeller_drag, c.halving_drag(), 0.1)


def _r_viscous(c: EffectContext) -> tuple[float, float, float, float]:
    p, on = c.rig.pendulum, c.rig.effects.rod_viscous_friction
    crit = 2.0 * math.sqrt(max(p.mgd_over_J, 1e-9))
    if on and p.c_over_J > 0.0:
        c = p.c_over_J
        return min(0.05 * c, 1e-3 * crit), max(20.0 * c, 2.0 * crit), c, 1.5 * c
    return 1e-3 * crit, 2.0 * crit, 0.0, 0.1 * crit


def _r_coulomb(c: EffectContext) -> tuple[float, float, float, float]:
    p = c.rig.pendulum
    off = p.coulomb_over_J if c.rig.effects.rod_coulomb_friction else 0.0
    return 0.0, off + 0.5 * p.mgd_over_J, off, off + 0.01 * p.mgd_over_J


def _r_stribeck(c: EffectContext) -> tuple[float, float, float, float]:
    p = c.rig.pendulum
    off = p.stribeck_over_J if c.rig.effects.rod_coulomb_friction else 0.0
    return 0.0, off + 0.5 * p.mgd_over_J, off, off + 0.01 * p.mgd_over_J


def _r_stribeck_velocity(c: EffectContext) -> tuple[float, float, float, float]:
    # above 3× the width of the model's smooth sign tanh(θ̇/v_ε): a narrower "Stribeck" bump would
    # only reshape the regularisation (it then stands in for a sharper sign, not for stiction)
    lo = 3.0 * c.rig.pendulum.friction_velocity
    return lo, max(2.0, 10.0 * lo), max(2.0, 10.0 * lo), max(0.1, 3.0 * lo)


def _r_thrust_law_k(c: EffectContext) -> tuple[float, float, float, float]:
    """K_q of f = K_q·|ω₂|^α over every exponent in [1, 3.5], start: thrust kept at ω_ref for α = 2.2."""
    k, a0 = c.rig.thrust.K_q, (c.rig.thrust.exponent if c.rig.effects.thrust_exponent else 2.0)
    w = max(c.omega_ref, 1e-9)
    span = [k * w ** (a0 - a) for a in (1.0, 3.5)]
    return 0.2 * min(span), 5.0 * max(span), k, k * w ** (a0 - 2.2)


def _r_end_stop(c: EffectContext) -> tuple[float, float, float, float]:
    p = c.rig.pendulum
    off = p.theta_max if c.rig.effects.end_stops else math.pi / 2
    return 0.05, math.pi / 2, off, min(c.theta_hi - 0.02, off)


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


def _lag(rig: Rig, v: Mapping[str, float]) -> Rig:
    new = rig.with_params("actuator", lag_time_constant=v["lag_time_constant"])
    return new.with_effects(actuator_lag=True)


def _delay(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("actuator", input_delay=v["input_delay"]).with_effects(input_delay=True)


def _back_emf(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("motor", K_omega=v["K_omega"]).with_effects(back_emf=True)


def _resistance(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("motor", R_a=v["R_a"])


def _inductance(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("motor", L_a=v["L_a"]).with_effects(armature_inductance="dynamic")


def _torque_constant(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("motor", K_t=v["K_t"])


def _rotor_friction(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("motor", B_m=v["B_m"]).with_effects(rotor_viscous_friction=True)


def _motor_time_constant(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("motor", J_m=v["J_m"])


def _drag(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("motor", K_d=v["K_d"]).with_effects(propeller_drag=True)


def _thrust_coefficient(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("thrust", K_q=v["K_q"])


def _thrust_law(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("thrust", K_q=v["K_q"], exponent=v["exponent"]).with_effects(thrust_exponent=True)


def _viscous(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("pendulum", c_over_J=v["c_over_J"]).with_effects(rod_viscous_friction=True)


def _coulomb(rig: Rig, v: Mapping[str, float]) -> Rig:
    new = rig.with_params("pendulum", coulomb_over_J=v["coulomb_over_J"])
    return new.with_effects(rod_coulomb_friction=True)


def _supply(rig: Rig, v: Mapping[str, float]) -> Rig:
    """Supply voltage V_s: the ideal map's v_supply; the Eq. 4.3 map's output k0 + k1·√(…)
    scales with V_s / v_supply (the bridge passes a fixed share of its supply)."""
    a = rig.actuator
    new = rig.with_params("actuator", v_supply=v["v_supply"])
    if rig.effects.hbridge_map:
        f = v["v_supply"] / a.v_supply
        new = new.with_params("actuator", hbridge_k0=a.hbridge_k0 * f, hbridge_k1=a.hbridge_k1 * f)
    return new


def _stribeck(rig: Rig, v: Mapping[str, float]) -> Rig:
    new = _coulomb(rig, {"coulomb_over_J": v["coulomb_over_J"]})
    return new.with_params("pendulum", stribeck_over_J=v["stribeck_over_J"],
                           stribeck_velocity=v["stribeck_velocity"])


def _gravity(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("pendulum", mgd_over_J=v["mgd_over_J"])


def _inertia(rig: Rig, v: Mapping[str, float]) -> Rig:
    s = v["J_scale"]
    p = rig.pendulum
    return rig.with_params("pendulum", mgd_over_J=p.mgd_over_J / s, c_over_J=p.c_over_J / s,
                           L_over_J=p.L_over_J / s, coulomb_over_J=p.coulomb_over_J / s)


def _end_stops(rig: Rig, v: Mapping[str, float]) -> Rig:
    new = rig.with_params("pendulum", theta_max=v["theta_max"]).with_effects(end_stops=True)
    p = rig.pendulum
    if p.stop_stiffness <= 0.0:
        # the nominal rig has no contact model: a stiff, critically damped contact whose penetration
        # under the largest gravity torque is about 1/STOP_STIFFNESS_FACTOR rad
        k = STOP_STIFFNESS_FACTOR * p.mgd_over_J
        new = new.with_params("pendulum", stop_stiffness=k, stop_damping=2.0 * math.sqrt(k))
    return new


def _quantisation(rig: Rig, v: Mapping[str, float]) -> Rig:
    return rig.with_params("sensors", theta_quantum=v["theta_quantum"]).with_effects(quantisation=True)


def _par(name: str, unit: str, limits: tuple[float, float], rig_field: str, doc: str,
         search: Callable[[EffectContext], tuple[float, float, float, float]],
         log: bool = False) -> EffectParameter:
    return EffectParameter(name, unit, limits, rig_field, doc, search, log)


_POS = (1e-300, math.inf)
_TH = "theta_dot"
_GAIN = ("gravity", "thrust_coefficient", "sensor_scale", "inertia")
_MOTOR = ("back_emf", "armature_resistance", "torque_constant", "rotor_friction", "propeller_drag")
_TIMING = ("actuator_lag", "input_delay", "motor_time_constant")
CATALOG: tuple[Effect, ...] = (
    Effect(
        "dead_zone", "actuator",
        "duty-cycle dead zone τ_dz: τ_e = max(0, τ − τ_dz)/(1 − τ_dz)",
        ("theta",),
        (_par("dead_zone", "1", (0.0, 0.95), "actuator.dead_zone", "dead-zone width τ_dz", _r_dead_zone),),
        {_TH: ("L/J·Δf(τ_dz)",), "i_a": ("Δv_a(τ_dz)/L_a",), "v_a": ("Δv_a(τ_dz)",)},
        "dead_zone", ("hbridge_drop",), _apply=_dead_zone,
    ),
    Effect(
        "hbridge_drop", "electrical",
        "H-bridge voltage drop V_d: v_a = max(0, k0 − V_d + k1·sqrt(k2·τ + k3)) (Eq. 4.3 map) or "
        "max(0, v_supply·τ − V_d) (ideal map)",
        ("theta",),
        (_par("V_drop", "V", (-math.inf, math.inf), "actuator.hbridge_k0",
              "voltage lost across the bridge switches V_d", _r_drop),),
        {_TH: ("L/J·Δf(V_d)",), "i_a": ("Δv_a(V_d)/L_a",), "v_a": ("Δv_a(V_d)",)},
        "hbridge_map", ("dead_zone",), _apply=_hbridge_drop,
    ),
    Effect(
        "actuator_lag", "actuator",
        "first-order actuator lag T_a: τ̇_f = (τ − τ_f)/T_a",
        ("theta",),
        (_par("lag_time_constant", "s", (0.0, 60.0), "actuator.lag_time_constant", "lag time constant T_a",
              _r_lag, log=True),),
        {_TH: ("L/J·Δf(T_a)",), "i_a": ("Δv_a(T_a)/L_a",), "v_a": ("Δv_a(T_a)",)},
        "actuator_lag", ("input_delay", "motor_time_constant"), _apply=_lag,
    ),
    Effect(
        "input_delay", "actuator",
        "input/transport delay T_d: the actuator sees τ(t − T_d)",
        ("theta",),
        (_par("input_delay", "s", (0.0, 5.0), "actuator.input_delay", "delay T_d", _r_delay),),
        {_TH: ("L/J·Δf(T_d)",), "i_a": ("Δv_a(T_d)/L_a",), "v_a": ("Δv_a(T_d)",)},
        "input_delay", ("actuator_lag", "motor_time_constant"), _apply=_delay,
    ),
    Effect(
        "back_emf", "motor",
        "back-EMF constant K_ω wrong or omitted: L_a·di_a/dt = v_a − R_a·i_a − K_ω·ω₁",
        ("i_a",),
        (_par("K_omega", "V*s/rad", _POS, "motor.K_omega", "back-EMF constant K_ω", _r_back_emf, log=True),),
        {_TH: ("L/J·Δf(K_ω)",), "i_a": ("−ΔK_ω·ω₁/L_a",), "omega_rotor": ("K_t·Δi_a(K_ω)/J_m",)},
        "back_emf", tuple(x for x in _MOTOR if x != "back_emf"), _apply=_back_emf,
    ),
    Effect(
        "armature_resistance", "electrical",
        "armature resistance R_a wrong: L_a·di_a/dt = v_a − R_a·i_a − K_ω·ω₁",
        ("i_a",),
        (_par("R_a", "ohm", _POS, "motor.R_a", "armature resistance R_a",
              lambda c: _scale_range(0.2, 5.0, 1.2)(c.rig.motor.R_a), log=True),),
        {_TH: ("L/J·Δf(R_a)",), "i_a": ("−ΔR_a·i_a/L_a",), "omega_rotor": ("K_t·Δi_a(R_a)/J_m",)},
        "", tuple(x for x in _MOTOR if x != "armature_resistance"), _apply=_resistance,
    ),
    Effect(
        "armature_inductance", "electrical",
        "armature inductance L_a wrong (electrical time constant L_a/R_a)",
        ("i_a",),
        (_par("L_a", "H", _POS, "motor.L_a", "armature inductance L_a",
              lambda c: _scale_range(0.01, 100.0, 3.0)(c.rig.motor.L_a), log=True),),
        {_TH: ("L/J·Δf(L_a)",), "i_a": ("(L_a/L_a' − 1)·di_a/dt",), "omega_rotor": ("K_t·Δi_a(L_a)/J_m",)},
        "armature_inductance", (), _apply=_inductance,
    ),
    Effect(
        "torque_constant", "motor",
        "motor torque constant K_t wrong: J_m·ω̇₁ = K_t·i_a − B_m·ω₁ − …",
        ("i_a", "omega_rotor"),
        (_par("K_t", "N*m/A", _POS, "motor.K_t", "torque constant K_t",
              lambda c: _scale_range(0.2, 5.0, 1.2)(c.rig.motor.K_t), log=True),),
        {_TH: ("L/J·Δf(K_t)",), "omega_rotor": ("ΔK_t·i_a/J_m",)},
        "", tuple(x for x in _MOTOR if x != "torque_constant"), _apply=_torque_constant,
    ),
    Effect(
        "rotor_friction", "motor",
        "rotor viscous friction B_m wrong or omitted: J_m·ω̇₁ = … − B_m·ω₁",
        ("omega_rotor",),
        (_par("B_m", "N*m*s/rad", _POS, "motor.B_m", "rotor viscous friction B_m", _r_rotor_friction,
              log=True),),
        {_TH: ("L/J·Δf(B_m)",), "omega_rotor": ("−ΔB_m·ω₁/J_m",)},
        "rotor_viscous_friction", tuple(x for x in _MOTOR if x != "rotor_friction"), _apply=_rotor_friction,
    ),
    Effect(
        "motor_time_constant", "motor",
        "rotor-side inertia J_m wrong (rotor + gear + propeller): the motor's mechanical time constant "
        "J_m/(B_m + 2·K_d·ω₁ + K_t·K_ω/R_a) scales with it, the thrust follows the duty cycle more "
        "slowly or faster",
        ("theta",),
        (_par("J_m", "kg*m^2", _POS, "motor.J_m", "rotor-side inertia J_m",
              lambda c: _scale_range(0.05, 20.0, 2.0)(c.rig.motor.J_m), log=True),),
        {_TH: ("L/J·Δf(J_m)",), "omega_rotor": ("−ΔJ_m·ω̇₁/J_m",)},
        "", ("actuator_lag", "input_delay"), _apply=_motor_time_constant, screened=False,
    ),
    Effect(
        "propeller_drag", "aerodynamic",
        "propeller drag torque wrong or omitted: J_m·ω̇₁ = … − K_d·ω₁|ω₁|",
        ("omega_rotor",),
        (_par("K_d", "N*m*s^2/rad^2", _POS, "motor.K_d", "drag torque coefficient K_d", _r_drag, log=True),),
        {_TH: ("L/J·Δf(K_d)",), "omega_rotor": ("−ΔK_d·ω₁|ω₁|/J_m",)},
        "propeller_drag", ("thrust_law", *(x for x in _MOTOR if x != "propeller_drag")), _apply=_drag,
    ),
    Effect(
        "thrust_coefficient", "aerodynamic",
        "thrust coefficient K_q wrong (a static load-cell fit, thesis Eq. 4.4): f = K_q·ω₂²",
        ("theta",),
        (_par("K_q", "N*s^2/rad^2", _POS, "thrust.K_q", "thrust coefficient K_q",
              lambda c: _scale_range(0.2, 5.0, 1.2)(c.rig.thrust.K_q), log=True),),
        {_TH: ("ΔK_q·(L/J)·ω₂²",)},
        "", ("thrust_law", *(x for x in _GAIN if x != "thrust_coefficient")), _apply=_thrust_coefficient,
        exclusive_with=("thrust_law",),
    ),
    Effect(
        "thrust_law", "aerodynamic",
        "thrust law f = K_q·|ω₂|^α with its level and exponent both wrong (α ≠ 2)",
        ("theta",),
        (_par("K_q", "N*s^a/rad^a", _POS, "thrust.K_q", "thrust-law coefficient K_q (units N·(s/rad)^α)",
              _r_thrust_law_k, log=True),
         _par("exponent", "1", (0.5, 4.0), "thrust.exponent", "thrust-law exponent α",
              lambda c: (1.0, 3.5, c.rig.thrust.exponent if c.rig.effects.thrust_exponent else 2.0, 2.2))),
        {_TH: ("L/J·Δf(K_q, α)",)},
        "thrust_exponent", ("thrust_coefficient", "propeller_drag", "gravity"), _apply=_thrust_law,
        exclusive_with=("thrust_coefficient",), nests=("thrust_coefficient",),
    ),
    Effect(
        "viscous_friction", "pendulum",
        "viscous friction of the rod wrong or omitted: θ̈ = … − (c/J)·θ̇",
        ("theta",),
        (_par("c_over_J", "1/s", _POS, "pendulum.c_over_J", "viscous friction over inertia c/J", _r_viscous,
              log=True),),
        {_TH: ("−θ̇",)},
        "rod_viscous_friction", ("coulomb_friction",), _apply=_viscous,
    ),
    Effect(
        "coulomb_friction", "pendulum",
        "Coulomb friction on the rod: θ̈ −= (T_f/J)·sgn(θ̇) (tanh-regularised)",
        ("theta",),
        (_par("coulomb_over_J", "rad/s^2", (0.0, math.inf), "pendulum.coulomb_over_J",
              "friction torque over inertia T_f/J", _r_coulomb),),
        {_TH: ("−tanh(θ̇/v_ε)",)},
        "rod_coulomb_friction", ("viscous_friction",), _apply=_coulomb, exclusive_with=("stribeck_friction",),
    ),
    Effect(
        "stribeck_friction", "pendulum",
        "dry friction of the rod with a Stribeck part: θ̈ −= (T_f/J + ((T_s − T_f)/J)·exp(−(θ̇/v_s)²))·"
        "sgn(θ̇): the friction at rest (stiction) exceeds the sliding friction and falls off over the "
        "Stribeck velocity v_s, so the damping depends on the swing's amplitude",
        ("theta",),
        (_par("coulomb_over_J", "rad/s^2", (0.0, math.inf), "pendulum.coulomb_over_J",
              "sliding (Coulomb) friction torque over inertia T_f/J", _r_coulomb),
         _par("stribeck_over_J", "rad/s^2", (0.0, math.inf), "pendulum.stribeck_over_J",
              "excess of the static over the sliding friction (T_s − T_f)/J", _r_stribeck),
         _par("stribeck_velocity", "rad/s", (1e-4, 100.0), "pendulum.stribeck_velocity",
              "Stribeck velocity v_s", _r_stribeck_velocity, log=True)),
        {_TH: ("−tanh(θ̇/v_ε)", "−exp(−(θ̇/v_s)²)·tanh(θ̇/v_ε)")},
        "rod_coulomb_friction", ("coulomb_friction", "viscous_friction"), _apply=_stribeck, screened=False,
        exclusive_with=("coulomb_friction",), nests=("coulomb_friction",), refines=("coulomb_friction",),
    ),
    Effect(
        "gravity", "pendulum",
        "gravity torque (mass · lever) wrong: θ̈ = −(mgd/J)·sin θ + …",
        ("theta",),
        (_par("mgd_over_J", "1/s^2", _POS, "pendulum.mgd_over_J", "gravity torque over inertia mgd/J",
              lambda c: _scale_range(0.2, 5.0, 1.2)(c.rig.pendulum.mgd_over_J), log=True),),
        {_TH: ("−sin θ",)},
        "", tuple(x for x in _GAIN if x != "gravity"), _apply=_gravity,
    ),
    Effect(
        "inertia", "pendulum",
        "rod inertia J wrong: every /J term (mgd/J, c/J, L/J, T_f/J) divided by J/J_nominal",
        ("theta",),
        (_par("J_scale", "1", _POS, "pendulum.L_over_J", "J true / J nominal",
              lambda c: (0.2, 5.0, 1.0, 1.2), log=True),),
        {_TH: ("θ̈_model",)},
        "", tuple(x for x in _GAIN if x != "inertia"), _apply=_inertia,
    ),
    Effect(
        "end_stops", "pendulum",
        "mechanical end stop at θ_max: one-sided spring-damper contact beyond it",
        ("theta",),
        (_par("theta_max", "rad", (0.0, math.pi), "pendulum.theta_max", "upper stop angle", _r_end_stop),),
        {_TH: ("contact(θ − θ_max)",)},
        "end_stops", (), _apply=_end_stops,
    ),
    Effect(
        "sensor_offset", "sensor",
        "angle-sensor offset: θ_recorded = θ − θ_offset",
        ("theta",),
        (_par("theta_offset", "rad", (-math.pi, math.pi), "measurement.theta_offset", "θ_model − θ_recorded",
              lambda c: (-0.6, 0.6, 0.0, 0.05)),),
        {_TH: ("−(mgd/J)·cos θ",)},
        "", (), kind="measurement",
    ),
    Effect(
        "sensor_scale", "sensor",
        "angle-sensor gain error: θ_recorded = s·θ",
        ("theta",),
        (_par("theta_scale", "1", _POS, "measurement.theta_scale", "sensor gain s",
              lambda c: (0.5, 2.0, 1.0, 1.1), log=True),),
        {_TH: ("s·θ̈_model(θ/s)",)},
        "", tuple(x for x in _GAIN if x != "sensor_scale"), kind="measurement",
    ),
    Effect(
        "quantisation", "sensor",
        "angle quantisation: θ_recorded = q·round(θ/q) (ADC/encoder LSB q)",
        ("theta",),
        (_par("theta_quantum", "rad", (0.0, 1.0), "sensors.theta_quantum", "angle LSB q",
              lambda c: (0.0, 0.2, 0.0, 0.006)),),
        {},
        "quantisation", (), kind="direct", _apply=_quantisation,
    ),
)

#: Rig quantities that drift between sessions without being missing physics (kind ``"drift"``):
#: fitted by :mod:`aeropend_ident.gap.drift` only, never candidates of the diagnosis.
DRIFT_ONLY: tuple[Effect, ...] = (
    Effect(
        "supply_voltage", "electrical",
        "supply voltage V_s of the H-bridge changed (battery charge, another supply): the whole drive "
        "map scales, v_a = (V_s/V_s,nominal)·v_a,nominal(τ). With the angle alone it acts as a "
        "thrust-gain change (thrust ∝ ω₁² ∝ v_a²); the recorded v_a separates the two",
        ("v_a",),
        (_par("v_supply", "V", _POS, "actuator.v_supply", "supply voltage V_s",
              lambda c: _scale_range(0.5, 2.0, 1.1)(c.rig.actuator.v_supply), log=True),),
        {"v_a": ("ΔV_s·τ",)},
        "", ("thrust_coefficient", "hbridge_drop"), kind="drift", _apply=_supply,
    ),
)

#: Catalog and drift-only entries keyed by effect name.
EFFECTS: dict[str, Effect] = {e.name: e for e in (*CATALOG, *DRIFT_ONLY)}


def get_effect(name: str) -> Effect:
    """Catalog (or drift-only) entry by name.

    Raises
    ------
    GapError
        If ``name`` is in neither :data:`CATALOG` nor :data:`DRIFT_ONLY` (the message lists the
        known names).
    """
    try:
        return EFFECTS[name]
    except KeyError:
        raise GapError(f"unknown effect {name!r}; the catalog has {list(EFFECTS)}") from None


# ------------------------------------------------------------------------------ detected, not fitted
def detect_quantum(y: np.ndarray) -> float:
    """LSB q of a recorded channel if its values lie on a lattice k·q (+ constant), else 0.

    The ``"direct"`` effect of the catalog (``quantisation``): a property of the recording, read
    from it, never fitted. The lattice step is the smallest gap between distinct values; the
    channel counts as quantised when every value sits within 1e-3·q of the lattice and there are
    fewer distinct values than a third of the samples.

    Parameters
    ----------
    y : ndarray, shape (n,)
        Recorded channel (e.g. θ [rad]).

    Returns
    -------
    float
        q in the channel's unit; 0.0 when the values are not on a lattice (or too few).
    """
    y = np.asarray(y, dtype=float)
    u = np.unique(np.round(y, 12))
    if u.size < 3 or u.size > y.size / 3:
        return 0.0
    gaps = np.diff(u)
    q = float(np.min(gaps[gaps > 1e-12])) if np.any(gaps > 1e-12) else 0.0
    if q <= 0.0:
        return 0.0
    frac = (y - u[0]) / q
    if np.max(np.abs(frac - np.round(frac))) > 1e-3:
        return 0.0
    return q


def measurement_noise(y: np.ndarray) -> float:
    """Standard deviation of the measurement noise of a recorded channel [its unit].

    The robust white-noise estimate (:func:`aeropend_ident.greybox.fit.noise_level`), at least
    the rounding noise q/√12 of a detected quantum (:func:`detect_quantum`): a quantised channel
    that rarely changes reads 0 in the first, while its resolution q still bounds what any model
    can match. The one noise floor of the gap diagnosis (where-analysis, effect ranking,
    attainable shrink).

    Parameters
    ----------
    y : ndarray, shape (n,)

    Returns
    -------
    float
        σ ≥ 0.
    """
    from aeropend_ident.greybox.fit import noise_level

    return max(noise_level(y), detect_quantum(y) / math.sqrt(12.0))


def apply_effects(rig: Rig, chosen: Mapping[str, Mapping[str, float]],
                  measurement: MeasurementMap | None = None,
                  ctx: EffectContext | None = None) -> tuple[Rig, MeasurementMap]:
    """Rig and measurement map with several effects applied in catalog order (drift-only first).

    Parameters
    ----------
    rig : Rig
        Nominal rig.
    chosen : mapping
        ``{effect name: {parameter: physical value}}``.
    measurement : MeasurementMap, optional
        Starting measurement map (default identity).
    ctx : EffectContext, optional
        Where missing parameter values take their probe values from.

    Returns
    -------
    (Rig, MeasurementMap)

    Raises
    ------
    GapError
        On an unknown effect or parameter, a missing value without ``ctx``, or a value outside the
        physical limits.
    """
    for name in chosen:
        get_effect(name)
    meas = measurement or MeasurementMap()
    for eff in (*DRIFT_ONLY, *CATALOG):  # a supply voltage is the base a bridge drop acts on
        if eff.name in chosen:
            vals = eff.values(chosen[eff.name], ctx)
            rig = eff.apply(rig, vals)
            meas = eff.measurement(meas, vals)
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
                           "resample first (aeropend_ident.greybox.fit.uniform_data)")
        ch = set(r.channels) & {"theta", "i_a", "v_a", "omega_rotor"}
        common = ch if common is None else common & ch
    return frozenset(common or set())


def nominal_model_check(rig: Rig) -> None:
    """Raise :class:`GapError` if the nominal rig cannot be simulated (e.g. no motor steady state)."""
    try:
        PlantModel(rig).equilibrium(0.1)
    except Exception as exc:
        raise GapError(f"nominal rig {rig.name!r} is not usable: {exc}") from exc
