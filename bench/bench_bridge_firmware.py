"""Firmware figures: flash/RAM per build variant and the AS5040 SSI read-out timing on simavr.

Builds the firmware for the ATmega2560 in its variants (``ANGLE=pwm``, ``ANGLE=ssi``, ``ANGLE=ssi``
with 22 clocks) and reports ``avr-size``; then runs the ``ANGLE=ssi`` emulator build in
``firmware/sim/harness.c`` for ``--seconds`` of MCU time with a constant AS5040 word and a 60 ms IR
pulse train, reads the frames through the bridge's serial link, and reports the SSI pin timing
measured by the harness (CSn low -> first CLK fall, shortest CLK half period, read-out duration
undisturbed / with nested UART interrupts), the emulated sample rate and the wall-clock speed
of the emulation.

    python -m bench.bench_bridge_firmware [--seconds 3] [--save]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import tempfile
import time
from pathlib import Path

from aeropend_bridge.protocol import Duty, SampleFrame
from aeropend_bridge.simavr_harness import harness_link

ROOT = Path(__file__).resolve().parents[1]
FW = ROOT / "firmware"
F_CPU = 16_000_000
VARIANTS = {"pwm": ["ANGLE=pwm"], "ssi": ["ANGLE=ssi"],
            "ssi22": ["ANGLE=ssi", "EXTRA_CFLAGS=-DSSI_CLOCKS=22"]}


def _make(build: Path, *args: str) -> None:
    r = subprocess.run(["make", "-C", str(FW), f"BUILD={build}", *args], capture_output=True, text=True,
                       timeout=180)
    if r.returncode != 0:
        raise RuntimeError(f"make {' '.join(args)} failed:\n{r.stdout}{r.stderr}")


def sizes(tmp: Path) -> dict[str, dict[str, int]]:
    """Flash (.text + .data) and RAM (.data + .bss) bytes of each build variant."""
    out = {}
    for name, args in VARIANTS.items():
        _make(tmp / name, *args)
        r = subprocess.run(["avr-size", "-A", str(tmp / name / "aeropend.elf")], capture_output=True,
                           text=True, check=True)
        sec = {m[0]: int(m[1]) for m in re.findall(r"^(\.\w+)\s+(\d+)", r.stdout, flags=re.M)}
        out[name] = {"flash_bytes": sec[".text"] + sec.get(".data", 0),
                     "ram_bytes": sec.get(".data", 0) + sec.get(".bss", 0)}
    return out


def ssi_on_simavr(tmp: Path, seconds: float) -> dict[str, float]:
    """Run the SSI emulator build; return pin timing [µs], sample rate and emulation speed."""
    build = tmp / "sim"
    _make(build, "all", "ANGLE=ssi", "EXTRA_CFLAGS=-DSIMAVR_TIMER1")
    _make(build, "harness")
    ev = build / "events.txt"
    ev.write_text("ssi 0 0x8020\n" + "".join(f"ir {t} 1\nir {t + 2000} 0\n"
                                             for t in range(10_000, int(seconds * 1e6), 60_000)))
    t_wall = time.monotonic()
    frames: list[SampleFrame] = []

    def on_frame(f: object, _t: int) -> None:
        if isinstance(f, SampleFrame):
            frames.append(f)

    argv = [str(build / "harness"), str(build / "aeropend.elf"), str(int(seconds * F_CPU)), "-e", str(ev)]
    with harness_link(argv, on_frame) as (proc, link):
        link.wait_connected(5)
        while proc.poll() is None:
            link.send(Duty.from_fraction(0.3))
            time.sleep(0.05)
        out, _ = proc.communicate(timeout=30)
        wall = time.monotonic() - t_wall
    v = next(ln.split()[1:] for ln in out.splitlines() if ln.startswith("SSITIMING"))
    t = dict(zip(v[0:8:2], (int(x) / 1000 for x in v[1:8:2]), strict=True))
    return {
        "ssi_clkfe_min_us": t["clkfe_min"], "ssi_clk_half_period_min_us": t["half_min"],
        "ssi_read_undisturbed_us": t["read_min"], "ssi_read_max_with_nested_isrs_us": t["read_max"],
        "ssi_clock_edges_per_read": int(v[9]),
        "emulated_sample_rate_hz": (frames[-1].seq + 1) / seconds if frames else 0.0,
        "frames_received": len(frames),
        "emulation_realtime_factor": seconds / wall,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="emulated MCU time [s]")
    ap.add_argument("--save", action="store_true", help="write bench/results/bridge_firmware.json")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        res: dict[str, object] = {"sizes": sizes(Path(d)), "simavr_ssi": ssi_on_simavr(Path(d), a.seconds),
                                  "host_load_avg_1min": os.getloadavg()[0], "host_cpus": os.cpu_count()}
    print(json.dumps(res, indent=1))
    if a.save:
        out = Path(__file__).parent / "results" / "bridge_firmware.json"
        out.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
