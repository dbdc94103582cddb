"""Catalog of candidate unmodelled effects for the sim-to-real gap diagnosis ("which").

Each :class:`Effect` is a small group of **physical parameters** that, added to a nominal rig,
changes the simulated response in one characteristic way. The catalog is not written here: every
hypothesis is declared once, as plain data, by the component or effect it belongs to
(:class:`aeropend_sim.components.base.Diagnosis` in its module under ``aeropend_sim.components``:
description, parameters and their search ranges, how it is applied to a rig, revealing channels,
confusable hypotheses, discrepancy-SINDy terms), and :func:`catalog` reads them from the registry
for the rig's actuator family: a hypothesis whose part does not belong on that family (a back-EMF
error on an ESC rig) is not a candidate. ``docs/gap.md`` lists them (a table generated from the
registry by ``tools/gen_model_tables.py``).

Every parameter is fitted in its physical unit, and its **search range is derived from the rig
and the recorded signals** (:class:`EffectContext`), not from the nominal value alone, so an
effect the nominal rig omits (K_d = 0, no dead zone, no delay, B_m = 0) is found at any
plausible size: e.g. the propeller drag spans 1e-3 to 3 times the drag that would halve the
steady rotor speed at the largest recorded duty cycle (:meth:`EffectContext.rotor_torque`).
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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np

from aeropend_ident.errors import GapError
from aeropend_ident.greybox.fit import measurement_noise  # noqa: F401  (re-exported: the gap tool's noise floor)
from aeropend_ident.io.csvspec.constant_input import excitation_problem
from aeropend_ident.io.resampling import detect_quantum  # noqa: F401  (re-exported: the gap tool's name for it)
from aeropend_sim.components import registry
from aeropend_sim.components.base import SECTIONS, Diagnosis
from aeropend_sim.components.xp import MATH
from aeropend_sim.model import OMEGA, TAU_F, plant_model
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording

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
class EffectContext:
    """Physical scales of a rig and its recordings that set the effects' search ranges (the ``ctx``
    of :attr:`aeropend_sim.components.base.Search.range`).

    Attributes
    ----------
    rig : Rig
        Nominal rig.
    duty_max : float
        Largest recorded duty cycle [1] (0.99 quantile).
    drive_max : float
        Nominal drive quantity at ``duty_max``: armature voltage v_a [V], or an ESC's rotor-speed
        set-point ω_ss [rad/s].
    omega_max : float
        Nominal steady rotor speed at ``duty_max`` [rad/s].
    omega_ref : float
        Nominal steady propeller speed ω₂ at the median recorded duty cycle [rad/s] (reference of
        the thrust law's level).
    theta_hi : float
        0.995 quantile of the recorded angle in the model frame [rad] (end-stop probe).
    free_settings : frozenset of str
        Effects whose held parameters (:attr:`EffectParameter.held`, e.g. the dry friction's onset
        width v_ε) are fitted; every other effect holds them at the rig's values
        (:func:`aeropend_ident.gap.which.fitting.fit_effects`). The diagnosis frees them where its
        validation data ask for it.
    """

    rig: Rig
    duty_max: float
    drive_max: float
    omega_max: float
    omega_ref: float
    theta_hi: float
    free_settings: frozenset[str] = frozenset()

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
        model = plant_model(rig)
        try:
            _, w_max, _ = motor_equilibrium(rig, d_max)
            _, w_med, _ = motor_equilibrium(rig, d_med)
        except IdentificationError as exc:
            raise GapError(f"nominal rig {rig.name!r} is not usable: {exc}") from exc
        th = np.asarray(theta, dtype=float)
        return cls(rig=rig, duty_max=d_max, drive_max=float(model.drive(d_max)),
                   omega_max=float(abs(w_max)), omega_ref=max(abs(w_med / rig.motor.gear_ratio), 1e-9),
                   theta_hi=float(np.quantile(th, 0.995)) if th.size else 0.5)

    @classmethod
    def from_prepared(cls, rig: Rig, preps: Sequence[Any]) -> EffectContext:
        """:meth:`from_data` over fit recordings as the fits take them
        (:class:`aeropend_ident.gap.which.data.Prepared`: ``y["theta"]`` [rad, model frame] and ``duty``),
        concatenated: the search ranges of every fit of the gap diagnosis.

        Raises
        ------
        GapError
            As :meth:`from_data`.
        """
        return cls.from_data(rig, np.concatenate([p.y["theta"] for p in preps]),
                             np.concatenate([p.duty for p in preps]))

    def rotor_torque(self, omega: float, without: str = "") -> float:
        """Nominal net torque on the rotor [N·m] at speed ω₁ [rad/s] and the drive at ``duty_max``.

        The rig's ``rotor_torque`` terms (motor torque K_t·i_a and the active loads,
        :meth:`aeropend_sim.components.assembly.Assembly.slot_values`) at the steady armature
        current of that drive and speed, leaving out the terms of the effect ``without`` (the torque
        that effect would have to balance).

        Raises
        ------
        GapError
            If the rig's family has no rotor torque balance (an ESC).
        """
        model = plant_model(self.rig.with_effects(armature_inductance="quasi_static"))
        a = model.assembly
        if not a.armature:
            raise GapError(f"rig {self.rig.name!r} ({self.rig.family}) has no rotor torque balance")
        x = model.states.initial()  # an effect's own state at its initial value
        x[OMEGA], x[TAU_F] = float(omega), self.duty_max
        point = a.point(MATH, x.tolist(), self.duty_max)
        skip = {t.label for t in registry.effect(without).terms} if without else set()
        terms = a.slot_values("rotor_torque", MATH, {"i_a": point["i_a"], "omega": float(omega)})
        return sum((v for k, v in terms.items() if k not in skip), 0.0)


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
    """One fitted parameter of an effect (a :class:`aeropend_sim.components.base.Search`).

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
    #: Held at the rig's value unless the diagnosis frees it (:attr:`EffectContext.free_settings`;
    #: the dry friction's onset width v_ε): :attr:`aeropend_sim.components.base.Search.held`.
    held: bool = False

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
    """One catalog entry: a :class:`aeropend_sim.components.base.Diagnosis` of the registry, with
    the operations the diagnosis needs (see the module docstring).

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
    confusable_with : tuple of str
        Effects with a similar signature on the channels named in ``needs_channels`` (of any
        family: a reader keeps the ones in its rig's catalog).
    kind : str
        ``"model"`` (changes the plant), ``"measurement"`` (θ transform), ``"direct"``
        (detected from the data itself, e.g. quantisation) or ``"drift"`` (a rig quantity that
        changes between sessions rather than missing physics: fitted by the session-drift
        analysis only, never chosen by the diagnosis; :func:`drift_only`).
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
    families : tuple of str
        Actuator families whose rigs can have it (its declaring part's).
    timing : bool
        Changes when the thrust follows the command (:func:`timing_effects`).
    power_law : tuple
        ``(level, exponent, exponent₀)``: a level compared between sessions at a reference speed
        (:attr:`aeropend_sim.components.base.Diagnosis.power_law`); empty: none.
    """

    name: str
    subsystem: str
    description: str
    needs_channels: tuple[str, ...]
    parameters: tuple[EffectParameter, ...]
    terms: dict[str, tuple[str, ...]]
    confusable_with: tuple[str, ...] = ()
    kind: str = "model"
    _apply: Callable[[Rig, Mapping[str, float]], Rig] | None = field(default=None, repr=False, compare=False)
    screened: bool = True
    exclusive_with: tuple[str, ...] = ()
    nests: tuple[str, ...] = ()
    refines: tuple[str, ...] = ()
    families: tuple[str, ...] = ()
    timing: bool = False
    power_law: tuple[str, str, float] | tuple[()] = ()

    @classmethod
    def of(cls, d: Diagnosis) -> Effect:
        """The catalog entry of a registry :class:`~aeropend_sim.components.base.Diagnosis`."""
        owner = registry.diagnosis_owner(d.name)
        fams = tuple(f.name for f in registry.families() if owner.applies_to(f) is None)
        params = tuple(EffectParameter(s.name, s.unit, s.limits, s.target, s.doc, s.range, s.log, s.held)
                       for s in d.search)
        return cls(d.name, d.subsystem, d.description, d.reveals, params, dict(d.sindy_terms),
                   d.confusable_with,
                   d.kind, d.apply, d.screened, d.exclusive_with, d.nests, d.refines, fams, d.timing,
                   d.power_law)

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

    def held_values(self, rig: Rig) -> dict[str, float]:
        """This effect's held parameters (:attr:`EffectParameter.held`, e.g. the dry friction's
        onset width v_ε) at the rig's values."""
        return {p.name: float(rig.value(p.rig_field)) for p in self.parameters if p.held}

    def apply(self, rig: Rig, values: Mapping[str, float]) -> Rig:
        """The rig with this effect switched on at the given physical values.

        Measurement transforms return the rig unchanged (see :meth:`measurement`,
        :func:`apply_effects`). A held parameter (:attr:`EffectParameter.held`, e.g. the dry
        friction's onset width v_ε) keeps the rig's value when ``values`` does not give it.

        Raises
        ------
        GapError
            On unknown or missing parameters, values outside the physical limits, values the rig
            format rejects, or a rig of a family this effect does not belong to.
        """
        vals = self.values({**self.held_values(rig), **dict(values)})
        if self._apply is None:
            return rig
        if rig.family not in self.families:
            raise GapError(f"effect {self.name!r} is not a hypothesis for rig {rig.name!r} of the "
                           f"{rig.family} "
                           f"family (it belongs to {' and '.join(self.families)} rigs)")
        try:
            return self._apply(rig, vals)
        except ValueError as exc:
            raise GapError(f"effect {self.name!r} with {vals}: rejected: {exc}") from exc

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
        for section in SECTIONS:
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


