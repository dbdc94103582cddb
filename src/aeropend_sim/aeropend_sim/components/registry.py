"""The registry: every component, family and effect declared under ``aeropend_sim.components``.

Discovery is automatic and the same for shipped and lab-written parts: a module that defines a
module-level ``COMPONENT``, ``FAMILY`` or ``EFFECT`` is registered when it lies below this package
(:func:`pkgutil.walk_packages`), when an installed package names it under the entry-point group
:data:`ENTRY_POINT_GROUP` (a lab's own effects and families, ``pip install``-ed), or when it is
handed to :func:`register` (a script, a test). Adding an effect, a family or a component is one
module and no list to edit. Every declaration is checked when it is registered
(:func:`check_declarations`): a term of an effect that reads another effect's parameter, a family
without exactly one drive map, a name that does not exist are refused then, with the part's name.
Lists are sorted by ``order``.

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
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import cache
from importlib.metadata import entry_points
from pathlib import Path
from types import ModuleType
from typing import Any

from aeropend_sim.components.base import (
    INPUTS,
    PARTS,
    SLOT_INPUTS,
    Component,
    Diagnosis,
    Effect,
    Family,
    Param,
    Part,
)

#: Family of a rig file that does not name one (every rig file before issue 35).
DEFAULT_FAMILY = "dc_hbridge"
#: Entry-point group of lab-written parts: each entry names a module defining ``COMPONENT``,
#: ``FAMILY`` and/or ``EFFECT``, e.g. in a lab package's pyproject.toml
#: ``[project.entry-points."aeropend.components"] motor_heating = "mylab.motor_heating"``.
ENTRY_POINT_GROUP = "aeropend.components"
#: Slots whose terms must have an inverse (steady-state design runs them backwards).
INVERTIBLE = ("duty", "drive", "thrust", "gear", "rotor_response")
#: Every family is built of one part of each of these kinds.
FAMILY_KINDS = frozenset(PARTS)

_registered: list[Part] = []
_derived: list[Any] = []


def derived(fn: Callable[..., Any]) -> Any:
    """:func:`functools.cache` for a function whose result is built from the registry, here or in
    another module (the rig format's validation plan, the compiled layouts): :func:`refresh` clears
    every such cache, so a part registered later is seen everywhere."""
    cached = cache(fn)
    _derived.append(cached)
    return cached


class RegistryError(LookupError):
    """An unknown family, component, effect or parameter name, or a declaration the registry refuses."""


def module_parts(module: ModuleType) -> list[Part]:
    """The parts a module declares (its ``FAMILY``, ``COMPONENT``, ``EFFECT``)."""
    return [d for name in ("FAMILY", "COMPONENT", "EFFECT") if (d := getattr(module, name, None)) is not None]


def _discovered() -> list[Part]:
    package = __name__.rpartition(".")[0]  # aeropend_sim.components
    found: list[Part] = []
    for info in pkgutil.walk_packages([str(Path(__file__).parent)], prefix=package + "."):
        found += module_parts(importlib.import_module(info.name))
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            module = ep.load()
        except Exception as exc:  # a broken plug-in is named, never skipped silently
            raise RegistryError(f"plug-in {ep.name!r} ({ep.value}, entry point {ENTRY_POINT_GROUP!r}) "
                                f"cannot be imported: {exc}") from exc
        if not isinstance(module, ModuleType) or not module_parts(module):
            raise RegistryError(f"plug-in {ep.name!r} ({ep.value}) must name a module defining COMPONENT, "
                                "FAMILY or EFFECT")
        found += module_parts(module)
    return found


@derived
def _declarations() -> tuple[tuple[Part, ...], tuple[Family, ...], tuple[Effect, ...]]:
    found = [*_discovered(), *_registered]
    families = [p for p in found if isinstance(p, Family)]
    effects = [p for p in found if isinstance(p, Effect)]
    components = [p for p in found if not isinstance(p, Family | Effect)]
    names = [p.name for p in found]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise RegistryError(f"declared twice: {dup}")
    key = lambda p: (p.order, p.name)  # noqa: E731
    out = (tuple(sorted(components, key=key)), tuple(sorted(families, key=key)),
           tuple(sorted(effects, key=key)))
    check_declarations(*out)
    return out


def check_declarations(components: Iterable[Part], families: Iterable[Family],
                       effects: Iterable[Effect]) -> None:
    """Refuse declarations that do not fit together, naming the part (run at every registration).

    Checked: each term's inputs are its slot's (:data:`SLOT_INPUTS`) and its parameters exist; an
    effect's terms read its own parameters and the components', never another effect's (which,
    switched off, hold their absent values); terms of :data:`INVERTIBLE` slots have an inverse;
    ``families``, ``refuses`` and ``usual_effects`` name parts that exist; each family is built of
    one part of every kind in :data:`FAMILY_KINDS` and has exactly one drive map (from
    :data:`INPUTS`).

    Raises
    ------
    RegistryError
        The first problem found, with the part's name.
    """
    components, families, effects = tuple(components), tuple(families), tuple(effects)
    everything = (*components, *families, *effects)
    names = {par.name for p in everything for par in p.params}
    effect_of = {par.name: e.name for e in effects for par in e.params}
    fam_names = {f.name for f in families}
    eff_names = {e.name for e in effects}
    for p in everything:
        own = {par.name for par in p.params}
        for term in p.terms:
            foreign = set(term.inputs) - set(term.states) - set(SLOT_INPUTS[term.slot])
            if foreign:
                raise RegistryError(f"{p.name}: term {term.label!r} in slot {term.slot!r} reads "
                                    f"{sorted(foreign)}; that slot gives {list(SLOT_INPUTS[term.slot])}")
            unknown = [a for a in term.param_names if a not in names]
            if unknown:
                raise RegistryError(f"{p.name}: term {term.label!r} reads unknown parameter(s) {unknown}")
            others = sorted(a for a in term.param_names if a not in own and a in effect_of)
            if isinstance(p, Effect) and others:
                raise RegistryError(f"effect {p.name}: term {term.label!r} reads {others}, parameter(s) of "
                                    f"effect {effect_of[others[0]]}; an effect's terms read its own "
                                    "parameters and the components' (always there), never another "
                                    "effect's (switched off, they hold their absent values)")
            if term.slot in INVERTIBLE and term.inverse is None:
                raise RegistryError(f"{p.name}: term {term.label!r} in slot {term.slot!r} needs an inverse")
        missing = sorted(set(p.families or ()) - fam_names)
        if missing:
            raise RegistryError(f"{p.name}: families {missing} do not exist; families are "
                                f"{sorted(fam_names)}")
    for fam in families:
        for what, named in (("refuses", fam.refuses), ("usual_effects", fam.usual_effects)):
            missing = sorted(set(named) - eff_names)
            if missing:
                raise RegistryError(f"family {fam.name}: {what} names {missing}, not effects; effects are "
                                    f"{sorted(eff_names)}")
        if fam.drive not in INPUTS:
            raise RegistryError(f"family {fam.name}: drive {fam.drive!r} is not an input ({list(INPUTS)})")
        built = _built(fam, components)
        drives = [p.name for p in built for t in p.terms if t.slot == "drive"]
        if len(drives) != 1:
            raise RegistryError(f"family {fam.name}: {len(drives)} drive maps ({drives}); a family has "
                                "exactly one, in its own module")
        kinds = FAMILY_KINDS - {p.part for p in built}
        if kinds:
            raise RegistryError(f"family {fam.name}: no {sorted(kinds)} part applies to it (parts: "
                                f"{[p.name for p in built]})")


def _built(fam: Family, components: Iterable[Part]) -> list[Part]:
    """The family and the components that apply to it (:meth:`Part.applies_to`), unsorted."""
    return [fam, *(c for c in components if c.applies_to(fam) is None)]


def refresh() -> None:
    """Discover again (a plug-in installed in a running process) and drop every cache built from
    the registry (every :func:`derived` function, here and elsewhere)."""
    for fn in _derived:
        fn.cache_clear()


def register(*parts: Part | ModuleType) -> None:
    """Register lab-written parts (or modules declaring them) the way shipped ones are found.

    Parameters
    ----------
    *parts : Component, Family, Effect or module
        The declarations (a module: its ``COMPONENT``, ``FAMILY``, ``EFFECT``).

    Raises
    ------
    RegistryError
        If a declaration does not fit (:func:`check_declarations`) or a name is taken, or for an
        effect once :mod:`aeropend_sim.params` is imported (the rig format's ``effects`` section is
        made once: a lab's effects come through :data:`ENTRY_POINT_GROUP`, found at the registry's
        first use); the registry is then as it was.
    """
    new: list[Part] = []
    for p in parts:
        got = module_parts(p) if isinstance(p, ModuleType) else [p]
        if not got or not all(isinstance(q, Component | Effect) for q in got):
            raise RegistryError(f"register: {p!r} is not a Component, Family, Effect or a module "
                                "declaring one")
        new += got
    _registered.extend(new)
    refresh()
    try:
        _declarations()
        owners()
        late = [q.name for q in new if isinstance(q, Effect)]
        if late and "aeropend_sim.params" in sys.modules:
            raise RegistryError(f"register: effect(s) {late} after the rig format was built "
                                "(aeropend_sim.params is imported: its effects section is made once); name "
                                f"the module under the entry-point group {ENTRY_POINT_GROUP!r}, or register "
                                "before loading any rig")
    except Exception:
        del _registered[len(_registered) - len(new):]
        refresh()
        raise


def unregister(*names: str) -> None:
    """Remove parts added with :func:`register` (by name); shipped and entry-point parts stay."""
    _registered[:] = [p for p in _registered if p.name not in names]
    refresh()


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


@derived
def legacy_switches() -> dict[str, tuple[str, ...]]:
    """Pre-issue-35 switch -> the effects it now stands for (``viscous_friction`` -> rod and rotor)."""
    out: dict[str, list[str]] = {}
    for e in effects():
        if e.legacy_switch:
            out.setdefault(e.legacy_switch, []).append(e.name)
    return {k: tuple(v) for k, v in out.items()}


@dataclass(frozen=True)
class Resolved:
    """A family resolved against the registry once: what a rig of it is built of.

    Attributes
    ----------
    family : Family
    parts : tuple of Part
        The family and the components of such a rig (its non-optional parts), by order.
    effects : tuple of Effect
        The effects that apply to it, by order.
    params : dict
        Its parameters (the parts' and the applicable effects'), key -> :class:`Param`.
    """

    family: Family
    parts: tuple[Part, ...]
    effects: tuple[Effect, ...]
    params: dict[str, Param]


@derived
def resolved(name: str) -> Resolved:
    """The family called ``name`` with its parts, effects and parameters (:class:`Resolved`): what
    the model, the compiled source and the rig format read of a family, resolved once.

    Raises
    ------
    RegistryError
        If there is no such family (the message lists the families).
    """
    fam = family(name)
    parts = tuple(sorted(_built(fam, components()), key=lambda p: (p.order, p.name)))
    effs = tuple(e for e in effects() if e.applies_to(fam) is None)
    return Resolved(fam, parts, effs, {par.key: par for p in (*parts, *effs) for par in p.params})


def family_parts(name: str) -> tuple[Part, ...]:
    """The family and the components of a rig of family ``name`` (its non-optional parts), by order."""
    return resolved(name).parts


def family_effects(name: str) -> tuple[Effect, ...]:
    """The effects that apply to a rig of family ``name``, by order."""
    return resolved(name).effects


@derived
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


@derived
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


def family_params(name: str) -> dict[str, Param]:
    """Parameters a rig of family ``name`` has (its parts' and applicable effects'), key -> Param."""
    return resolved(name).params


@derived
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


@derived
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
