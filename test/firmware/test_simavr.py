"""The real firmware on an emulated ATmega2560 (simavr), read by the bridge's serial link.

Builds the firmware with ``-DSIMAVR_TIMER1`` (simavr 1.6 lacks Timer1 phase-correct PWM on
the ATmega2560: the only difference is fast PWM with TOP = ICR1 = 509, the same 510-tick
2.040 ms period) and the harness ``firmware/sim/harness.c`` (libsimavr; the
UART as a pty, ADC inputs driven in mV), runs 3 s of MCU time and checks: decoded ADC values,
the sample rate in emulated time (490.2 Hz ± 1 %), no sequence gaps, commands (duty) applied,
the 250 ms firmware watchdog, and firmware counters (no RX errors).

Not emulated (simavr 1.6): Timer1 phase-correct PWM, the analogue front end. No IR edges are
driven in this run (speed stays "stale", period 0); the IR capture path and the AS5040 SSI
read-out run on simavr in ``test_firmware_simavr_io.py`` (the harness drives ICP4 and the SSI
pins), and the capture logic's corner cases also in ``firmware/test/test_codec.c``.
"""

from __future__ import annotations

import itertools
import shutil
import subprocess
import threading
import time
from pathlib import Path

import pytest

from aeropend_bridge.protocol import (
    FLAG_ENABLED,
    FLAG_SPEED_STALE,
    FLAG_WATCHDOG,
    Duty,
    SampleFrame,
    StatusFrame,
)
from aeropend_bridge.simavr_harness import harness_link, wait_drained

ROOT = Path(__file__).resolve().parents[2]
FW = ROOT / "firmware"
F_CPU = 16_000_000
SIM_SECONDS = 3.0
#: The last command's duty (the earlier ones are 0.5): a value the frames show only once it arrived.
LAST_DUTY = 0.25
A0_MV, A1_MV, A2_MV, A3_MV = 500, 1000, 2500, 1500

