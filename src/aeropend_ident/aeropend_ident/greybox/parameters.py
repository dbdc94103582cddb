"""The parameters of a grey-box fit: their specs (bounds, parametrisation, scale), the rig-frame offset.

A parameter is addressed as ``"section.field"`` of :class:`aeropend_sim.params.Rig` plus
:data:`THETA_OFFSET` (θ_model = θ_recorded + θ_offset, :func:`rig_theta_offset`); its
:class:`ParameterSpec` comes from the declaration of the component or effect that owns it
(:func:`parameter_spec`); :func:`default_parameters` is the set a θ-only recording determines and
:func:`apply_parameters` writes values into a rig. Used by :mod:`aeropend_ident.greybox.fit`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from aeropend_ident.errors import IdentificationError
from aeropend_sim.components import registry
from aeropend_sim.components.base import Effect
from aeropend_sim.model import plant_model
from aeropend_sim.params import Rig, RigFileError
from aeropend_sim.recording_frame import FrameError, RecordingFrame, read_recording_frame

#: Name of the angle-offset parameter: θ_model = θ_recorded + θ_offset [rad].
THETA_OFFSET = "theta_offset"


#: Parameters that never reach θ (sensor model) and cannot be fitted.
_NOT_FITTABLE_SECTIONS = ("sensors",)


def rig_theta_offset(rig_ref: str | Path) -> float:
    """Nominal angle offset θ_model − θ_recorded [rad] declared by a rig file.

    Rig files may carry an optional top-level block (ignored by
    :func:`aeropend_sim.params.load_rig`)::

        recording_frame:
          theta_offset: {value: 1.5707963, unit: rad, source: "..."}
          theta_scale: {value: 1.0, unit: "1", source: "..."}   # optional sensor gain

    for rigs whose sensor zero is not the model's θ = 0 (centre of mass below the pivot), e.g.
    a see-saw that measures from the horizontal; θ_recorded = theta_scale·(θ_model − theta_offset)
    (``theta_scale`` is written by the gap diagnosis when it finds a sensor-gain error, see
    :func:`rig_theta_scale`).

    Parameters
    ----------
    rig_ref : str or Path
        Shipped rig name (``"jahoyosr_rig"``) or path to a ``.yaml`` rig file.

    Returns
    -------
    float
        The offset [rad]; 0.0 if the file has no ``recording_frame`` block.

    Raises
    ------
    IdentificationError
        If the file cannot be found or read, or the block is malformed (wrong unit, no source,
        not a number).
    """
    return _recording_frame(rig_ref).offset


def rig_theta_scale(rig_ref: str | Path) -> float:
    """Angle-sensor gain s [1] of a rig file's ``recording_frame.theta_scale`` (1.0 if absent).

    See :func:`rig_theta_offset` for the block. Raises :class:`IdentificationError` as it does,
    and if s is not > 0.
    """
    return _recording_frame(rig_ref).scale


def _recording_frame(rig_ref: str | Path) -> RecordingFrame:
    """The rig file's ``recording_frame`` (:mod:`aeropend_sim.recording_frame`), errors as ours."""
    try:
        return read_recording_frame(rig_ref)
    except FrameError as exc:
        raise IdentificationError(str(exc)) from exc


@dataclass(frozen=True)
class ParameterSpec:
    """How one parameter is fitted.

    Attributes
    ----------
    name : str
        ``"section.field"`` or :data:`THETA_OFFSET`.
    unit : str
        SI unit (from the rig field metadata).
    initial : float
        Starting value (rig file or override).
    lower, upper : float
        Bounds in parameter units (``lower < upper``).
    log : bool
        Fitted as log(p) (strictly positive parameters).
    scale : float
        Parameter units per optimiser unit of a linear parameter (unused for log parameters).

    Notes
    -----
    Optimiser coordinates start at 1 at the lower bound: z = 1 + ln(p/lower) (log) or
    z = 1 + (p − lower)/scale (linear). :func:`scipy.optimize.least_squares` takes relative
    finite-difference steps (``diff_step``·|z|), which would collapse for a coordinate at or near 0
    (a dead zone or Coulomb term of 0, a log-parameter of 1); z ≥ 1 keeps every step well above
    the simulator's integration tolerance.
    """

    name: str
    unit: str
    initial: float
    lower: float
    upper: float
    log: bool
    scale: float

    def to_z(self, value: float) -> float:
        """Optimiser coordinate (>= 1 inside the bounds) of a parameter value."""
        if self.log:
            return 1.0 + math.log(value / self.lower)
        return 1.0 + (float(value) - self.lower) / self.scale

    def from_z(self, z: float) -> float:
        """Parameter value of an optimiser coordinate."""
        if self.log:
            return self.lower * math.exp(z - 1.0)
        return self.lower + (float(z) - 1.0) * self.scale

    def dp_dz(self, value: float) -> float:
        """Derivative of the parameter with respect to its coordinate at ``value``."""
        return value if self.log else self.scale


