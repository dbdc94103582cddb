"""Rig parameter sets: dataclasses and the YAML rig-file format.

A rig file describes one aeropendulum (real or simulated) in SI units. Every number is written
as ``{value: ..., unit: "...", source: "..."}`` so its provenance travels with it; the loader
checks each unit against the one the model expects and raises :class:`RigFileError` naming the
file, the key and what was expected. The ``effects`` section switches the model's optional
effects on and off (see :class:`Effects` and ``docs/model.md``), so the same code simulates a
rig with or without a given effect.

Rig files shipped with the package: ``thesis_rig`` (coherent set derived from the thesis),
``thesis_sim`` (the thesis' own simulated plant, equations printed with Figs. 5.3/5.4) and
third-party rigs from ``shared/data/real`` (``jahoyosr_rig``, ``aeroshield_rig``, ...).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import MISSING, dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any

import yaml


class RigFileError(ValueError):
    """A rig file or parameter set is malformed or physically invalid."""


def _p(unit: str, doc: str, positive: bool = False, nonneg: bool = False,
       default: float | None = None) -> Any:
    """Dataclass field metadata: unit, meaning, sign constraint; ``default``: an optional key (a
    later model term whose default leaves the model as it was; rig files may omit it)."""
    meta = {"unit": unit, "doc": doc, "positive": positive, "nonneg": nonneg}
    return field(metadata=meta) if default is None else field(default=default, metadata=meta)


@dataclass(frozen=True)
class ActuatorParams:
    """Duty cycle τ -> armature voltage v_a chain (PWM, H-bridge)."""

    v_supply: float = _p("V", "H-bridge supply: ideal map v_a = v_supply·τ", positive=True)
    hbridge_k0: float = _p("V", "Eq. 4.3 k0 in v_a = k0 + k1·sqrt(k2·τ + k3)")
    hbridge_k1: float = _p("V", "Eq. 4.3 k1", nonneg=True)
    hbridge_k2: float = _p("1", "Eq. 4.3 k2 (τ as a fraction)", nonneg=True)
    hbridge_k3: float = _p("1", "Eq. 4.3 k3", nonneg=True)
    dead_zone: float = _p("1", "duty-cycle dead zone τ_dz", nonneg=True)
    lag_time_constant: float = _p("s", "first-order actuator lag T_a", nonneg=True)
    input_delay: float = _p("s", "input (transport) delay T_d", nonneg=True)


@dataclass(frozen=True)
class MotorParams:
    """Armature RL circuit, rotor mechanics and gearbox (thesis Eqs. 3.4-3.5)."""

    R_a: float = _p("ohm", "armature resistance", positive=True)
    L_a: float = _p("H", "armature inductance", positive=True)
    K_omega: float = _p("V*s/rad", "back-EMF constant K_ω", nonneg=True)
    K_t: float = _p("N*m/A", "torque constant K_t", positive=True)
    J_m: float = _p("kg*m^2", "rotor-side inertia (rotor + gear + propeller reflected)", positive=True)
    B_m: float = _p("N*m*s/rad", "rotor viscous friction", nonneg=True)
    T_c: float = _p("N*m", "rotor Coulomb friction torque", nonneg=True)
    K_d: float = _p("N*m*s^2/rad^2", "propeller drag torque on the rotor: K_d·ω1·|ω1|", nonneg=True)
    gear_ratio: float = _p("1", "n = ω1/ω2 (rotor turns n times faster than the propeller)", positive=True)


@dataclass(frozen=True)
class ThrustParams:
    """Propeller thrust f = K_q·|ω2|^α (thesis Eq. 3.3 with α = 2)."""

    K_q: float = _p("N*s^2/rad^2", "thrust coefficient K_q (for α = 2)", nonneg=True)
    exponent: float = _p("1", "thrust-law exponent α (used when effects.thrust_exponent)", positive=True)


@dataclass(frozen=True)
class PendulumParams:
    """Rod dynamics per unit inertia (thesis Eq. 3.2) and end stops."""

    mgd_over_J: float = _p("1/s^2", "gravity term m·g·d/J", nonneg=True)
    c_over_J: float = _p("1/s", "viscous friction c/J", nonneg=True)
    L_over_J: float = _p("1/(kg*m)", "thrust lever arm over inertia L/J", positive=True)
    coulomb_over_J: float = _p("rad/s^2", "Coulomb friction torque over inertia T_f/J", nonneg=True)
    theta_min: float = _p("rad", "lower end stop")
    theta_max: float = _p("rad", "upper end stop")
    stop_stiffness: float = _p("1/s^2", "end-stop contact stiffness over inertia", nonneg=True)
    stop_damping: float = _p("1/s", "end-stop contact damping over inertia", nonneg=True)
    friction_velocity: float = _p("rad/s", "tanh regularisation width of sign(θ̇)", positive=True)
    stribeck_over_J: float = _p("rad/s^2", "Stribeck excess of the static over the Coulomb friction "
                                "(T_s − T_f)/J (used when effects.coulomb_friction; 0 = none)", nonneg=True,
                                default=0.0)
    stribeck_velocity: float = _p("rad/s", "Stribeck velocity v_s: the excess decays as exp(−(θ̇/v_s)²)",
                                  positive=True, default=0.1)


@dataclass(frozen=True)
class SensorParams:
    """Measurement noise (SNR) and ADC quantisation of the acquisition channels."""

    snr_db: float = _p("dB", "signal-to-noise ratio of every measured channel")
    theta_quantum: float = _p("rad", "angle LSB (AS5040 PWM -> RC -> 10-bit ADC: 2π/1024)", nonneg=True)
    i_a_quantum: float = _p("A", "armature-current LSB", nonneg=True)
    v_a_quantum: float = _p("V", "armature-voltage LSB", nonneg=True)
    omega_quantum: float = _p("rad/s", "speed LSB", nonneg=True)
    theta_rms: float = _p("rad", "reference RMS of θ for the SNR in per-sample stepping", positive=True)
    i_a_rms: float = _p("A", "reference RMS of i_a for the SNR in per-sample stepping", positive=True)
    v_a_rms: float = _p("V", "reference RMS of v_a for the SNR in per-sample stepping", positive=True)
    omega_rms: float = _p("rad/s", "reference RMS of ω for the SNR in per-sample stepping", positive=True)


#: Allowed values of ``effects.armature_inductance``.
INDUCTANCE_MODES = ("dynamic", "quasi_static")


@dataclass(frozen=True)
class Effects:
    """Switches of the model's optional effects (see ``docs/model.md`` for each equation)."""

    hbridge_map: bool = False
    armature_inductance: str = "dynamic"
    back_emf: bool = True
    dead_zone: bool = False
    viscous_friction: bool = True
    coulomb_friction: bool = False
    propeller_drag: bool = True
    thrust_exponent: bool = False
    actuator_lag: bool = False
    input_delay: bool = False
    end_stops: bool = False
    sensor_noise: bool = False
    quantisation: bool = False

    def __post_init__(self) -> None:
        if self.armature_inductance not in INDUCTANCE_MODES:
            raise RigFileError(
                f"effects.armature_inductance = {self.armature_inductance!r}; expected one of "
                f"{INDUCTANCE_MODES}"
            )


