"""Reproducer (CI flake, 2026-11-30): the landing CI of 9bfcfb1 failed ``test_bridge_swap``: the
bridge half of its closed loop (fake firmware with the plant in the loop ↔ ``bridge`` ↔
``controller``, fl_pid, step to 0.4 rad, 4 s) settled at 0.3586 rad over its last 0.5 s, against
0.4 ± 0.03, with every one of its 1962 samples received.

This script runs that bridge half and stops one process for ``--stall`` seconds ``--at`` seconds
after the controller starts (SIGSTOP / SIGCONT of the bridge or the controller; for the fake
firmware, its own thread kept from the GIL by a busy loop of this process), then prints the mean,
least and largest angle of the last 0.5 s, the largest receipt latency, the fake firmware's writer
lateness and its watchdog trips.

Measured on the idle 2-core machine (0.3 s stalls 6.3 s after the controller's start, inside the
last 0.5 s of its run): the controller stopped: the rod dipped to 0.26 rad, the tail's mean 0.3967;
the bridge stopped: the firmware's 250 ms watchdog cut the motor once, the rod dipped to 0.36 rad,
the tail's mean 0.4003; the fake firmware's thread held: nothing (its plant runs on the frames'
time); 0.1 s stalls of the bridge or the controller: nothing. One 0.3 s stall does not bring the
tail's mean down to the CI's 0.3586: a longer or repeated one would; which process stalled there,
and how long, is not known (the test now prints these timings in a failure).

Usage: ``python -m bench.repro.bridge_swap_stall --who bridge --at 6.3 --stall 0.3``
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path

from aeropend_bridge.bridge_core import Calibration
from aeropend_bridge.fake_mcu import FakeMcu
from aeropend_sim.params import load_rig
from aeropend_sim.ros.harness import isolated_env, node_command, random_domain, reap, stop
from aeropend_sim.simulation import PlantStepper


def _stall(who: str, at: float, stall: float, procs: dict[str, subprocess.Popen]) -> None:
    time.sleep(at)
    if who == "mcu":  # keep the fake firmware's thread from the GIL
        end = time.monotonic() + stall
        while time.monotonic() < end:
            pass
    elif who in procs:
        os.kill(procs[who].pid, signal.SIGSTOP)
        time.sleep(stall)
        os.kill(procs[who].pid, signal.SIGCONT)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bridge_swap_stall", description=__doc__.split("\n\n")[0])
    ap.add_argument("--who", choices=("none", "bridge", "controller", "mcu"), default="bridge")
    ap.add_argument("--at", type=float, default=6.3, help="seconds after the controller starts (default 6.3)")
    ap.add_argument("--stall", type=float, default=0.3, help="seconds stopped (default 0.3)")
    a = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="swap-stall-"))
    env = isolated_env(random_domain(101, 200))
    rig = load_rig("thesis_rig")
    mcu = FakeMcu(tmp / "tty", plant=PlantStepper(rig),
                  calibration=Calibration.from_rig(rig, theta_offset=math.pi)).start()
    bridge = subprocess.Popen([*node_command("bridge", "aeropend_bridge.bridge_node"), "--ros-args",
                               "-p", f"port:={tmp / 'tty'}", "-p", f"theta_offset:={math.pi}"],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ctl = None
    try:
        time.sleep(1.0)
        ctl = subprocess.Popen([*node_command("controller", "aeropend_control.controller_node"), "--ros-args",
                                "-p", "steps:=[0.0, 0.4]", "-p", "duration:=4.0",
                                "-p", f"trace:={tmp / 't.csv'}"],
                               env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        threading.Thread(target=_stall, args=(a.who, a.at, a.stall, {"bridge": bridge, "controller": ctl}),
                         daemon=True).start()
        ctl.wait(timeout=60)
    finally:
        stop(bridge, signal.SIGTERM, timeout=10)
        mcu.stop()
        reap(ctl)
    rows = list(csv.DictReader((tmp / "t.csv").open()))
    t_end = float(rows[-1]["t"])
    tail = [float(r["theta"]) for r in rows if float(r["t"]) > t_end - 0.5]
    print(f"{a.who} stopped {a.stall} s at {a.at} s: {len(rows)} samples; last 0.5 s: mean "
          f"{sum(tail) / len(tail):.4f} rad, least {min(tail):.4f}, largest {max(tail):.4f}; largest receipt "
          f"latency {max(float(r['recv_latency']) for r in rows) * 1e3:.1f} ms; fake firmware's writer up to "
          f"{mcu.max_lateness_s * 1e3:.1f} ms late, watchdog trips {mcu.watchdog_trips}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
