"""Input kinds: how a lab logs its actuator command, and the affine map to the duty cycle τ.

The one home of the input kinds: the ``csv_import`` flags (``--input-kind``, ``--input-offset``,
``--input-span``, ``--input-law``), the preset files' keys (``input_kind``, ``input_offset``,
``input_span``, ``input_law``) and docs/csv_import.md read :data:`INPUT_KINDS`.

Every kind maps the logged value x to the duty cycle τ ∈ [0, 1] by

    τ = (x − offset) / span, clipped to [0, 1],

(then τ² for a voltage treated as an RMS value, ``law = "rms"``). ``offset`` is the logged value at
τ = 0 and ``span`` the change from τ = 0 to τ = 1, in the kind's unit. Values outside
[offset, offset + span] are clipped and counted: an ESC pulse width below the low end of its
calibrated range is τ = 0 (the ESC is armed and the motor stands still), not an error.

For an ESC, τ is the throttle as a fraction of the ESC's calibrated range (the ``esc`` actuator
family's τ, docs/model.md): a lab that calibrated its ESC to 1.1–2.3 ms states offset 1.1 ms and
span 1.2 ms. A rotor that only starts above some throttle is the rig's idle throttle τ₀
(``actuator.idle_duty``), a property of the rig fitted from data, not of the input map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aeropend_ident.errors import CsvImportError

__all__ = ["INPUT_KINDS", "LAWS", "InputKind", "InputMap", "input_map"]

#: Laws from the mapped fraction to τ: ``linear`` (τ = fraction), ``rms`` (τ = fraction²: the firmware
#: treats the logged voltage as an RMS value, e.g. AutomationShield's ``actuatorWriteVolt``).
LAWS: tuple[str, ...] = ("linear", "rms")


@dataclass(frozen=True)
class InputKind:
    """One way of logging the actuator command.

    Attributes
    ----------
    name : str
        Key (``input_kind`` in a preset, ``--input-kind`` on the command line).
    unit : str
        Unit of the logged value, of ``offset`` and of ``span``.
    meaning : str
        What the logged value is.
    offset, span : float or None
        Defaults of the map; None: the lab must state it (no default fits every rig).
    offset_meaning, span_meaning : str
        What ``offset`` / ``span`` are for this kind and how to read them off the rig.
    laws : tuple of str
        Allowed laws (:data:`LAWS`).
    bounds : (float, float) or None
        Range [offset, offset + span] must lie within (a unit mistake, e.g. µs given as ms, lands
        outside).
    """

    name: str
    unit: str
    meaning: str
    offset: float | None
    span: float | None
    offset_meaning: str
    span_meaning: str
    laws: tuple[str, ...] = ("linear",)
    bounds: tuple[float, float] | None = None


_PULSE_OFFSET = ("pulse width at zero throttle: the low end of the ESC's calibrated throttle range (the "
                 "arming pulse, e.g. 1.1 ms); anything at or below it is τ = 0")
_PULSE_SPAN = ("full-throttle minus zero-throttle pulse width of the ESC calibration (e.g. 1.2 ms for a "
               "1.1-2.3 ms range)")

#: The input kinds, by name.
INPUT_KINDS: dict[str, InputKind] = {k.name: k for k in (
    InputKind("duty", "1", "duty-cycle fraction τ", 0.0, 1.0, "value at τ = 0", "value from τ = 0 to τ = 1",
              bounds=(0.0, 1.0)),
    InputKind("percent", "%", "duty cycle in percent", 0.0, 100.0, "percent at τ = 0",
              "percent from τ = 0 to full duty", bounds=(0.0, 100.0)),
    InputKind("pwm", "counts", "PWM compare value of a timer (Arduino analogWrite 0-255, a 10-bit timer "
              "0-1023, ...)", 0.0, 255.0, "counts at τ = 0",
              "counts at full duty minus the offset: the timer's TOP (255 for analogWrite, 1023 for 10 "
              "bits)"),
    InputKind("voltage", "V", "commanded voltage of a voltage amplifier or motor driver", 0.0, None,
              "voltage at τ = 0", "voltage at full command V_max (the amplifier's range or the supply)",
              laws=LAWS),
    InputKind("pulse_width_ms", "ms", "ESC / servo pulse width in milliseconds", None, None, _PULSE_OFFSET,
              _PULSE_SPAN, bounds=(0.0, 20.0)),
    InputKind("pulse_width_us", "us", "ESC / servo pulse width in microseconds (Servo.writeMicroseconds)",
              None, None, _PULSE_OFFSET.replace("1.1 ms", "1100 us"),
              _PULSE_SPAN.replace("1.2 ms for a 1.1-2.3 ms", "1200 us for a 1100-2300 us"),
              bounds=(0.0, 20000.0)),
    InputKind("servo_deg", "deg", "Arduino Servo.write angle sent to an ESC (0-180 deg spans the ESC's "
              "calibrated pulse range)", 0.0, 180.0,
              "angle at zero throttle (the ESC's low end; 0 by default)",
              "full-throttle minus zero-throttle angle (180 by default)", bounds=(0.0, 180.0)),
)}


@dataclass(frozen=True)
class InputMap:
    """A validated affine input map τ = law(clip((x − offset) / span, 0, 1)) (:func:`input_map`)."""

    kind: InputKind
    offset: float
    span: float
    law: str = "linear"

    def duty(self, x: np.ndarray) -> tuple[np.ndarray, int, int]:
        """Duty cycle of logged values.

        Parameters
        ----------
        x : ndarray, shape (N,)
            Logged actuator values [``kind.unit``].

        Returns
        -------
        (tau, below, above)
            τ ∈ [0, 1], shape (N,), and how many values lay below ``offset`` / above
            ``offset + span`` (clipped).
        """
        ratio = (np.asarray(x, dtype=float) - self.offset) / self.span
        below, above = int((ratio < 0).sum()), int((ratio > 1).sum())
        tau = np.clip(ratio, 0.0, 1.0)
        return (tau**2 if self.law == "rms" else tau), below, above

    def describe(self) -> str:
        """The map as text, e.g. ``τ = (x − 1.1 ms) / 1.2 ms (pulse_width_ms)``."""
        u = "" if self.kind.unit == "1" else f" {self.kind.unit}"
        core = f"(x − {self.offset:g}{u}) / {self.span:g}{u}" if self.offset else f"x / {self.span:g}{u}"
        law = f"({core})²" if self.law == "rms" else core
        return f"τ = {law}, clipped to [0, 1] ({self.kind.name})"


def _number(key: str, value: object, kind: InputKind) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise CsvImportError(f"{key} = {value!r}: expected a finite number [{kind.unit}] for input_kind "
                             f"{kind.name!r}")
    return float(value)


def input_map(kind: str, offset: float | None = None, span: float | None = None, law: str = "linear",
              where: str = "") -> InputMap:
    """Validate an input map (kind, offset, span, law), defaults from :data:`INPUT_KINDS`.

    Parameters
    ----------
    kind : str
        A key of :data:`INPUT_KINDS`.
    offset, span : float, optional
        Logged value at τ = 0 and its change to τ = 1 [kind's unit]; None: the kind's default.
    law : {"linear", "rms"}
        ``rms`` only for ``voltage``.
    where : str
        Prefix of the error messages (e.g. the preset file).

    Returns
    -------
    InputMap

    Raises
    ------
    CsvImportError
        Unknown kind or law, a missing offset/span the kind has no default for, a span ≤ 0, a
        non-finite value, or a range outside the kind's bounds; the message names the key and
        what was expected.
    """
    pre = f"{where}: " if where else ""
    if kind not in INPUT_KINDS:
        raise CsvImportError(f"{pre}input_kind {kind!r}: expected one of {list(INPUT_KINDS)}")
    k = INPUT_KINDS[kind]
    if law not in k.laws:
        raise CsvImportError(f"{pre}input_law {law!r}: input_kind {kind!r} takes {' or '.join(k.laws)}")
    values = {}
    for key, given, default, meaning in (("input_offset", offset, k.offset, k.offset_meaning),
                                         ("input_span", span, k.span, k.span_meaning)):
        if given is None and default is None:
            raise CsvImportError(f"{pre}input_kind {kind!r} needs {key} [{k.unit}]: the {meaning}")
        try:
            values[key] = _number(key, default if given is None else given, k)
        except CsvImportError as exc:
            raise CsvImportError(f"{pre}{exc}") from None
    off, sp = values["input_offset"], values["input_span"]
    if not sp > 0:
        raise CsvImportError(f"{pre}input_span = {sp:g} {k.unit}: expected > 0, the {k.span_meaning}")
    if k.bounds is not None and not (k.bounds[0] <= off and off + sp <= k.bounds[1]):
        other = [o.name for o in INPUT_KINDS.values() if o.bounds and o.name != kind and o.unit != k.unit
                 and o.bounds[0] <= off and off + sp <= o.bounds[1] and o.name.startswith(kind.split("_")[0])]
        hint = f" (in {INPUT_KINDS[other[0]].unit}? that is input_kind {other[0]!r})" if other else ""
        lo, hi = k.bounds
        raise CsvImportError(f"{pre}input_offset = {off:g} and input_span = {sp:g} put the {kind} range at "
                             f"{off:g}-{off + sp:g} {k.unit}, outside {lo:g}-{hi:g} {k.unit}{hint}")
    return InputMap(k, off, sp, law)
