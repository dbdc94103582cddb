"""Wire protocol between the ATmega2560 firmware and the host (see ``firmware/PROTOCOL.md``).

Pure Python, no rclpy. Byte-compatible with the C codec ``firmware/src/protocol.c``; both are
checked against the golden vectors in ``firmware/test_vectors.json``.

Framing: ``COBS(payload || crc16_le(payload)) || 0x00``.

* COBS (Consistent Overhead Byte Stuffing) removes every 0x00 from the frame, so 0x00 is an
  unambiguous frame delimiter: a receiver resynchronises at the next 0x00 after any error.
* CRC-16/CCITT-FALSE: polynomial 0x1021, init 0xFFFF, no reflection, xorout 0x0000
  (check value ``crc16(b"123456789") == 0x29B1``), computed over the unstuffed payload and
  appended little-endian.
* Payload byte 0 is the frame type; all multi-byte fields are little-endian.

:class:`FrameDecoder` never raises on input bytes: every malformed frame is counted in
:class:`DecoderStats` and decoding resumes at the next delimiter.
"""

from __future__ import annotations

import binascii
import math
import struct
from dataclasses import dataclass, field

#: Serial line rate [bit/s]: exact at 16 MHz with U2X (UBRR = 3), see PROTOCOL.md.
BAUD = 500_000
#: Frame delimiter.
DELIM = 0x00
#: Largest accepted *unstuffed* frame (payload + CRC) [bytes]; longer runs are dropped.
MAX_FRAME = 64

# Frame types (payload byte 0).
T_SAMPLE = 0x01
T_STATUS = 0x02
T_DUTY = 0x10
T_ENABLE = 0x11
T_RATE = 0x12
T_CALIBRATE = 0x13
T_HELLO = 0x03
T_SAMPLE_PULSE = 0x04
T_PULSE = 0x14
T_HELLO_REQ = 0x15

#: Protocol version announced in HELLO frames (version 1 had no HELLO).
PROTOCOL_VERSION = 2
#: HELLO actuator codes -> names (the rig file's ``actuator.family`` they drive).
ACTUATORS = {1: "hbridge", 2: "esc"}
#: HELLO angle-sensor codes -> names.
SENSORS = {1: "pot", 2: "ssi", 3: "encoder"}
#: HELLO channel bits.
CH_I_A = 0x01
CH_V_A = 0x02
CH_THETA = 0x04
CH_SPEED = 0x08
#: HELLO channel bit of an encoder build with its index (Z) wired: θ is absolute once homed.
CH_INDEX = 0x10
#: Wire value of an i16 channel the build does not measure (published as NaN, never 0).
ABSENT_I16 = -32768
#: Wire value of the propeller period when the build has no speed sensor.
ABSENT_U32 = 0xFFFFFFFF
#: ESC pulse-width unit on the wire [s] (Timer3 at 16 MHz / 8).
PULSE_TICK_S = 0.5e-6

#: Timer4 input-capture tick [s] (16 MHz / prescaler 64 = 4 µs).
TIMER4_TICK_S = 4e-6
#: Calibration items of :class:`Calibrate`.
CAL_I_A_OFFSET = 1
CAL_THETA_OFFSET = 2

# Sample flags.
FLAG_ENABLED = 0x01
FLAG_WATCHDOG = 0x02
FLAG_SPIKE = 0x04
FLAG_SPEED_STALE = 0x08
#: SSI build: the AS5040 read-out was rejected (parity, OCF, COF or field range); θ repeats the
#: last valid angle.
FLAG_ANGLE_INVALID = 0x10
#: SSI build: AS5040 linearity alarm (θ used, may be inaccurate).
FLAG_ANGLE_LIN = 0x20
#: Encoder build with an index (:data:`CH_INDEX`): no index edge since reset, θ counts from the
#: power-up position, not from the rod hanging at rest (same bit as :data:`FLAG_ANGLE_LIN`). In
#: such a build :data:`FLAG_ANGLE_INVALID` also marks an index edge at a count other than the
#: index's (counts were missed since the previous one; the firmware re-homed).
FLAG_ANGLE_UNHOMED = 0x20
#: θ comes from the AS5040 SSI read-out (firmware built with ``ANGLE=ssi``), else PWM -> RC -> ADC.
FLAG_ANGLE_SSI = 0x40
#: ESC build: the arming sequence is running (minimum pulse; commands are not applied yet).
FLAG_ARMING = 0x80


