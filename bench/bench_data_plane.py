"""Reproducer and benchmark of the DDS data plane: do the plant's samples reach every subscriber?

Two scenarios, each run ``--runs`` times, optionally with a concurrent CPU hog (one busy
process, ``stress --cpu 1``-like):

``lockstep``
    The main job's node graph (``pipeline.run_graph``: recorder + lock-step ``sim_node`` +
    excitation, separate processes), one attempt per run, no retry. Per run: samples the plant
    published (its shutdown summary) vs ``joint_states`` messages in the bag, the excitation's
    commands (one per sample but the last) vs ``duty_cycle`` messages in the bag, the longest gap
    in the recorded stamps (simulated time) and the number of stalls (stamp gaps > 20 ms).
``stream``
    A real-time ``sim_node`` (``timing_log``: the instant every sample was taken) and two plain
    rclpy subscriber processes (``--listener``, contract ``SAMPLE_SUB_QOS``, or ``--sub-depth``).
    Per subscriber: samples received vs published while it listened, the longest gap in received
    stamps (stamps are ``start + k·T_s``, so a stamp gap means lost samples, never a plant
    overrun), stalls (stamp gaps > 20 ms) and the longest gap in receive time, attributed to the
    plant when the plant's own sample instants have a gap there too (an overrun), else to the
    delivery.

Results: ``bench/results/data_plane[_<tag>].json`` and ``.md`` (per run and totals). Examples::

    .venv/bin/python -m bench.bench_data_plane --scenario lockstep --runs 50 --hog on
    .venv/bin/python -m bench.bench_data_plane --scenario stream --duration 1800 --hog off
    .venv/bin/python -m bench.bench_data_plane --runs 10 --hog both --tag before

The environment of the nodes is this process's (``FASTRTPS_DEFAULT_PROFILES_FILE``,
``RMW_FASTRTPS_PUBLICATION_MODE``, ... apply), each run on a private ``ROS_DOMAIN_ID`` with
localhost-only discovery.
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
from typing import Any

import numpy as np

from aeropend_sim.contract import TOPIC_DUTY_CYCLE
from aeropend_sim.ros.harness import isolated_env, node_command, random_domain, stop, summary_fields

ROOT = Path(__file__).resolve().parents[1]

RESULTS = ROOT / "bench" / "results"
PERIOD_NS = 2_048_000
#: A gap in received stamps longer than this is a stall (issue 15: 20 ms ≈ 10 samples).
STALL_NS = 20_000_000
HOG = [sys.executable, "-c", "while True: pass"]


# ------------------------------------------------------------------------------ listener process
def listener(out: Path, capacity: int, depth: int) -> int:
    """Subscriber process: record (header stamp, monotonic receipt) of every ``joint_states``.

    Subscribes to both sample topics, as the controller does, with the contract's subscription
    QoS (best effort, volatile) and a keep-last queue of ``depth`` (0 = ``SAMPLE_SUB_QOS``).
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import BatteryState, JointState

    from aeropend_sim.contract import TOPIC_ARMATURE, TOPIC_JOINT_STATES
    from aeropend_sim.ros.node_shell import init_with_stop_event

    if depth <= 0:
        from aeropend_sim.ros import ros_contract
        qos = ros_contract.SAMPLE_SUB_QOS
    else:  # explicit depth (also runs against a checkout from before SAMPLE_SUB_QOS existed)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                         reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)

    stop_event = init_with_stop_event(None)
    stamps = np.zeros(capacity, dtype=np.int64)
    recv = np.zeros(capacity, dtype=np.int64)
    n = [0]

    def on_sample(msg: JointState) -> None:
        i = n[0]
        if i < capacity:
            stamps[i] = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            recv[i] = time.monotonic_ns()
            n[0] = i + 1

    node = rclpy.create_node("data_plane_listener")
    node.create_subscription(JointState, TOPIC_JOINT_STATES, on_sample, qos)
    node.create_subscription(BatteryState, TOPIC_ARMATURE, lambda msg: None, qos)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while not stop_event.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    finally:
        np.savez(out, stamp_ns=stamps[:n[0]], recv_ns=recv[:n[0]])
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


