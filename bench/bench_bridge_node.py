"""Benchmark of the ``bridge`` node at the firmware rate: frames/s sustained and host CPU.

Runs the pty fake MCU (490.2 frames/s) and the bridge node in a subprocess for ``--seconds``,
subscribes to ``/aeropend/joint_states`` and reads the bridge's CPU time from /proc.

    python -m bench.bench_bridge_node --seconds 10 [--save]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from sensor_msgs.msg import JointState

from aeropend_bridge.fake_mcu import FakeMcu
from aeropend_sim.contract import TOPIC_JOINT_STATES
from aeropend_sim.ros.harness import isolated_env, node_command, private_node, random_domain, stop
from aeropend_sim.ros.ros_contract import SAMPLE_SUB_QOS


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run(seconds: float) -> dict[str, float]:
    """Measure for ``seconds`` after a 3 s warm-up."""
    domain = random_domain(101, 200)
    tmp = Path(tempfile.mkdtemp())
    mcu = FakeMcu(tmp / "tty").start()
    proc = subprocess.Popen([*node_command("bridge", "aeropend_bridge.bridge_node"), "--ros-args",
                             "-p", f"port:={tmp / 'tty'}"], env=isolated_env(domain),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    got: list[int] = [0]
    try:
        with private_node("bench_bridge", domain) as (node, ex):
            node.create_subscription(JointState, TOPIC_JOINT_STATES, lambda m: got.__setitem__(0, got[0] + 1),
                                     SAMPLE_SUB_QOS)
            end = time.monotonic() + 3.0
            while time.monotonic() < end:
                ex.spin_once(timeout_sec=0.01)
            n0, c0, t0 = got[0], _cpu_s(proc.pid), time.monotonic()
            while time.monotonic() < t0 + seconds:
                ex.spin_once(timeout_sec=0.01)
            n1, c1, t1 = got[0], _cpu_s(proc.pid), time.monotonic()
    finally:
        stop(proc, signal.SIGINT, timeout=10)
        mcu.stop()
    return {"seconds": t1 - t0, "frames_per_s_received": (n1 - n0) / (t1 - t0),
            "firmware_rate_hz": 16e6 / 64 / 510,
            "bridge_cpu_percent_of_one_core": 100 * (c1 - c0) / (t1 - t0),
            # CPU per frame: less sensitive to other load on the machine than the percentage
            "bridge_cpu_us_per_frame": 1e6 * (c1 - c0) / max(n1 - n0, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--save", action="store_true", help="write bench/results/bridge_node.json")
    a = ap.parse_args()
    res: dict[str, object] = {**run(a.seconds), "host_load_avg_1min": os.getloadavg()[0],
                              "host_cpus": os.cpu_count()}
    print(json.dumps(res, indent=1))
    if a.save:
        (Path(__file__).parent / "results" / "bridge_node.json").write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