class ProtocolError(ValueError):
    """A frame or a field value violates the protocol."""


# --------------------------------------------------------------------------- CRC + COBS
def crc16(data: bytes | bytearray | memoryview, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0).

    Parameters
    ----------
    data : bytes-like
        Bytes to check.
    crc : int
        Initial value (0xFFFF; pass a previous result to continue).

    Returns
    -------
    int
        CRC in [0, 0xFFFF]; ``crc16(b"123456789") == 0x29B1``.

    Notes
    -----
    The standard library's ``binascii.crc_hqx`` is this CRC (CRC-CCITT, MSB first); the
    firmware's table-driven C version is checked against the same golden vectors.
    """
    return binascii.crc_hqx(bytes(data), crc)


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (result contains no 0x00; delimiter not appended).

    Same algorithm as ``cobs_encode`` in ``firmware/src/protocol.c``: a code byte gives the
    distance to the next (implicit) zero; code 0xFF marks a full 254-byte block without zero.
    """
    out = bytearray([0])
    code_idx = 0
    code = 1
    for b in bytes(data):
        if b == 0:
            out[code_idx] = code
            code_idx = len(out)
            out.append(0)
            code = 1
        else:
            out.append(b)
            code += 1
            if code == 0xFF:
                out[code_idx] = code
                code_idx = len(out)
                out.append(0)
                code = 1
    out[code_idx] = code
    return bytes(out)


def cobs_decode(data: bytes) -> bytes | None:
    """Decode one COBS-encoded frame (without delimiter); ``None`` if it is malformed."""
    out = bytearray()
    idx = 0
    n = len(data)
    while idx < n:
        code = data[idx]
        if code == 0 or idx + code > n:
            return None
        block = data[idx + 1:idx + code]
        if 0 in block:
            return None
        out += block
        idx += code
        if code != 0xFF and idx < n:
            out.append(0)
    return bytes(out)


def encode_frame(payload: bytes) -> bytes:
    """Frame ``payload``: COBS(payload + CRC16 little-endian) + 0x00 delimiter."""
    if not payload:
        raise ProtocolError("empty payload: a frame needs at least the type byte")
    if len(payload) + 2 > MAX_FRAME:
        raise ProtocolError(f"payload of {len(payload)} bytes exceeds {MAX_FRAME - 2}")
    body = bytes(payload) + struct.pack("<H", crc16(payload))
    return cobs_encode(body) + b"\x00"


# --------------------------------------------------------------------------- frame types
_SAMPLE = struct.Struct("<BHIHhHIBB")  # type seq t_us i_a v_a theta period duty flags
_STATUS = struct.Struct("<BHHHHHH")    # type rx_frames rx_errors tx_overflows wd_trips spikes angle_errors
_SAMPLE_PULSE = struct.Struct("<BHIhhHIHB")  # as _SAMPLE with a u16 applied pulse [0.5 µs] for duty
# type version actuator sensor channels frame_hz pulse_min pulse_max arm_ms silence_ms counts_per_rev
_HELLO = struct.Struct("<BBBBBHHHHHI")