#: Every hypothesis of the registry (all families, catalog and drift-only) keyed by name.
EFFECTS: dict[str, Effect] = {d.name: Effect.of(d) for d in registry.diagnoses()}


@cache
def catalog(family: str = registry.DEFAULT_FAMILY) -> tuple[Effect, ...]:
    """The candidate effects of the diagnosis for a rig of actuator family ``family``, in catalog order.

    Read from the registry (:func:`aeropend_sim.components.registry.diagnoses`): the hypotheses of
    every part that belongs on that family, without the drift-only ones (:func:`drift_only`).

    Raises
    ------
    GapError
        On an unknown family.
    """
    return tuple(EFFECTS[d.name] for d in _diagnoses(family) if d.kind != "drift")


@cache
def drift_only(family: str = registry.DEFAULT_FAMILY) -> tuple[Effect, ...]:
    """Rig quantities of ``family`` that drift between sessions without being missing physics (kind
    ``"drift"``): fitted by :mod:`aeropend_ident.gap.drift` only, never candidates of the diagnosis."""
    return tuple(EFFECTS[d.name] for d in _diagnoses(family) if d.kind == "drift")


def timing_effects(family: str = registry.DEFAULT_FAMILY) -> tuple[str, ...]:
    """Names of the catalog effects of ``family`` that change when the thrust follows the command
    (a lag, a delay, a slow rotor): confirmed by a grey-box fit when the where-analysis sees the
    simulated response lead or lag the recorded one."""
    return tuple(e.name for e in catalog(family) if e.timing)


