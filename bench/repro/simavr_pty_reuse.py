"""Reproducer: a test's serial link read another test's emulator after its own had ended.

The clean-clone CI run at d13b121 failed three ``test_simavr_esc[esc490_pot]`` tests (xdist,
three workers): a sequence gap, ESC pulses 500-1000 µs off the value the frames reported applied,
no 1700 µs pulse after the last command; in a stress run also the potentiometer build's angle off
its fixed 512 counts. Alone they passed. Cause, in the test harness: the simavr harness announced
its pty as ``/dev/pts/N``. When it exits, the host's :class:`~aeropend_bridge.serial_link.SerialLink`
(still running: the test waits until no byte arrives for 0.5 s) loses the port and reconnects, as to
a board unplugged and plugged in again, by the same path; the kernel meanwhile gives ``/dev/pts/N``
to the next pty opened on the machine — another test's harness — and the link reads that emulator's
frames as its own (another build, another MCU time, another angle sensor). The reconnect window
grew from 0.2 s to 0.5 s at 606c6f2 (``wait_drained``); the next CI run failed.

This script makes it deterministic: harness A runs 0.5 s of MCU time with a link connected; once A
has exited, harness B (the encoder build) starts and runs 2 s of wall time while A's link stays up. Frames A's
link received after A ended are counted, once with the link opened by ``/dev/pts/N`` (as before)
and once by the name the harness now announces (a symlink of its own, removed on exit,
``firmware/sim/harness.c`` link_open), which must give 0.

Usage: ``python -m bench.repro.simavr_pty_reuse``; writes ``bench/results/repro_simavr_pty_reuse.json``.
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

from aeropend_bridge.protocol import SampleFrame
from aeropend_bridge.serial_link import SerialLink
from aeropend_bridge.simavr_harness import build_emulator, read_pty_path

ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware"
F_CPU = 16_000_000
BUILDS = {"a": ("ACTUATOR=esc", "ESC_HZ=490", "ANGLE=pwm"),
          "b": ("ACTUATOR=esc", "ESC_HZ=50", "ANGLE=encoder")}


def _build(tmp: Path) -> dict[str, Path]:
    return {name: build_emulator(FW, tmp / name, make) for name, make in BUILDS.items()}


def _start(d: Path, seconds: float) -> subprocess.Popen[str]:
    return subprocess.Popen([str(d / "harness"), str(d / "aeropend.elf"), str(int(seconds * F_CPU))],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def trial(builds: dict[str, Path], by_pts: bool) -> dict:
    frames: list[tuple[int, SampleFrame]] = []
    a = _start(builds["a"], 0.5)
    path = read_pty_path(a)
    a_real = os.path.realpath(path)
    port = a_real if by_pts else path
    link = SerialLink(port, lambda f, t: frames.append((t, f)) if isinstance(f, SampleFrame) else None,
                      clock_ns=time.monotonic_ns)
    link.start()
    b = None
    try:
        assert link.wait_connected(5)
        a.communicate(timeout=60)
        time.sleep(0.3)  # A's bytes read; the link notices the hang-up and starts reconnecting
        ended = time.monotonic_ns()
        n_own = len(frames)
        b = _start(builds["b"], 1.5)
        b_real = os.path.realpath(read_pty_path(b))
        time.sleep(2.0)  # B runs on only while someone reads it (the harness's flow control)
    finally:
        link.stop()
        for proc in (a, b):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.communicate()
    foreign = [f for t, f in frames if t > ended]
    return {"opened_by": "/dev/pts/N" if by_pts else "the harness's own name", "a_pty": a_real,
            "b_pty": b_real, "own_frames": n_own,
            "frames_read_after_a_ended": len(foreign), "reconnects": link.connects - 1}


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        builds = _build(Path(tmp))
        trials = [trial(builds, by_pts) for by_pts in (True, False)]
    out = ROOT / "bench" / "results" / "repro_simavr_pty_reuse.json"
    out.write_text(json.dumps({"trials": trials}, indent=1) + "\n")
    for t in trials:
        print(f"link opened by {t['opened_by']}: {t['own_frames']} own frames, "
              f"{t['frames_read_after_a_ended']} read after its harness ended ({t['reconnects']} reconnects; "
              f"A on {t['a_pty']}, B on {t['b_pty']})")
    return 0 if trials[-1]["frames_read_after_a_ended"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
