"""``gap-batch`` on an archive of 50 sessions through a local Dask cluster (issue 37, item 4).

The archive is what a lab accumulates over weeks: one 24 s recording a session of the thesis rig
(θ only, 100 Hz, sensor noise on, APRBS duty in [0.3, 0.8] from rest), written as rosbag2 folders by
:func:`aeropend_ident.io.bag_writer.write_bag`. From session 30 on the propeller is replaced by one
with a 20 % larger thrust coefficient K_q (the drift the table must find). The batch runs the
console script's ``main`` exactly as ``gap-batch ARCHIVE/ --rig thesis_rig -o OUT --workers 2``:
every session's ``gap`` is one case of a ``LocalCluster``, then the drift fits across sessions.

Measured: the wall time of the whole batch and of the archive's writing, the per-session ``gap``
times the batch records, how many sessions were diagnosed, and whether the drift table flags the
thrust-to-weight ratio K_q/(mgd/J) (what θ alone determines) with its step at session 30.

Writes ``bench/results/gap_batch.json``.

Usage: ``python -m bench.bench_gap_batch [--sessions 50] [--workers 2] [--out PATH]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from aeropend_ident.cli.gap_batch import main as gap_batch
from aeropend_ident.io.bag_writer import write_bag
from bench.fixtures.sessions import thesis_session

RESULTS = Path(__file__).resolve().parent / "results"
#: K_q of the sessions after the propeller change, over the nominal.
K_Q_FACTOR = 1.2


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=50, help="sessions in the archive")
    ap.add_argument("--change-at", type=int, default=30, help="first session with the new propeller")
    ap.add_argument("--workers", type=int, default=2, help="workers of the local Dask cluster")
    ap.add_argument("--out", default=str(RESULTS / "gap_batch.json"), help="result JSON")
    args = ap.parse_args(argv)
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="gap_batch_") as tmp:
        root = Path(tmp) / "archive"
        root.mkdir()
        t0 = time.perf_counter()
        for i in range(args.sessions):
            k_q = K_Q_FACTOR if i >= args.change_at else 1.0
            write_bag(thesis_session(1000 + i, k_q), root / f"s{i:03d}", rig_name="thesis_rig")
        t_write = time.perf_counter() - t0
        out = Path(tmp) / "batch"
        t0 = time.perf_counter()
        rc = gap_batch([str(root), "--rig", "thesis_rig", "-o", str(out),
                        "--workers", str(args.workers), "-q"])
        wall = time.perf_counter() - t0
        doc = json.loads((out / "batch.json").read_text())
    rows = doc["rows"]
    diagnosed = [r for r in rows if r.get("exit") == 0]
    drift = doc.get("drift", {})
    by_effect = {r["effect"]: r for r in drift.get("rows", [])}
    ratio = None
    if "thrust_coefficient" in by_effect and "gravity" in by_effect:
        kq = np.asarray(by_effect["thrust_coefficient"]["values"], float)
        g = np.asarray(by_effect["gravity"]["values"], float)
        r = kq / g
        before, after = r[:args.change_at], r[args.change_at:]
        ratio = {"median_before": float(np.median(before)), "median_after": float(np.median(after)),
                 "step": float(np.median(after) / np.median(before)),
                 "spread_before": float(np.std(before) / np.median(before))}
    per = [float(r["elapsed_s"]) for r in rows if r.get("elapsed_s") is not None]
    result = {
        "meta": {"commit": subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                                          text=True, cwd=RESULTS.parent.parent).stdout.strip(),
                 "machine": f"{os.cpu_count()} cores, {platform.platform()}",
                 "python": platform.python_version(), "load_before": list(load_before),
                 "load_after": list(os.getloadavg()), "argv": argv or [],
                 "engine": doc["meta"].get("engine"), "workers": doc["meta"].get("workers")},
        "sessions": args.sessions, "change_at": args.change_at, "k_q_factor": K_Q_FACTOR,
        "exit": rc, "diagnosed": len(diagnosed), "write_s": t_write, "wall_s": wall,
        "per_session_s": {"median": float(np.median(per)) if per else None,
                          "max": float(np.max(per)) if per else None},
        "drifting": drift.get("drifting"), "thrust_to_weight": ratio,
    }
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k != "meta"}, indent=1))
    return 0 if rc == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