pytestmark = [
    pytest.mark.timeout(60),
    pytest.mark.skipif(
        shutil.which("avr-gcc") is None or not Path("/usr/include/simavr/sim_avr.h").is_file(),
        reason="needs avr-gcc + libsimavr-dev/libsimavrparts1 (scripts/setup_env.sh installs them as root)"),
]


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    build = tmp_path_factory.mktemp("simfw")
    for target, extra in (("all", "EXTRA_CFLAGS=-DSIMAVR_TIMER1"), ("harness", "")):
        args = ["make", "-C", str(FW), f"BUILD={build}", target] + ([extra] if extra else [])
        r = subprocess.run(args, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stdout + r.stderr
    return build / "aeropend.elf", build / "harness"


def test_firmware_on_simavr(built: tuple[Path, Path]) -> None:
    elf, harness = built
    cycles = int(SIM_SECONDS * F_CPU)
    frames: list[tuple[int, object]] = []
    lock = threading.Lock()

    def on_frame(frame: object, host_ns: int) -> None:
        with lock:
            frames.append((host_ns, frame))

    sends: list[float] = []
    argv = [str(harness), str(elf), str(cycles), str(A0_MV), str(A1_MV), str(A2_MV), str(A3_MV)]
    with harness_link(argv, on_frame) as (proc, link):
        assert link.wait_connected(5)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.0:  # 1 s of duty 0.5 at 50 Hz
            link.send(Duty.from_fraction(0.5))
            sends.append(time.monotonic())
            time.sleep(0.02)
        link.send(Duty.from_fraction(LAST_DUTY))  # the last command: its arrival shows in the frames
        sends.append(time.monotonic())
        out, err = proc.communicate(timeout=30)  # then silence until the emulation ends
        wait_drained(link)  # the reader may run behind the emulator on a loaded host
    assert "CYCLES" in out, err
    samples = [(t, f) for t, f in frames if isinstance(f, SampleFrame)]
    status = [f for _, f in frames if isinstance(f, StatusFrame)]
    assert len(samples) > 500, (len(samples), link.decoder.stats)
    # --- no sequence gaps and 2.040 ms between samples (MCU clock)
    seqs = [f.seq for _, f in samples]
    assert all((b - a) & 0xFFFF == 1 for a, b in itertools.pairwise(seqs)), "sequence gap"
    dts = {b.t_us - a.t_us for (_, a), (_, b) in itertools.pairwise(samples)}
    assert dts == {2040}
    # --- rate in emulated time: samples sent = last seq + 1 (first sample after ~2 ms)
    sim_s = int(out.split("CYCLES")[1].split()[0]) / F_CPU
    rate = (seqs[-1] + 1) / sim_s
    wall = (samples[-1][0] - samples[0][0]) / 1e9
    print(f"emulated rate {rate:.2f} Hz over {sim_s:.3f} s; wall-clock rate "
          f"{(len(samples) - 1) / wall:.1f} Hz; decoder {link.decoder.stats}")
    assert rate == pytest.approx(490.196, rel=0.01)
    # --- ADC values (AVcc 5 V; v_a differential A3 − A1 on the 2.56 V reference)
    f = samples[-1][1]
    assert f.i_a == pytest.approx(A0_MV * 1024 / 5000, abs=1)
    assert f.theta == pytest.approx(A2_MV * 1024 / 5000, abs=1)
    # simavr 1.6 scales differential results by 1024/Vref (the datasheet says 512/Vref for
    # gain 1): accept either and say which one was seen.
    dv = (A3_MV - A1_MV) / 2560
    assert f.v_a in (pytest.approx(dv * 512, abs=1), pytest.approx(dv * 1024, abs=1)), f.v_a
    print(f"v_a counts {f.v_a} for {A3_MV - A1_MV} mV: datasheet scale {dv * 512:.1f}, x1024 scale "
          f"{dv * 1024:.1f}")
    assert f.flags & FLAG_ENABLED and f.flags & FLAG_SPEED_STALE and f.period == 0
    # --- duty applied while commands flow; firmware watchdog: 0 within 250 ms of silence
    during = [fr for t, fr in samples if sends[5] * 1e9 < t < sends[-1] * 1e9]
    assert during and all(fr.duty == 128 and not fr.flags & FLAG_WATCHDOG for fr in during[5:])
    # the watchdog's interval on the MCU's own clock: the last command (a duty no earlier command
    # had) arrived after the last sample that still shows 0.5 and before the first that shows it.
    # Read-side lag on a loaded host does not enter (frames read late made the first frame read
    # after the last send predate the command's arrival: 265 ms measured with three test workers).
    last = round(LAST_DUTY * 256)
    first_new = next(k for k, (_, fr) in enumerate(samples) if fr.duty == last)
    arrived_after, arrived_by = samples[first_new - 1][1].t_us, samples[first_new][1].t_us
    trip = next(fr for _, fr in samples[first_new:] if fr.flags & FLAG_WATCHDOG)
    wd_s = (trip.t_us - arrived_by) * 1e-6
    print(f"firmware watchdog: duty 0 {wd_s * 1e3:.1f} ms (MCU time) after the sample that applied the "
          "last command")
    assert trip.duty in (0, last)  # the frame flags the trip; duty 0 from the next interval on
    later = [fr for _, fr in samples if fr.t_us > trip.t_us]
    assert later and all(fr.duty == 0 for fr in later)
    # within 250 ms of the command (firmware/src/main.c: tick 122 after it, <= 248.9 ms), and not
    # before 200 ms (the silence must be real)
    assert (trip.t_us - arrived_by) * 1e-6 <= 0.25 and (trip.t_us - arrived_after) * 1e-6 >= 0.2
    # --- firmware counters
    assert status, "no STATUS frame"
    assert status[-1].rx_errors == 0 and status[-1].rx_frames >= 40 and status[-1].tx_overflows == 0