@dataclass(frozen=True)
class SampleFrame:
    """MCU -> host: one acquisition sample (every TOV1 overflow, 2.048 ms).

    Attributes
    ----------
    seq : int
        Sequence number, uint16, +1 per sample sent (wraps).
    t_us : int
        MCU timestamp of the sample instant [µs], uint32 (wraps after 71.6 min).
    i_a : int
        Armature-current ADC counts (A0, 5 V reference, 10-bit, 0..1023; minus the
        calibration offset, so it may go negative down to -1023).
    v_a : int
        Armature-voltage ADC counts, differential A3−A1, 2.56 V reference, signed 10-bit
        (-512..511).
    theta : int
        Angle counts, 0..1023 ↔ 0..360°, offset-corrected mod 1024: AS5040 PWM -> RC -> ADC, or
        the AS5040 SSI word's D9..D0 in the ``ANGLE=ssi`` build (flag bit 6).
    period : int
        Propeller period in Timer4 ticks (4 µs), uint32; 0 = no valid edge pair recently.
    duty : int
        Applied OCR1 value 0..255 over the interval ending at this sample (τ = duty/255); 0 in
        an ESC build's frame (see ``pulse``).
    flags : int
        Bit 0 enabled, bit 1 watchdog tripped, bit 2 spike rejected, bit 3 speed stale,
        bit 4 angle read-out invalid (SSI word rejected, or an impossible encoder transition),
        bit 5 AS5040 linearity alarm, bit 6 angle from SSI, bit 7 ESC arming.

    A channel the build does not measure carries :data:`ABSENT_I16` (``i_a``, ``v_a``) or
    :data:`ABSENT_U32` (``period``).
    """

    seq: int
    t_us: int
    i_a: int
    v_a: int
    theta: int
    period: int
    duty: int
    flags: int = 0

    #: Applied ESC pulse [0.5 µs]; ``None`` for an H-bridge frame (see :class:`PulseSampleFrame`).
    pulse = None

    def payload(self) -> bytes:
        """Unstuffed payload (without CRC)."""
        try:
            return _SAMPLE.pack(T_SAMPLE, self.seq, self.t_us, self.i_a & 0xFFFF, self.v_a,
                                self.theta, self.period, self.duty, self.flags)
        except struct.error as exc:
            raise ProtocolError(f"sample field out of range in {self}: {exc}") from None


@dataclass(frozen=True)
class PulseSampleFrame(SampleFrame):
    """MCU -> host: the sample of an ESC build (frame type 0x04, 20 bytes).

    The :class:`SampleFrame` fields (``duty`` is 0: the build has no PWM duty) and

    Attributes
    ----------
    pulse : int
        Servo pulse applied over the interval ending at this sample [0.5 µs units].
    """

    pulse: int = 0  # type: ignore[assignment]

    def payload(self) -> bytes:
        """Unstuffed payload (without CRC)."""
        try:
            return _SAMPLE_PULSE.pack(T_SAMPLE_PULSE, self.seq, self.t_us, self.i_a, self.v_a,
                                      self.theta, self.period, self.pulse, self.flags)
        except struct.error as exc:
            raise ProtocolError(f"sample field out of range in {self}: {exc}") from None


@dataclass(frozen=True)
class StatusFrame:
    """MCU -> host: firmware counters, sent every 256 samples (all uint16, wrapping).

    ``angle_errors`` counts rejected AS5040 SSI read-outs (``ANGLE=ssi`` build; always 0 in
    the PWM-interface build, where the field was reserved).
    """

    rx_frames: int
    rx_errors: int
    tx_overflows: int
    watchdog_trips: int
    spikes: int
    angle_errors: int = 0

    def payload(self) -> bytes:
        """Unstuffed payload (without CRC)."""
        return _STATUS.pack(T_STATUS, self.rx_frames, self.rx_errors, self.tx_overflows,
                            self.watchdog_trips, self.spikes, self.angle_errors)


