"""The fake firmware's writer schedule (``FakeMcu._due``): late wake-ups catch up in one write."""

from __future__ import annotations

import time

import pytest

from aeropend_bridge.fake_mcu import FIRMWARE_PERIOD_S, FakeMcu


def test_a_late_wake_up_sends_every_frame_due_since_the_last_one(tmp_path) -> None:
    # woke 100 ms late: frames 10 .. 59 are due (49 periods of 2.04 ms behind frame 10), all in
    # one write, so a writer thread that waits for the GIL still keeps 490.2 Hz on average
    mcu = FakeMcu(tmp_path / "tty")
    k = 10
    t0 = time.monotonic() - k * FIRMWARE_PERIOD_S - 0.1
    due, anchor = mcu._due(k, t0)
    assert anchor == t0
    assert due - k == pytest.approx(0.1 / FIRMWARE_PERIOD_S + 1, abs=2)


def test_an_early_wake_up_sends_one_frame_and_n_frames_caps_the_batch(tmp_path) -> None:
    mcu = FakeMcu(tmp_path / "tty")
    t0 = time.monotonic() - 9.5 * FIRMWARE_PERIOD_S  # frame 10 is due only in 1 ms
    assert mcu._due(10, t0) == (11, t0)
    capped = FakeMcu(tmp_path / "tty", n_frames=20)
    assert capped._due(10, time.monotonic() - 0.3)[0] == 20


def test_a_stall_over_half_a_second_is_dropped_not_sent_in_one_burst(tmp_path) -> None:
    mcu = FakeMcu(tmp_path / "tty")
    t0 = time.monotonic() - 10 * FIRMWARE_PERIOD_S - 2.0  # two seconds behind frame 10
    due, anchor = mcu._due(10, t0)
    assert due in (10 + 1, 10 + 2)  # the schedule restarts at frame 10: no 980-frame burst
    assert anchor > t0 + 1.9
