"""Functional core of the hardware bridge (no rclpy): units, clock mapping, watchdog, stats.

* :class:`Calibration` converts raw sample frames to a contract :class:`~aeropend_sim.contract.Sample`
  in SI units with the constants of a rig YAML file (``sensors`` LSBs, ``motor.gear_ratio``).
* :class:`ClockMapper` maps the MCU's 32-bit µs clock to ROS time: offset from the lower
  envelope of (host receive time − MCU time), drift by a least-squares line through the
  per-window minima; stamps stay strictly increasing.
* :class:`SequenceTracker` counts lost frames from 16-bit sequence gaps.
* :class:`FirmwareHandshake` recognises the protocol-1 firmware from its sample stream (the
  lifecycle bridge's configure step).
* :class:`CommandWatchdog` forces duty 0 after controller silence.
* :class:`Backoff` paces reconnection attempts.
* :class:`BridgeStats` collects the diagnostics counters.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from aeropend_bridge.protocol import (
    ABSENT_I16,
    ABSENT_U32,
    FLAG_ANGLE_INVALID,
    FLAG_ANGLE_UNHOMED,
    TIMER4_TICK_S,
    SampleFrame,
)
from aeropend_sim.contract import Sample, validate_duty

TWO_PI = 2.0 * math.pi


class BridgeConfigError(ValueError):
    """A bridge parameter or calibration constant is invalid."""


class FirmwareError(RuntimeError):
    """The serial port cannot be opened or does not carry the aeropend firmware's protocol."""


@dataclass(frozen=True)
class Calibration:
    """Raw-count -> SI conversion of sample frames (see ``firmware/PROTOCOL.md``).

    Attributes
    ----------
    i_a_lsb : float
        Armature current per ADC count [A] (rig ``sensors.i_a_quantum``); 0: not measured (NaN).
    v_a_lsb : float
        Armature voltage per differential ADC count [V] (rig ``sensors.v_a_quantum``); 0: not
        measured (NaN).
    theta_lsb : float
        Angle per ADC count [rad] (rig ``sensors.theta_quantum``, 2π/1024).
    theta_offset : float
        Angle [rad] read when the rod hangs down (subtracted, result wrapped to (−π, π]).
    gear_ratio : float
        Rotor speed / propeller speed (rig ``motor.gear_ratio``).
    tick_s : float
        Timer4 tick [s].
    pulses_per_rev : int
        IR pulses per propeller revolution.
    homing : bool
        The firmware homes its encoder on the index (HELLO channel
        :data:`~aeropend_bridge.protocol.CH_INDEX`): until the first index edge (flag
        :data:`~aeropend_bridge.protocol.FLAG_ANGLE_UNHOMED`) θ is unknown in the rod's frame (NaN).
    """

    i_a_lsb: float
    v_a_lsb: float
    theta_lsb: float
    theta_offset: float = 0.0
    gear_ratio: float = 1.0
    tick_s: float = TIMER4_TICK_S
    pulses_per_rev: int = 1
    homing: bool = False

    def __post_init__(self) -> None:
        for name in ("i_a_lsb", "v_a_lsb", "theta_lsb", "gear_ratio", "tick_s"):
            v = getattr(self, name)
            zero_ok = name in ("i_a_lsb", "v_a_lsb") and v == 0  # a channel the rig does not measure
            if not (math.isfinite(v) and v > 0) and not zero_ok:
                raise BridgeConfigError(f"calibration {name} = {v!r} must be a finite positive number")
        if not math.isfinite(self.theta_offset):
            raise BridgeConfigError(f"calibration theta_offset = {self.theta_offset!r} is not finite")
        if self.pulses_per_rev < 1:
            raise BridgeConfigError(f"pulses_per_rev = {self.pulses_per_rev} must be >= 1")

    @classmethod
    def from_rig(cls, rig: object, theta_offset: float = 0.0) -> Calibration:
        """Build from a loaded rig (:func:`aeropend_sim.params.load_rig`)."""
        s = rig.sensors  # type: ignore[attr-defined]
        return cls(i_a_lsb=float(s.i_a_quantum), v_a_lsb=float(s.v_a_quantum),
                   theta_lsb=float(s.theta_quantum), theta_offset=float(theta_offset),
                   gear_ratio=float(rig.motor.gear_ratio))  # type: ignore[attr-defined]

    def homed(self, f: SampleFrame) -> bool:
        """Whether the frame's θ is in the rod's frame: always, unless the firmware homes on an
        encoder index it has not seen yet."""
        return not (self.homing and f.flags & FLAG_ANGLE_UNHOMED)

    def to_sample(self, f: SampleFrame, stamp_ns: int, duty: float | None = None) -> Sample:
        """Convert a sample frame to SI units.

        θ̇ is not measured (NaN); so are the channels the frame marks absent
        (:data:`~aeropend_bridge.protocol.ABSENT_I16`, :data:`~aeropend_bridge.protocol.ABSENT_U32`)
        and those the rig does not measure (LSB 0): NaN, never 0. ``duty`` is the applied τ
        (:meth:`aeropend_bridge.family.CommandMap.applied`); default the H-bridge's ``duty / 255``.
        θ is NaN while an index-homing encoder has not seen its index (:meth:`homed`).
        """
        theta = f.theta * self.theta_lsb - self.theta_offset
        theta = math.remainder(theta, TWO_PI)
        if theta == -math.pi:
            theta = math.pi
        if not self.homed(f):
            theta = math.nan
        if f.period == ABSENT_U32:
            omega_prop = math.nan
        elif f.period > 0:
            omega_prop = TWO_PI / (f.period * self.tick_s * self.pulses_per_rev)
        else:
            omega_prop = 0.0
        i_a = math.nan if f.i_a == ABSENT_I16 or self.i_a_lsb == 0 else f.i_a * self.i_a_lsb
        v_a = math.nan if f.v_a == ABSENT_I16 or self.v_a_lsb == 0 else f.v_a * self.v_a_lsb
        return Sample(
            stamp_ns=int(stamp_ns), theta=theta, theta_dot=math.nan,
            omega_rotor=omega_prop * self.gear_ratio, omega_prop=omega_prop,
            i_a=i_a, v_a=v_a, duty=f.duty / 255.0 if duty is None else duty,
        )