@dataclass(frozen=True)
class Rig:
    """A complete rig: parameters, effect switches and sampling."""

    name: str
    description: str
    sample_period: float
    actuator: ActuatorParams
    motor: MotorParams
    thrust: ThrustParams
    pendulum: PendulumParams
    sensors: SensorParams
    effects: Effects
    sources: dict[str, str] = field(default_factory=dict)

    def with_effects(self, **switches: Any) -> Rig:
        """Copy of the rig with some effect switches changed (e.g. ``dead_zone=True``)."""
        return dataclasses.replace(self, effects=dataclasses.replace(self.effects, **switches))

    def with_params(self, section: str, **values: float) -> Rig:
        """Copy of the rig with some parameters of one section changed.

        Raises
        ------
        RigFileError
            If ``section`` or a parameter name does not exist.
        """
        if section not in _SECTIONS:
            raise RigFileError(f"unknown rig section {section!r}; expected one of {list(_SECTIONS)}")
        current = getattr(self, section)
        names = {f.name for f in fields(current)}
        bad = sorted(set(values) - names)
        if bad:
            raise RigFileError(f"{section} has no parameter(s) {bad}; expected some of {sorted(names)}")
        new = dataclasses.replace(current, **{k: float(v) for k, v in values.items()})
        _check_section(section, new, "<with_params>")
        return dataclasses.replace(self, **{section: new})


