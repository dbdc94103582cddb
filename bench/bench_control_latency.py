"""Benchmark: real-time closed loop at 488 Hz, plant and controller in separate processes.

Runs ``sim_node`` (``mode:=realtime``, ``timing_log``) and ``controller`` (``mode:=realtime``,
step to 0.4 rad) for ``--duration`` seconds of sample time and measures the issue's loop latency
**at the plant process**: for every sample, the monotonic instant the plant took it (its
sampler's wake-up at the deadline, just before publishing) → the instant the plant received
the command answering it. Commands are matched to the controller's trace rows (one per controlled
sample stamp) by their duty value in arrival order (:func:`match_commands`). Reported:

* ``loop_latency``: sample taken → command received at the plant, p50 / p99 / max [ms];
* ``missed_samples``: samples of the controlled window whose command did not reach the plant
  before the next sample was taken (the plant then applied the previous duty for one more
  period); causes: ``dropped_samples`` (never seen by the controller: best-effort sample QoS),
  ``late_commands`` (received after the next sample) and ``lost_commands`` (published by the
  controller, never received by the plant); ``missed_samples_after_first_500ms`` leaves out the
  start-up transient (the first samples after the controller's subscription matched);
* the controller's compute time (its receipt → command published), the plant's overruns and
  dropped time, the load average before and after the run (the machine is shared), and the step
  metrics of the run.

Platform check (``--wakeup-check`` seconds, default 20; 0 = skip): a bare SCHED_FIFO Python
thread (no ROS, memory locked, GC off) sleeping to absolute 2.048 ms deadlines, in its own
process; its wake-up lateness shows what the machine alone allows (stored as ``platform_wakeup``).

Stall monitor (during every run): one such sleeper per CPU, pinned to it, at a SCHED_FIFO
priority above the plant's and the controller's, waking every 2 ms for the whole run. A wake-up
later than ``--stall-ms`` (default 0.5 ms) marks the interval [deadline, wake-up] on that CPU as a
**machine stall**: the highest-priority thread of the machine could not run there, so nothing
aeropend does (priorities, executors, QoS) could have run either. Each missed sample is then
*attributed* (``missed_attribution``): ``all_cpus`` if every CPU was stalled at some instant between
the sample and the command's receipt (a whole-VM stall), ``some_cpus`` if at least one was, else
``none`` (the miss is aeropend's own). Every miss is listed with its latency split (plant publish
→ controller receipt, controller compute, publish → plant receipt) and the overlapping stall.

Options: ``--duration`` [s], ``--rt-priority`` (SCHED_FIFO for the plant's sampler/executor and
the controller's executor; 0 = normal scheduling), ``--executor events|single`` (controller),
``--plant-executor events|single`` (plant; baseline: single),
``--strategy``, ``--stall-ms``, ``--out`` (JSON path; default
``bench/results/control_latency.json``). Run on a quiet machine for the figure that matters:
``.venv/bin/python -m bench.bench_control_latency``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import minimum_filter1d

from aeropend_control.controller_core import SIGNALS
from aeropend_control.metrics import step_metrics
from aeropend_sim.ros.harness import (
    isolated_env,
    node_command,
    random_domain,
    reap,
    stop,
    summary_fields,
    summary_line,
)

OUT = Path(__file__).resolve().parent / "results" / "control_latency.json"
PERIOD_S = 2.048e-3
#: Samples of the start-up transient (first 0.5 s: DDS matching of the command path, first
#: callbacks) reported apart.
STARTUP = round(0.5 / PERIOD_S)
#: Default wake-up period of the stall monitors [ns] (``--monitor-period-ms``).
MONITOR_PERIOD_NS = 2_000_000
#: SCHED_FIFO priority of the stall monitors: above the plant's and the controller's (50) and DDS'.
MONITOR_PRIORITY = 70


def _pct(x: np.ndarray) -> dict[str, float]:
    x = x[np.isfinite(x)]
    return {"p50_ms": round(float(np.percentile(x, 50)), 4), "p99_ms": round(float(np.percentile(x, 99)), 4),
            "max_ms": round(float(x.max()), 4), "n": int(x.size)}


def _cpu_busy() -> tuple[int, int, int]:
    """(busy, total, steal) jiffies of all CPUs from /proc/stat (steal: time the hypervisor ran others)."""
    with open("/proc/stat", encoding="ascii") as fh:
        vals = [int(v) for v in fh.readline().split()[1:]]
    idle = vals[3] + vals[4]
    return sum(vals) - idle, sum(vals), vals[7] if len(vals) > 7 else 0


def match_commands(ctl_duty: np.ndarray, cmd_duty: np.ndarray) -> np.ndarray:
    """Row of the controller trace each received command answers (−1: none), by duty value.

    Commands arrive in publishing order (reliable topic) but some may be lost under load, so the
    i-th command is matched to the first trace row at or after the previous match with the same
    duty (float64, bit-exact over the wire). If equal duties repeat across a lost command the
    match is the earlier row, i.e. the latency is over-estimated, never under-estimated.
    """
    rows = np.full(cmd_duty.size, -1, dtype=np.int64)
    j = 0
    for i, v in enumerate(cmd_duty):
        jj = j
        while jj < ctl_duty.size and ctl_duty[jj] != v:
            jj += 1
        if jj < ctl_duty.size:
            rows[i] = jj
            j = jj + 1
    return rows


def analyse(trace_rows: np.ndarray, timing: dict[str, np.ndarray]) -> tuple[dict, list[dict]]:
    """Match commands to samples (see module doc) and compute latency and missed samples.

    Returns the result fields and the missed samples of the controlled window, each a dict with
    ``k`` (plant sample index), ``cause`` (``late`` / ``dropped`` / ``lost``), ``t_s`` (since the
    window's first sample), ``window_ns`` (monotonic [sample taken, command received or next
    sample taken]) and, for late commands, the latency and its split [ms].
    """
    col = {name: trace_rows[:, i] for i, name in enumerate(SIGNALS)}
    stamps, taken, recv = timing["stamp_ns"], timing["taken_ns"], timing["recv_ns"]
    ctl_stamp = np.round(col["stamp_s"] * 1e9).astype(np.int64)
    k_row = np.searchsorted(stamps, ctl_stamp - 100_000)  # plant sample of each controlled stamp
    near = stamps[np.minimum(k_row, stamps.size - 1)]
    if np.any(k_row >= stamps.size) or np.any(np.abs(near - ctl_stamp) > 1000):
        raise RuntimeError("controller stamps do not match the plant's samples")
    row = match_commands(col["duty"], timing["duty"])
    ok = row >= 0
    k, rcv = k_row[row[ok]], recv[ok]
    lat_ms = (rcv - taken[k]) * 1e-6
    nxt = np.minimum(k + 1, taken.size - 1)
    on_time = rcv < taken[nxt]
    window = np.arange(k_row[0], k_row[-1] + 1)
    answered_on_time = np.zeros(taken.size, dtype=bool)
    answered_on_time[k[on_time]] = True
    seen = np.zeros(taken.size, dtype=bool)
    seen[k_row] = True
    # stamps are the ROS times of the plant's deadlines, ``taken`` its monotonic wake-ups: their
    # difference is a clock offset plus the plant's lateness. The offset grows whenever the plant
    # drops time after an overrun, so it is taken as the smallest difference over the next 0.5 s
    # (samples taken within ~0.1 ms of their deadline are the rule there).
    # The controller's receipt and publish instants are measured from the stamp, so they are moved
    # to the instant the sample was taken by the whole offset change (dropped time + lateness).
    offset = taken - stamps
    w = STARTUP
    plant_late_ms = (offset - minimum_filter1d(offset, size=w, origin=-(w // 2), mode="nearest")) * 1e-6
    stamp_to_taken_ms = (offset - offset.min()) * 1e-6
    first_rcv = {int(kk): (int(r), j) for j, (kk, r) in reversed(list(enumerate(zip(k, rcv, strict=True))))}
    trace_of = {int(kk): j for j, kk in enumerate(k_row)}
    matched_rows = row[ok]
    misses = []
    for kk in window[~answered_on_time[window]]:
        kk = int(kk)
        end = int(taken[min(kk + 1, taken.size - 1)])
        miss = {"k": kk, "t_s": round((taken[kk] - taken[k_row[0]]) * 1e-9, 4)}
        if kk in first_rcv:
            r, j = first_rcv[kk]
            tr = matched_rows[j]
            # controller receipt / publish after the sample was taken (not after its stamp)
            rl = col["recv_latency"][tr] * 1e3 - stamp_to_taken_ms[kk]
            pl = col["pub_latency"][tr] * 1e3 - stamp_to_taken_ms[kk]
            total = (r - taken[kk]) * 1e-6
            miss.update(cause="late", window_ns=[int(taken[kk]), r], latency_ms=round(total, 3),
                        split_ms={"plant_late": round(float(plant_late_ms[kk]), 3),
                                  "to_controller": round(rl, 3), "controller_compute": round(pl - rl, 3),
                                  "to_plant": round(total - pl, 3)})
        else:
            miss.update(cause="dropped" if kk not in trace_of else "lost", window_ns=[int(taken[kk]), end])
        misses.append(miss)
    fields = {
        "samples_in_window": int(window.size),
        "commands_received": int(recv.size),
        "commands_matched": int(np.count_nonzero(ok)),
        "commands_published": int(ctl_stamp.size),
        "loop_latency_sample_to_command_receipt": _pct(lat_ms),
        "missed_samples": int(np.count_nonzero(~answered_on_time[window])),
        "missed_samples_after_first_500ms": int(np.count_nonzero(~answered_on_time[window[STARTUP:]])),
        "dropped_samples": int(np.count_nonzero(~seen[window])),
        "late_commands": int(np.count_nonzero(~on_time)),
        "lost_commands": int(ctl_stamp.size - np.count_nonzero(ok)),
        "controller_compute_receipt_to_publish": _pct((col["pub_latency"] - col["recv_latency"]) * 1e3),
        "stamp_to_controller_receipt": _pct(col["recv_latency"] * 1e3),
    }
    return fields, misses


def stall_intervals(monitor: dict[str, np.ndarray], stall_ms: float) -> np.ndarray:
    """Machine stalls seen by one CPU's monitor: (n, 2) int64 [deadline, wake-up] ns, late > ``stall_ms``."""
    late = monitor["late_ns"]
    big = late > stall_ms * 1e6
    dl = monitor["deadline_ns"][big]
    return np.column_stack([dl, dl + late[big]]) if dl.size else np.zeros((0, 2), dtype=np.int64)


