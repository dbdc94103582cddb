"""Benchmark of the simulated plant node in real-time mode.

Runs ``sim_node`` (mode realtime) in one subprocess and a subscriber in another, for 20 s of
measurement, and reports

* the achieved sample rate and the sample-period jitter (p50 / p99 / max of |Δt − T_s|) from the
  header stamps and from the arrival times at the subscriber,
* lost samples (gaps in the stamp grid seen by the best-effort subscriber) and the node's own
  overrun count (from its shutdown summary),
* the cost of one ``PlantStepper.step`` (p50 / p99, µs) measured in this process.

Writes ``bench/results/sim_node.json`` and prints a table::

    /tmp/venv/bin/python -m bench.bench_sim_node [--duration 20] [--rig thesis_rig]
        [--rt-priority 0 20] [--out bench/results/sim_node.json]

Each ``--rt-priority`` value is one run (0 = normal scheduling, the node's default; > 0 =
SCHED_FIFO for the sampler thread where permitted).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from aeropend_sim.contract import SAMPLE_PERIOD_S
from aeropend_sim.params import load_rig, shipped_rigs
from aeropend_sim.ros.harness import isolated_env, node_command, random_domain, reap, stop, summary_fields
from aeropend_sim.simulation import PlantStepper

HERE = Path(__file__).resolve().parent


# ------------------------------------------------------------------------------------- subscriber
def run_subscriber(out: Path, duration: float, warmup: float) -> int:
    """Subscriber process: record (stamp ns, arrival monotonic ns) of joint_states to ``out``."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState

    from aeropend_sim.contract import TOPIC_JOINT_STATES
    from aeropend_sim.ros.ros_contract import SAMPLE_SUB_QOS

    rclpy.init()
    node = rclpy.create_node("bench_subscriber")
    stamps: list[int] = []
    arrivals: list[int] = []
    recording = [False]

    def on_js(msg: JointState) -> None:
        if recording[0]:
            arrivals.append(time.monotonic_ns())
            stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        elif not stamps:
            recording.append(time.monotonic())  # first message seen

    node.create_subscription(JointState, TOPIC_JOINT_STATES, on_js, SAMPLE_SUB_QOS)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    deadline_first = time.monotonic() + 30.0
    while len(recording) == 1 and time.monotonic() < deadline_first:
        ex.spin_once(timeout_sec=0.05)
    if len(recording) == 1:
        print("no sample within 30 s", file=sys.stderr)
        return 1
    t_end = time.monotonic() + warmup
    while time.monotonic() < t_end:
        ex.spin_once(timeout_sec=0.01)
    recording[0] = True
    t_end = time.monotonic() + duration
    while time.monotonic() < t_end:
        ex.spin_once(timeout_sec=0.01)
    np.savez(out, stamps=np.asarray(stamps, dtype=np.int64), arrivals=np.asarray(arrivals, dtype=np.int64))
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# ------------------------------------------------------------------------------------- statistics
def jitter_stats(dt_ns: np.ndarray, span_ns: int, count: int, period_s: float) -> dict[str, float]:
    """Rate (count−1)/span and |Δt − T| statistics [µs] of the intervals ``dt_ns``."""
    dt = np.asarray(dt_ns, dtype=float) * 1e-9
    err = np.abs(dt - period_s) * 1e6
    return {
        "rate_hz": float((count - 1) / (span_ns * 1e-9)),
        "period_mean_us": float(dt.mean() * 1e6),
        "jitter_p50_us": float(np.percentile(err, 50)),
        "jitter_p99_us": float(np.percentile(err, 99)),
        "jitter_max_us": float(err.max()),
    }


