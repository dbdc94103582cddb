"""Rig parameter sets: the :class:`Rig` and the YAML rig-file format, built on the component registry.

A rig file describes one aeropendulum (real or simulated) in SI units. It names its actuator
family (``actuator.family``: ``dc_hbridge``, ``voltage_amplifier`` or ``esc``; absent =
``dc_hbridge``, the format of every rig file before issue 35) and gives **only what the rig has**:

* the family's required parameters (a component parameter without an ``absent`` value, e.g.
  ``motor.R_a`` of a DC motor, ``actuator.omega_max`` of an ESC) and the rod's ``mgd_over_J`` and
  ``L_over_J`` or the geometry they follow from (``pendulum.mass``, ``com_distance``,
  ``thrust_arm`` and optionally ``inertia``, by default a point mass m·d²);
* any effect parameter it knows. Everything absent is **not modelled**: it takes its
  :attr:`~aeropend_sim.components.base.Param.absent` value (T_c = 0: no brush friction) and the
  load report says so (:attr:`Rig.load_notes`, :meth:`Rig.load_report`); never a load error.

Every number given is written ``{value: ..., unit: "...", source: "..."}``: the loader checks each
unit against the registry's and refuses a number without a source, naming the file and the key.

The ``effects:`` section switches the effects (:class:`Effects`; see ``docs/model.md``). A switch
the file omits is on when one of its effect's parameters is given with a value other than its
absent value; in a file of the pre-family format (no ``actuator.family``) it takes the default of
that format instead. The pre-issue-35 switches ``viscous_friction`` and ``coulomb_friction`` are
read as both halves they stood for (rod and rotor), with a note in the load report.
:func:`rig_to_dict` and :func:`save_rig` write the minimal form (what is stated or modelled, the
family, the switches that differ from what the parameters imply); ``load_rig(save_rig(r)) == r``.

Rig files shipped with the package: ``thesis_rig`` (coherent set derived from the thesis),
``thesis_sim`` (the thesis' own simulated plant, equations printed with Figs. 5.3/5.4) and
third-party rigs from ``shared/data/real`` (``jahoyosr_rig``, ``aeroshield_rig``, ...).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, make_dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from aeropend_sim.components import registry
from aeropend_sim.components.base import SECTIONS, Effect
from aeropend_sim.files.safe_yaml import YamlRefusedError, load_yaml, parse_yaml


class RigFileError(ValueError):
    """A rig file or parameter set is malformed or physically invalid."""


#: Source of a parameter the rig file does not give (its absent value: not modelled).
NOT_MODELLED = "not modelled (not in the rig file)"
#: Source of a setting the rig file does not give (its documented default).
DEFAULT = "default (not in the rig file)"
#: Source of a value changed in code where the rig file gave none (:meth:`Rig.with_params`).
SET_IN_CODE = "set in code (not in the rig file)"
#: Start of the source of a value the loader derived from other values of the file.
DERIVED = "derived by the rig loader: "
#: Start of the source of a parameter ``rig new`` left for ``rig fit``: its value is a clearly
#: marked starting value, not a measurement (``rig fit`` keeps it when the recordings cannot
#: determine it, with the reason after this marker).
TO_BE_FITTED = "to be fitted (rig fit)"
#: Start of the source of a value ``rig fit`` determined (its uncertainty and provenance follow).
FITTED = "fitted (rig fit)"

#: Allowed values of ``effects.armature_inductance`` (its on and off modes).
INDUCTANCE_MODES: tuple[str, str] = registry.effect("armature_inductance").modes  # type: ignore[assignment]
#: Keys a rig file may have at its top level. ``recording_frame`` (optional) describes how a rig's
#: recorded angle relates to the model's θ (read by
#: :func:`aeropend_ident.greybox.parameters.rig_theta_offset`);
#: ``hardware`` (optional) the angle sensor and ESC pulse map the bridge checks against the firmware
#: (read by :func:`aeropend_bridge.family.read_rig_hardware`).
TOP_LEVEL_KEYS = frozenset({"name", "description", "sample_period", "effects", "recording_frame", "hardware",
                            *SECTIONS})

_UNIT_ALIASES = {"Ω": "ohm", "Ohm": "ohm", "ohms": "ohm", "-": "1", "": "1", "rad/s²": "1/s^2"}


# ------------------------------------------------------------------------------ generated dataclasses
def _camel(name: str) -> str:
    return "".join(part.capitalize() for part in name.split("_"))


def _register(cls: type) -> type:
    """Make a generated class picklable (reachable as ``aeropend_sim.params.<name>``)."""
    cls.__module__ = __name__
    cls.__qualname__ = cls.__name__
    globals()[cls.__name__] = cls
    return cls


#: Section classes made so far, by family, section and their parameters: a registry refresh
#: (a part registered later) keeps the class of a section whose parameters did not change, so the
#: rigs built before stay valid.
_SECTION_CLASSES: dict[tuple[str, str, tuple[Any, ...]], type] = {}


def section_class(family: str, section: str) -> type:
    """Frozen dataclass of one rig section for a family: one float field per parameter the family
    has in that section (:func:`aeropend_sim.components.registry.family_params`), with the field
    metadata ``unit``, ``doc``, ``positive``, ``nonneg`` and ``param`` (the :class:`Param`)."""
    params = tuple(p for p in registry.family_params(family).values() if p.section == section)
    key = (family, section, params)
    if key not in _SECTION_CLASSES:
        specs = [(p.name, float, field(metadata={
            "unit": p.unit, "doc": p.doc, "positive": p.sign == "positive", "nonneg": p.sign == "nonneg",
            "param": p})) for p in params]
        name = f"{_camel(family)}{_camel(section)}Params"
        _SECTION_CLASSES[key] = _register(make_dataclass(name, specs, frozen=True))
    return _SECTION_CLASSES[key]


def __getattr__(name: str) -> type:
    """Reach a generated section class by name in a process that has not built it yet (PEP 562).

    A rig unpickled in another process (a Dask worker, a process pool) names its section classes as
    ``aeropend_sim.params.<Family><Section>Params``; they are made on first use by
    :func:`section_class`, so a fresh process builds them here.

    Raises
    ------
    AttributeError
        When ``name`` is no family's section class.
    """
    if name.endswith("Params") and not name.startswith("_"):
        for fam in registry.families():
            for section in SECTIONS:
                if f"{_camel(fam.name)}{_camel(section)}Params" == name:
                    return section_class(fam.name, section)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _effects_post_init(self: Any) -> None:
    for e in registry.effects():
        v = getattr(self, e.name)
        if e.modes:
            if v not in e.modes:
                raise RigFileError(f"effects.{e.name} = {v!r}; expected one of {e.modes}")
        elif not isinstance(v, bool):
            raise RigFileError(f"effects.{e.name} = {v!r} must be true or false")


def _make_effects() -> type:
    specs = [(e.name, str if e.modes else bool, field(default=e.off)) for e in registry.effects()]
    cls = make_dataclass("Effects", specs, frozen=True, namespace={"__post_init__": _effects_post_init})
    cls.__doc__ = ("Switches of the model's optional effects, one field per registered effect "
                   "(``docs/model.md``); all off by default (generated from "
                   ":mod:`aeropend_sim.components.registry`).")
    return _register(cls)


Effects = _make_effects()


def _status(source: str) -> str:
    """Provenance class of a parameter source: stated, derived, not modelled, default, set in code,
    to be fitted or fitted (a value derived from a to-be-fitted input is itself to be fitted)."""
    if source.startswith(TO_BE_FITTED):
        return "to be fitted"
    if source.startswith(FITTED):
        return "fitted"
    if source == NOT_MODELLED:
        return "not modelled"
    if source == DEFAULT:
        return "default"
    if source == SET_IN_CODE:
        return "set in code"
    if source.startswith(DERIVED):
        return "to be fitted" if TO_BE_FITTED in source else "derived"
    return "stated"


def _why_not(key: str, family: str) -> str:
    """Why a parameter of the registry is not one of the family's (its owner's reason)."""
    owner = registry.owners()[key]
    reason = owner.applies_to(registry.family(family)) or owner.why_not
    fams = " and ".join(registry.families_with(key))
    return f"{key} is declared by {owner.name}, part of {fams} rigs: {reason}"


@registry.derived  # a part registered later may change it
def _validation_plan(family: str) -> tuple[tuple, tuple, tuple, tuple]:
    """What :meth:`Rig.__post_init__` checks for a rig of ``family``, worked out once per family
    (a fit builds thousands of rigs): the section classes, the effects the family cannot have (with
    why), ``(key, section, name, Param, owning effect's name or None)`` per parameter, and the
    parts' cross-checks.

    Raises
    ------
    RegistryError
        On an unknown family (:func:`aeropend_sim.components.registry.family`).
    """
    fam = registry.family(family)
    classes = tuple((section, section_class(family, section)) for section in SECTIONS)
    inapplicable = tuple((eff, why) for eff in registry.effects() if (why := eff.applies_to(fam)) is not None)
    owners = registry.owners()
    params = tuple((key, p.section, p.name, p, owners[key].name if isinstance(owners[key], Effect) else None)
                   for key, p in registry.family_params(family).items())
    checks = tuple(part.check for part in (*registry.family_parts(family), *registry.family_effects(family))
                   if part.check is not None)
    return classes, inapplicable, params, checks


# ------------------------------------------------------------------------------ the rig
@dataclass(frozen=True)
class Rig:
    """A complete rig: actuator family, parameters per section, effect switches, sampling.

    The sections (``actuator``, ``motor``, ``thrust``, ``pendulum``, ``sensors``) are frozen
    dataclasses generated per family (:func:`section_class`); ``rig.motor.R_a`` etc. read a value.
    Construction validates: effects that do not apply to the family are off, every parameter is
    valid for its owner's state (:meth:`aeropend_sim.components.base.Param.violation`), and the
    parts' cross-checks hold.

    Attributes
    ----------
    sources : dict
        ``"section.name"`` (and ``"sample_period"``) -> where the number comes from
        (:data:`NOT_MODELLED`, :data:`DEFAULT`, :data:`SET_IN_CODE`, a :data:`DERIVED` account or
        the rig file's own source).
    family : str
        Actuator family.
    load_notes : tuple of str
        What the loader read, derived, assumed or did not model (not part of equality).
    """

    name: str
    description: str
    sample_period: float
    actuator: Any
    motor: Any
    thrust: Any
    pendulum: Any
    sensors: Any
    effects: Any
    sources: dict[str, str] = field(default_factory=dict)
    family: str = registry.DEFAULT_FAMILY
    load_notes: tuple[str, ...] = field(default=(), compare=False)

    def __post_init__(self) -> None:
        classes, inapplicable, params, checks = _validation_plan(self.family)
        for section, cls in classes:
            if type(getattr(self, section)) is not cls:
                got = type(getattr(self, section)).__name__
                raise RigFileError(f"rig {self.name!r}: section {section} is a {got}; expected "
                                   f"{cls.__name__} (family {self.family})")
        for eff, why in inapplicable:
            if eff.is_on(getattr(self.effects, eff.name)):
                raise RigFileError(f"effect {eff.name} cannot be on for a rig of the {self.family} "
                                   f"family: {why}")
        sections = {section: getattr(self, section) for section, _ in classes}
        values = {key: float(getattr(sections[section], name)) for key, section, name, _, _ in params}
        object.__setattr__(self, "_values", values)  # the rig is immutable: read once, copied out
        on = {e.name for e in registry.effects() if e.is_on(getattr(self.effects, e.name))}
        for key, _, _, p, owner in params:
            msg = p.violation(values[key], owner is None or owner in on)
            if msg:
                raise RigFileError(msg)
        for check in checks:
            if msg := check(values):
                raise RigFileError(msg)

    # ------------------------------------------------------------------ reading
    def value(self, key: str) -> float:
        """The value of parameter ``"section.name"``.

        Raises
        ------
        RigFileError
            If the rig's family has no such parameter (the message says why).
        """
        section, _, name = key.partition(".")
        if key not in registry.family_params(self.family):
            if key in registry.params():
                raise RigFileError(f"rig {self.name!r} ({self.family}) has no {_why_not(key, self.family)}")
            raise RigFileError(f"no parameter {key!r}")
        return float(getattr(getattr(self, section), name))

    def values(self) -> dict[str, float]:
        """Every parameter of the rig, ``{"section.name": value}`` (a new dict on every call)."""
        return dict(self._values)

    def status(self, key: str) -> str:
        """Provenance of a parameter: ``stated``, ``derived``, ``not modelled``, ``default``,
        ``set in code``, ``to be fitted`` (a starting value ``rig new`` wrote) or ``fitted``
        (``rig fit``)."""
        return _status(self.sources.get(key, SET_IN_CODE))

    def load_report(self) -> str:
        """The load report: per parameter stated / derived / not modelled / default, and notes."""
        lines = [f"rig {self.name!r}, actuator family {self.family}"]
        for key, p in registry.family_params(self.family).items():
            v = self.value(key)
            lines.append(f"  {self.status(key):<13} {key} = {v:g} {p.unit}  ({p.doc})")
        lines += [f"  note: {n}" for n in self.load_notes]
        todo = [k for k in registry.family_params(self.family) if self.status(k) == "to be fitted"]
        if todo:
            lines.append(f"  note: {len(todo)} parameter(s) hold starting values, not measurements "
                         f"({', '.join(todo)}): fit them with `rig fit` before trusting the model")
        return "\n".join(lines)

    # ------------------------------------------------------------------ copies
    def with_effects(self, **switches: Any) -> Rig:
        """Copy of the rig with some effect switches changed (e.g. ``dead_zone=True``).

        The pre-issue-35 switches ``viscous_friction`` and ``coulomb_friction`` set every effect
        they stood for (:func:`aeropend_sim.components.registry.legacy_switches`).

        Raises
        ------
        RigFileError
            On an unknown switch, an invalid value, or an effect the family cannot have.
        """
        expanded = expand_switches(switches, "<with_effects>")
        return dataclasses.replace(self, effects=dataclasses.replace(self.effects, **expanded))

    def with_params(self, section: str, **values: float) -> Rig:
        """Copy of the rig with some parameters of one section changed.

        A parameter the rig did not model gets the source :data:`SET_IN_CODE`.

        Raises
        ------
        RigFileError
            If ``section`` or a parameter name does not exist for the rig's family, or a value
            is invalid.
        """
        if section not in SECTIONS:
            raise RigFileError(f"unknown rig section {section!r}; expected one of {list(SECTIONS)}")
        current = getattr(self, section)
        names = {f.name for f in fields(current)}
        bad = sorted(set(values) - names)
        if bad:
            why = [_why_not(f"{section}.{b}", self.family) for b in bad
                   if f"{section}.{b}" in registry.params()]
            raise RigFileError(f"{section} has no parameter(s) {bad} on a {self.family} rig; expected some "
                               f"of {sorted(names)}" + (f" ({'; '.join(why)})" if why else ""))
        new = dataclasses.replace(current, **{k: float(v) for k, v in values.items()})
        sources = dict(self.sources)
        for k, v in values.items():
            key = f"{section}.{k}"
            unstated = _status(sources.get(key, SET_IN_CODE)) in ("not modelled", "default")
            if unstated and float(v) != getattr(current, k):
                sources[key] = SET_IN_CODE
        return dataclasses.replace(self, sources=sources, **{section: new})


def expand_switches(switches: dict[str, Any], where: str) -> dict[str, Any]:
    """Switches with the pre-issue-35 names replaced by the effects they stand for.

    Raises
    ------
    RigFileError
        On a name that is neither a switch nor a legacy switch.
    """
    legacy = registry.legacy_switches()
    known = {e.name for e in registry.effects()}
    out: dict[str, Any] = {}
    bad = sorted(k for k in switches if k not in known and k not in legacy)
    if bad:
        raise RigFileError(f"{where}: unknown effect(s) {bad}; expected some of "
                           f"{sorted(known | set(legacy))}")
    for k, v in switches.items():  # a legacy switch first, so an explicit half given with it wins
        if k in legacy:
            out.update(dict.fromkeys(legacy[k], v))
    out.update({k: v for k, v in switches.items() if k in known})
    return out


# ------------------------------------------------------------------------------ reading rig files
def _norm_unit(unit: str) -> str:
    u = str(unit).strip().replace("·", "*").replace(" ", "")
    return _UNIT_ALIASES.get(u, u)


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


def _family_of(data: dict[str, Any], where: str) -> tuple[str, bool]:
    """(family, legacy format) of a parsed rig file."""
    node = data.get("actuator")
    if isinstance(node, dict) and "family" in node:
        fam = node["family"]
        try:
            registry.family(str(fam))
        except registry.RegistryError as exc:
            raise RigFileError(f"{where}: actuator.family: {exc}") from exc
        return str(fam), False
    return registry.DEFAULT_FAMILY, True


def _read_sections(data: dict[str, Any], family: str, legacy: bool,
                   where: str) -> dict[str, tuple[float, str]]:
    """Every number the file gives, ``{key: (value, source)}``, checked against the family's keys."""
    named = "no actuator.family, so dc_hbridge" if legacy else f"actuator.family {family}"
    fam_params = registry.family_params(family)
    geometry = {p.key: p for c in registry.family_parts(family) for p in getattr(c, "geometry", ())}
    given: dict[str, tuple[float, str]] = {}
    for section in SECTIONS:
        node = data.get(section, {})
        if node is None:
            node = {}
        if not isinstance(node, dict):
            raise RigFileError(f"{where}: section {section!r} must be a mapping, got {type(node).__name__}")
        for name, item in node.items():
            key = f"{section}.{name}"
            if key == "actuator.family":
                continue
            p = fam_params.get(key) or geometry.get(key)
            if p is None:
                if key in registry.params():
                    raise RigFileError(f"{where}: {key} is not a parameter of this rig ({named}): "
                                       f"{_why_not(key, family)}")
                known = sorted(k.partition(".")[2] for k in (*fam_params, *geometry)
                               if k.startswith(section + "."))
                raise RigFileError(f"{where}: unknown key(s) {[name]} in section {section!r}; expected "
                                   f"{known}")
            given[key] = _read_quantity(item, key, p.unit, where)
    return given


def _derive_geometry(given: dict[str, tuple[float, str]], family: str, where: str,
                     notes: list[str]) -> dict[str, tuple[float, str]]:
    """Parameters the components derive from the geometry the file gives (the rod's mgd/J, L/J)."""
    out: dict[str, tuple[float, str]] = {}
    for comp in registry.family_parts(family):
        geo = getattr(comp, "geometry", ())
        stated = {p.key: given[p.key][0] for p in geo if p.key in given}
        if not stated:
            continue
        for p in geo:
            if p.key in stated and (msg := p.violation(stated[p.key])):
                raise RigFileError(f"{where}: {msg}")
        try:
            derived = comp.derive(stated)  # type: ignore[union-attr]
        except KeyError as exc:
            p = next(g for g in geo if g.key == exc.args[0])
            raise RigFileError(f"{where}: missing {p.key} [{p.unit}] ({p.doc}): the geometry "
                               f"{sorted(stated)} needs it to derive {comp.name}'s parameters") from None
        for key, (value, how) in derived.items():
            if key in given:
                raise RigFileError(f"{where}: {key} is given and also derived from the geometry "
                                   f"{sorted(stated)}; give one or the other")
            srcs = "; ".join(f"{k} = {given[k][0]:g} ({given[k][1]})" for k in sorted(stated))
            out[key] = (value, f"{DERIVED}{how}; {srcs}")
            notes.append(f"{key} = {value:.6g} derived: {how}")
    return out


def _read_switches(data: dict[str, Any], where: str, notes: list[str]) -> dict[str, Any]:
    node = data.get("effects", {}) or {}
    if not isinstance(node, dict):
        raise RigFileError(f"{where}: effects must be a mapping of switches, got {type(node).__name__}")
    for k, v in node.items():
        eff = next((e for e in registry.effects() if e.name == k), None)
        if eff is not None and eff.modes:
            continue  # checked by Effects
        if not isinstance(v, bool) and (eff is not None or k in registry.legacy_switches()):
            raise RigFileError(f"{where}: effects.{k} = {v!r} must be true or false")
    switches = expand_switches(dict(node), where)
    for k, halves in registry.legacy_switches().items():
        if k in node:
            notes.append(f"effects.{k} (the switch before issue 35) read as {' and '.join(halves)} = "
                         f"{node[k]}")
    return switches


def _default_switch(eff: Effect, given: dict[str, tuple[float, str]], legacy: bool,
                    values: Mapping[str, float], period: float) -> tuple[Any, str | None]:
    """An omitted switch and the load note it needs: on when a parameter of the effect is given with
    a non-absent value (new format), or the pre-family format's default (legacy format; a mode needs
    its parameters); off, with the reason, when the effect is too fast for the sample period
    (:attr:`Effect.negligible`)."""
    modelled = any(p.key in given and given[p.key][0] != p.absent for p in eff.params)
    if not legacy:
        switch = eff.on if modelled else eff.off
    elif eff.modes and eff.legacy_default == eff.on:
        switch = eff.on if all(p.key in given for p in eff.params) else eff.off
    else:
        switch = eff.legacy_default
    why = eff.negligible(values, period) if eff.negligible and eff.is_on(switch) else None
    return (eff.off, f"effects.{eff.name} = {eff.off}: {why}") if why else (switch, None)


def rig_from_dict(data: dict[str, Any], where: str = "<dict>") -> Rig:
    """Build a :class:`Rig` from the parsed YAML structure of a rig file (module doc).

    Raises
    ------
    RigFileError
        On a missing required section or key, a wrong unit, a missing source, a non-number, a key
        the family does not have, an effect the family cannot have, or a value outside its
        physical range; the message names ``where`` and the key.
    """
    if not isinstance(data, dict):
        raise RigFileError(f"{where}: top level must be a mapping, got {type(data).__name__}")
    unknown_top = sorted(set(data) - TOP_LEVEL_KEYS)
    if unknown_top:
        raise RigFileError(
            f"{where}: unknown top-level key(s) {unknown_top}; expected some of {sorted(TOP_LEVEL_KEYS)}"
        )
    family, legacy = _family_of(data, where)
    fam_params = registry.family_params(family)
    for section in SECTIONS:
        need = [k for k, p in fam_params.items() if p.section == section and p.required]
        if need and not isinstance(data.get(section), dict):
            raise RigFileError(f"{where}: missing section {section!r} (a {family} rig needs {need})")
    notes: list[str] = []
    given = _read_sections(data, family, legacy, where)
    given.update(_derive_geometry(given, family, where, notes))
    sources: dict[str, str] = {}
    values: dict[str, float] = {}
    for key, p in fam_params.items():
        if key in given:
            values[key], sources[key] = given[key]
        elif p.required:
            raise RigFileError(f"{where}: missing {key} [{p.unit}] ({p.doc})")
        else:
            values[key] = float(p.absent)  # type: ignore[arg-type]
            sources[key] = DEFAULT if p.setting else NOT_MODELLED
            status = "default" if p.setting else "not modelled"
            notes.append(f"{key}: {status}, {p.absent:g} {p.unit} ({p.doc})")
    period, sources["sample_period"] = _read_quantity(data.get("sample_period"), "sample_period", "s", where)
    if period <= 0:
        raise RigFileError(f"{where}: sample_period = {period} must be > 0")
    switches = _read_switches(data, where, notes)
    fam = registry.family(family)
    for eff in registry.effects():
        if eff.name not in switches:
            applies = eff.applies_to(fam) is None
            switches[eff.name], note = (_default_switch(eff, given, legacy, values, period) if applies
                                        else (eff.off, None))
            notes += [note] if note else []
    try:
        return Rig(
            name=str(data.get("name", Path(where).stem)),
            description=str(data.get("description", "")),
            sample_period=period,
            effects=Effects(**switches),
            sources=sources,
            family=family,
            load_notes=tuple(notes),
            **_sections(family, values),
        )
    except RigFileError as exc:
        raise RigFileError(f"{where}: {exc}") from None


def _sections(family: str, values: dict[str, float]) -> dict[str, Any]:
    out = {}
    for section in SECTIONS:
        cls = section_class(family, section)
        out[section] = cls(**{f.name: values[f"{section}.{f.name}"] for f in fields(cls)})
    return out


def rig_to_dict(rig: Rig) -> dict[str, Any]:
    """Inverse of :func:`rig_from_dict`: the minimal form (units and sources included).

    Written: the family; every parameter whose source is not :data:`NOT_MODELLED`/:data:`DEFAULT`
    or whose value differs from its absent value; the switches that differ from what the written
    parameters imply.
    """
    out: dict[str, Any] = {"name": rig.name, "description": rig.description}
    out["sample_period"] = {
        "value": rig.sample_period, "unit": "s",
        "source": rig.sources.get("sample_period", "") or "set in code",
    }
    written: dict[str, tuple[float, str]] = {}
    for section in SECTIONS:
        node: dict[str, Any] = {"family": rig.family} if section == "actuator" else {}
        for key, p in registry.family_params(rig.family).items():
            if p.section != section:
                continue
            value, source = rig.value(key), rig.sources.get(key, SET_IN_CODE)
            if _status(source) in ("not modelled", "default") and value == p.absent:
                continue
            if _status(source) in ("not modelled", "default"):
                source = SET_IN_CODE
            written[key] = (value, source)
            node[p.name] = {"value": value, "unit": p.unit, "source": source}
        if node:
            out[section] = node
    fam = registry.family(rig.family)
    switches = {}
    values = rig.values()
    for eff in registry.effects():
        if eff.applies_to(fam) is None:
            value = getattr(rig.effects, eff.name)
            implied, _ = _default_switch(eff, written, False, values, rig.sample_period)
            if value != implied:
                switches[eff.name] = value
    out["effects"] = switches
    return out


def load_rig(name_or_path: str | Path) -> Rig:
    """Load a rig file by path or by the name of a shipped rig (e.g. ``"thesis_rig"``).

    The rig's :attr:`Rig.load_notes` (and :meth:`Rig.load_report`) say what was stated, derived,
    not modelled or defaulted.

    Raises
    ------
    RigFileError
        If the file does not exist, is not valid YAML, holds a YAML alias or is above the size limit
        (:mod:`aeropend_sim.files.safe_yaml`) or violates the format.
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
        text, where = None, str(path)
    try:
        data = parse_yaml(text, where, "a rig file") if text is not None else load_yaml(path, "a rig file")
    except YamlRefusedError as exc:
        raise RigFileError(str(exc)) from None
    except yaml.YAMLError as exc:
        raise RigFileError(f"{where}: not valid YAML: {exc}") from exc
    return rig_from_dict(data, where)


def save_rig(rig: Rig, path: str | Path) -> None:
    """Write a rig file (YAML, the minimal form) that :func:`load_rig` reads back to an equal :class:`Rig`."""
    text = yaml.safe_dump(rig_to_dict(rig), sort_keys=False, allow_unicode=True)
    Path(path).write_text(text, encoding="utf-8")


def shipped_rigs() -> list[str]:
    """Names of the rig files shipped with ``aeropend_sim``."""
    folder = resources.files("aeropend_sim") / "rigs"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))