@dataclass
class SequenceTracker:
    """Count frames lost on the line from 16-bit sequence numbers.

    Attributes
    ----------
    received, lost, resets : int
        Frames seen, frames missing (sum of gaps), and jumps treated as an MCU restart
        (gap > ``max_gap`` or backwards).
    """

    max_gap: int = 1000
    received: int = 0
    lost: int = 0
    resets: int = 0
    _last: int | None = None

    def update(self, seq: int) -> int:
        """Register ``seq``; return the number of frames missing just before it."""
        self.received += 1
        gap = 0
        if self._last is not None:
            d = (seq - self._last - 1) & 0xFFFF
            if d <= self.max_gap:
                gap = d
                self.lost += d
            else:
                self.resets += 1
        self._last = seq
        return gap

    def restart(self) -> None:
        """Forget the last sequence number (after a reconnect)."""
        self._last = None


@dataclass
class FirmwareHandshake:
    """Recognise the protocol-1 acquisition firmware from the sample frames it streams.

    Protocol version 1 (``firmware/PROTOCOL.md``) has no version frame; its version is the frame
    layout and the firmware's clock: a SAMPLE frame is 19 bytes with a valid CRC (checked by the
    decoder), ``seq`` counts up by one per frame and ``t_us`` is the Timer1 overflow count times
    ``period_us`` (2040 µs), so consecutive frames are ``divider · 2040`` µs apart with
    ``divider`` in 1..255. ``needed`` consecutive frames that satisfy this identify the firmware;
    a wrong baud rate, another sketch or a different firmware version does not produce them.

    Attributes
    ----------
    needed : int
        Consecutive consistent frames required.
    period_us : int
        Timer1 overflow period of the firmware [µs].
    frames : int
        Sample frames offered so far.
    run, longest : int
        Current and longest run of consecutive consistent frames.
    """

    needed: int = 8
    period_us: int = 2040
    frames: int = 0
    run: int = 0
    longest: int = 0
    _last: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.needed < 2:
            raise BridgeConfigError(f"handshake needs at least 2 frames, got {self.needed}")

    def update(self, seq: int, t_us: int) -> bool:
        """Offer one sample frame's ``seq`` and ``t_us``; return whether the firmware is recognised."""
        self.frames += 1
        if self._last is None:
            self.run = 1
        else:
            dseq = (seq - self._last[0]) & 0xFFFF
            dt = (t_us - self._last[1]) & 0xFFFFFFFF
            steady = dseq == 1 and dt % self.period_us == 0 and 1 <= dt // self.period_us <= 255
            self.run = self.run + 1 if steady else 1
        self._last = (seq, t_us)
        self.longest = max(self.longest, self.run)
        return self.recognised

    @property
    def recognised(self) -> bool:
        """True once ``needed`` consecutive consistent frames were seen."""
        return self.longest >= self.needed