# ------------------------------------------------------------------------------------ analysis
def gaps(values: np.ndarray, threshold: int) -> tuple[int, int, np.ndarray]:
    """(longest step, number of steps > threshold, indices of those steps) of a sorted array."""
    if values.size < 2:
        return 0, 0, np.zeros(0, dtype=int)
    d = np.diff(values)
    idx = np.flatnonzero(d > threshold)
    return int(d.max()), int(idx.size), idx


def stream_stats(stamps: np.ndarray, recv: np.ndarray, plant_stamps: np.ndarray,
                 plant_taken: np.ndarray) -> dict[str, Any]:
    """Delivery figures of one subscriber against the plant's record of what it published."""
    if stamps.size == 0:
        return {"received": 0, "published": 0, "fraction": 0.0, "stalls": 0}
    lo, hi = int(stamps.min()), int(stamps.max())
    window = (plant_stamps >= lo) & (plant_stamps <= hi)
    published = int(np.count_nonzero(window))
    unique = np.unique(stamps)
    longest_stamp, stalls, _ = gaps(unique, STALL_NS)
    # receive-time gaps: does the plant's own sampling show a gap there (an overrun)?
    order = np.argsort(recv)
    r = recv[order]
    longest_recv, recv_gaps, idx = gaps(r, STALL_NS)
    latency = (recv - _taken_of(stamps, plant_stamps, plant_taken)) / 1e6
    by_plant = 0
    for i in idx:
        k = np.searchsorted(plant_taken, [r[i], r[i + 1]])
        seg = plant_taken[max(k[0] - 1, 0):min(k[1] + 1, plant_taken.size)]
        if seg.size >= 2 and np.diff(seg).max() > STALL_NS // 2:
            by_plant += 1
    return {
        "received": int(unique.size), "published": published,
        "fraction": unique.size / published if published else 0.0,
        "lost": published - int(unique.size),
        "longest_stamp_gap_ms": longest_stamp / 1e6, "stalls": stalls,
        "longest_recv_gap_ms": longest_recv / 1e6, "recv_gaps": recv_gaps,
        "recv_gaps_by_plant_overrun": by_plant,
        "latency_p50_ms": float(np.percentile(latency, 50)), "latency_max_ms": float(latency.max()),
    }


def _taken_of(stamps: np.ndarray, plant_stamps: np.ndarray, plant_taken: np.ndarray) -> np.ndarray:
    idx = np.clip(np.searchsorted(plant_stamps, stamps), 0, plant_stamps.size - 1)
    return plant_taken[idx]


