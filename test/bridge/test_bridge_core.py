"""Unit tests of the bridge's functional core: units, clock mapping, sequence gaps, watchdog."""

from __future__ import annotations

import math
import random

import pytest

from aeropend_bridge.bridge_core import (
    Backoff,
    BridgeConfigError,
    BridgeStats,
    Calibration,
    ClockMapper,
    CommandWatchdog,
    FirmwareHandshake,
    RateMeter,
    SequenceTracker,
    firmware_trips_since,
)
from aeropend_bridge.protocol import FLAG_ANGLE_INVALID, FLAG_ANGLE_SSI, FLAG_ENABLED, SampleFrame
from aeropend_sim.params import load_rig


@pytest.fixture(scope="module")
def cal() -> Calibration:
    return Calibration.from_rig(load_rig("thesis_rig"), theta_offset=math.pi)


def test_calibration_from_rig_units(cal: Calibration) -> None:
    rig = load_rig("thesis_rig")
    # 512 counts = 180° = the offset -> θ = 0; 768 counts -> +π/2.
    f = SampleFrame(seq=1, t_us=0, i_a=338, v_a=-200, theta=768, period=15000, duty=255, flags=1)
    s = cal.to_sample(f, 123)
    assert s.stamp_ns == 123
    assert s.theta == pytest.approx(math.pi / 2, abs=1e-4)
    assert s.i_a == pytest.approx(338 * rig.sensors.i_a_quantum)
    assert s.i_a == pytest.approx(1.0, rel=1e-3)  # 338 counts ≈ 1.0 A on the thesis rig
    assert s.v_a == pytest.approx(-1.0)  # 200 counts × 5 mV
    assert s.omega_prop == pytest.approx(2 * math.pi / 0.06)  # 15000 × 4 µs = 60 ms per rev
    assert s.omega_rotor == pytest.approx(s.omega_prop * rig.motor.gear_ratio)
    assert s.duty == 1.0 and math.isnan(s.theta_dot)
    assert cal.to_sample(SampleFrame(1, 0, 0, 0, 512, 0, 0), 0).omega_prop == 0.0
    # Wrap into (−π, π]: 0 counts = −π -> reported +π.
    assert cal.to_sample(SampleFrame(1, 0, 0, 0, 0, 0, 0), 0).theta == pytest.approx(math.pi)


def test_calibration_rejects_bad_constants() -> None:
    with pytest.raises(BridgeConfigError, match=r"v_a_lsb = -0\.005"):
        Calibration(i_a_lsb=0.003, v_a_lsb=-0.005, theta_lsb=0.006)
    with pytest.raises(BridgeConfigError, match="theta_offset = nan"):
        Calibration(i_a_lsb=0.003, v_a_lsb=0.005, theta_lsb=0.006, theta_offset=math.nan)


def test_sequence_tracker_gaps_wrap_and_reset() -> None:
    s = SequenceTracker()
    for q in (65533, 65534, 65535, 0, 1, 4, 5):
        s.update(q)
    assert s.lost == 2 and s.received == 7
    s.update(30000)  # jump: MCU restart, not 29994 lost frames
    assert s.resets == 1 and s.lost == 2
    s.restart()
    s.update(7)
    assert s.lost == 2


def test_clock_mapper_tracks_offset_and_drift() -> None:
    """MCU clock 150 ppm slow, random USB latency 0.2-3 ms: stamps within 0.3 ms of the truth."""
    rng = random.Random(1)
    m = ClockMapper(window_s=1.0, windows=20)
    period_us = 2040
    ros0 = 1_700_000_000_000_000_000
    skew = 150e-6
    errs = []
    last = -1
    for k in range(60 * 490):  # 60 s, crosses no wrap
        mcu_us = k * period_us
        true_ns = ros0 + round(mcu_us * 1000 * (1 + skew))
        host = true_ns + 200_000 + round(rng.expovariate(1 / 500_000))
        stamp = m.update(mcu_us & 0xFFFFFFFF, host)
        assert stamp > last
        last = stamp
        if k > 490 * 5:
            errs.append(stamp - (true_ns + 200_000))
    assert max(abs(e) for e in errs) < 300_000, (min(errs), max(errs))
    assert m.drift_ppm == pytest.approx(150, abs=10)


def test_clock_mapper_unwraps_32bit_microseconds() -> None:
    m = ClockMapper()
    a = m.unwrap(2**32 - 1000)
    b = m.unwrap(1040)
    assert b - a == 2040 * 1000