@dataclass
class ClockMapper:
    """Map MCU timestamps (32-bit µs, wrapping) to ROS time [ns].

    Each frame gives ``d = host_receive_ns − mcu_ns`` = true offset + transmission latency ≥
    true offset. The minimum of ``d`` per window of ``window_s`` is the best offset estimate of
    that window; a least-squares line through the last ``windows`` minima tracks the relative
    drift of the two clocks. Before the first window closes, the running minimum is used.

    Parameters
    ----------
    window_s : float
        Length of one minimum window [s] of MCU time.
    windows : int
        Number of window minima in the drift fit.
    """

    window_s: float = 1.0
    windows: int = 30
    _wraps: int = 0
    _last_raw: int | None = None
    _win_start: int | None = None
    _win_min: float = math.inf
    _win_min_t: int = 0
    _mins: deque = field(default_factory=deque)
    _slope: float = 0.0
    _intercept: float | None = None
    _t_ref: int = 0
    _last_stamp: int = -1
    resets: int = 0

    def reset(self) -> None:
        """Start over (MCU restarted or serial link reconnected)."""
        self._wraps = 0
        self._last_raw = None
        self._win_start = None
        self._win_min = math.inf
        self._mins.clear()
        self._slope = 0.0
        self._intercept = None
        self.resets += 1

    def unwrap(self, t_us: int) -> int:
        """MCU time [ns] from the wrapping 32-bit µs counter."""
        if self._last_raw is not None and t_us < self._last_raw and self._last_raw - t_us > 2**31:
            self._wraps += 1
        self._last_raw = t_us
        return (self._wraps * 2**32 + t_us) * 1000

    @property
    def drift_ppm(self) -> float:
        """Estimated rate of the host clock relative to the MCU clock − 1 [ppm]."""
        return self._slope * 1e6

    def offset_ns(self, mcu_ns: int) -> float:
        """Current offset estimate ROS − MCU [ns] at MCU time ``mcu_ns``."""
        if self._intercept is None:
            return self._win_min
        return self._intercept + self._slope * (mcu_ns - self._t_ref)

    def update(self, t_us: int, host_ns: int) -> int:
        """Register a frame received at ``host_ns`` (ROS time); return its stamp [ns]."""
        mcu = self.unwrap(t_us)
        d = host_ns - mcu
        if self._win_start is None:
            self._win_start = mcu
        if d < self._win_min:
            self._win_min, self._win_min_t = d, mcu
        if mcu - self._win_start >= self.window_s * 1e9:
            self._mins.append((self._win_min_t, self._win_min))
            while len(self._mins) > self.windows:
                self._mins.popleft()
            self._fit()
            self._win_start = mcu
            self._win_min = d
            self._win_min_t = mcu
        off = self.offset_ns(mcu)
        if d < off:  # a frame can never arrive before it was sampled: lower the estimate
            off = d
            if self._intercept is not None:
                self._intercept -= self.offset_ns(mcu) - d
        stamp = round(mcu + off)
        if stamp <= self._last_stamp:
            stamp = self._last_stamp + 1
        self._last_stamp = stamp
        return stamp

    def _fit(self) -> None:
        pts = list(self._mins)
        self._t_ref = pts[-1][0]
        if len(pts) < 3:
            self._slope = 0.0
            self._intercept = min(p[1] for p in pts)
            return
        n = len(pts)
        tm = sum(p[0] for p in pts) / n
        dm = sum(p[1] for p in pts) / n
        sxx = sum((p[0] - tm) ** 2 for p in pts)
        sxy = sum((p[0] - tm) * (p[1] - dm) for p in pts)
        slope = sxy / sxx if sxx > 0 else 0.0
        # Lower envelope: shift the line down to touch the lowest minimum.
        intercept = min(p[1] - slope * (p[0] - self._t_ref) for p in pts)
        self._slope, self._intercept = slope, intercept


def firmware_trips_since(before: int | None, now: int) -> int:
    """Trips of the firmware's own command watchdog between two STATUS frames.

    Parameters
    ----------
    before : int or None
        ``watchdog_trips`` of the previous STATUS frame (None: this is the first one, whose count
        may hold trips from before the bridge connected: 0 is returned).
    now : int
        ``watchdog_trips`` of this one (a 16-bit counter that wraps).

    Returns
    -------
    int
        The new trips, 0..65535.
    """
    return 0 if before is None else (int(now) - int(before)) & 0xFFFF


