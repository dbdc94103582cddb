"""Reproducer: the fake firmware's writer stalls for a full garbage collection of its host process.

``test_bridge_swap.py`` runs :class:`aeropend_bridge.fake_mcu.FakeMcu` (the emulated firmware and
its plant) as a thread of the pytest process. In the exclusive part of the fresh-clone CI of
bdd1a12, after the other exclusive tests had grown that process' heap, the writer ran up to
206 ms late and the bridge half of the test settled at 0.3157 rad against 0.4 ± 0.03 (its watchdog
did not trip). A late writer catches up in one burst (``FakeMcu._run``), and the plant steps through
the burst on the duty of the moment: the host is blind for the length of the stall, and the rod
dips as it does when the controller stalls (``bench/repro/bridge_swap_stall.py``). A generation-2
collection scans the whole heap while every thread of the process waits for the GIL: a full
collection of a fresh import of the test's modules (208 k objects) took 90 ms here.

This script holds a ballast heap of ``OBJECTS`` tracked objects, runs a FakeMcu with the thesis
plant for 4 s while the main thread allocates (as the test's bookkeeping does), once with the
collector as it is and once after ``gc.collect(); gc.freeze()`` (``aeropend_sim.ros.harness.frozen_gc``),
and prints the writer's largest lateness.

Measured (2-core machine, 3 million objects, 2026-11-30): 720.9 ms late with the collector as it is,
29.0 ms after ``gc.freeze()``.

Usage: ``.venv/bin/python -m bench.repro.fake_mcu_gc_pause [OBJECTS]``
"""

from __future__ import annotations

import gc
import math
import sys
import tempfile
import time
from pathlib import Path


def run(objects: int, freeze: bool) -> float:
    """The writer's largest lateness [s] over 4 s beside a ballast heap of ``objects`` lists."""
    from aeropend_bridge.bridge_core import Calibration
    from aeropend_bridge.fake_mcu import FakeMcu
    from aeropend_sim.params import load_rig
    from aeropend_sim.simulation import PlantStepper

    ballast = [[i] for i in range(objects)]
    rig = load_rig("thesis_rig")
    if freeze:
        gc.collect()
        gc.freeze()
    try:
        with tempfile.TemporaryDirectory() as d:
            mcu = FakeMcu(Path(d) / "tty", plant=PlantStepper(rig),
                          calibration=Calibration.from_rig(rig, theta_offset=math.pi)).start()
            junk: list = []
            t_end = time.monotonic() + 4.0
            while time.monotonic() < t_end:
                junk.append([[j] for j in range(2000)])
                junk = junk[-50:]
                time.sleep(0.001)
            mcu.stop()
    finally:
        gc.unfreeze()
    del ballast
    return mcu.max_lateness_s


def main() -> None:
    objects = int(sys.argv[1]) if len(sys.argv) > 1 else 3_000_000
    for freeze in (False, True):
        late = run(objects, freeze)
        print(f"{objects} ballast objects, gc.freeze() {'after' if freeze else 'not'} called: "
              f"the writer up to {late * 1e3:.1f} ms late")


if __name__ == "__main__":
    main()
