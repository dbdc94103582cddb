"""Reproducer: the main job's bag lost the tail of ``/clock`` while every sample was there.

A fresh-clone CI run (359ee84) failed ``test_record_play_roundtrip.py::test_the_main_jobs_bag_replays``
with 188 ``/clock`` ticks against 1101 ``joint_states`` messages in the lock-step bag. The recorded
ticks were the first ones, with consecutive publication sequence numbers: the recorder's ``/clock``
reader stopped receiving, and everything after it was lost. Cause: at shutdown the lock-step plant
waited for its readers' acknowledgements (:func:`aeropend_sim.ros.node_shell.wait_acknowledged`) on
its two sample writers only, not on its ``/clock`` writer. A tick lost on the way (a full transport
buffer while the recorder was not scheduled) holds back every later tick in the reliable reader
until the writer's next heartbeat (Fast DDS: every 3 s) repairs it; a 2-3 s run ends first and the
plant's exit destroys the writer with the repair pending (the mechanism of
``bench/repro/writer_exit.py``, on a writer the fix there had not listed).

This script runs ``--parallel`` main-job graphs (recorder, lock-step plant, excitation; two steps)
at a time beside ``--hogs`` busy processes each, ``--runs`` times, and counts in every bag the
``/clock`` ticks against the ``joint_states`` messages (one each per publication). Measured on
2 cores, 3 parallel, 1 hog each: before the fix 2 of 21 bags lost the tail (130 of 1102 and 243 of
1104 ticks kept); after it 0 of 30. Exit status 1 if any bag lost a tick::

    .venv/bin/python -m bench.repro.lockstep_clock_tail --parallel 3 --runs 10
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path


def one_run(out: Path) -> tuple[int, int]:
    """One main-job graph into ``out``; returns (``/clock`` ticks, ``joint_states`` messages)."""
    from aeropend_ident.io.bag_reader import RawBagReader
    from aeropend_ident.pipeline import run_graph
    from aeropend_sim.contract import TOPIC_CLOCK, TOPIC_JOINT_STATES

    signal_params = ["signal:=lhs", "n:=2", "tau_min:=0.35", "tau_max:=0.7", "hold_min:=1.0", "hold_max:=1.2"]
    bag = run_graph(out, "thesis_rig", "lockstep", 1, signal_params, noise=True)
    with RawBagReader(bag) as reader:
        counts = {name: topic.count for name, topic in reader.topics.items()}
    return counts.get(TOPIC_CLOCK, 0), counts[TOPIC_JOINT_STATES]


def worker(runs: int, hogs: int) -> int:
    """``runs`` graphs one after the other, each on its own ROS domain, beside ``hogs`` busy loops."""
    from aeropend_sim.ros.harness import DISCOVERY, random_domain

    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(hogs)]
    lost = 0
    try:
        for k in range(runs):
            os.environ.update(ROS_DOMAIN_ID=str(random_domain()), **DISCOVERY)
            clock, samples = one_run(Path(tempfile.mkdtemp(prefix="clock_tail_")) / "main")
            lost += clock != samples
            flag = "  TAIL LOST" if clock != samples else ""
            print(f"run {k}: /clock {clock} joint_states {samples}{flag}", flush=True)
    finally:
        for p in busy:
            p.kill()
    return lost


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--parallel", type=int, default=3, help="graphs running at once")
    p.add_argument("--runs", type=int, default=10, help="graphs per parallel worker")
    p.add_argument("--hogs", type=int, default=1, help="busy processes beside each worker")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        return 1 if worker(args.runs, args.hogs) else 0
    procs = [subprocess.Popen([sys.executable, "-m", "bench.repro.lockstep_clock_tail", "--worker",
                               "--runs", str(args.runs), "--hogs", str(args.hogs)])
             for _ in range(args.parallel)]
    failed = sum(proc.wait() != 0 for proc in procs)
    print(f"{failed} of {args.parallel} workers saw a bag lose /clock ticks")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