@dataclass
class CommandWatchdog:
    """Hold the last valid duty; 0 after ``timeout_ns`` without a valid command.

    Attributes
    ----------
    accepted, rejected, trips : int
        Valid commands, invalid ones (NaN, out of range) and timeouts.
    """

    timeout_ns: int
    accepted: int = 0
    rejected: int = 0
    trips: int = 0
    _duty: float = 0.0
    _last_ns: int | None = None
    _tripped: bool = True

    def offer(self, value: float, now_ns: int) -> str | None:
        """Offer a command; return ``None`` if accepted, else the rejection reason."""
        try:
            duty = validate_duty(value)
        except ValueError as exc:
            self.rejected += 1
            return str(exc)
        self.accepted += 1
        self._duty = duty
        self._last_ns = now_ns
        self._tripped = False
        return None

    def disarm(self) -> None:
        """Forget the held command: duty 0 until the next valid one (counters kept)."""
        self._duty = 0.0
        self._last_ns = None
        self._tripped = True

    def duty(self, now_ns: int) -> float:
        """Duty to apply at ``now_ns`` (0 before the first command and after a timeout)."""
        if self._last_ns is None:
            return 0.0
        if now_ns - self._last_ns > self.timeout_ns:
            if not self._tripped:
                self._tripped = True
                self.trips += 1
            return 0.0
        return self._duty

    @property
    def tripped(self) -> bool:
        """True while the duty is forced to 0 (no command yet, or timed out)."""
        return self._tripped


@dataclass
class Backoff:
    """Exponential reconnection delay: ``initial_s`` doubling up to ``max_s``."""

    initial_s: float = 0.05
    max_s: float = 2.0
    _next: float = 0.0

    def __post_init__(self) -> None:
        if not (0 < self.initial_s <= self.max_s):
            raise BridgeConfigError(
                f"backoff initial {self.initial_s!r} s / max {self.max_s!r} s: need 0 < initial <= max")
        self._next = self.initial_s

    def next_delay(self) -> float:
        """Delay before the next attempt [s] (then doubles)."""
        d = self._next
        self._next = min(self._next * 2.0, self.max_s)
        return d

    def reset(self) -> None:
        """Connection succeeded: start from ``initial_s`` again."""
        self._next = self.initial_s


@dataclass
class RateMeter:
    """Frames per second over a sliding window of host time."""

    window_ns: int = 1_000_000_000
    _times: deque = field(default_factory=deque)

    def tick(self, now_ns: int) -> None:
        """Register one frame at ``now_ns``."""
        self._times.append(now_ns)
        while self._times and now_ns - self._times[0] > self.window_ns:
            self._times.popleft()

    def rate(self, now_ns: int) -> float:
        """Frames/s in the window ending at ``now_ns``."""
        while self._times and now_ns - self._times[0] > self.window_ns:
            self._times.popleft()
        return len(self._times) / (self.window_ns * 1e-9)


@dataclass
class BridgeStats:
    """Counters reported on ``/diagnostics``.

    ``angle_invalid`` counts samples whose AS5040 SSI read-out the firmware rejected (flag
    bit 4, ``ANGLE=ssi`` build: θ repeats the last valid angle; encoder builds: an impossible
    quadrature transition, or counts missed between two index edges); ``angle_valid`` is False
    while the latest sample carries that flag. ``angle_homed`` is False while the latest sample's θ
    is not in the rod's frame (an index-homing encoder before its first index edge).
    """

    samples: int = 0
    status_frames: int = 0
    reconnects: int = 0
    connected: bool = False
    angle_invalid: int = 0
    angle_valid: bool = True
    angle_homed: bool = True
    mcu_status: dict[str, int] = field(default_factory=dict)

    def count_sample(self, f: SampleFrame, homed: bool = True) -> None:
        """Register one received sample frame (sample and angle-validity counters); ``homed``:
        :meth:`Calibration.homed` of the frame."""
        self.samples += 1
        self.angle_homed = homed
        self.angle_valid = not f.flags & FLAG_ANGLE_INVALID
        if not self.angle_valid:
            self.angle_invalid += 1

    def diagnostics(self, rate_hz: float, seq: SequenceTracker, decoder_errors: dict[str, int],
                    watchdog: CommandWatchdog, clock: ClockMapper) -> list[tuple[str, str]]:
        """Key/value pairs of the diagnostic status (all strings, as diagnostic_msgs wants)."""
        kv = [
            ("connected", str(self.connected)),
            ("rate_hz", f"{rate_hz:.2f}"),
            ("samples", str(self.samples)),
            ("angle_invalid_samples", str(self.angle_invalid)),
            ("angle_homed", str(self.angle_homed)),
            ("sequence_gaps_lost_frames", str(seq.lost)),
            ("sequence_resets", str(seq.resets)),
            ("reconnects", str(self.reconnects)),
            ("commands_accepted", str(watchdog.accepted)),
            ("commands_rejected", str(watchdog.rejected)),
            ("watchdog_trips", str(watchdog.trips)),
            ("clock_drift_ppm", f"{clock.drift_ppm:.1f}"),
        ]
        kv += [(f"decoder_{k}", str(v)) for k, v in decoder_errors.items()]
        kv += [(f"mcu_{k}", str(v)) for k, v in self.mcu_status.items()]
        return kv
