"""Reproducer (CI flake, 2026-11-26): ``test_autostart_keeps_the_firmware_watchdog_quiet_before_the_
executor_spins`` failed in a fresh-clone CI run and in 1 of 4 reruns of it alone on an idle 2-core
machine, with the fake firmware's watchdog tripped once.

Cause: the test counted every trip up to the moment it read the counter, after the bridge process
had exited. ``finish`` sends the bridge's last command; the process then tears down (node,
rclpy, interpreter) without commands, and the firmware's 250 ms watchdog trips as it must with the
host gone. Whenever the teardown took longer than 250 ms the test failed, although no command gap
while the bridge ran came near the watchdog (the longest: 43-47 ms).

This script runs the test's bridge script against a fake firmware and prints, per run, the trips,
each trip's time after the bridge's last command (always ≈ 0.251 s) and the longest gap between
commands. Fix: the fake records each trip's time (``FakeMcu.trip_times``) and the test counts only
trips before the bridge's last command.

Usage: ``python -m bench.repro.watchdog_after_finish [--runs 5]``
"""

from __future__ import annotations

import argparse
import itertools
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from aeropend_bridge.fake_mcu import FakeMcu
from aeropend_sim.ros.harness import isolated_env, random_domain

ROOT = Path(__file__).resolve().parents[2]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="runs of the bridge script")
    args = ap.parse_args(argv)
    src = (ROOT / "test" / "ros" / "bridge" / "test_bridge_lifecycle.py").read_text(encoding="utf-8")
    script = re.search(r'AUTOSTART_WITHOUT_SPIN = """(.*?)"""', src, re.S).group(1)
    for i in range(args.runs):
        link = Path(tempfile.mkdtemp()) / "ttyACM_fake"
        mcu = FakeMcu(link).start()
        try:
            env = isolated_env(random_domain(101, 200))
            subprocess.run([sys.executable, "-c", script, str(link)], env=env, capture_output=True, text=True,
                           timeout=60)
            time.sleep(0.3)  # past the watchdog period after the process has gone
        finally:
            mcu.stop()
        ts = [t for t, _ in mcu.commands]
        gap = max((b - a for a, b in itertools.pairwise(ts)), default=float("nan"))
        after = [round(t - ts[-1], 3) for t in mcu.trip_times] if ts else []
        print(f"run {i}: {mcu.watchdog_trips} trip(s), after the last command by {after} s; "
              f"longest gap between commands {gap:.3f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
