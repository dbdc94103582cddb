"""Reproducer: a reliable writer that exits before its readers acknowledged loses the tail.

Issue 15 (data plane), seventh cause. In 1 of 12 hogged main-job graphs the bag lacked 307 of
9768 duty-cycle commands while every sample was there (``bench/results/data_plane_ack_before``):
the excitation node exits after its last command, and a DDS writer that is destroyed drops what
its reliable readers have not acknowledged; a sample lost on the way (full socket buffer while the
reader's process was not scheduled) is repaired only after the writer's next heartbeat, which
never comes. The excitation waited at most 2 s for acknowledgements and did not say when that ran
out; the lock-step plant did not wait at all.

This script makes the reader's process unschedulable deterministically: a listener process
(reliable keep-all, like the recorder in lock-step) is stopped with SIGSTOP, a writer process
publishes ``--count`` messages (reliable keep-all) and exits, then the listener is continued and
counts what arrives. ``--wait none`` exits right after publishing (the old plant),
``--wait 2`` waits up to 2 s for acknowledgements (the old excitation), ``--wait node_shell`` uses
:func:`aeropend_sim.ros.node_shell.wait_acknowledged` (the fix). The listener is stopped for
``--stall`` seconds in every mode. Results: ``bench/results/repro_writer_exit.json``::

    .venv/bin/python -m bench.repro.writer_exit --runs 5
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from aeropend_sim.ros.harness import isolated_env, random_domain

ROOT = Path(__file__).resolve().parents[2]

TOPIC = "/repro/commands"


def _qos():
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE, depth=0)


def listener(idle_s: float) -> int:
    """Count messages until none arrived for ``idle_s`` after the first one; print the count."""
    import rclpy
    from std_msgs.msg import Float64

    rclpy.init()
    node = rclpy.create_node("repro_listener")
    got: list[float] = []
    node.create_subscription(Float64, TOPIC, lambda m: got.append(m.data), _qos())
    print("ready", flush=True)
    last = time.monotonic()
    n = 0
    while True:
        rclpy.spin_once(node, timeout_sec=0.05)
        if len(got) != n:
            n, last = len(got), time.monotonic()
        elif n and time.monotonic() - last > idle_s:
            break
        elif not n and time.monotonic() - last > 60.0:
            break
    print(f"received {n}", flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def writer(count: int, wait: str) -> int:
    """Publish ``count`` messages once the listener is matched, then wait as ``wait`` says."""
    import rclpy
    from rclpy.duration import Duration
    from std_msgs.msg import Float64

    from aeropend_sim.ros.node_shell import wait_acknowledged

    rclpy.init()
    node = rclpy.create_node("repro_writer")
    pub = node.create_publisher(Float64, TOPIC, _qos())
    while pub.get_subscription_count() == 0:
        rclpy.spin_once(node, timeout_sec=0.05)
    print("matched", flush=True)
    sys.stdin.readline()  # the driver stops the listener, then says go
    for k in range(count):
        pub.publish(Float64(data=float(k)))
    acked = None
    if wait == "node_shell":
        acked = wait_acknowledged(node, [pub])
    elif wait != "none":
        acked = pub.wait_for_all_acked(Duration(seconds=float(wait)))
    print(f"published {count} acked {acked}", flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def one_run(count: int, wait: str, stall: float) -> dict:
    env = isolated_env(random_domain(150, 230))
    me = [sys.executable, str(Path(__file__).resolve())]
    lis = subprocess.Popen([*me, "--role", "listener"], env=env, stdout=subprocess.PIPE, text=True)
    assert lis.stdout is not None
    assert lis.stdout.readline().strip() == "ready"
    wr = subprocess.Popen([*me, "--role", "writer", "--count", str(count), "--wait", wait], env=env,
                          stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert wr.stdout is not None and wr.stdin is not None
    assert wr.stdout.readline().strip() == "matched"
    time.sleep(0.5)  # discovery settles both ways
    os.kill(lis.pid, signal.SIGSTOP)
    t0 = time.monotonic()
    wr.stdin.write("go\n")
    wr.stdin.flush()
    time.sleep(stall)
    os.kill(lis.pid, signal.SIGCONT)
    out_w = wr.stdout.read()
    wr.wait(timeout=60)
    out_l = lis.stdout.read()
    lis.wait(timeout=120)
    received = int(out_l.split("received")[-1].split()[0])
    return {"wait": wait, "count": count, "stall_s": stall, "received": received,
            "lost": count - received, "writer": out_w.strip(), "seconds": round(time.monotonic() - t0, 2)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--role", choices=("driver", "listener", "writer"), default="driver")
    ap.add_argument("--count", type=int, default=5000)
    ap.add_argument("--wait", default="none")
    ap.add_argument("--stall", type=float, default=3.0, help="seconds the listener is stopped")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "repro_writer_exit.json")
    args = ap.parse_args()
    if args.role == "listener":
        return listener(idle_s=15.0)
    if args.role == "writer":
        return writer(args.count, args.wait)
    runs = []
    for wait in ("none", "2", "node_shell"):  # the old plant, the old excitation, the fix
        for k in range(args.runs):
            r = one_run(args.count, wait, args.stall)
            print(f"wait={wait} run {k}: received {r['received']} of {r['count']} ({r['writer']})",
                  flush=True)
            runs.append(r)
    modes = ("none", "2", "node_shell")
    summary = {w: {"runs": sum(r["wait"] == w for r in runs),
                   "runs_with_loss": sum(r["wait"] == w and r["lost"] > 0 for r in runs),
                   "lost": sum(r["lost"] for r in runs if r["wait"] == w)} for w in modes}
    args.out.write_text(json.dumps({"summary": summary, "runs": runs, "loadavg": os.getloadavg()}, indent=1))
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