def step_cost(rig_name: str, n: int = 5000) -> dict[str, float]:
    """Wall time of ``PlantStepper.step`` [µs] over a square-wave duty sequence."""
    rig = load_rig(rig_name)
    stepper = PlantStepper(rig, seed=0)
    t = np.empty(n)
    for k in range(n):
        duty = 0.55 if (k // 250) % 2 else 0.4
        t0 = time.perf_counter()
        stepper.step(duty)
        t[k] = time.perf_counter() - t0
    us = t * 1e6
    return {"p50_us": float(np.percentile(us, 50)), "p99_us": float(np.percentile(us, 99)),
            "max_us": float(us.max()), "n": n}


def measure_node(rig: str, rt_priority: int, duration: float, warmup: float) -> dict:
    """Run sim_node (realtime) and a subscriber process; return rate/jitter/overrun figures."""
    env = isolated_env(random_domain(101, 200))
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "sub.npz"
        node = subprocess.Popen(
            [*node_command("sim_node", "aeropend_sim.ros.sim_node"), "--ros-args", "-p", f"rig:={rig}",
             "-p", "mode:=realtime", "-p", f"rt_priority:={rt_priority}"],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )
        sub = subprocess.Popen(
            [sys.executable, __file__, "--subscriber", str(data), "--duration", str(duration),
             "--warmup", str(warmup)],
            env=env,
        )
        try:
            sub_status = sub.wait(timeout=duration + warmup + 60)
        finally:
            reap(sub)
            node_err = stop(node, signal.SIGINT, timeout=10, kill_on_timeout=True).stderr
        if sub_status != 0:
            raise RuntimeError(f"subscriber failed (status {sub_status}); node log:\n{node_err}")
        rec = np.load(data)
        stamps, arrivals = rec["stamps"], rec["arrivals"]
    period = load_rig(rig).sample_period
    k = np.rint((stamps - stamps[0]) / (period * 1e9)).astype(np.int64)
    contiguous = np.flatnonzero(np.diff(k) == 1)
    return {
        "rt_priority": rt_priority,
        "fifo_granted": rt_priority > 0 and "cannot set SCHED_FIFO" not in node_err,
        "loadavg_1min": {"before": load_before, "after": os.getloadavg()[0]},
        "received": int(stamps.size),
        "lost_at_subscriber": int(k[-1] + 1 - stamps.size),
        # intervals between consecutive samples only: a sample lost in transport is not jitter
        "stamps": jitter_stats(np.diff(stamps)[contiguous], int(stamps[-1] - stamps[0]), stamps.size, period),
        "arrivals": jitter_stats(np.diff(arrivals)[contiguous], int(arrivals[-1] - arrivals[0]), stamps.size,
                                 period),
        "node_summary": summary_fields(node_err),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="measurement time [s] per run")
    ap.add_argument("--warmup", type=float, default=1.0, help="time [s] skipped after the first sample")
    ap.add_argument("--rig", default="thesis_rig" if "thesis_rig" in shipped_rigs() else "thesis_sim")
    ap.add_argument("--rt-priority", type=int, nargs="+", default=[0, 20],
                    help="sim_node rt_priority of each run (0 = normal scheduling)")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "sim_node.json")
    ap.add_argument("--subscriber", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.subscriber is not None:
        return run_subscriber(args.subscriber, args.duration, args.warmup)

    period = load_rig(args.rig).sample_period
    runs = [measure_node(args.rig, prio, args.duration, args.warmup) for prio in args.rt_priority]
    result = {
        "benchmark": "sim_node realtime",
        "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "host": {"machine": platform.machine(), "cpus": os.cpu_count(), "python": platform.python_version()},
        "rig": args.rig,
        "duration_s": args.duration,
        "nominal_rate_hz": 1.0 / period,
        "sample_period_s": SAMPLE_PERIOD_S,
        "runs": runs,
        "step_cost_us": step_cost(args.rig),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")

    def fmt3(d: dict) -> str:
        return f"{d['jitter_p50_us']:.0f} / {d['jitter_p99_us']:.0f} / {d['jitter_max_us']:.0f}"

    rows = [("", *(f"rt_priority {r['rt_priority']}" + ("" if r["fifo_granted"] or not r["rt_priority"]
                                                         else " (denied)") for r in runs))]
    rows += [
        ("rate from stamps [Hz]", *(f"{r['stamps']['rate_hz']:.2f}" for r in runs)),
        ("rate from arrivals [Hz]", *(f"{r['arrivals']['rate_hz']:.2f}" for r in runs)),
        ("stamp jitter p50/p99/max [µs]", *(fmt3(r["stamps"]) for r in runs)),
        ("arrival jitter p50/p99/max [µs]", *(fmt3(r["arrivals"]) for r in runs)),
        ("received / lost samples", *(f"{r['received']} / {r['lost_at_subscriber']}" for r in runs)),
        ("node overruns", *(r["node_summary"].get("overruns", "?") for r in runs)),
        ("node dropped time [ms]", *(r["node_summary"].get("dropped_ms", "?") for r in runs)),
        ("node max lateness [ms]", *(r["node_summary"].get("max_late_ms", "?") for r in runs)),
        ("load avg before/after", *(f"{r['loadavg_1min']['before']:.2f} / {r['loadavg_1min']['after']:.2f}"
                                    for r in runs)),
    ]
    widths = [max(len(str(row[i])) for row in rows) for i in range(len(rows[0]))]
    print(f"sim_node realtime benchmark: rig {args.rig}, {args.duration:g} s per run, "
          f"nominal {1.0 / period:.2f} Hz, {os.cpu_count()} CPUs")
    for row in rows:
        print("  " + "  ".join(f"{c:<{w}}" for c, w in zip(row, widths, strict=True)))
    sc = result["step_cost_us"]
    print(f"  PlantStepper.step: p50 {sc['p50_us']:.1f} µs, p99 {sc['p99_us']:.1f} µs (n = {sc['n']})")
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