# ------------------------------------------------------------------------------------ scenarios
def run_stream(duration: float, rt_priority: int, depth: int, tmp: Path) -> dict[str, Any]:
    """One real-time run: plant + two listeners for ``duration`` seconds."""
    env = isolated_env(random_domain(101, 200))
    timing = tmp / "timing.npz"
    outs = [tmp / f"listener{i}.npz" for i in range(2)]
    capacity = int(duration * 600) + 10_000
    cmd = [*node_command("sim_node"), "--ros-args", "-p", "mode:=realtime", "-p", "noise:=true",
           "-p", f"timing_log:={timing}", "-p", f"timing_capacity:={capacity}",
           "-p", f"rt_priority:={rt_priority}"]
    # node output goes to files: a pipe nobody reads during a long run fills up (64 KiB) and then
    # blocks the node's next log call (it stopped the plant's samples after ≈ 10 min once)
    plant_log = tmp / "sim_node.log"
    with plant_log.open("w") as f:
        plant = subprocess.Popen(cmd, env=env, stdout=f, stderr=subprocess.STDOUT, text=True)
    subs = []
    for i, o in enumerate(outs):
        with (tmp / f"listener{i}.log").open("w") as f:
            subs.append(subprocess.Popen([sys.executable, __file__, "--listener", str(o), "--capacity",
                                          str(capacity), "--sub-depth", str(depth)],
                                         env=env, stdout=f, stderr=subprocess.STDOUT, text=True))
    try:
        time.sleep(duration + 3.0)  # discovery and matching, then the measured stretch
        stop_ns = time.monotonic_ns()
        for s in subs:
            stop(s, signal.SIGINT, timeout=30)
        stop(plant, signal.SIGINT, timeout=30)
    finally:
        for p in (*subs, plant):
            if p.poll() is None:
                p.kill()
                p.communicate()
    log = plant_log.read_text(errors="replace")
    fields = summary_fields(log)
    t = np.load(timing)
    ps, pt = t["stamp_ns"], t["taken_ns"]
    late = np.diff(pt)
    published = int(fields.get("samples", -1))
    run: dict[str, Any] = {
        # the plant's own count (its summary) and how many of those its timing log holds
        "plant_published": published, "plant_logged": int(ps.size),
        "plant_overruns": int(fields.get("overruns", -1)),
        "plant_longest_sample_interval_ms": float(late.max() / 1e6) if late.size else 0.0,
        # the sampler must have run to the end: its last sample taken just before the stop
        "plant_last_sample_before_stop_s": round((stop_ns - int(pt[-1])) / 1e9, 3) if pt.size else None,
        "plant_errors": [ln for ln in log.splitlines() if "ERROR" in ln or "stopped at sample" in ln][:5],
        "subscribers": [],
    }
    for o in outs:
        d = np.load(o)
        run["subscribers"].append(stream_stats(d["stamp_ns"], d["recv_ns"], ps, pt))
    last = run["plant_last_sample_before_stop_s"]
    alive = last is not None and last < 1.0
    run["ok"] = alive and not run["plant_errors"] and all(
        s["stalls"] == 0 and s["fraction"] >= 0.999 for s in run["subscribers"])
    return run


