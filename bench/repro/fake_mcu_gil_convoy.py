"""Reproducer (CI flake, 2026-11-26): ``test_bridge_node_against_fake_mcu`` failed in a fresh-clone
CI run with the bridge's diagnostic ``rate_hz`` at 226 Hz, expected 490.2 ± 5 % (the MCU-clock stamps
of the same run were exact: 490.18 Hz).

Cause: the fake firmware runs as a thread of the test process, beside the test's rclpy client,
which spins for every one of ~980 messages/s. The writer released and re-took the GIL two or three
times per frame (``select``, ``os.write``, ``sleep``); while another thread of the process runs
Python code, each re-take waits up to the switch interval (5 ms), and frames that fell behind were
still written one per wake-up. On a slower or busier machine the client's thread is busy enough
for the host to see fewer than half of the frames per second: a GIL convoy, not a bridge fault.

Fix: every frame due since the last wake-up goes out in one ``os.write`` (``FakeMcu._due``), as a
USB CDC link delivers whatever the firmware queued since the last host poll.

This script counts the frames the fake writes in ``--seconds`` with and without a busy Python
thread in the same process, for the writer as it is and for the old one (one frame per wake-up).
Measured on the 2-core machine (3 s each): old writer 489.9 Hz idle / 124.2 Hz busy; batched
writer 490.5 / 491.2 Hz.

Usage: ``python -m bench.repro.fake_mcu_gil_convoy [--seconds 3]``
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
import tty
from pathlib import Path

from aeropend_bridge.fake_mcu import FakeMcu


class PerFrameMcu(FakeMcu):
    """The writer before the fix: one frame per wake-up, however far behind schedule."""

    def _due(self, k: int, t0: float) -> tuple[int, float]:
        _, t0 = super()._due(k, t0)  # keeps the re-anchoring after a stall
        return k + 1, t0


def frame_rate(cls: type[FakeMcu], busy: bool, seconds: float) -> float:
    """Frames/s the fake writes while a reader drains the pty (and a thread spins, if ``busy``)."""
    with tempfile.TemporaryDirectory() as tmp:
        mcu = cls(Path(tmp) / "tty").start()
        fd = os.open(mcu.link, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(fd)
        end = time.monotonic() + seconds

        def spin() -> None:
            while time.monotonic() < end:
                pass

        if busy:
            threading.Thread(target=spin, daemon=True).start()
        t0, n0 = time.monotonic(), len(mcu.sent)
        while time.monotonic() < end:
            try:
                os.read(fd, 65536)
            except BlockingIOError:
                time.sleep(0.001)
        rate = (len(mcu.sent) - n0) / (time.monotonic() - t0)
        os.close(fd)
        mcu.stop()
        return rate


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="length of each count")
    a = ap.parse_args(argv)
    for cls, name in ((PerFrameMcu, "one frame per wake-up (before)"), (FakeMcu, "batched (now)")):
        idle, busy = frame_rate(cls, False, a.seconds), frame_rate(cls, True, a.seconds)
        print(f"{name:32s} idle {idle:6.1f} Hz   busy thread beside it {busy:6.1f} Hz")
    return 0


if __name__ == "__main__":
    sys.exit(main())