def test_watchdog_rejects_nan_and_out_of_range_then_times_out() -> None:
    w = CommandWatchdog(timeout_ns=100_000_000)
    assert w.duty(0) == 0.0 and w.tripped
    for bad in (math.nan, math.inf, -0.1, 1.2):
        reason = w.offer(bad, 0)
        assert reason is not None and ("not finite" in reason or "outside [0, 1]" in reason)
    assert w.rejected == 4 and w.accepted == 0
    assert w.offer(0.4, 1_000) is None
    assert w.duty(50_000_000) == 0.4 and not w.tripped
    assert w.duty(100_001_001) == 0.0 and w.tripped and w.trips == 1
    assert w.duty(200_000_000) == 0.0 and w.trips == 1
    assert w.offer(0.3, 200_000_000) is None and w.duty(200_000_001) == 0.3


def test_backoff_and_rate_meter() -> None:
    b = Backoff(0.05, 0.3)
    assert [b.next_delay() for _ in range(4)] == [0.05, 0.1, 0.2, 0.3]
    b.reset()
    assert b.next_delay() == 0.05
    with pytest.raises(BridgeConfigError, match="initial 0 s"):
        Backoff(0, 1)
    r = RateMeter()
    for k in range(1000):
        r.tick(k * 2_040_000)
    assert r.rate(999 * 2_040_000) == pytest.approx(490, abs=2)


def test_stats_count_rejected_ssi_angles() -> None:
    """Samples flagged 'angle invalid' (SSI build) are counted and shown on the diagnostics."""
    st = BridgeStats()
    ok, bad = FLAG_ENABLED | FLAG_ANGLE_SSI, FLAG_ENABLED | FLAG_ANGLE_SSI | FLAG_ANGLE_INVALID
    for k, flags in enumerate([ok] * 5 + [bad] * 3 + [ok] * 2 + [bad]):
        st.count_sample(SampleFrame(k, k * 2040, 0, 0, 700, 0, 0, flags))
        assert st.angle_valid == (flags == ok)
    assert (st.samples, st.angle_invalid) == (11, 4)
    kv = dict(st.diagnostics(490.0, SequenceTracker(), {}, CommandWatchdog(timeout_ns=10**8), ClockMapper()))
    assert kv["angle_invalid_samples"] == "4" and kv["samples"] == "11"


def test_firmware_handshake_recognises_the_protocol_1_sample_stream() -> None:
    # divider 1, then a RATE 2 taking effect mid-run; seq and the 32-bit µs clock wrap
    h = FirmwareHandshake(needed=8)
    seq0, t0 = 65530, 2**32 - 3 * 2040 + 0  # t_us = overflow count × 2040 µs, wrapping
    frames = [((seq0 + k) & 0xFFFF, (t0 + 2040 * k) & 0xFFFFFFFF) for k in range(5)]
    frames += [((seq0 + 5 + k) & 0xFFFF, (t0 + 2040 * 4 + 4080 * (k + 1)) & 0xFFFFFFFF) for k in range(3)]
    results = [h.update(s, t) for s, t in frames]
    assert results == [False] * 7 + [True]
    assert (h.frames, h.longest) == (8, 8)


def test_firmware_handshake_rejects_other_streams() -> None:
    # a lost frame restarts the run: 7 + 7 consistent frames never make 8
    h = FirmwareHandshake(needed=8)
    for k in [*range(7), *range(8, 15)]:
        h.update(k, 2040 * k)
    assert not h.recognised and h.longest == 7
    # another clock (2048 µs per sample, e.g. a firmware with a different timer set-up)
    h = FirmwareHandshake(needed=8)
    assert not any(h.update(k, 2048 * k) for k in range(50)) and h.longest == 1
    # a stalled clock (same t_us twice) and a divider beyond 255
    h = FirmwareHandshake(needed=3)
    assert not h.update(0, 0) and not h.update(1, 0) and not h.update(2, 256 * 2040)
    assert h.longest == 1
    with pytest.raises(BridgeConfigError, match="at least 2 frames, got 1"):
        FirmwareHandshake(needed=1)


def test_watchdog_disarm_forgets_the_held_command_keeps_counts() -> None:
    wd = CommandWatchdog(timeout_ns=100_000_000)
    assert wd.offer(0.6, 0) is None
    assert wd.duty(1_000) == 0.6
    wd.disarm()
    assert wd.duty(2_000) == 0.0 and wd.accepted == 1
    assert wd.offer(0.3, 3_000) is None and wd.duty(4_000) == 0.3


def test_firmware_trips_since_counts_across_the_16_bit_wrap() -> None:
    """The firmware's STATUS counts its own watchdog's trips in a wrapping 16-bit counter; the first
    STATUS after connecting may hold trips from before (none counted)."""
    assert firmware_trips_since(None, 7) == 0
    assert firmware_trips_since(7, 7) == 0
    assert firmware_trips_since(7, 10) == 3
    assert firmware_trips_since(65534, 1) == 3
