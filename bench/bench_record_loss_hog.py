"""Real-time recording under CPU hogs: the loss ``record`` reports equals the loss in the bag (issue 62).

One run per ``--hogs`` value: ``sim_node`` (mode realtime, the default rig), ``excitation``
(realtime APRBS of ``--duration`` s, then duty 0) and ``record`` (the contract topics) in their own
processes on a private ROS domain, beside that many CPU hogs (``python -c "while True: pass"``) on
this 2-core machine; with ``--freeze S`` the recorder is also starved outright (SIGSTOP for S s, 3 s
into the excitation, then SIGCONT: the worst a hog can do to it). After the excitation has ended
the recorder is stopped with SIGINT. Then,
per topic, what ``record`` printed and stored (``aeropend.loss`` in metadata.yaml) is compared with
a count made here, independently:

* ``joint_states``: the samples missing between the bag's header stamps (the plant stamps sample k
  at start + k·T_s, so a step of n periods is n − 1 samples lost);
* ``duty_cycle``: the commands ``excitation`` says it sent (its log line, + the final duty 0)
  minus the messages in the bag.

The bar holds when both counts agree on both topics in every run (``agree``). Writes
``bench/results/record_loss_hog.json``::

    .venv/bin/python -m bench.bench_record_loss_hog [--hogs 0 4 12] [--freeze 0 1] [--duration 8]

One run per (hogs, freeze) pair.
"""

from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from aeropend_ident.io.bag_reader import bag_metadata
from aeropend_ident.io.integrity.loss import LOSS_KEY
from aeropend_sim.contract import TOPIC_DUTY_CYCLE, TOPIC_JOINT_STATES
from aeropend_sim.params import load_rig
from aeropend_sim.ros.harness import isolated_env, node_command, random_domain, reap, stop
from aeropend_sim.sim_core import DEFAULT_RIG

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "record_loss_hog.json"
HOG = "while True: pass"


def _bag_contents(bag: Path) -> tuple[np.ndarray, int]:
    """(sorted joint_states header stamps [ns], duty_cycle message count) of a bag."""
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        stamps, n_duty = [], 0
        wanted = [c for c in reader.connections if c.topic in (TOPIC_JOINT_STATES, TOPIC_DUTY_CYCLE)]
        for conn, _, raw in reader.messages(wanted):
            if conn.topic == TOPIC_DUTY_CYCLE:
                n_duty += 1
            else:
                h = reader.deserialize(raw, conn.msgtype).header.stamp
                stamps.append(h.sec * 1_000_000_000 + h.nanosec)
    return np.sort(np.array(stamps, dtype=np.int64)), n_duty


def _freeze(proc: subprocess.Popen, seconds: float) -> None:
    proc.send_signal(signal.SIGSTOP)
    time.sleep(seconds)
    proc.send_signal(signal.SIGCONT)


def run_once(hogs: int, freeze: float, duration: float, workdir: Path) -> dict:
    """One recording beside ``hogs`` CPU hogs (recorder frozen ``freeze`` s); two loss counts per topic."""
    env = isolated_env(random_domain())
    bag = workdir / f"hogs{hogs}_freeze{freeze:g}"
    period = load_rig(DEFAULT_RIG).sample_period
    procs: list[subprocess.Popen] = [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(hogs)]
    try:
        sim = subprocess.Popen([*node_command("sim_node", "aeropend_sim.ros.sim_node"), "--ros-args", "-p",
                                f"rig:={DEFAULT_RIG}"], env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
        procs.append(sim)
        rec = subprocess.Popen([*node_command("record", "aeropend_ident.nodes.record"), "-o", str(bag)],
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        procs.append(rec)
        time.sleep(3.0)  # both up and matched before the first command
        if freeze > 0:
            threading.Timer(3.0 + 3.0, _freeze, (rec, freeze)).start()  # ~3 s into the excitation
        exc = subprocess.run([*node_command("excitation", "aeropend_sim.ros.excitation_node"), "--signal",
                              "aprbs", "--duration", str(duration), "--zero-at-end", "--min-subscribers", "2",
                              "--wait-timeout", "30"], env=env, capture_output=True, text=True,
                             timeout=duration + 120)
        time.sleep(1.0)
        rec_out = stop(rec, signal.SIGINT, timeout=30, kill_on_timeout=True).stdout or ""
        sim_out = stop(sim, signal.SIGINT, timeout=10, kill_on_timeout=True).stdout or ""
    finally:
        reap(*procs)
    if exc.returncode != 0:
        raise SystemExit(f"excitation failed: {exc.stderr}")
    m = re.search(r"sent (\d+) commands .*?( \+ duty 0)?$", exc.stderr, re.M)
    if m is None:
        raise SystemExit(f"excitation did not say what it sent: {exc.stderr}")
    sent = int(m.group(1)) + (1 if m.group(2) else 0)
    stored = json.loads(bag_metadata(bag).get("custom_data", {}).get(LOSS_KEY, "{}"))
    printed = {t: (int(a), int(b)) for t, a, b in re.findall(r"(/\S+) (\d+) of (\d+) lost", rec_out)}
    stamps, n_duty = _bag_contents(bag)
    steps = np.rint(np.diff(stamps) / (period * 1e9)).astype(np.int64)
    counted = {TOPIC_JOINT_STATES: (stamps.size, int(np.sum(np.maximum(steps - 1, 0)))),
               TOPIC_DUTY_CYCLE: (n_duty, sent - n_duty)}
    topics = {}
    for name, (in_bag, mine) in counted.items():
        rep = stored.get(name, {}).get("lost", 0)
        said = printed.get(name, (0, 0))[0]
        topics[name] = {"in_bag": in_bag, "lost_counted_here": mine, "lost_stored_by_record": rep,
                        "lost_printed_by_record": said, "method": stored.get(name, {}).get("method"),
                        "agree": mine == rep == said}
    overruns = re.findall(r"overruns=(\d+)", sim_out)
    return {"hogs": hogs, "recorder_frozen_s": freeze, "duration_s": duration, "duty_commands_sent": sent,
            "sim_overruns": int(overruns[-1]) if overruns else None, "topics": topics,
            "record_loss_line": next((ln for ln in rec_out.splitlines() if ln.startswith("record: loss")),
                                     None),
            "agree": all(t["agree"] for t in topics.values())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hogs", type=int, nargs="+", default=[0, 4, 12], help="CPU hogs (default 0 4 12)")
    ap.add_argument("--freeze", type=float, nargs="+", default=[0.0, 1.0],
                    help="seconds the recorder is stopped (SIGSTOP) mid-run (default 0 1)")
    ap.add_argument("--duration", type=float, default=8.0, help="excitation length [s] (default 8)")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        runs = [run_once(h, f, args.duration, Path(tmp)) for h in args.hogs for f in args.freeze]
    res = {"runs": runs, "agree": all(r["agree"] for r in runs)}
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    for r in runs:
        print(f"hogs {r['hogs']}, recorder frozen {r['recorder_frozen_s']:g} s: "
              f"sim overruns {r['sim_overruns']}; "
              + "; ".join(f"{t} in bag {v['in_bag']}, lost: counted {v['lost_counted_here']}, record "
                          f"{v['lost_printed_by_record']} (stored {v['lost_stored_by_record']})"
                          for t, v in r["topics"].items()))
    print("agree:", res["agree"])
    return 0 if res["agree"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