_SECTIONS: dict[str, type] = {
    "actuator": ActuatorParams,
    "motor": MotorParams,
    "thrust": ThrustParams,
    "pendulum": PendulumParams,
    "sensors": SensorParams,
}

#: Keys a rig file may have at its top level. ``recording_frame`` (optional) describes how a rig's
#: recorded angle relates to the model's θ (read by :func:`aeropend_ident.greybox.fit.rig_theta_offset`).
TOP_LEVEL_KEYS = frozenset({"name", "description", "sample_period", "effects", "recording_frame", *_SECTIONS})

_UNIT_ALIASES = {"Ω": "ohm", "Ohm": "ohm", "ohms": "ohm", "-": "1", "": "1", "rad/s²": "1/s^2"}


def _norm_unit(unit: str) -> str:
    u = str(unit).strip().replace("·", "*").replace(" ", "")
    return _UNIT_ALIASES.get(u, u)


def _check_section(section: str, obj: Any, where: str) -> None:
    for f in fields(obj):
        v = getattr(obj, f.name)
        if not math.isfinite(v):
            raise RigFileError(f"{where}: {section}.{f.name} = {v!r} is not finite")
        if f.metadata.get("positive") and v <= 0:
            raise RigFileError(f"{where}: {section}.{f.name} = {v!r} must be > 0 ({f.metadata['doc']})")
        if f.metadata.get("nonneg") and v < 0:
            raise RigFileError(f"{where}: {section}.{f.name} = {v!r} must be >= 0 ({f.metadata['doc']})")
    if section == "pendulum" and obj.theta_min >= obj.theta_max:
        raise RigFileError(
            f"{where}: pendulum.theta_min = {obj.theta_min} must be < theta_max = {obj.theta_max}"
        )
    if section == "actuator" and obj.dead_zone >= 1.0:
        raise RigFileError(f"{where}: actuator.dead_zone = {obj.dead_zone} must be < 1 (a fraction)")


def _read_quantity(node: Any, key: str, unit: str, where: str) -> tuple[float, str]:
    if not isinstance(node, dict) or "value" not in node:
        raise RigFileError(
            f"{where}: {key} must be a mapping {{value, unit, source}}, got {node!r}"
        )
    got = _norm_unit(node.get("unit", ""))
    if got != _norm_unit(unit):
        raise RigFileError(f"{where}: {key} has unit {node.get('unit')!r}; expected {unit!r}")
    if "source" not in node or not str(node["source"]).strip():
        raise RigFileError(f"{where}: {key} has no 'source' (every number must say where it comes from)")
    try:
        value = float(node["value"])
    except (TypeError, ValueError) as exc:
        raise RigFileError(f"{where}: {key}.value = {node['value']!r} is not a number") from exc
    return value, str(node["source"])


