"""Reproducer: a Python subscriber in a process with a large heap loses real-time samples.

``test_sim_node_ros.py::test_realtime_rate_and_stamps`` subscribes to the plant's 488 Hz sample
topics from inside the pytest process. Late in a full test run that process holds millions of
objects; the cyclic garbage collector's full (generation 2) collections then scan them all while
the subscriber's callbacks keep allocating (one tuple and one message per sample), and the
subscriber stops taking samples for the length of a collection. A best-effort keep-last queue of
100 samples (0.2 s) overflows during a long one: the fresh-clone run that failed received 1249 of
~1709 samples in 3.5 s, an earlier one showed a 1.32 s jump in the received stamps.

This script runs the real ``sim_node`` (``mode:=realtime``) and, in this process, the same
subscriber as the test, for ``--seconds`` with a ballast heap of ``--objects`` objects, once with
the collector on and once after ``gc.freeze()`` (the ballast moved to the permanent generation, as
``sim_node`` and the controller do for their own threads); with ``--force-gen2`` one full
collection runs in the middle of the window (what happens when the process reaches its
generation-2 threshold there). Per run it prints: samples received / sample slots, the longest gap
between receipts, the number and longest duration of generation-2 collections (``gc.callbacks``).

Measured (2-core machine, 8 million ballast objects, ``--force-gen2``): collector on, the full
collection took 543 and 653 ms, the subscriber received 90.4 % and 87.8 % of the samples (the
test requires 95 %); after ``gc.freeze()`` it took 2.9 and 2.6 ms, 100 % received. Without the
forced collection no generation-2 collection fell in a 3.5 s window (100 % received either way):
the loss needs the threshold to be reached during the window, hence an intermittent failure.

Usage: ``.venv/bin/python -m bench.repro.subscriber_heap [--objects 3000000] [--seconds 3.5]``
"""

from __future__ import annotations

import argparse
import gc
import json
import signal
import subprocess
import sys
import threading
import time

import numpy as np

from aeropend_sim.ros.harness import (
    frozen_gc,
    gc_pauses,
    isolated_env,
    node_command,
    private_node,
    random_domain,
    reap,
    stop,
)

PERIOD_NS = 2_048_000


def run(domain: int, seconds: float, freeze: bool, force: bool) -> dict:
    from sensor_msgs.msg import BatteryState, JointState

    from aeropend_sim.contract import TOPIC_ARMATURE, TOPIC_JOINT_STATES
    from aeropend_sim.ros.ros_contract import SAMPLE_SUB_QOS

    args = [*node_command("sim_node", "aeropend_sim.ros.sim_node"), "--ros-args", "-p", "rig:=thesis_sim",
            "-p", "mode:=realtime", "-p", "rt_priority:=20"]
    proc = subprocess.Popen(args, env=isolated_env(domain), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    js: list = []
    try:
        with private_node("heap_client", domain) as (node, executor):
            node.create_subscription(JointState, TOPIC_JOINT_STATES, lambda m: js.append(
                (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, time.monotonic_ns(), m)),
                SAMPLE_SUB_QOS)
            node.create_subscription(BatteryState, TOPIC_ARMATURE, lambda m: None, SAMPLE_SUB_QOS)
            end = time.monotonic() + 20.0
            while not js and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.005)
            with frozen_gc() if freeze else gc_pauses() as pauses:
                js.clear()
                if force:  # the full collection a late pytest process runs when its threshold is reached
                    threading.Timer(seconds / 2, gc.collect).start()
                end = time.monotonic() + seconds
                while time.monotonic() < end:
                    executor.spin_once(timeout_sec=0.005)
    finally:
        stop(proc, signal.SIGTERM)
        reap(proc)
    stamps = np.array([s for s, _, _ in js], dtype=np.int64)
    arrivals = np.array([a for _, a, _ in js], dtype=np.int64)
    slots = int((stamps[-1] - stamps[0]) // PERIOD_NS) + 1 if stamps.size > 1 else 0
    return {"freeze": freeze, "received": int(stamps.size), "slots": slots,
            "received_fraction": stamps.size / slots if slots else 0.0,
            "longest_receipt_gap_ms": float(np.max(np.diff(arrivals)) * 1e-6) if arrivals.size > 1 else None,
            "gen2_collections": len(pauses), "longest_gen2_ms": 1e3 * max(pauses, default=0.0)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", type=int, default=3_000_000, help="ballast heap (objects tracked by the GC)")
    ap.add_argument("--seconds", type=float, default=3.5)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--force-gen2", action="store_true",
                    help="run one full collection in the middle of each window (as a late pytest process "
                         "does when its generation-2 threshold is reached)")
    args = ap.parse_args(argv)
    ballast = [[i] for i in range(args.objects)]  # lists: tracked by the cyclic collector
    out = []
    for _ in range(args.repeats):
        for freeze in (False, True):
            r = run(random_domain(), args.seconds, freeze, args.force_gen2)
            out.append(r)
            print(json.dumps(r), flush=True)
    del ballast
    return 0


if __name__ == "__main__":
    sys.exit(main())