def attribute(misses: list[dict], stalls: list[np.ndarray], bin_ns: int = 20_000) -> dict:
    """Attribute each missed sample to machine stalls (module doc); annotates ``misses`` in place.

    A miss is ``all_cpus`` if some instant of its window (sample taken → command received, or →
    next sample) lies inside a stall of every CPU's monitor, ``some_cpus`` if it overlaps a stall of
    at least one, else ``none``. Instants are resolved to ``bin_ns``.
    """
    counts = {"all_cpus": 0, "some_cpus": 0, "none": 0}
    for miss in misses:
        a, b = miss["window_ns"]
        edges = np.arange(a, b + bin_ns, bin_ns)
        hit = np.zeros((len(stalls), edges.size), dtype=bool)
        worst = 0.0
        for c, iv in enumerate(stalls):
            sel = iv[(iv[:, 1] > a) & (iv[:, 0] < b)]
            for s0, s1 in sel:
                hit[c] |= (edges >= s0) & (edges <= s1)
                worst = max(worst, (s1 - s0) * 1e-6)
        if stalls and hit.all(axis=0).any():
            kind = "all_cpus"
        elif hit.any():
            kind = "some_cpus"
        else:
            kind = "none"
        miss["machine_stall"] = kind
        miss["longest_overlapping_stall_ms"] = round(worst, 3)
        counts[kind] += 1
    return counts


