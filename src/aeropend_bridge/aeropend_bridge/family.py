"""What the rig drives and measures, checked against the firmware's HELLO; the one command map.

Functional core (no rclpy). A rig file names its actuator family (``actuator.family``) and may
carry a ``hardware`` block (ignored by :func:`aeropend_sim.params.load_rig`, read here)::

    hardware:
      angle_sensor: encoder            # pot (ADC), ssi (AS5040 SSI) or encoder
      counts_per_rev: {value: 4000, unit: "1", source: "1000-line encoder read x4"}
      encoder_index: true              # encoder: its index (Z) is wired (firmware ENC_INDEX build)
      pulse_offset: {value: 1.0e-3, unit: s, source: "ESC calibrated 1.0-2.0 ms"}   # esc only
      pulse_span: {value: 1.0e-3, unit: s, source: "ESC calibrated 1.0-2.0 ms"}     # esc only

* :func:`read_rig_hardware` reads it (defaults: the thesis' 1024-count angle interfaces, an ESC
  calibrated to 1.0–2.0 ms — the same offset/span vocabulary as ``csv_import``'s pulse inputs).
* :func:`check_firmware` compares it with the firmware's :class:`~aeropend_bridge.protocol.HelloFrame`
  (or a protocol-1 firmware without HELLO) and raises :class:`FamilyMismatchError` naming both sides
  before anything is armed.
* :class:`CommandMap` is the one place where the controller's τ ∈ [0, 1] becomes a wire command
  (H-bridge: DUTY τ·65535; ESC: PULSE offset + τ·span) and the applied value of a sample frame
  becomes τ again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import yaml

from aeropend_bridge.bridge_core import BridgeConfigError, FirmwareError
from aeropend_bridge.protocol import (
    CH_I_A,
    CH_INDEX,
    CH_SPEED,
    CH_THETA,
    CH_V_A,
    FLAG_ANGLE_SSI,
    PULSE_TICK_S,
    Duty,
    HelloFrame,
    Pulse,
    SampleFrame,
)
from aeropend_sim.files.safe_yaml import YamlRefusedError, load_yaml, parse_yaml

#: Rig family -> the firmware actuator that drives it (None: no aeropend firmware does).
FIRMWARE_ACTUATOR = {"dc_hbridge": "hbridge", "esc": "esc", "voltage_amplifier": None}
#: Angle sensors a rig file may name.
ANGLE_SENSORS = ("pot", "ssi", "encoder")
#: Default ESC calibration [s]: 1.0 ms = τ 0 (arming / disarm pulse), 2.0 ms = τ 1.
DEFAULT_PULSE_OFFSET_S = 1.0e-3
DEFAULT_PULSE_SPAN_S = 1.0e-3


class HardwareError(BridgeConfigError):
    """A malformed ``hardware`` block of a rig file (the message names the key)."""


class FamilyMismatchError(FirmwareError):
    """The firmware on the port does not drive or measure what the rig file says."""


@dataclass(frozen=True)
class RigHardware:
    """What a rig file says its hardware is.

    Attributes
    ----------
    rig : str
        Rig name (for messages).
    family : str
        ``actuator.family`` of the rig file.
    angle_sensor : str or None
        ``pot``, ``ssi``, ``encoder``; None: not stated (a 1024-count ADC or SSI interface).
    counts_per_rev : int or None
        Encoder counts per revolution (lines × 4); None unless stated.
    encoder_index : bool or None
        Whether the encoder's index (Z) is wired and the firmware homes on it; None: not stated.
    pulse_offset, pulse_span : float
        ESC map [s]: pulse = pulse_offset + τ·pulse_span.
    """

    rig: str
    family: str
    angle_sensor: str | None = None
    counts_per_rev: int | None = None
    encoder_index: bool | None = None
    pulse_offset: float = DEFAULT_PULSE_OFFSET_S
    pulse_span: float = DEFAULT_PULSE_SPAN_S

    @property
    def actuator(self) -> str | None:
        """The firmware actuator of the family (``hbridge``, ``esc``; None: none exists)."""
        return FIRMWARE_ACTUATOR.get(self.family)


def _quantity(block: dict, key: str, unit: str, where: str) -> float | None:
    node = block.get(key)
    if node is None:
        return None
    if not isinstance(node, dict) or set(node) - {"value", "unit", "source"}:
        raise HardwareError(f"{where}: hardware.{key} must be {{value, unit: {unit}, source}}, got {node!r}")
    if str(node.get("unit", "")) != unit:
        raise HardwareError(f"{where}: hardware.{key} has unit {node.get('unit')!r}; expected {unit!r}")
    if not str(node.get("source", "")).strip():
        raise HardwareError(f"{where}: hardware.{key} has no source")
    try:
        value = float(node["value"])
    except (KeyError, TypeError, ValueError):
        raise HardwareError(f"{where}: hardware.{key}.value {node.get('value')!r} is not a number") from None
    if not math.isfinite(value) or value <= 0:
        raise HardwareError(f"{where}: hardware.{key} = {value!r} must be a finite positive number")
    return value


def read_rig_hardware(rig_ref: str | Path, family: str, name: str | None = None) -> RigHardware:
    """The ``hardware`` block of a rig file (path to a .yaml or a shipped rig's name).

    Parameters
    ----------
    rig_ref : str or Path
        The rig file.
    family : str
        Its actuator family (``Rig.family`` of the loaded rig).
    name : str, optional
        Rig name for messages (default ``rig_ref``).

    Returns
    -------
    RigHardware
        Defaults where the block (or a key) is absent.

    Raises
    ------
    HardwareError
        If the file cannot be read or the block is malformed: an unknown key or angle sensor, a
        quantity without unit/source, a non-positive value, a fractional ``counts_per_rev``.
    """
    path = Path(rig_ref)
    where = str(rig_ref)
    try:
        if path.suffix in (".yaml", ".yml"):
            data = load_yaml(path, "a rig file") or {}
        else:
            text = (resources.files("aeropend_sim") / "rigs" / f"{rig_ref}.yaml").read_text(encoding="utf-8")
            data = parse_yaml(text, f"{rig_ref}.yaml", "a rig file") or {}
    except YamlRefusedError as exc:
        raise HardwareError(str(exc)) from None
    except (OSError, yaml.YAMLError) as exc:
        raise HardwareError(f"cannot read rig file {rig_ref!s}: {exc}") from exc
    block = data.get("hardware") or {}
    if not isinstance(block, dict):
        raise HardwareError(f"{where}: hardware must be a mapping, got {block!r}")
    unknown = sorted(set(block) - {"angle_sensor", "counts_per_rev", "encoder_index", "pulse_offset",
                                   "pulse_span"})
    if unknown:
        raise HardwareError(f"{where}: unknown hardware key(s) {unknown}; expected angle_sensor, "
                            "counts_per_rev, encoder_index, pulse_offset, pulse_span")
    index = block.get("encoder_index")
    if index is not None and not isinstance(index, bool):
        raise HardwareError(f"{where}: hardware.encoder_index {index!r} must be true or false")
    if index and block.get("angle_sensor") != "encoder":
        raise HardwareError(f"{where}: hardware.encoder_index is true but angle_sensor is "
                            f"{block.get('angle_sensor')!r}; an index belongs to an encoder")
    sensor = block.get("angle_sensor")
    if sensor is not None and sensor not in ANGLE_SENSORS:
        raise HardwareError(f"{where}: hardware.angle_sensor {sensor!r} is not one of {list(ANGLE_SENSORS)}")
    cpr = _quantity(block, "counts_per_rev", "1", where)
    if cpr is not None and cpr != int(cpr):
        raise HardwareError(f"{where}: hardware.counts_per_rev = {cpr} must be a whole number")
    offset = _quantity(block, "pulse_offset", "s", where)
    span = _quantity(block, "pulse_span", "s", where)
    return RigHardware(rig=name or str(rig_ref), family=family, angle_sensor=sensor,
                       counts_per_rev=None if cpr is None else int(cpr), encoder_index=index,
                       pulse_offset=DEFAULT_PULSE_OFFSET_S if offset is None else offset,
                       pulse_span=DEFAULT_PULSE_SPAN_S if span is None else span)


def legacy_hello(sample: SampleFrame) -> HelloFrame:
    """The HELLO a protocol-1 firmware (no HELLO frame) would send: H-bridge, every channel, the
    angle from the ADC or (flag bit 6) the AS5040 SSI read-out, 1024 counts per revolution."""
    sensor = 2 if sample.flags & FLAG_ANGLE_SSI else 1
    return HelloFrame(1, 1, sensor, CH_I_A | CH_V_A | CH_THETA | CH_SPEED, 490, 0, 0, 0, 249, 1024)


def check_firmware(hw: RigHardware, hello: HelloFrame, theta_quantum: float | None = None) -> None:
    """Refuse a firmware that does not drive or measure what the rig file says.

    Parameters
    ----------
    hw : RigHardware
        The rig file's hardware.
    hello : HelloFrame
        The firmware's announcement (:func:`legacy_hello` for protocol-1 firmware).
    theta_quantum : float, optional
        The rig's ``sensors.theta_quantum`` [rad/count]; for SSI and encoder builds it must be
        2π / counts per revolution (within 0.5 %).

    Raises
    ------
    FamilyMismatchError
        Naming the rig's and the firmware's actuator, sensor, counts, encoder index or pulse range.
    """
    fw = f"the firmware on the port drives {hello.actuator_name!r} and reads {hello.sensor_name!r}"
    want = hw.actuator
    if want is None:
        raise FamilyMismatchError(f"rig {hw.rig!r} is a {hw.family} rig: no aeropend firmware drives it "
                                  f"({fw}); a lab bridge node stands in for `bridge` (docs/hardware.md, "
                                  "bridge_check)")
    if hello.actuator_name != want:
        raise FamilyMismatchError(f"rig {hw.rig!r} is a {hw.family} rig (firmware actuator {want!r}) but "
                                  f"{fw}: flash the {want} build (firmware/README.md) or choose this rig's "
                                  "rig file")
    sensors = (hw.angle_sensor,) if hw.angle_sensor else ("pot", "ssi")
    if hello.sensor_name not in sensors:
        said = f"names angle sensor {hw.angle_sensor!r}" if hw.angle_sensor else \
            "names no hardware.angle_sensor (a 1024-count ADC or SSI interface)"
        raise FamilyMismatchError(f"rig {hw.rig!r} {said} but {fw}")
    if hw.counts_per_rev is not None and hw.counts_per_rev != hello.counts_per_rev:
        raise FamilyMismatchError(f"rig {hw.rig!r} states {hw.counts_per_rev} counts per revolution but the "
                             f"firmware counts {hello.counts_per_rev}")
    if hw.encoder_index is not None and hw.encoder_index != hello.has(CH_INDEX):
        raise FamilyMismatchError(
            f"rig {hw.rig!r} says its encoder's index is {'' if hw.encoder_index else 'not '}wired "
            f"(hardware.encoder_index: {str(hw.encoder_index).lower()}) but the firmware on the port "
            + ("has no index input: flash an ENC_INDEX build" if hw.encoder_index else
               "homes on an index (an ENC_INDEX build) and would hold the output off for ever")
            + " (firmware/README.md)")
    if theta_quantum is not None and hello.sensor_name in ("ssi", "encoder"):
        if abs(theta_quantum * hello.counts_per_rev / (2 * math.pi) - 1) > 5e-3:
            raise FamilyMismatchError(f"rig {hw.rig!r}: sensors.theta_quantum {theta_quantum:.6g} rad is not "
                                 f"2π/{hello.counts_per_rev} = {2 * math.pi / hello.counts_per_rev:.6g} rad "
                                 f"of the firmware's {hello.sensor_name}")
    if want == "esc":
        lo, hi = hw.pulse_offset * 1e6, (hw.pulse_offset + hw.pulse_span) * 1e6
        if lo < hello.pulse_min_us - 0.25 or hi > hello.pulse_max_us + 0.25:
            raise FamilyMismatchError(f"rig {hw.rig!r} maps τ 0..1 to {lo:g}..{hi:g} µs but the firmware's "
                                      f"pulse range is {hello.pulse_min_us}..{hello.pulse_max_us} µs")


@dataclass(frozen=True)
class CommandMap:
    """The one map between the controller's τ ∈ [0, 1] and the wire (DUTY or PULSE).

    Attributes
    ----------
    actuator : str
        ``hbridge`` or ``esc``.
    pulse_offset, pulse_span : float
        ESC: pulse [s] = pulse_offset + τ·pulse_span (unused for the H-bridge).
    """

    actuator: str
    pulse_offset: float = DEFAULT_PULSE_OFFSET_S
    pulse_span: float = DEFAULT_PULSE_SPAN_S

    @classmethod
    def for_rig(cls, hw: RigHardware) -> CommandMap:
        """The map of a rig file (its actuator and, for an ESC, its pulse calibration).

        Raises
        ------
        FamilyMismatchError
            If no firmware drives the rig's family.
        """
        if hw.actuator is None:
            raise FamilyMismatchError(f"rig {hw.rig!r}: no aeropend firmware drives a {hw.family} rig")
        return cls(hw.actuator, hw.pulse_offset, hw.pulse_span)

    def command(self, tau: float) -> Duty | Pulse:
        """The wire command for τ.

        Raises
        ------
        ProtocolError
            If τ is not finite or outside [0, 1].
        """
        if self.actuator == "esc":
            Duty.from_fraction(tau)  # the same validation of τ
            return Pulse.from_seconds(self.pulse_offset + float(tau) * self.pulse_span)
        return Duty.from_fraction(tau)

    def off(self) -> Duty | Pulse:
        """Motor off: DUTY 0, or the ESC's zero-throttle (disarm) pulse."""
        return self.command(0.0)

    def tau_of_pulse(self, pulse_s: float) -> float:
        """τ of an ESC pulse width: (pulse − pulse_offset) / pulse_span, clipped to [0, 1].

        Parameters
        ----------
        pulse_s : float
            Pulse width [s] (a width below ``pulse_offset``, e.g. 0 before the first pulse, is τ 0).

        Returns
        -------
        float
            τ ∈ [0, 1] [1].
        """
        tau = (float(pulse_s) - self.pulse_offset) / self.pulse_span
        return min(1.0, max(0.0, tau))

    def applied(self, f: SampleFrame) -> float:
        """τ applied over the interval ending at sample ``f`` (ESC: from its pulse, clipped to [0, 1])."""
        if self.actuator == "esc" and f.pulse is not None:
            return self.tau_of_pulse(f.pulse * PULSE_TICK_S)
        return f.duty / 255.0
