"""``rig new``: a rig file for a lab's own rig, every parameter of its family marked for a person.

Read from the component registry (never a second list): the family's parameters
(:func:`aeropend_sim.components.registry.family_params`), each with its unit, meaning, absent
value, fit bounds and how a lab measures it (:attr:`aeropend_sim.components.base.Param.measure`).
Each parameter is marked

* **stated** — given by the lab (``--stated NAME=VALUE[unit]``, unit checked and converted);
* **to be fitted** — the family's base parameters and the parameters of the effects a lab's rig
  usually has (its family's ``usual_effects``): a clearly marked starting value (the declaration's
  :attr:`~aeropend_sim.components.base.Param.typical`, or one derived from the stated geometry)
  with the source :data:`aeropend_sim.params.TO_BE_FITTED`, which ``rig fit`` replaces;
* **not modelled** — the other effects: written as a commented-out to-be-fitted line, so a person
  switches one on by removing the ``#``.

Every line carries the physical meaning and a plausible range (:func:`plausible_range`: the fit
bounds the declaration gives, or a range derived from the stated geometry and masses, e.g.
J ≥ m·d² for the inertia, mgd/J ≤ g/d). ``rig fit`` searches the same ranges.

When the lab states the rod's geometry (``pendulum.mass``, ``com_distance``, ``thrust_arm``), the
file keeps it and marks the inertia ``pendulum.inertia`` to be fitted: mgd/J and L/J then follow
from the geometry and one fitted inertia (the loader's derivation), and the thrust scale is no
longer confounded with L/J.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence

from aeropend_sim.components import registry
from aeropend_sim.components.base import SECTIONS, Effect, Param
from aeropend_sim.components.pendulum.rod import G
from aeropend_sim.files.safe_yaml import parse_yaml
from aeropend_sim.params import TO_BE_FITTED, RigFileError, rig_from_dict
from aeropend_sim.rigfile.units import UnitError, convert

#: Base parameters a lab states (or leaves at their absent value) rather than fits, with the reason.
STATED_ONLY: dict[str, str] = {
    "motor.gear_ratio": "stated or 1 (direct drive): θ and thrust cannot tell it from K_q",
}
#: Geometry keys that make the rod's parameters derivable (the inertia is then fitted).
GEOMETRY_NEEDED = ("pendulum.mass", "pendulum.com_distance", "pendulum.thrust_arm")
INERTIA = "pendulum.inertia"
SAMPLE_PERIOD = "sample_period"
#: Source of a value given with ``--stated``.
STATED = "stated by the lab (rig new --stated)"
#: Starting sample period [s] when none is stated (rig fit sets it from the recordings).
DEFAULT_SAMPLE_PERIOD = 0.01
#: Relative span of a plausible range around a typical value without declared fit bounds.
TYPICAL_SPAN = 100.0

HEADER = """\
# Rig file of an aeropendulum with the actuator family {family}, written by `rig new` (aeropend).
# Every number is {{value, unit, source}} in SI units; each parameter is marked
#   STATED        given by the lab (a measurement, a data sheet)
#   TO BE FITTED  a starting value only: `rig fit {file} RECORDINGS... -o fitted.yaml` fits it
#   NOT MODELLED  commented out (the effect is off): remove the '#' to have it fitted too
#                 (and set its switch under effects: to true)
# with its meaning and a plausible range. `rig check {file}` shows the state of every parameter.
"""


def _geometry() -> dict[str, Param]:
    return {p.key: p for c in registry.components() for p in getattr(c, "geometry", ())}


def stated_keys(family: str) -> dict[str, Param]:
    """Keys ``--stated`` accepts for a family: its parameters, the rod's geometry (and
    ``sample_period``, which is not a Param)."""
    return {**registry.family_params(family), **_geometry()}


def parse_stated(family: str, items: Sequence[str]) -> dict[str, float]:
    """``["pendulum.mass=0.12kg", "motor.T_m=80ms"]`` -> ``{key: value in the registry unit}``.

    Raises
    ------
    RigFileError
        On a malformed item, a key the family has not (the message says why), a unit that does not
        convert, a value its declaration refuses, a key given twice, or an incomplete geometry.
    """
    keys = stated_keys(family)
    out: dict[str, float] = {}
    for item in items:
        key, eq, text = str(item).partition("=")
        key = key.strip()
        if not eq or not key or not text.strip():
            raise RigFileError(f"--stated {item!r}: expected NAME=VALUE[unit], e.g. pendulum.mass=0.12kg")
        if key in out:
            raise RigFileError(f"--stated {key} given twice")
        if key == SAMPLE_PERIOD:
            unit, param = "s", None
        elif key in keys:
            param = keys[key]
            unit = param.unit
        elif key in registry.params():
            owner = registry.owners()[key]
            why = owner.applies_to(registry.family(family)) or owner.why_not
            raise RigFileError(f"--stated {key}: not a parameter of a {family} rig ({owner.name}: {why})")
        else:
            raise RigFileError(f"--stated {key}: unknown parameter; a {family} rig has {sorted(keys)} and "
                               f"{SAMPLE_PERIOD}")
        try:
            value = convert(text, unit, f"--stated {key}")
        except UnitError as exc:
            raise RigFileError(str(exc)) from None
        if param is not None and (msg := param.violation(value)):
            raise RigFileError(f"--stated: {msg}")
        if param is None and not value > 0.0:
            raise RigFileError(f"--stated {SAMPLE_PERIOD} = {value!r} s must be > 0")
        out[key] = value
    geo = [k for k in GEOMETRY_NEEDED if k in out]
    if (geo or INERTIA in out) and len(geo) != len(GEOMETRY_NEEDED):
        missing = [k for k in GEOMETRY_NEEDED if k not in out]
        given = sorted(set(geo) | ({INERTIA} & set(out)))
        raise RigFileError(f"--stated gives {given} but not {missing}: the rod's geometry is used as a whole "
                           "(mass, com_distance and thrust_arm, optionally inertia), or state "
                           "pendulum.mgd_over_J / L_over_J instead")
    derived = _derived_by_geometry(out)
    both = sorted(set(derived) & set(out))
    if both:
        raise RigFileError(f"--stated gives {both} and the geometry they are derived from; give one or the "
                           "other")
    return out


def _derived_by_geometry(stated: Mapping[str, float]) -> dict[str, float]:
    """Rod parameters that the stated geometry determines (with a placeholder inertia)."""
    if not all(k in stated for k in GEOMETRY_NEEDED):
        return {}
    rod = next(c for c in registry.components() if getattr(c, "geometry", ()))
    given = {k: stated[k] for k in (*GEOMETRY_NEEDED, INERTIA) if k in stated}
    given.setdefault(INERTIA, inertia_start(stated))
    return {k: v for k, (v, _) in rod.derive(given).items()}  # type: ignore[misc]


def inertia_start(stated: Mapping[str, float]) -> float:
    """Starting inertia [kg·m²]: 1.5 × the point mass m·d² (a rod, motor and propeller)."""
    return 1.5 * stated["pendulum.mass"] * stated["pendulum.com_distance"] ** 2


def plausible_range(key: str, stated: Mapping[str, float]) -> tuple[float, float, str]:
    """(lower, upper, how) of a parameter to be fitted, in its unit.

    From the stated geometry where it bounds the parameter (J ≥ m·d² about the pivot; mgd/J ≤ g/d),
    else the declaration's fit bounds (:class:`aeropend_sim.components.base.FitBounds`), else
    typical ÷/× :data:`TYPICAL_SPAN`. ``rig fit`` searches this range.
    """
    if key == INERTIA:
        j0 = stated["pendulum.mass"] * stated["pendulum.com_distance"] ** 2
        return j0, 100.0 * j0, "J ≥ m·d² (the point mass about the pivot) up to 100 m·d²"
    if key == "pendulum.mgd_over_J" and "pendulum.com_distance" in stated:
        top = G / stated["pendulum.com_distance"]
        return 0.01 * top, top, "≤ g/d (a point mass at the stated com_distance), down to 1 % of it"
    if key == "actuator.v_offset":
        span = 0.2 * stated.get("actuator.v_max", 10.0)
        return -span, span, "±20 % of the amplifier's full scale"
    if key == "actuator.idle_duty":
        return 0.0, 0.6, "0 … 0.6 of the command range"
    if key == "actuator.curve_exponent":
        return 0.3, 3.0, "0.3 … 3 (1: a linear ESC)"
    p = registry.param(key)
    fb = p.fit
    if fb is not None and fb.lower is not None and fb.upper is not None:
        return fb.lower, fb.upper, "the declaration's fit bounds"
    typ = p.typical if p.typical else 1.0
    return typ / TYPICAL_SPAN, typ * TYPICAL_SPAN, f"typical {typ:g} ÷/× {TYPICAL_SPAN:g}"


def start_value(key: str, stated: Mapping[str, float]) -> float:
    """The clearly marked starting value of a parameter to be fitted."""
    if key == INERTIA:
        return inertia_start(stated)
    lo, hi, _ = plausible_range(key, stated)
    p = registry.param(key)
    if p.typical is not None and lo <= p.typical <= hi:
        return float(p.typical)
    return math.sqrt(lo * hi) if lo > 0.0 else 0.5 * (lo + hi)


def roles(family: str, stated: Mapping[str, float]) -> dict[str, str]:
    """Each parameter of the family (and the rod's inertia when the geometry is stated) ->
    ``"stated"``, ``"to be fitted"``, ``"derived"`` (from the stated geometry), ``"absent"``
    (a base parameter the lab states or leaves at its absent value) or ``"not modelled"``."""
    fam_parts = {p.key for part in registry.family_parts(family) for p in part.params}
    usual = set(registry.family(family).usual_effects)
    derived = _derived_by_geometry(stated)
    out: dict[str, str] = {}
    for key, p in registry.family_params(family).items():
        owner = registry.owners()[key]
        if key in stated:
            out[key] = "stated"
        elif key in derived:
            out[key] = "derived"
        elif p.setting:
            out[key] = "default"
        elif key in fam_parts:
            out[key] = "absent" if key in STATED_ONLY else "to be fitted"
        elif isinstance(owner, Effect) and owner.name in usual:
            out[key] = "to be fitted"
        else:
            out[key] = "not modelled"
    if derived:
        out[INERTIA] = "stated" if INERTIA in stated else "to be fitted"
    return out


def _quantity(value: float, unit: str, source: str) -> str:
    return f"{{value: {value!r}, unit: {json.dumps(unit)}, source: {json.dumps(source, ensure_ascii=False)}}}"


def _entry(key: str, role: str, stated: Mapping[str, float], sources: Mapping[str, str]) -> list[str]:
    """The commented lines of one parameter in its section."""
    p = _param(key)
    name = p.name
    head = f"  # {p.symbol or name} [{p.unit}]: {p.doc}"
    if role == "stated":
        source = sources.get(key, STATED)
        return [head + " — STATED", f"  {name}: {_quantity(stated[key], p.unit, source)}"]
    if role == "to be fitted" or (role == "not modelled" and fittable(key)):
        lo, hi, how = plausible_range(key, stated)
        mark = "TO BE FITTED" if role == "to be fitted" else "NOT MODELLED (remove the '#' to fit it)"
        unit = "" if p.unit == "1" else f" {p.unit}"
        lines = [head + f" — {mark}", f"  #   plausible {lo:.4g} … {hi:.4g}{unit} ({how})"]
        if p.measure:
            lines.append(f"  #   measure: {p.measure}")
        line = f"{name}: {_quantity(start_value(key, stated), p.unit, TO_BE_FITTED)}"
        return [*lines, f"  {line}" if role == "to be fitted" else f"  # {line}"]
    return []


def fittable(key: str) -> bool:
    """Whether ``rig fit`` can fit a parameter: it reaches θ (not a sensor's) and its declaration gives
    fit bounds or a typical value."""
    p = _param(key)
    return p.section != "sensors" and not p.setting and (p.fit is not None or p.typical is not None)


def _param(key: str) -> Param:
    return registry.params().get(key) or _geometry()[key]


def new_rig_text(family: str, stated: Mapping[str, float], *, name: str = "my_rig",
                 file: str = "my_rig.yaml", sources: Mapping[str, str] | None = None) -> str:
    """The YAML text of a new rig file (module docstring): loads with
    :func:`aeropend_sim.params.load_rig`.

    Parameters
    ----------
    family : str
        Actuator family.
    stated : mapping
        ``{key: value}`` in registry units (:func:`parse_stated`).
    name, file : str
        The rig's name and the file name (quoted in the header's commands).
    sources : mapping, optional
        Sources of stated values (default "stated by the lab (rig new --stated)").

    Raises
    ------
    RigFileError
        On an unknown family, or if the text would not load (a bug: the message says which key).
    """
    registry.family(family)
    sources = dict(sources or {})
    role = roles(family, stated)
    lines = [HEADER.format(family=family, file=file).rstrip("\n"), f"name: {json.dumps(name)}",
             f"description: {json.dumps(f'{family} rig (rig new); fill in what you know, then rig fit')}"]
    if SAMPLE_PERIOD in stated:
        sp = _quantity(stated[SAMPLE_PERIOD], "s", sources.get(SAMPLE_PERIOD, STATED))
    else:
        sp = _quantity(DEFAULT_SAMPLE_PERIOD, "s", f"{TO_BE_FITTED}: the recordings' sample interval")
    lines.append(f"sample_period: {sp}")
    for section in SECTIONS:
        body: list[str] = [f"  family: {family}"] if section == "actuator" else []
        keys = [k for k in role if k.partition(".")[0] == section]
        for key in keys:
            body += _entry(key, role[key], stated, sources)
        if section == "pendulum":
            for key in GEOMETRY_NEEDED:
                if key in stated:
                    body += _entry(key, "stated", stated, sources)
        if body:
            lines.append(f"{section}:")
            lines += body
    on = [e for e in registry.family_effects(family)
          if any(role.get(p.key) in ("to be fitted", "stated") for p in e.params if not p.setting)]
    switches = [f"  {e.name}: {json.dumps(e.on)}" for e in on]
    lines += ["effects:", *switches] if switches else ["effects: {}"]
    text = "\n".join(lines) + "\n"
    try:
        rig_from_dict(parse_yaml(text, file, "a rig file"), file)
    except RigFileError as exc:  # pragma: no cover - a template that does not load is a bug here
        raise RigFileError(f"rig new wrote a file that does not load: {exc}") from exc
    return text