def run(duration: float, rt_priority: int, executor: str, strategy: str, stall_ms: float = 0.5,
        monitor_period_ns: int = MONITOR_PERIOD_NS, plant_executor: str = "events") -> dict:
    """One real-time run under the stall monitor; returns the result dict (see module doc)."""
    env = isolated_env(random_domain())
    # SCHED_FIFO for the whole process (chrt) so that the DDS threads created at rclpy.init inherit
    # it; the nodes' rt_priority raises their hot thread (sampler / executor) above that.
    rt = ["chrt", "-f", str(max(rt_priority - 10, 1))] if rt_priority > 0 and shutil.which("chrt") else []
    load0 = os.getloadavg()
    cpu0 = _cpu_busy()
    with tempfile.TemporaryDirectory() as tmp:
        trace, timing_file = Path(tmp) / "trace.csv", Path(tmp) / "timing.npz"
        # the plant's output goes to a file: a pipe read only at the end fills up (64 KiB) during a
        # long run and then blocks the plant's next log call (docs/data_plane.md)
        sim_log = Path(tmp) / "sim_node.log"
        monitors = (start_monitors(duration + 120, MONITOR_PRIORITY, Path(tmp), monitor_period_ns)
                    if monitor_period_ns > 0 else [])
        with sim_log.open("w") as f:
            sim = subprocess.Popen(
                [*rt, *node_command("sim_node", "aeropend_sim.ros.sim_node"), "--ros-args",
                 "-p", "mode:=realtime", "-p", f"rt_priority:={rt_priority}",
                 "-p", f"timing_log:={timing_file}", "-p", f"executor:={plant_executor}",
                 "-p", f"timing_capacity:={int(duration * 600) + 10_000}"],
                env=env, stdout=f, stderr=subprocess.STDOUT, text=True)
        ctl = None
        try:
            time.sleep(1.0)
            ctl = subprocess.Popen(
                [*rt, *node_command("controller", "aeropend_control.controller_node"), "--ros-args",
                 "-p", "mode:=realtime", "-p", "steps:=[0.0, 0.4]", "-p", f"strategy:={strategy}",
                 "-p", f"duration:={duration}", "-p", f"trace:={trace}",
                 "-p", f"rt_priority:={rt_priority}", "-p", f"executor:={executor}"],
                env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            ctl_out, _ = ctl.communicate(timeout=duration + 60)
            time.sleep(0.2)
            stop(sim, signal.SIGTERM, timeout=15)
        finally:
            reap(ctl, sim)
            watched = collect_monitors(monitors)
        rows = list(csv.reader(trace.open()))
        timing = dict(np.load(timing_file))
        sim_out = sim_log.read_text(errors="replace")
    cpu1 = _cpu_busy()
    load1 = os.getloadavg()
    assert tuple(rows[0]) == SIGNALS, rows[0]
    d = np.array(rows[1:], dtype=float)
    ctl_summary = summary_line(ctl_out)
    met = step_metrics(d[:, SIGNALS.index("t")], d[:, SIGNALS.index("theta")], 0.4)
    fields, misses = analyse(d, timing)
    stalls = [stall_intervals(m, stall_ms) for m in watched]
    attributed = attribute(misses, stalls)
    return {
        "setup": {"duration_s": duration, "strategy": strategy, "rt_priority": rt_priority,
                  "executor": executor, "plant_executor": plant_executor,
                  "python": platform.python_version(), "machine": platform.machine(),
                  "cpus": os.cpu_count()},
        "load": {"loadavg_1min_before": round(load0[0], 2), "loadavg_1min_after": round(load1[0], 2),
                 "cpu_busy_fraction_during_run": round((cpu1[0] - cpu0[0]) / max(cpu1[1] - cpu0[1], 1), 3),
                 "cpu_steal_fraction_during_run": round((cpu1[2] - cpu0[2]) / max(cpu1[1] - cpu0[1], 1), 4)},
        **fields,
        "missed_attribution": attributed,
        "stall_monitor": {"stall_ms": stall_ms, "period_ms": monitor_period_ns * 1e-6,
                          "sched_fifo_priority": MONITOR_PRIORITY,
                          "cpus": [{"cpu": int(m["cpu"]), "wakeups": int(m["n"]),
                                    "p50_ms": round(float(m["p50_ns"]) * 1e-6, 4),
                                    "p99_ms": round(float(m["p99_ns"]) * 1e-6, 4),
                                    "max_ms": round(float(m["max_ns"]) * 1e-6, 4),
                                    "stalls": int(iv.shape[0])}
                                   for m, iv in zip(watched, stalls, strict=True)]},
        "misses": misses[:2000],
        "plant_summary": summary_fields(sim_out),
        "controller_summary": [ctl_summary] if ctl_summary is not None else [],
        "step_metrics": met.as_dict(),
    }


def _sleeper(seconds: float, prio: int, period_ns: int, cpu: int | None = None,
             stop_on_sigterm: bool = False, ready: Path | None = None) -> tuple[int, np.ndarray]:
    """A bare real-time sleeper in this process: SCHED_FIFO ``prio`` (0 = normal), memory locked,
    1 µs timer slack, GC off, optionally pinned to ``cpu``, sleeping to absolute deadlines every
    ``period_ns`` for ``seconds`` (or until SIGTERM; ``ready`` is created once that stops it
    cleanly). Returns (first deadline [ns], lateness of every wake-up [ns])."""
    import ctypes
    import gc

    if cpu is not None:
        os.sched_setaffinity(0, {cpu})
    if prio > 0:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
    libc = ctypes.CDLL(None)
    libc.mlockall(3)
    libc.prctl(29, 1000, 0, 0, 0)  # 1 µs timer slack
    n = int(seconds * 1e9 // period_ns)
    late = np.zeros(n, dtype=np.int64)
    stop_flag: list[int] = []
    if stop_on_sigterm:
        signal.signal(signal.SIGTERM, lambda *_: stop_flag.append(1))  # ends the watch, data kept
    if ready is not None:
        ready.touch()
    gc.disable()
    t0 = time.monotonic_ns() + period_ns
    for k in range(n):
        deadline = t0 + k * period_ns
        while (rem := deadline - time.monotonic_ns()) > 0:
            time.sleep(rem * 1e-9)
        late[k] = time.monotonic_ns() - deadline
        if stop_flag:
            return t0, late[:k + 1]
    return t0, late


def _wakeup_child(seconds: float, prio: int) -> None:
    """Child process of :func:`wakeup_check`: prints the lateness statistics as JSON."""
    _, late = _sleeper(seconds, prio, round(PERIOD_S * 1e9))
    ms = late * 1e-6
    print(json.dumps({"seconds": seconds, "sched_fifo_priority": prio, **_pct(ms),
                      "over_1ms": int((ms > 1.0).sum()), "over_2ms": int((ms > 2.048).sum()),
                      "over_5ms": int((ms > 5.0).sum())}))


def _monitor_child(seconds: float, prio: int, cpu: int, out: str, period_ns: int) -> None:
    """Child process of the stall monitor: one sleeper pinned to ``cpu``; writes ``out`` (.npz)."""
    t0, late = _sleeper(seconds, prio, period_ns, cpu, stop_on_sigterm=True, ready=Path(out + ".ready"))
    keep = np.flatnonzero(late > 100_000)  # only the wake-ups later than 0.1 ms are kept
    np.savez(out, deadline_ns=t0 + keep * period_ns, late_ns=late[keep], n=late.size, cpu=cpu,
             p50_ns=np.percentile(late, 50), p99_ns=np.percentile(late, 99), max_ns=late.max())


def start_monitors(seconds: float, prio: int, tmp: Path,
                   period_ns: int) -> list[tuple[subprocess.Popen, Path]]:
    """Start one stall-monitor process per CPU for ``seconds`` (module doc)."""
    procs = []
    for cpu in sorted(os.sched_getaffinity(0)):
        out = tmp / f"monitor_cpu{cpu}.npz"
        procs.append((subprocess.Popen([sys.executable, __file__, "--monitor-child", str(seconds), str(prio),
                                        str(cpu), str(out), str(period_ns)]), out))
    # the run starts only once every monitor watches (and a SIGTERM then ends it cleanly)
    deadline = time.monotonic() + 60.0
    while not all(Path(str(out) + ".ready").exists() for _, out in procs):
        if time.monotonic() > deadline or any(proc.poll() is not None for proc, _ in procs):
            raise RuntimeError("a stall monitor did not start within 60 s")
        time.sleep(0.05)
    return procs


def collect_monitors(procs: list[tuple[subprocess.Popen, Path]],
                     timeout: float = 10.0) -> list[dict[str, np.ndarray]]:
    """End the monitors (SIGTERM) and load what each recorded."""
    res = []
    for proc, _ in procs:
        proc.send_signal(signal.SIGTERM)
    for proc, out in procs:
        if proc.wait(timeout=timeout) != 0:
            raise RuntimeError(f"stall monitor {out.name} exited with {proc.returncode}")
        res.append(dict(np.load(out)))
    return res


def wakeup_check(seconds: float, prio: int) -> dict:
    """Wake-up lateness of a bare SCHED_FIFO sleeper at the sample period (see module doc)."""
    out = subprocess.run([sys.executable, __file__, "--wakeup-child", str(seconds), str(prio)],
                         capture_output=True, text=True, timeout=seconds + 30, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of sample time")
    ap.add_argument("--rt-priority", type=int, default=50, help="SCHED_FIFO priority (0 = off)")
    ap.add_argument("--executor", default="events", choices=("events", "single"), help="the controller's")
    ap.add_argument("--plant-executor", default="events", choices=("events", "single"), help="the plant's")
    ap.add_argument("--strategy", default="fl_pid")
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--wakeup-check", type=float, default=20.0, help="platform check [s] (0 = skip)")
    ap.add_argument("--baseline", action="store_true",
                    help="also run with rt_priority 0 and the single executor ('baseline')")
    ap.add_argument("--stall-ms", type=float, default=0.5,
                    help="monitor wake-up lateness [ms] that counts as a machine stall")
    ap.add_argument("--monitor-period-ms", type=float, default=MONITOR_PERIOD_NS * 1e-6,
                    help="stall monitors' wake-up period [ms] (0 = no monitor: every miss counts as 'none')")
    args = ap.parse_args(argv)
    period_ns = round(args.monitor_period_ms * 1e6)
    res = run(args.duration, args.rt_priority, args.executor, args.strategy, args.stall_ms, period_ns,
              args.plant_executor)
    if args.wakeup_check > 0:
        res["platform_wakeup"] = wakeup_check(args.wakeup_check, args.rt_priority + 10)
    if args.baseline:
        res["baseline"] = run(args.duration, 0, "single", args.strategy, args.stall_ms, period_ns, "single")
    print(json.dumps(res, indent=1))
    Path(args.out).write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    return res


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--wakeup-child":
        _wakeup_child(float(sys.argv[2]), int(sys.argv[3]))
    elif len(sys.argv) == 7 and sys.argv[1] == "--monitor-child":
        _monitor_child(float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5], int(sys.argv[6]))
    else:
        main()