def run_lockstep(tmp: Path, seed: int) -> dict[str, Any]:
    """One attempt of the main job's node graph; published vs recorded samples."""
    from aeropend_ident.errors import PipelineError
    from aeropend_ident.io.bags import read_bag
    from aeropend_ident.pipeline import DEFAULT_SIGNAL, plant_sample_count, run_graph

    env_domain = str(random_domain(101, 200))
    old = {k: os.environ.get(k) for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
    os.environ.update(ROS_DOMAIN_ID=env_domain, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    t0 = time.monotonic()
    try:
        bag = run_graph(tmp, "thesis_rig", "lockstep", seed, DEFAULT_SIGNAL, True)
        error = ""
    except PipelineError as exc:
        bag, error = None, str(exc)
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    seconds = time.monotonic() - t0
    published = plant_sample_count(tmp / "logs" / "sim_node.log")
    recorded, longest, stalls, where, first_k, last_k = 0, 0.0, 0, [], -1, -1
    commands = 0
    if bag is not None:
        try:
            rec = read_bag(bag, require_duty=False)
            commands = int(rec.meta["message_counts"].get(TOPIC_DUTY_CYCLE, 0))
            # lock-step stamps are k·T_s of simulated time from 0: the sample index is the stamp
            stamps = rec.stamp0_ns + np.round(rec.t * 1e9).astype(np.int64)
            recorded = int(stamps.size)
            first_k, last_k = (int(stamps[i]) // PERIOD_NS for i in (0, -1))
            g, stalls, idx = gaps(stamps, STALL_NS)
            longest = g / 1e6
            where = [[round(stamps[i] * 1e-9, 3), round((stamps[i + 1] - stamps[i]) * 1e-6, 1)] for i in idx]
        except Exception as exc:
            error = f"{type(exc).__name__}: {exc}"
    # the plant's last sample (no command after it) counts: it was published and must be recorded;
    # lock-step: one command per sample but the last, each answered by the plant, so the
    # excitation published published − 1 commands, and the bag must hold every one of them
    commands_published = (published or 1) - 1
    return {"published": published, "unacked_warnings": unacked_warnings(tmp / "logs"),
            "recorded": recorded, "lost": (published or 0) - recorded,
            "commands_published": commands_published, "commands_recorded": commands,
            "commands_lost": commands_published - commands,
            "longest_stamp_gap_ms": longest, "stalls": stalls, "stall_at_s_ms": where,
            "first_recorded_sample": first_k, "last_recorded_sample": last_k,
            "seconds": round(seconds, 1),
            "error": error,
            "ok": (not error and published is not None and recorded == published
                   and commands == commands_published)}


def unacked_warnings(logs: Path) -> list[str]:
    """Shutdown warnings of writers whose reliable readers had not acknowledged everything."""
    out = []
    for log in sorted(logs.glob("*.log")):
        out += [f"{log.stem}: {line.strip()}" for line in log.read_text(errors="replace").splitlines()
                if "not acknowledged within" in line]
    return out


# ------------------------------------------------------------------------------------ report
def machine() -> dict[str, Any]:
    return {"platform": platform.platform(), "cpus": os.cpu_count(), "python": platform.python_version(),
            "loadavg": os.getloadavg(),
            "env": {k: v for k, v in os.environ.items()
                    if k.startswith(("FASTRTPS", "FASTDDS", "RMW_", "ROS_"))}}


def render(result: dict[str, Any]) -> str:
    lines = [f"# Data-plane benchmark {result.get('tag') or ''}".rstrip(), "",
             f"Machine: {result['machine']['platform']}, {result['machine']['cpus']} CPUs; "
             f"node environment: `{result['machine']['env']}`", ""]
    for key, agg in result["totals"].items():
        lines.append(f"- **{key}**: " + ", ".join(f"{k} {v}" for k, v in agg.items()))
    lines += ["", "| scenario | hog | run | figures |", "|---|---|---|---|"]
    for r in result["runs"]:
        if r["scenario"] == "lockstep":
            span = f"{r.get('first_recorded_sample', '?')}..{r.get('last_recorded_sample', '?')}"
            fig = (f"published {r['published']}, recorded {r['recorded']} (samples {span}), commands "
                   f"{r.get('commands_recorded', '?')}/{r.get('commands_published', '?')}, longest gap "
                   f"{r['longest_stamp_gap_ms']:.1f} ms, stalls {r['stalls']}, {r['seconds']} s"
                   + (f", error: {r['error'][:80]}" if r["error"] else ""))
        else:
            fig = f"plant overruns {r['plant_overruns']}; " + "; ".join(
                f"sub{i}: {s['received']}/{s['published']} ({s['fraction']:.4%}), longest stamp gap "
                f"{s.get('longest_stamp_gap_ms', 0):.1f} ms, stalls {s['stalls']}, longest receive gap "
                f"{s.get('longest_recv_gap_ms', 0):.1f} ms ({s.get('recv_gaps_by_plant_overrun', 0)} of "
                f"{s.get('recv_gaps', 0)} > 20 ms at plant overruns)"
                for i, s in enumerate(r["subscribers"]))
        lines.append(f"| {r['scenario']} | {r['hog']} | {r['run']} | {'ok' if r['ok'] else 'FAIL'}: {fig} |")
    return "\n".join(lines) + "\n"


def totals(runs: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for scenario in ("lockstep", "stream"):
        for hog in ("off", "on"):
            rs = [r for r in runs if r["scenario"] == scenario and r["hog"] == hog]
            if not rs:
                continue
            agg: dict[str, Any] = {"runs": len(rs), "failed": sum(not r["ok"] for r in rs)}
            if scenario == "lockstep":
                agg["lost_samples"] = sum(max(r["lost"], 0) for r in rs)
                agg["runs_with_loss"] = sum(r["lost"] > 0 for r in rs)
                agg["lost_commands"] = sum(max(r.get("commands_lost", 0), 0) for r in rs)
                agg["runs_with_command_loss"] = sum(r.get("commands_lost", 0) > 0 for r in rs)
                agg["stalls"] = sum(r["stalls"] for r in rs)
                agg["errors"] = sum(bool(r["error"]) for r in rs)
            else:
                subs = [s for r in rs for s in r["subscribers"]]
                agg["min_fraction"] = round(min(s["fraction"] for s in subs), 5)
                agg["stalls"] = sum(s["stalls"] for s in subs)
                agg["longest_stamp_gap_ms"] = round(max(s.get("longest_stamp_gap_ms", 0) for s in subs), 1)
                agg["plant_overruns"] = sum(r["plant_overruns"] for r in rs)
            out[f"{scenario}, hog {hog}"] = agg
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", choices=("lockstep", "stream", "both"), default="both")
    ap.add_argument("--runs", type=int, default=10, help="runs per scenario and hog setting")
    ap.add_argument("--hog", choices=("off", "on", "both"), default="both")
    ap.add_argument("--duration", type=float, default=30.0, help="stream: seconds per run")
    ap.add_argument("--rt-priority", type=int, default=0, help="stream: sim_node rt_priority")
    ap.add_argument("--sub-depth", type=int, default=0,
                    help="stream: subscribers' queue depth (0 = the contract's SAMPLE_SUB_QOS)")
    ap.add_argument("--tag", default="", help="suffix of the result files")
    ap.add_argument("--listener", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--capacity", type=int, default=1 << 20, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.listener is not None:
        return listener(args.listener, args.capacity, args.sub_depth)
    scenarios = ("lockstep", "stream") if args.scenario == "both" else (args.scenario,)
    hogs = ("off", "on") if args.hog == "both" else (args.hog,)
    stem = RESULTS / ("data_plane" + (f"_{args.tag}" if args.tag else ""))
    result: dict[str, Any] = {"tag": args.tag, "machine": machine(), "args": vars(args) | {"listener": None},
                              "runs": []}
    for hog in hogs:
        hog_proc = subprocess.Popen(HOG) if hog == "on" else None
        try:
            for scenario in scenarios:
                for i in range(args.runs):
                    with tempfile.TemporaryDirectory(prefix="data_plane_") as tmp:
                        if scenario == "lockstep":
                            run = run_lockstep(Path(tmp), seed=i + 1)
                        else:
                            run = run_stream(args.duration, args.rt_priority, args.sub_depth, Path(tmp))
                    run.update(scenario=scenario, hog=hog, run=i + 1, loadavg=os.getloadavg()[0])
                    result["runs"].append(run)
                    brief = {k: run[k] for k in ("published", "recorded", "stalls", "seconds") if k in run}
                    if scenario == "stream":
                        brief = {"fractions": [round(s["fraction"], 5) for s in run["subscribers"]],
                                 "stalls": [s["stalls"] for s in run["subscribers"]],
                                 "overruns": run["plant_overruns"]}
                    verdict = "ok" if run["ok"] else "FAIL"
                    print(f"{scenario} hog {hog} run {i + 1}: {verdict} {brief}", flush=True)
                    result["totals"] = totals(result["runs"])
                    stem.with_suffix(".json").write_text(json.dumps(result, indent=1))
        finally:
            if hog_proc is not None:
                hog_proc.kill()
                hog_proc.wait()
    result["totals"] = totals(result["runs"])
    stem.with_suffix(".json").write_text(json.dumps(result, indent=1))
    stem.with_suffix(".md").write_text(render(result))
    print(json.dumps(result["totals"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
