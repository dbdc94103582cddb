"""Reproducer: the simavr harness drops UART bytes when its pty is not drained (issue 15).

``test_bridge_simavr_ros[ssi]`` failed once under load (two benchmarks running): the bridge
counted 29 lost frames (sequence gaps) with 2 CRC and 1 COBS errors, i.e. bytes missing from the
stream the emulated ATmega2560 sent. simavr's ``uart_pty`` part moves the UART's bytes into a
512-byte FIFO that its own thread copies to the pty; ``uart_pty_fifo_write`` drops a byte when the
FIFO is full. Whenever that thread cannot write (pty full: the reader is slow) or does not run
(starved on a loaded host) for longer than 512 bytes take (≈ 45 ms of 490 Hz samples), the
emulated MCU keeps running and its bytes are lost — a loss no real USB-serial link has (its
transfers do not depend on the host's scheduler, and the host kernel buffers ~64 KiB).

This script makes the same loss deterministic: it builds the firmware and the harness, reads
the pty for ``--read`` s, stops reading for ``--pause`` s (the pty fills, then the FIFO), reads
again, and counts the sequence gaps and malformed frames with the bridge's decoder and tracker. With the
harness' flow control (``firmware/sim/harness.c``: the emulation waits while the host is behind;
since the harness serves the pty itself, see ``simavr_link_race.py``) the count must be 0.

Usage: ``python -m bench.repro.simavr_pty_overflow [--pause 8] [--read 2]``; writes
``bench/results/repro_simavr_pty_overflow.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from aeropend_bridge.bridge_core import SequenceTracker
from aeropend_bridge.protocol import FrameDecoder, SampleFrame
from aeropend_bridge.simavr_harness import read_pty_path

ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware"


def _read_for(fd: int, seconds: float, dec: FrameDecoder, frames: list[SampleFrame]) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        ready, _, _ = select.select([fd], [], [], 0.05)
        if ready:
            frames += [f for f in dec.feed(os.read(fd, 65536)) if isinstance(f, SampleFrame)]


def run(pause: float, read: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        for target, extra in (("all", ["EXTRA_CFLAGS=-DSIMAVR_TIMER1"]), ("harness", [])):
            r = subprocess.run(["make", "-C", str(FW), f"BUILD={tmp}", target, *extra], capture_output=True,
                               text=True, timeout=300)
            if r.returncode != 0:
                raise SystemExit(r.stdout + r.stderr)
        cmd = [str(Path(tmp) / "harness"), str(Path(tmp) / "aeropend.elf"), "0",  # run until stopped
               "500", "1000", "2500", "1500"]  # A0..A3 [mV]
        sim = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            fd = os.open(read_pty_path(sim), os.O_RDWR | os.O_NOCTTY)
            dec, frames = FrameDecoder(), []
            _read_for(fd, read, dec, frames)
            before = len(frames)
            time.sleep(pause)  # not reading: the pty fills, then the harness' FIFO
            _read_for(fd, read, dec, frames)
            os.close(fd)
        finally:
            sim.terminate()
            sim.wait(timeout=10)
    # the bridge's own gap count; every jump counts as lost frames here (no MCU restart in this run)
    seq = SequenceTracker(max_gap=0xFFFF)
    for f in frames:
        seq.update(f.seq)
    gaps = seq.lost
    return {"pause_s": pause, "read_s": read, "frames": len(frames), "frames_before_pause": before,
            "lost_frames": gaps, "crc_errors": dec.stats.crc_errors, "cobs_errors": dec.stats.cobs_errors,
            "malformed": dec.stats.errors}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pause", type=float, default=8.0, help="seconds without reading the pty")
    ap.add_argument("--read", type=float, default=2.0, help="seconds of reading before and after")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "repro_simavr_pty_overflow.json"))
    args = ap.parse_args(argv)
    res = run(args.pause, args.read)
    print(json.dumps(res, indent=1))
    Path(args.out).write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
