"""Serial link over a pty against the Python fake MCU (no ROS): soak with 1 % byte corruption,
unplug/replug reconnection, command delivery and rejection of invalid duty values."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from aeropend_bridge.bridge_core import Backoff, SequenceTracker
from aeropend_bridge.fake_mcu import FakeMcu
from aeropend_bridge.protocol import Duty, ProtocolError, SampleFrame, StatusFrame
from aeropend_bridge.serial_link import SerialLink

pytestmark = pytest.mark.timeout(60)


class Sink:
    """Collects frames from the reader thread."""

    def __init__(self) -> None:
        self.samples: list[SampleFrame] = []
        self.status: list[StatusFrame] = []
        self.seq = SequenceTracker()
        self.lock = threading.Lock()

    def __call__(self, frame: object, host_ns: int) -> None:
        with self.lock:
            if isinstance(frame, SampleFrame):
                self.samples.append(frame)
                self.seq.update(frame.seq)
            elif isinstance(frame, StatusFrame):
                self.status.append(frame)


def _wait(cond, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


def test_soak_one_percent_corruption_lost_equals_corrupted(tmp_path: Path) -> None:
    n = 20_000  # 40 s of firmware output, sent as fast as the pty takes it
    mcu = FakeMcu(tmp_path / "tty", period_s=0.0, corrupt_p=0.01, seed=7, n_frames=n,
                  paused=True).start()
    sink = Sink()
    link = SerialLink(str(tmp_path / "tty"), sink)
    link.start()
    try:
        assert link.wait_connected(5)
        time.sleep(0.1)
        mcu.resume()
        assert _wait(lambda: len(sink.samples) >= n - len(mcu.corrupted) and mcu.done.is_set(), 40)
        time.sleep(0.1)
    finally:
        link.stop()
        mcu.stop()
    got = {f.seq: f for f in sink.samples}
    corrupted = {k & 0xFFFF for k in mcu.corrupted if k < n}
    missing = {k & 0xFFFF for k in range(n)} - set(got)
    st = link.decoder.stats
    print(f"frames {n}, corrupted {len(corrupted)}, received {len(sink.samples)}, lost (seq gaps) "
          f"{sink.seq.lost}, decoder errors {st.errors} (crc {st.crc_errors}, cobs {st.cobs_errors}, "
          f"length {st.length_errors}, type {st.type_errors})")
    assert 0.15 * n < len(corrupted) < 0.30 * n  # ~21 % of 23-byte frames at 1 % per byte
    assert missing == corrupted  # every corrupted frame detected, no valid frame lost
    assert sink.seq.lost == len(corrupted)  # ... and counted by the sequence gaps
    assert st.errors >= 0.9 * len(corrupted)  # and by the decoder (merged frames: one error)
    for seq, f in got.items():  # no corrupted frame slipped through as valid
        assert f == mcu.sent[seq], seq
    assert len(sink.samples) == n - len(corrupted)


def test_unplug_replug_reconnects_and_commands_flow(tmp_path: Path) -> None:
    link_path = tmp_path / "ttyACM_fake"
    mcu = FakeMcu(link_path).start()
    sink = Sink()
    events: list[str] = []
    link = SerialLink(str(link_path), sink, on_event=events.append, backoff=Backoff(0.02, 0.2))
    link.start()
    try:
        assert link.wait_connected(5)
        assert _wait(lambda: len(sink.samples) > 100, 5)
        assert link.send(Duty.from_fraction(0.5))
        assert _wait(lambda: mcu.duty_ocr == 128, 2)
        assert _wait(lambda: any(f.duty == 128 for f in sink.samples[-50:]), 2)
        mcu.unplug()
        assert _wait(lambda: not link.connected, 2), events
        n_before = len(sink.samples)
        time.sleep(0.3)
        assert not link.send(Duty(0))  # nothing to write to while unplugged
        mcu.replug()
        t0 = time.monotonic()
        assert link.wait_connected(3), events
        print(f"reconnected after {time.monotonic() - t0:.3f} s; events: {events}")
        assert _wait(lambda: len(sink.samples) > n_before + 100, 5)
        assert link.connects == 2 and link.disconnects >= 1
        assert link.send(Duty.from_fraction(0.2))
        assert _wait(lambda: mcu.duty_ocr == 51, 2)
    finally:
        link.stop()
        mcu.stop()
    assert any("lost" in e for e in events) and any("connection 2" in e for e in events)


def test_invalid_duty_never_reaches_the_wire(tmp_path: Path) -> None:
    for bad in (float("nan"), float("inf"), -0.01, 1.01, 100.0):
        with pytest.raises(ProtocolError, match="not a finite value in"):
            Duty.from_fraction(bad)


def test_fake_mcu_watchdog_trips_without_commands(tmp_path: Path) -> None:
    mcu = FakeMcu(tmp_path / "tty").start()
    sink = Sink()
    link = SerialLink(str(tmp_path / "tty"), sink)
    link.start()
    try:
        assert link.wait_connected(5)
        link.send(Duty.from_fraction(0.8))
        assert _wait(lambda: mcu.duty_ocr == 204, 2)
        t0 = time.monotonic()
        assert _wait(lambda: mcu.duty_ocr == 0, 2)
        assert 0.2 < time.monotonic() - t0 < 0.5
        assert mcu.watchdog_trips == 1
    finally:
        link.stop()
        mcu.stop()
