"""Reproducer: a ROS 2 Python node whose stderr nobody reads freezes, every thread of it.

The 30-min stream run of ``bench_data_plane.py`` once received no sample after ≈ 500 s: the
benchmark read the plant's stderr pipe only at the end, the pipe filled (64 KiB) and the plant's
next log call blocked in ``RcutilsLogger.log`` (seen with py-spy). rclpy's log call keeps the GIL
while it writes, so the real-time sampler thread stops too, although it does not log itself
(docs/data_plane.md). This script makes it happen in seconds: the plant's stderr is a pipe shrunk
to one page (4 KiB) that is never read, and a publisher sends a valid duty command every 0.5 s, so
the plant's 0.25 s command timeout fires twice a second and is logged. A subscriber counts the
samples in each 5 s window; they stop once the pipe is full (measured: 1887, 2405, 1923, then 0
from 15-20 s on). The cure is on the parent's side: read the node's output or send it to a file,
as ``ros2 launch``, the main job and the benchmarks do. Exits 1 when the samples stopped::

    .venv/bin/python -m bench.repro.unread_stderr --seconds 40
"""

from __future__ import annotations

import argparse
import fcntl
import subprocess
import sys
import time

from aeropend_sim.ros.harness import isolated_env, node_command, private_node, random_domain, reap

F_SETPIPE_SZ = 1031  # Linux fcntl: set a pipe's capacity


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=40.0)
    args = ap.parse_args()
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from aeropend_sim.contract import TOPIC_DUTY_CYCLE, TOPIC_JOINT_STATES
    from aeropend_sim.ros.ros_contract import COMMAND_QOS, SAMPLE_SUB_QOS

    domain = random_domain(101, 200)
    plant = subprocess.Popen([*node_command("sim_node"), "--ros-args", "-p", "mode:=realtime"],
                             env=isolated_env(domain), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    fcntl.fcntl(plant.stderr.fileno(), F_SETPIPE_SZ, 4096)  # never read below
    counts: list[int] = []
    try:
        with private_node("repro_unread_stderr", domain) as (node, executor):
            got = [0]

            def on_sample(_msg: JointState) -> None:
                got[0] += 1

            node.create_subscription(JointState, TOPIC_JOINT_STATES, on_sample, SAMPLE_SUB_QOS)
            pub = node.create_publisher(Float64, TOPIC_DUTY_CYCLE, COMMAND_QOS)
            t0 = time.monotonic()
            next_cmd, window_end = t0, t0 + 5.0
            while time.monotonic() - t0 < args.seconds:
                executor.spin_once(timeout_sec=0.01)
                now = time.monotonic()
                if now >= next_cmd:
                    pub.publish(Float64(data=0.3))
                    next_cmd = now + 0.5
                if now >= window_end:
                    counts.append(got[0])
                    got[0] = 0
                    window_end += 5.0
                    print(f"{now - t0:5.1f} s: {counts[-1]} samples in the last 5 s", flush=True)
    finally:
        reap(plant)
    stalled = any(c == 0 for c in counts[1:])
    print("STALL: the plant stopped sampling" if stalled else "ok: the plant kept sampling")
    return 1 if stalled else 0


if __name__ == "__main__":
    sys.exit(main())
