"""Benchmark: ``csv_import`` of a 10-million-row log into an MCAP bag, time and peak memory.

A synthetic lab log (time [s] at 490 Hz, PWM counts 0-255, angle [deg] with noise: 10 million
rows, about 250 MB, 5.7 h of recording) is written once to a temporary folder, then the
``csv_import`` console script imports it (``--preset``-free column options, ``-o`` an MCAP bag)
in a child process; the wall time and the child's peak resident memory (``ru_maxrss`` from
``os.wait4``) are measured, and the bag's message count is checked against 3 × rows. The bar of
issue 62: ≤ 60 s and ≤ 1 GB on the 2-core development machine.

Writes ``bench/results/csv_import.json`` and prints one line.
Run: ``.venv/bin/python -m bench.bench_csv_import`` (``--rows N`` for a smaller run, which does
not write the result file unless ``--out`` is given).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
OUT = ROOT / "results" / "csv_import.json"
ROWS = 10_000_000
#: Bars of issue 62.
MAX_SECONDS = 60.0
MAX_BYTES = 1 << 30


def write_log(path: Path, rows: int, block: int = 1_000_000) -> int:
    """Write a synthetic lab log of ``rows`` rows (time [s] at 490 Hz, PWM, angle [deg]).

    Returns its size [bytes]."""
    rng = np.random.default_rng(0)
    with path.open("w") as fh:
        fh.write("t [s],PWM [0-255],angle [deg]\n")
        for a in range(0, rows, block):
            k = np.arange(a, min(rows, a + block))
            t = k / 490.0
            pwm = (128 + 100 * np.sign(np.sin(2 * np.pi * 0.05 * t))).astype(int)
            angle = 30 * np.sin(2 * np.pi * 0.3 * t) + rng.normal(0, 0.05, len(k))
            np.savetxt(fh, np.column_stack([t, pwm, angle]), fmt=["%.6f", "%d", "%.4f"], delimiter=",")
    return path.stat().st_size


def run_import(csv: Path, bag: Path) -> dict[str, float | int]:
    """Run ``csv_import`` on ``csv`` into the MCAP bag ``bag`` in a child; its time and peak memory."""
    exe = Path(sys.executable).parent / "csv_import"
    cmd = [str(exe), str(csv), "--time-col", "t [s]", "--input-col", "PWM [0-255]", "--input-kind", "pwm",
           "--angle-col", "angle [deg]", "--angle-unit", "deg", "-o", str(bag), "--start-time", "zero"]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - t0
    out, err = proc.stdout.read().decode(), proc.stderr.read().decode()  # type: ignore[union-attr]
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"csv_import failed: {err or out}")
    return {"seconds": seconds, "peak_rss_bytes": int(usage.ru_maxrss) * 1024, "summary": out.strip()}


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; write the result file for the full 10-million-row run (or ``--out``)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--rows", type=int, default=ROWS)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    out = args.out or (OUT if args.rows == ROWS else None)
    tmp = Path(tempfile.mkdtemp(prefix="bench_csv_import_"))
    try:
        csv = tmp / "log.csv"
        t0 = time.perf_counter()
        size = write_log(csv, args.rows)
        gen = time.perf_counter() - t0
        res = run_import(csv, tmp / "bag")
        from aeropend_ident.io.bag_reader import bag_metadata

        meta = bag_metadata(tmp / "bag")
        messages = int(meta["message_count"])
        bag_bytes = sum(f.stat().st_size for f in (tmp / "bag").iterdir())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    result = {
        "what": "csv_import of a synthetic lab log (t [s] at 490 Hz, PWM, angle [deg]) into an MCAP bag, "
                "one child process; peak memory = the child's ru_maxrss",
        "rows": args.rows,
        "csv_bytes": size,
        "seconds": round(float(res["seconds"]), 2),
        "rows_per_s": round(args.rows / float(res["seconds"])),
        "peak_rss_bytes": res["peak_rss_bytes"],
        "peak_rss_mb": round(int(res["peak_rss_bytes"]) / 2**20, 1),
        "bag_messages": messages,
        "bag_bytes": bag_bytes,
        "messages_ok": messages == 3 * args.rows,
        "bar": {"max_seconds": MAX_SECONDS, "max_peak_bytes": MAX_BYTES},
        "meets_bar": bool(float(res["seconds"]) <= MAX_SECONDS and int(res["peak_rss_bytes"]) <= MAX_BYTES),
        "csv_write_seconds": round(gen, 1),
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                    "platform": platform.platform()},
    }
    print(f"csv_import {args.rows} rows ({size / 1e6:.0f} MB): {result['seconds']} s, peak "
          f"{result['peak_rss_mb']} MB, {messages} messages (bar {MAX_SECONDS:.0f} s, 1 GB: "
          f"{'met' if result['meets_bar'] else 'NOT met'})")
    if out is not None:
        out.write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