def _field_meta(name: str, rig: Rig) -> tuple[str, str, Any]:
    """(section, field, dataclasses.Field) of a ``"section.field"`` name, or raise."""
    section, _, fname = name.partition(".")
    sections = [f.name for f in fields(rig) if dataclasses.is_dataclass(getattr(rig, f.name))
                and f.name != "effects" and f.name not in _NOT_FITTABLE_SECTIONS]
    if section not in sections:
        raise IdentificationError(
            f"parameter {name!r}: unknown or non-fittable section {section!r}; expected "
            f"'{THETA_OFFSET}' or 'section.field' with section in {sections}"
        )
    for f in fields(getattr(rig, section)):
        if f.name == fname:
            return section, fname, f
    known = sorted(f.name for f in fields(getattr(rig, section)))
    raise IdentificationError(
        f"parameter {name!r}: {section} has no field {fname!r}; expected one of {known}"
    )


def parameter_spec(
    name: str,
    rig: Rig,
    theta_offset: float = 0.0,
    initial: float | None = None,
    bounds: tuple[float, float] | None = None,
) -> ParameterSpec:
    """Fit specification (bounds, parametrisation, scale) of one parameter.

    Parameters
    ----------
    name : str
        ``"section.field"`` (e.g. ``"pendulum.c_over_J"``) or :data:`THETA_OFFSET`.
    rig : Rig
        Supplies the initial value and the unit; the parameter's effect must be switched on.
    theta_offset : float
        Initial angle offset [rad] (for :data:`THETA_OFFSET`).
    initial : float, optional
        Overrides the rig's value as starting point.
    bounds : (float, float), optional
        Overrides the physical bounds.

    Raises
    ------
    IdentificationError
        On an unknown name, a parameter whose effect is switched off, a non-positive start for
        a log parameter, or an initial value outside the bounds.
    """
    if name == THETA_OFFSET:
        x0 = float(theta_offset if initial is None else initial)
        lo, hi = bounds if bounds is not None else (x0 - math.pi / 2, x0 + math.pi / 2)
        spec = ParameterSpec(name, "rad", x0, float(lo), float(hi), False, 0.1)
    else:
        section, fname, f = _field_meta(name, rig)
        need = _switch_needed(name, rig)
        if need is not None:
            raise IdentificationError(
                f"parameter {name!r} does not affect the output of rig {rig.name!r}: it needs "
                f"effects.{need[0]} = {need[1]!r} (is {getattr(rig.effects, need[0])!r})"
            )
        x0 = float(getattr(getattr(rig, section), fname) if initial is None else initial)
        declared = f.metadata["param"].fit
        if declared is not None:
            lo_b, hi_b, log = declared.lower, declared.upper, declared.log
        else:
            lo_b, hi_b, log = None, None, bool(f.metadata.get("positive"))
        if log and x0 <= 0.0:
            if name == "actuator.lag_time_constant":
                x0 = 0.05  # switched on with T_a = 0: start from a typical small-motor lag
            else:
                raise IdentificationError(
                    f"parameter {name!r} starts at {x0!r}; expected > 0 (it is fitted as a logarithm)"
                )
        if lo_b is None:
            lo_b = x0 * 1e-3 if log else (0.0 if f.metadata.get("nonneg") else x0 - 10.0 * abs(x0) - 1.0)
        if hi_b is None:
            hi_b = x0 * 1e3 if log else max(10.0 * abs(x0), 1.0) + x0
        lo, hi = bounds if bounds is not None else (lo_b, hi_b)
        typical = declared.scale if declared is not None else None
        scale = 1.0 if log else (typical or max(abs(x0), 0.01 * (hi - lo), 1e-3))
        spec = ParameterSpec(name, f.metadata["unit"], x0, float(lo), float(hi), bool(log), float(scale))
    if not spec.lower < spec.upper:
        raise IdentificationError(f"parameter {name!r}: bounds {spec.lower!r} .. {spec.upper!r} are empty")
    if spec.log and spec.lower <= 0.0:
        raise IdentificationError(
            f"parameter {name!r}: lower bound {spec.lower!r} must be > 0 (log parameter)"
        )
    if not spec.lower <= spec.initial <= spec.upper:
        raise IdentificationError(
            f"parameter {name!r}: initial value {spec.initial!r} {spec.unit} outside the bounds "
            f"[{spec.lower!r}, {spec.upper!r}]"
        )
    return spec