def _diagnoses(family: str) -> tuple[Diagnosis, ...]:
    try:
        return registry.diagnoses(family)
    except registry.RegistryError as exc:
        raise GapError(str(exc)) from None


#: The catalog and drift-only entries of the default family (``dc_hbridge``, the thesis rig).
CATALOG: tuple[Effect, ...] = catalog()
DRIFT_ONLY: tuple[Effect, ...] = drift_only()


def get_effect(name: str) -> Effect:
    """Catalog (or drift-only) entry by name, of any family.

    Raises
    ------
    GapError
        If no component or effect of the registry declares a hypothesis ``name`` (the message lists
        the known names).
    """
    try:
        return EFFECTS[name]
    except KeyError:
        raise GapError(f"unknown effect {name!r}; the catalog has {list(EFFECTS)}") from None


# ------------------------------------------------------------------------------ detected, not fitted
# detect_quantum (the ``quantisation`` effect's "direct" reading) lives in io/recording_input.py: the
# resampling reads it too (a quantised channel is not interpolated). measurement_noise, the noise
# floor it sets, lives in greybox/fit.py: the grey-box fits read it too.



def apply_effects(rig: Rig, chosen: Mapping[str, Mapping[str, float]],
                  measurement: MeasurementMap | None = None,
                  ctx: EffectContext | None = None) -> tuple[Rig, MeasurementMap]:
    """Rig and measurement map with several effects applied in catalog order.

    Parameters
    ----------
    rig : Rig
        Nominal rig.
    chosen : mapping
        ``{effect name: {parameter: physical value}}``.
    measurement : MeasurementMap, optional
        Starting measurement map (default identity).
    ctx : EffectContext, optional
        Where missing parameter values take their probe values from (a held parameter,
        e.g. v_ε, keeps the rig's value, :meth:`Effect.held_values`).

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
    for eff in EFFECTS.values():  # catalog order: a supply voltage (order 5) is what a bridge drop acts on
        if eff.name in chosen:
            vals = eff.values({**eff.held_values(rig), **dict(chosen[eff.name])}, ctx)
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
                     min_samples: int = MIN_RECORDING_SAMPLES,
                     need_changing_input: bool = False) -> frozenset[str]:
    """Validate recordings for the gap diagnosis; return the channels every one of them has.

    Parameters
    ----------
    recordings : sequence of Recording
    what : str
        Name used in messages (``"fit recordings"``, ``"held-out recordings"``).
    min_samples : int
        Fewest samples per recording.
    need_changing_input : bool
        Refuse a set in which no recording's duty cycle changes (the fit recordings).

    Raises
    ------
    GapError
        Empty sequence; an item that is not a Recording; no ``theta`` channel; NaN/inf in θ, the
        duty cycle or another channel; duty outside [0, 1]; too few samples; a constant duty cycle
        that cannot explain θ (a driven log without its command) or under which θ does not move;
        with ``need_changing_input``, a constant duty cycle in every recording.
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
            # a free decay or a step from rest is accepted (the rod's dynamics); a driven log without
            # its command, or a rod that does not move, is refused with the csv_import message
            why = excitation_problem(r.t, r.duty, r.channels["theta"],
                                     "channel theta_ref" if "theta_ref" in r.extra else None)
            if why is not None:
                raise GapError(f"{src}: {why[1]}")
        dt = np.diff(r.t)
        if np.ptp(dt) > 1e-3 * np.median(dt):
            raise GapError(f"{src}: non-uniform sampling (dt from {dt.min():.4g} to {dt.max():.4g} s); "
                           "resample first (aeropend_ident.io.resampling.uniform_recording, "
                           "which every command applies)")
        ch = set(r.channels) & {"theta", "i_a", "v_a", "omega_rotor"}
        common = ch if common is None else common & ch
    if need_changing_input and all(np.ptp(r.duty) == 0.0 for r in recs):
        raise GapError(
            f"the duty cycle is constant in every one of the {what} "
            f"({', '.join(r.source or '?' for r in recs)}): the diagnosis needs at least one whose command "
            "changes (a step logged with samples before it, a staircase, PRBS); free decays and holds are "
            "accepted beside it")
    return frozenset(common or set())


def nominal_model_check(rig: Rig) -> None:
    """Raise :class:`GapError` if the nominal rig cannot be simulated (e.g. no motor steady state)."""
    try:
        plant_model(rig).equilibrium(0.1)
    except Exception as exc:
        raise GapError(f"nominal rig {rig.name!r} is not usable: {exc}") from exc
