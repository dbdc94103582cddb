"""Reproducer: the real-time simulator node built its plant in the sampler thread, after it offered
its topics, so a client that drove it at once saw its first command applied late.

Two fresh-clone CIs (of 072b91e and of 945e438) failed ``test_passes_on_sim_node``: ``bridge_check``
saw τ = 0 in samples received more than 0.5 s after its first command of τ = 0.3, and stamps 0.5 s
behind their receive time. ``sim_node`` created its publishers and its command subscription, then
started the sampler thread, which built the plant: loading the compiled kernels from the disk cache
(numba's cache loader imports ``scipy.linalg`` and numba's array maths) takes 0.5-1 s and holds the
GIL most of that time. Meanwhile the checker had found the topics and started driving; the node's
executor thread, starved, took the commands late, and sample 0 was published that late (an overrun:
the stamps lag wall time by it for the rest of the run). Measured on 2026-12-01 before the fix, five
runs: τ applied 257, 304, 369, 439 ms and once not within 0.5 s after the first command (a FAIL);
stamps 440-688 ms behind their receive time. The node now builds and warms the plant before it
creates its topics.

This script runs ``sim_node`` (real time, thesis rig) and ``bridge_check`` against it ``--runs``
times and prints, per run, the delay of the first applied command and the largest stamp age; it
exits 1 when a run fails the check or applies the command later than ``--limit-ms``::

    .venv/bin/python -m bench.repro.sim_start_stall --runs 5
"""

from __future__ import annotations

import argparse
import re
import signal
import subprocess
import sys

from aeropend_sim.ros.harness import isolated_env, node_command, random_domain, stop

CHECK = node_command("bridge_check", "aeropend_bridge.bridge_check_node")
SIM = node_command("sim_node", "aeropend_sim.ros.sim_node")


def one_run() -> tuple[float | None, float | None, bool]:
    """(ms from the first command to τ applied or None, largest stamp age [ms] or None, passed)."""
    env = isolated_env(random_domain(101, 200))
    sim = subprocess.Popen([*SIM, "--ros-args", "-p", "mode:=realtime"], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        r = subprocess.run([*CHECK, "--node", "/aeropend_sim", "--drive", "1.5", "--silence", "0.8",
                            "--discover", "20"], env=env, capture_output=True, text=True, timeout=60)
    finally:
        stop(sim, signal.SIGINT, timeout=10)
    applied = re.search(r"applied (\d+) ms after the first command", r.stdout)
    age = re.search(r"stamps within ([\d.]+) ms of", r.stdout)
    return (float(applied[1]) if applied else None, float(age[1]) if age else None, r.returncode == 0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--limit-ms", type=float, default=250.0,
                    help="a first command applied later than this counts as the stall (default 250)")
    args = ap.parse_args()
    bad = 0
    for k in range(args.runs):
        applied, age, ok = one_run()
        late = applied is None or applied > args.limit_ms
        bad += (not ok) or late
        print(f"run {k + 1}: τ applied {'-' if applied is None else f'{applied:.0f}'} ms after the first "
              f"command, stamps within {'-' if age is None else f'{age:.1f}'} ms of their receipt, "
              f"check {'passed' if ok else 'FAILED'}", flush=True)
    print(f"{bad} of {args.runs} runs stalled or failed")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