@dataclass(frozen=True)
class Duty:
    """Host -> MCU: duty cycle command, ``value`` = τ·65535 (uint16); feeds the watchdog."""

    value: int

    @classmethod
    def from_fraction(cls, tau: float) -> Duty:
        """Command for duty fraction ``tau`` in [0, 1].

        Raises
        ------
        ProtocolError
            If ``tau`` is NaN/inf or outside [0, 1].
        """
        t = float(tau)
        if not math.isfinite(t) or t < 0.0 or t > 1.0:
            raise ProtocolError(f"duty fraction {tau!r} is not a finite value in [0, 1]")
        return cls(round(t * 65535))

    def payload(self) -> bytes:
        """Unstuffed payload (without CRC)."""
        return struct.pack("<BH", T_DUTY, self.value)


@dataclass(frozen=True)
class Enable:
    """Host -> MCU: enable (1) / disable (0) the H-bridge output."""

    on: bool

    def payload(self) -> bytes:
        """Unstuffed payload (without CRC)."""
        return struct.pack("<BB", T_ENABLE, 1 if self.on else 0)


@dataclass(frozen=True)
class Rate:
    """Host -> MCU: send one sample every ``divider`` TOV1 overflows (1..255, 1 = 488 Hz)."""

    divider: int

    def payload(self) -> bytes:
        """Unstuffed payload (without CRC)."""
        if not 1 <= self.divider <= 255:
            raise ProtocolError(f"rate divider {self.divider} outside 1..255")
        return struct.pack("<BB", T_RATE, self.divider)


@dataclass(frozen=True)
class Calibrate:
    """Host -> MCU: set calibration ``item`` (1 = i_a zero offset, 2 = θ zero offset) in counts."""

    item: int
    value: int

    def payload(self) -> bytes:
        """Unstuffed payload (without CRC)."""
        if self.item not in (CAL_I_A_OFFSET, CAL_THETA_OFFSET):
            raise ProtocolError(f"calibration item {self.item} unknown (1 = i_a, 2 = theta)")
        if not -1024 < self.value < 1024:
            raise ProtocolError(f"calibration offset {self.value} counts outside -1023..1023")
        return struct.pack("<BBh", T_CALIBRATE, self.item, self.value)


@dataclass(frozen=True)
class HelloFrame:
    """MCU -> host: what the firmware build drives and measures (after reset, on request, and
    after every STATUS frame).

    Attributes
    ----------
    version : int
        Protocol version (2).
    actuator : int
        1 H-bridge PWM, 2 ESC servo pulse (:data:`ACTUATORS`).
    sensor : int
        1 ADC (AS5040 PWM -> RC, potentiometer), 2 AS5040 SSI, 3 quadrature encoder (:data:`SENSORS`).
    channels : int
        Measured channels, bits :data:`CH_I_A`, :data:`CH_V_A`, :data:`CH_THETA`, :data:`CH_SPEED`;
        :data:`CH_INDEX` when an encoder build has its index wired.
    frame_hz : int
        Actuator output frame rate [Hz] (H-bridge PWM 490; ESC 50..490).
    pulse_min_us, pulse_max_us : int
        ESC pulse range [µs]; the minimum is the arming / disarm pulse (0 for the H-bridge).
    arm_ms : int
        ESC: minimum pulse held after reset [ms] (0 for the H-bridge).
    silence_ms : int
        Firmware command watchdog: output off / minimum pulse this long after the last command [ms].
    counts_per_rev : int
        θ counts per revolution (1024 for ADC and SSI, lines × 4 for an encoder).
    """

    version: int
    actuator: int
    sensor: int
    channels: int
    frame_hz: int
    pulse_min_us: int
    pulse_max_us: int
    arm_ms: int
    silence_ms: int
    counts_per_rev: int

    @property
    def actuator_name(self) -> str:
        """``hbridge``, ``esc`` or ``unknown actuator <code>``."""
        return ACTUATORS.get(self.actuator, f"unknown actuator {self.actuator}")

    @property
    def sensor_name(self) -> str:
        """``pot``, ``ssi``, ``encoder`` or ``unknown sensor <code>``."""
        return SENSORS.get(self.sensor, f"unknown sensor {self.sensor}")

    def has(self, channel_bit: int) -> bool:
        """Whether the build measures the channel (a ``CH_*`` bit)."""
        return bool(self.channels & channel_bit)

    def payload(self) -> bytes:
        """Unstuffed payload (without CRC)."""
        return _HELLO.pack(T_HELLO, self.version, self.actuator, self.sensor, self.channels, self.frame_hz,
                           self.pulse_min_us, self.pulse_max_us, self.arm_ms, self.silence_ms,
                           self.counts_per_rev)


