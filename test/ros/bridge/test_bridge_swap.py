"""Swapping the simulated plant for the hardware bridge changes nothing else in the graph.

The same ``controller`` (fl_pid, step to 0.4 rad) runs (a) against ``sim_node`` (real time)
and (b) against ``bridge`` reading the pty fake MCU with the same plant model in the loop
(outputs quantised to ADC counts / Timer4 ticks, duty from the commands the bridge writes).
No parameter of the controller differs; both closed loops must settle at the reference.
"""

from __future__ import annotations

import csv
import math
import signal
import subprocess
import time
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from aeropend_bridge.bridge_core import Calibration
from aeropend_bridge.fake_mcu import FakeMcu
from aeropend_sim.params import load_rig
from aeropend_sim.ros.harness import frozen_gc, isolated_env, node_command, random_domain, stop
from aeropend_sim.simulation import PlantStepper

#: exclusive: the fake MCU streams 490 Hz from a thread of the pytest process itself, the bridge and the
#: real-time controller answer it; beside the parallel suite (CI at f349c21) the controller's trace held
#: 1538 samples of a 4 s run, under the 80 % of 490 Hz this test requires. The fake MCU drops a
#: backlog over 0.5 s (docs/findings/data_plane.md, tenth cause), so a starved host process loses
#: samples by design; which process was starved was not established (their output is not kept).
pytestmark = [pytest.mark.ros, pytest.mark.exclusive, pytest.mark.timeout(60)]
REF = 0.4
DURATION = 4.0


def _run_controller(env: dict[str, str], trace: Path) -> None:
    r = subprocess.run([*node_command("controller", "aeropend_control.controller_node"), "--ros-args",
                        "-p", f"steps:=[0.0, {REF}]", "-p", f"duration:={DURATION}", "-p", f"trace:={trace}"],
                       env=env, capture_output=True, text=True, timeout=40)
    assert r.returncode == 0, r.stderr[-2000:]


def _settled(trace: Path) -> tuple[float, int, float]:
    """(mean θ over the last 0.5 s [rad], samples, the largest receipt latency of a sample [s])."""
    rows = list(csv.DictReader(trace.open()))
    assert len(rows) > 0.8 * DURATION * 490, len(rows)
    t_end = float(rows[-1]["t"])
    tail = [float(r["theta"]) for r in rows if float(r["t"]) > t_end - 0.5]
    return sum(tail) / len(tail), len(rows), max(float(r["recv_latency"]) for r in rows)


def test_same_controller_against_sim_and_bridge(tmp_path: Path) -> None:
    rig = load_rig("thesis_rig")
    # (a) simulated plant
    env = isolated_env(random_domain(101, 200))
    sim = subprocess.Popen([*node_command("sim_node", "aeropend_sim.ros.sim_node"), "--ros-args",
                            "-p", "rig:=thesis_rig"], env=env, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    try:
        time.sleep(1.0)
        _run_controller(env, tmp_path / "sim.csv")
    finally:
        stop(sim, signal.SIGTERM, timeout=10)
    # (b) hardware bridge + fake firmware with the same plant model
    env = isolated_env(random_domain(101, 200))
    cal = Calibration.from_rig(rig, theta_offset=math.pi)
    # the fake firmware is a thread of this process: a full garbage collection of the heap the earlier
    # tests left stalls its writer, which then steps the plant through the missed frames on a stale
    # duty (fresh-clone CI of bdd1a12: 206 ms late, settled at 0.3157 rad;
    # bench/repro/fake_mcu_gc_pause.py: 764 ms late beside 3 million objects, 8 ms with them frozen)
    with frozen_gc():
        mcu = FakeMcu(tmp_path / "tty", plant=PlantStepper(rig), calibration=cal).start()
        bridge = subprocess.Popen([*node_command("bridge", "aeropend_bridge.bridge_node"), "--ros-args",
                                   "-p", f"port:={tmp_path / 'tty'}", "-p", f"theta_offset:={math.pi}"],
                                  env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            time.sleep(1.0)
            t_run = time.monotonic()
            _run_controller(env, tmp_path / "bridge.csv")
            t_end = time.monotonic()
        finally:
            stop(bridge, signal.SIGTERM, timeout=10)
            mcu.stop()
    theta_sim, n_sim, late_sim = _settled(tmp_path / "sim.csv")
    theta_hw, n_hw, late_hw = _settled(tmp_path / "bridge.csv")
    # the fake firmware's watchdog cuts the motor when no command came for 250 ms, as the firmware does;
    # a trip before the controller's exit is the loop falling silent (a starved process or host)
    trips = [round(t - t_run, 2) for t in mcu.trip_times if t < t_end]
    timing = (f"largest receipt latency: sim {late_sim * 1e3:.1f} ms, bridge {late_hw * 1e3:.1f} ms; "
              f"the fake firmware's writer up to {mcu.max_lateness_s * 1e3:.1f} ms late; its watchdog "
              f"tripped at {trips} s of the bridge run")
    print(f"settled θ: sim {theta_sim:.4f} rad ({n_sim} samples), bridge {theta_hw:.4f} rad "
          f"({n_hw} samples); {timing}")
    assert theta_sim == pytest.approx(REF, abs=0.03), timing
    assert theta_hw == pytest.approx(REF, abs=0.03), timing
    assert abs(theta_sim - theta_hw) < 0.03, timing
