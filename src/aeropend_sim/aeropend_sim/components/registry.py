"""The registry: every component, family and effect declared under ``aeropend_sim.components``.

Discovery is automatic: every module below this package that defines a module-level
``COMPONENT``, ``FAMILY`` or ``EFFECT`` is registered (:func:`pkgutil.walk_packages`), so adding
an effect is one new module and no list to edit. Lists are sorted by ``order``.

Readers (the rig format, the model, the docs tables, the grey-box fit, the gap diagnosis) ask the
registry, never a list of their own:

>>> from aeropend_sim.components import registry
>>> registry.effect("rotor_viscous_friction").params[0].key
'motor.B_m'
>>> registry.family("esc").drive
'omega_sp'
"""

from __future__ import annotations

import importlib
import pkgutil
from functools import cache
from pathlib import Path

from aeropend_sim.components.base import Component, Diagnosis, Effect, Family, Param, Part

#: Family of a rig file that does not name one (every rig file before issue 35).
DEFAULT_FAMILY = "dc_hbridge"


class RegistryError(LookupError):
    """An unknown family, component, effect or parameter name."""


@cache
def _declarations() -> tuple[tuple[Part, ...], tuple[Family, ...], tuple[Effect, ...]]:
    package = __name__.rpartition(".")[0]  # aeropend_sim.components
    components: list[Part] = []
    families: list[Family] = []
    effects: list[Effect] = []
    for info in pkgutil.walk_packages([str(Path(__file__).parent)], prefix=package + "."):
        module = importlib.import_module(info.name)
        if (d := getattr(module, "FAMILY", None)) is not None:
            families.append(d)
        if (d := getattr(module, "COMPONENT", None)) is not None:
            components.append(d)
        if (d := getattr(module, "EFFECT", None)) is not None:
            effects.append(d)
    names = [p.name for p in (*components, *families, *effects)]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise RegistryError(f"declared twice: {dup}")
    key = lambda p: (p.order, p.name)  # noqa: E731
    return (tuple(sorted(components, key=key)), tuple(sorted(families, key=key)),
            tuple(sorted(effects, key=key)))


def families() -> tuple[Family, ...]:
    """Every actuator family, by order."""
    return _declarations()[1]


def components() -> tuple[Component, ...]:
    """Every non-family component, by order."""
    return _declarations()[0]  # type: ignore[return-value]


def effects() -> tuple[Effect, ...]:
    """Every effect, by order (the order they are listed and applied in)."""
    return _declarations()[2]


def parts() -> tuple[Part, ...]:
    """Families, components and effects, by order."""
    return tuple(sorted((*families(), *components(), *effects()), key=lambda p: (p.order, p.name)))


def family(name: str) -> Family:
    """The family called ``name``.

    Raises
    ------
    RegistryError
        If there is none (the message lists the families).
    """
    for f in families():
        if f.name == name:
            return f
    raise RegistryError(f"unknown actuator family {name!r}; expected one of {[f.name for f in families()]}")


def effect(name: str) -> Effect:
    """The effect whose switch is ``name``.

    Raises
    ------
    RegistryError
        If there is none (the message lists the switches).
    """
    for e in effects():
        if e.name == name:
            return e
    raise RegistryError(f"unknown effect {name!r}; expected one of {[e.name for e in effects()]}")


@cache
def legacy_switches() -> dict[str, tuple[str, ...]]:
    """Pre-issue-35 switch -> the effects it now stands for (``viscous_friction`` -> rod and rotor)."""
    out: dict[str, list[str]] = {}
    for e in effects():
        if e.legacy_switch:
            out.setdefault(e.legacy_switch, []).append(e.name)
    return {k: tuple(v) for k, v in out.items()}


@cache
def family_parts(name: str) -> tuple[Part, ...]:
    """The family and the components of a rig of family ``name`` (its non-optional parts), by order."""
    fam = family(name)
    comps = [c for c in components() if c.families is None or name in c.families]
    return tuple(sorted((fam, *comps), key=lambda p: (p.order, p.name)))


@cache
def family_effects(name: str) -> tuple[Effect, ...]:
    """The effects that apply to a rig of family ``name``, by order."""
    fam = family(name)
    return tuple(e for e in effects() if e.applies_to(fam) is None)


@cache
def owners() -> dict[str, Part]:
    """Parameter key -> the component or effect that declares it.

    Raises
    ------
    RegistryError
        If two declarations declare the same key or the same parameter name (names are the
        arguments of term functions, so they are unique over the registry).
    """
    out: dict[str, Part] = {}
    by_name: dict[str, str] = {}
    for p in parts():
        for par in p.params:
            if par.key in out:
                raise RegistryError(f"parameter {par.key} declared by both {out[par.key].name} and {p.name}")
            if par.name in by_name:
                raise RegistryError(f"parameter name {par.name!r} used by both {by_name[par.name]} and "
                                    f"{par.key}")
            out[par.key] = p
            by_name[par.name] = par.key
    return out


@cache
def params() -> dict[str, Param]:
    """Every parameter of the registry, key -> Param, in declaration order of their owners."""
    return {par.key: par for p in parts() for par in p.params}


def param(key: str) -> Param:
    """The parameter ``"section.name"``.

    Raises
    ------
    RegistryError
        If no component or effect declares it.
    """
    try:
        return params()[key]
    except KeyError:
        raise RegistryError(f"no component or effect declares the parameter {key!r}") from None


@cache
def family_params(name: str) -> dict[str, Param]:
    """Parameters a rig of family ``name`` has (its parts' and applicable effects'), key -> Param."""
    return {par.key: par for p in (*family_parts(name), *family_effects(name)) for par in p.params}


@cache
def diagnoses(family_name: str | None = None) -> tuple[Diagnosis, ...]:
    """The gap diagnosis' hypotheses (:class:`Diagnosis`, catalog and drift), by catalog order.

    ``family_name``: only those of the parts that belong on a rig of that family (a back-EMF error on an
    ESC rig is not a hypothesis: its part says why, :meth:`Part.applies_to`).

    Raises
    ------
    RegistryError
        On an unknown family, or two parts declaring the same diagnosis name.
    """
    fam = None if family_name is None else family(family_name)
    out: dict[str, Diagnosis] = {}
    for p in parts():
        if fam is not None and p.applies_to(fam) is not None:
            continue
        for d in p.diagnoses:
            if d.name in out:
                raise RegistryError(f"diagnosis {d.name!r} declared twice")
            out[d.name] = d
    return tuple(sorted(out.values(), key=lambda d: (d.order, d.name)))


@cache
def diagnosis_owner(name: str) -> Part:
    """The component or effect that declares the diagnosis ``name``.

    Raises
    ------
    RegistryError
        If no part declares it (the message lists the names).
    """
    for p in parts():
        for d in p.diagnoses:
            if d.name == name:
                return p
    raise RegistryError(f"unknown diagnosis {name!r}; expected one of {[d.name for d in diagnoses()]}")


def families_with(key: str) -> tuple[str, ...]:
    """Names of the families whose rigs have parameter ``key``."""
    return tuple(f.name for f in families() if key in family_params(f.name))