@dataclass(frozen=True)
class Pulse:
    """Host -> MCU (ESC build): servo pulse width command in 0.5 µs units; feeds the watchdog.

    The firmware clamps it to its announced range (:class:`HelloFrame` ``pulse_min_us`` ..
    ``pulse_max_us``); the H-bridge build ignores it (counted as an RX error).
    """

    half_us: int

    @classmethod
    def from_seconds(cls, width_s: float) -> Pulse:
        """Command for a pulse of ``width_s`` seconds (rounded to 0.5 µs).

        Raises
        ------
        ProtocolError
            If the width is not finite or outside 0 … 32.7675 ms.
        """
        w = float(width_s)
        if not math.isfinite(w) or not 0.0 <= w <= 0xFFFF * PULSE_TICK_S:
            raise ProtocolError(f"pulse width {width_s!r} s is not a finite value in [0, 32.7675 ms]")
        return cls(round(w / PULSE_TICK_S))

    def payload(self) -> bytes:
        """Unstuffed payload (without CRC)."""
        return struct.pack("<BH", T_PULSE, self.half_us)


@dataclass(frozen=True)
class HelloRequest:
    """Host -> MCU: ask for a :class:`HelloFrame` now (protocol-1 firmware counts it as an RX error)."""

    def payload(self) -> bytes:
        """Unstuffed payload (without CRC)."""
        return bytes([T_HELLO_REQ])


Frame = (SampleFrame | PulseSampleFrame | StatusFrame | HelloFrame | Duty | Pulse | HelloRequest | Enable
         | Rate | Calibrate)


def parse_payload(payload: bytes) -> Frame:
    """Parse a CRC-checked payload into its frame dataclass.

    Raises
    ------
    ProtocolError
        Unknown type or wrong length for the type (the message names both).
    """
    if not payload:
        raise ProtocolError("empty payload")
    t = payload[0]
    n = len(payload)

    def need(size: int, name: str) -> None:
        if n != size:
            raise ProtocolError(f"{name} frame (type 0x{t:02x}) has {n} bytes, expected {size}")

    if t == T_SAMPLE:
        need(_SAMPLE.size, "sample")
        _, seq, t_us, i_a, v_a, theta, period, duty, flags = _SAMPLE.unpack(payload)
        if i_a >= 0x8000:
            i_a -= 0x10000
        return SampleFrame(seq, t_us, i_a, v_a, theta, period, duty, flags)
    if t == T_SAMPLE_PULSE:
        need(_SAMPLE_PULSE.size, "pulse sample")
        _, seq, t_us, i_a, v_a, theta, period, pulse, flags = _SAMPLE_PULSE.unpack(payload)
        return PulseSampleFrame(seq, t_us, i_a, v_a, theta, period, 0, flags, pulse=pulse)
    if t == T_HELLO:
        need(_HELLO.size, "hello")
        return HelloFrame(*_HELLO.unpack(payload)[1:])
    if t == T_PULSE:
        need(3, "pulse")
        return Pulse(struct.unpack_from("<H", payload, 1)[0])
    if t == T_HELLO_REQ:
        need(1, "hello request")
        return HelloRequest()
    if t == T_STATUS:
        need(_STATUS.size, "status")
        return StatusFrame(*_STATUS.unpack(payload)[1:])
    if t == T_DUTY:
        need(3, "duty")
        return Duty(struct.unpack_from("<H", payload, 1)[0])
    if t == T_ENABLE:
        need(2, "enable")
        return Enable(bool(payload[1]))
    if t == T_RATE:
        need(2, "rate")
        if payload[1] == 0:
            raise ProtocolError("rate divider 0 is invalid (1..255)")
        return Rate(payload[1])
    if t == T_CALIBRATE:
        need(4, "calibrate")
        item, value = struct.unpack_from("<Bh", payload, 1)
        return Calibrate(item, value)
    raise ProtocolError(f"unknown frame type 0x{t:02x} ({n} bytes)")