def rig_from_dict(data: dict[str, Any], where: str = "<dict>") -> Rig:
    """Build a :class:`Rig` from the parsed YAML structure of a rig file.

    Raises
    ------
    RigFileError
        On a missing section or key, a wrong unit, a missing source, a non-number or a value
        outside its physical range; the message names ``where`` and the key.
    """
    if not isinstance(data, dict):
        raise RigFileError(f"{where}: top level must be a mapping, got {type(data).__name__}")
    unknown_top = sorted(set(data) - TOP_LEVEL_KEYS)
    if unknown_top:
        raise RigFileError(
            f"{where}: unknown top-level key(s) {unknown_top}; expected some of {sorted(TOP_LEVEL_KEYS)}"
        )
    sources: dict[str, str] = {}
    built: dict[str, Any] = {}
    for section, cls in _SECTIONS.items():
        node = data.get(section)
        if not isinstance(node, dict):
            raise RigFileError(f"{where}: missing section {section!r}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(node) - known)
        if unknown:
            raise RigFileError(
                f"{where}: unknown key(s) {unknown} in section {section!r}; expected {sorted(known)}"
            )
        kwargs = {}
        for f in fields(cls):
            if f.name not in node and f.default is not MISSING:
                kwargs[f.name] = f.default
                sources[f"{section}.{f.name}"] = "default (not in the rig file)"
                continue
            if f.name not in node:
                raise RigFileError(
                    f"{where}: missing {section}.{f.name} [{f.metadata['unit']}] ({f.metadata['doc']})"
                )
            kwargs[f.name], sources[f"{section}.{f.name}"] = _read_quantity(
                node[f.name], f"{section}.{f.name}", f.metadata["unit"], where
            )
        obj = cls(**kwargs)
        _check_section(section, obj, where)
        built[section] = obj
    period, sources["sample_period"] = _read_quantity(data.get("sample_period"), "sample_period", "s", where)
    if period <= 0:
        raise RigFileError(f"{where}: sample_period = {period} must be > 0")
    eff_node = data.get("effects", {}) or {}
    eff_known = {f.name for f in fields(Effects)}
    bad = sorted(set(eff_node) - eff_known)
    if bad:
        raise RigFileError(f"{where}: unknown effect(s) {bad}; expected some of {sorted(eff_known)}")
    for k, v in eff_node.items():
        if k != "armature_inductance" and not isinstance(v, bool):
            raise RigFileError(f"{where}: effects.{k} = {v!r} must be true or false")
    return Rig(
        name=str(data.get("name", Path(where).stem)),
        description=str(data.get("description", "")),
        sample_period=period,
        effects=Effects(**eff_node),
        sources=sources,
        **built,
    )


def rig_to_dict(rig: Rig) -> dict[str, Any]:
    """Inverse of :func:`rig_from_dict` (units and sources included)."""
    out: dict[str, Any] = {"name": rig.name, "description": rig.description}
    out["sample_period"] = {
        "value": rig.sample_period, "unit": "s", "source": rig.sources.get("sample_period", "")
    }
    for section in _SECTIONS:
        obj = getattr(rig, section)
        out[section] = {
            f.name: {
                "value": getattr(obj, f.name),
                "unit": f.metadata["unit"],
                "source": rig.sources.get(f"{section}.{f.name}", "set in code"),
            }
            for f in fields(obj)
        }
    out["effects"] = dataclasses.asdict(rig.effects)
    return out


def load_rig(name_or_path: str | Path) -> Rig:
    """Load a rig file by path or by the name of a shipped rig (e.g. ``"thesis_rig"``).

    Raises
    ------
    RigFileError
        If the file does not exist, is not valid YAML or violates the format.
    """
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        shipped = resources.files("aeropend_sim") / "rigs" / f"{name_or_path}.yaml"
        if shipped.is_file():
            text, where = shipped.read_text(encoding="utf-8"), f"{name_or_path}.yaml"
        else:
            raise RigFileError(
                f"no rig named {name_or_path!r}; shipped rigs are {shipped_rigs()} "
                "(or give a path to a .yaml file)"
            )
    else:
        if not path.is_file():
            raise RigFileError(f"rig file {path} does not exist")
        text, where = path.read_text(encoding="utf-8"), str(path)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise RigFileError(f"{where}: not valid YAML: {exc}") from exc
    return rig_from_dict(data, where)


def save_rig(rig: Rig, path: str | Path) -> None:
    """Write a rig file (YAML) that :func:`load_rig` reads back to an equal :class:`Rig`."""
    text = yaml.safe_dump(rig_to_dict(rig), sort_keys=False, allow_unicode=True)
    Path(path).write_text(text, encoding="utf-8")


def shipped_rigs() -> list[str]:
    """Names of the rig files shipped with ``aeropend_sim``."""
    folder = resources.files("aeropend_sim") / "rigs"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))