def _switch_needed(name: str, rig: Rig) -> tuple[str, Any] | None:
    """The effect switch (name, value) parameter ``name`` needs to reach the output of ``rig``, or
    None when it does: its owner effect must be on, and a drive map it belongs to must not be
    superseded by an effect's map (the ideal map's v_supply while ``hbridge_map`` is on)."""
    owner = registry.owners()[name]
    if isinstance(owner, Effect):
        return None if getattr(rig.effects, owner.name) == owner.on else (owner.name, owner.on)
    pname = name.partition(".")[2]
    drive = plant_model(rig).assembly.slots.get("drive", ())
    if len(drive) > 1 and any(pname in t.param_names for t in drive[:-1]):
        top = next(e for e in registry.effects() if any(t is drive[-1] for t in e.terms))
        return top.name, top.off
    return None


def default_parameters(rig: Rig, theta_offset: float = 0.0) -> list[str]:
    """Default fitted set for θ-only data (see the module docstring).

    The same for every actuator family: the rod is common to all of them, L/J absorbs the whole
    thrust scale of the drive (an H-bridge map, an amplifier's gain or an ESC's throttle map times
    K_q), and the switched-on effects add their parameters only when the rig has them (an ESC has
    no dead zone of its own: its idle throttle is part of its map).

    Parameters
    ----------
    rig : Rig
    theta_offset : float
        The rig's recording-frame offset [rad]; a non-zero value adds :data:`THETA_OFFSET`.
    """
    names = ["pendulum.mgd_over_J", "pendulum.c_over_J", "pendulum.L_over_J"]
    e = rig.effects
    if not e.rod_viscous_friction:
        names.remove("pendulum.c_over_J")
    if e.dead_zone:
        names.append("actuator.dead_zone")
    if e.actuator_lag:
        names.append("actuator.lag_time_constant")
    if e.input_delay:
        names.append("actuator.input_delay")
    if e.rod_coulomb_friction:
        names.append("pendulum.coulomb_over_J")
    if theta_offset != 0.0:
        names.append(THETA_OFFSET)
    return names


def apply_parameters(
    rig: Rig, values: Mapping[str, float], theta_offset: float = 0.0
) -> tuple[Rig, float]:
    """Rig and angle offset with some parameters replaced.

    A changed :data:`THETA_OFFSET` moves the end stops (written in the model frame) by the same
    amount, so they stay at their recorded-frame angles: the stops are fixed to the sensor, the
    offset only says where gravity's "down" is.

    Parameters
    ----------
    rig : Rig
    values : mapping
        ``{name: value}`` with names as in :func:`parameter_spec`.
    theta_offset : float
        The offset [rad] that ``rig``'s end stops are written for.

    Returns
    -------
    (Rig, float)
        The new rig and the new offset.

    Raises
    ------
    IdentificationError
        On an unknown name or a value the rig format rejects.
    """
    per_section: dict[str, dict[str, float]] = {}
    offset = float(theta_offset)
    for name, v in values.items():
        if name == THETA_OFFSET:
            offset = float(v)
            continue
        section, fname, _ = _field_meta(name, rig)
        per_section.setdefault(section, {})[fname] = float(v)
    shift = offset - float(theta_offset)
    if shift != 0.0:
        p = per_section.setdefault("pendulum", {})
        p["theta_min"] = p.get("theta_min", rig.pendulum.theta_min) + shift
        p["theta_max"] = p.get("theta_max", rig.pendulum.theta_max) + shift
    try:
        for section, kv in per_section.items():
            rig = rig.with_params(section, **kv)
    except RigFileError as exc:
        raise IdentificationError(f"parameter values rejected by the rig format: {exc}") from exc
    return rig, offset