def encode(frame: Frame) -> bytes:
    """Encode a frame dataclass to wire bytes (including the trailing delimiter)."""
    return encode_frame(frame.payload())


# --------------------------------------------------------------------------- decoder
@dataclass
class DecoderStats:
    """Counters of a :class:`FrameDecoder` (all monotonic)."""

    frames: int = 0
    bytes: int = 0
    cobs_errors: int = 0
    crc_errors: int = 0
    length_errors: int = 0
    type_errors: int = 0
    oversize: int = 0
    empty: int = 0
    last_error: str = ""

    @property
    def errors(self) -> int:
        """Total malformed frames (every kind)."""
        return self.cobs_errors + self.crc_errors + self.length_errors + self.type_errors + self.oversize


@dataclass
class FrameDecoder:
    """Incremental stream decoder: feed arbitrary bytes, get complete valid frames.

    Never raises on input data. Bytes before the first delimiter are discarded as a partial
    frame only if they do not form a valid frame; empty frames (``00 00``) are ignored.
    """

    max_frame: int = MAX_FRAME
    stats: DecoderStats = field(default_factory=DecoderStats)
    _buf: bytearray = field(default_factory=bytearray)
    _overflow: bool = False

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Consume ``data``; return the frames completed by it, in order."""
        out: list[Frame] = []
        data = bytes(data)
        self.stats.bytes += len(data)
        start = 0
        limit = self.max_frame + 2  # stuffed size bound: COBS adds 1 byte per 254
        while True:
            end = data.find(b"\x00", start)
            chunk = data[start:] if end < 0 else data[start:end]
            if not self._overflow:
                if len(self._buf) + len(chunk) > limit:
                    self._overflow = True
                    self._buf.clear()
                else:
                    self._buf += chunk
            if end < 0:
                break
            if self._overflow:
                self.stats.oversize += 1
                self.stats.last_error = f"frame longer than {limit} bytes"
                self._overflow = False
            else:
                frame = self._finish(bytes(self._buf))
                if frame is not None:
                    out.append(frame)
            self._buf.clear()
            start = end + 1
        return out

    def _finish(self, raw: bytes) -> Frame | None:
        s = self.stats
        if not raw:
            s.empty += 1
            return None
        body = cobs_decode(raw)
        if body is None:
            s.cobs_errors += 1
            s.last_error = f"bad COBS encoding in {len(raw)}-byte frame {raw[:8].hex()}..."
            return None
        if len(body) < 3:
            s.length_errors += 1
            s.last_error = f"frame of {len(body)} bytes is shorter than type + CRC (3)"
            return None
        payload, crc_rx = body[:-2], body[-2] | (body[-1] << 8)
        crc = crc16(payload)
        if crc != crc_rx:
            s.crc_errors += 1
            s.last_error = f"CRC mismatch: received 0x{crc_rx:04x}, computed 0x{crc:04x}"
            return None
        try:
            frame = parse_payload(payload)
        except ProtocolError as exc:
            if "unknown frame type" in str(exc):
                s.type_errors += 1
            else:
                s.length_errors += 1
            s.last_error = str(exc)
            return None
        s.frames += 1
        return frame
