"""Reproducer (CI flake): ``test_bridge_node_against_fake_mcu`` failed once in a fresh-clone CI run
with the fake firmware's 250 ms command watchdog tripped once (``watchdog_trips == 1``) although
the bridge re-sends the duty every 20 ms while active.

Cause: on connect (in configure) the bridge sends ENABLE 0 and duty 0, which arms the firmware
watchdog, but it sent keep-alives only while *active*; when configure → activate took more than
250 ms (firmware recognition under load) the watchdog tripped once. Deterministic form:
``test_bridge_lifecycle_ros.py`` keeps the bridge configured and inactive for > 2 s and asserts no
trip (1 trip before the fix, 0 after). Fix: duty-0 keep-alives while configured but inactive.

This script runs the original test repeatedly, optionally under the CPU hog of
``bench_data_plane.py``, and counts failures with their messages (the test reports the longest
gap between commands the fake MCU received and when it happened). Before the fix: 0 of 12 runs
failed under two hogs (the race needs a configure slower than 250 ms; it is rare).

Usage: ``python -m bench.repro.firmware_watchdog_trip [--runs 20] [--hog]``
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

from bench.bench_data_plane import HOG

ROOT = Path(__file__).resolve().parents[2]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--hog", action="store_true", help="one busy-loop process per core while testing")
    a = ap.parse_args(argv)
    hogs = [subprocess.Popen(HOG) for _ in range(2)] if a.hog else []
    fails = []
    try:
        for i in range(a.runs):
            r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider",
                                "test/ros/bridge/test_bridge_node.py::test_bridge_node_against_fake_mcu"],
                               cwd=ROOT, capture_output=True, text=True)
            msg = [ln for ln in r.stdout.splitlines() if "AssertionError" in ln or re.match(r"^E\s", ln)]
            print(f"run {i + 1}: rc {r.returncode} {msg[:3]}", flush=True)
            if r.returncode != 0:
                fails.append(msg)
    finally:
        for h in hogs:
            h.kill()
    print(f"{len(fails)} of {a.runs} runs failed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
