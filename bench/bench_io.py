"""Benchmark: CSV import and contract-bag write/read throughput.

* CSV import (:func:`aeropend_ident.io.csv_import.import_csv`) in rows/s on the real jahoyosr
  Hoja3 log (15 555 rows, read from ``../shared/data/real``; skipped when absent) and on a
  synthetic 1e6-row file (3 columns, like a 490 Hz log of 34 min).
* Bag write (:func:`aeropend_ident.io.bag_writer.write_bag`) and read (:func:`read_bag`) in samples/s
  (one sample = joint_states + armature + duty_cycle messages) for MCAP and SQLite3, on a
  600 s thesis-rate recording (292 969 samples) with all channels; the read also with the
  per-message ``typestore`` decoder for comparison.

Writes ``bench/results/io.json`` and prints a table.
Run: ``/tmp/venv/bin/python -m bench.bench_io`` (``--quick`` for a smaller run).
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.io.bag_writer import write_bag
from aeropend_ident.io.bags import read_bag
from aeropend_ident.io.csv_import import CsvSpec, import_csv
from aeropend_sim.contract import SAMPLE_PERIOD_S
from aeropend_sim.recording import Recording

ROOT = Path(__file__).resolve().parent
OUT = ROOT / "results" / "io.json"
REAL = ROOT.parents[1] / "shared" / "data" / "real"
HOJA3 = REAL / "jahoyosr__Aeropendulum" / "sheet_Hoja3_pwm_steps_openloop.csv"


def _best(fn: Callable[[], Any], repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _synthetic_csv(path: Path, rows: int) -> None:
    rng = np.random.default_rng(0)
    t = np.arange(rows) * SAMPLE_PERIOD_S
    pwm = rng.integers(0, 256, rows)
    angle = 30 * np.sin(2 * np.pi * 0.3 * t) + rng.normal(0, 0.05, rows)
    with path.open("w") as fh:
        fh.write("t [s],PWM [0-255],angle [deg]\n")
        np.savetxt(fh, np.column_stack([t, pwm, angle]), fmt=["%.6f", "%d", "%.4f"], delimiter=",")


def _recording(n: int) -> Recording:
    rng = np.random.default_rng(1)
    t = np.arange(n) * SAMPLE_PERIOD_S
    return Recording(
        t=t, duty=rng.uniform(0.3, 1.0, n),
        channels={name: rng.standard_normal(n) for name in
                  ("theta", "theta_dot", "omega_rotor", "omega_prop", "i_a", "v_a")},
        source="bench", stamp0_ns=1_700_000_000_000_000_000,
    )


def bench(quick: bool = False) -> dict[str, Any]:
    repeats = 1 if quick else 3
    results: dict[str, Any] = {"csv_import": {}, "bag": {}}
    tmp = Path(tempfile.mkdtemp(prefix="bench_io_"))
    try:
        if HOJA3.exists():
            wall = _best(lambda: import_csv(HOJA3, "jahoyosr_hoja3"), repeats)
            results["csv_import"]["hoja3_15555_rows"] = {"rows": 15555, "wall_s": wall,
                                                         "rows_per_s": 15555 / wall}
        rows = 100_000 if quick else 1_000_000
        big = tmp / "big.csv"
        _synthetic_csv(big, rows)
        spec = CsvSpec(time_col="t [s]", input_col="PWM [0-255]", input_kind="pwm", angle_col="angle [deg]",
                       angle_unit="deg")
        wall = _best(lambda: import_csv(big, spec), repeats)
        results["csv_import"][f"synthetic_{rows}_rows"] = {
            "rows": rows, "bytes": big.stat().st_size, "wall_s": wall, "rows_per_s": rows / wall}

        n = round((60.0 if quick else 600.0) / SAMPLE_PERIOD_S)
        rec = _recording(n)
        for storage in ("mcap", "sqlite3"):
            k = 0

            def write(storage: str = storage) -> None:
                nonlocal k
                k += 1
                write_bag(rec, tmp / f"{storage}_{k}", storage=storage)

            w = _best(write, repeats)
            bag = tmp / f"{storage}_1"
            size = sum(p.stat().st_size for p in bag.iterdir())
            r_vec = _best(lambda b=bag: read_bag(b), repeats)
            r_ts = _best(lambda b=bag: read_bag(b, decoder="typestore"), 1)
            back = read_bag(bag)
            assert np.array_equal(back.channels["theta"], rec.channels["theta"])
            results["bag"][storage] = {
                "samples": n, "messages": 3 * n, "bytes": size,
                "write_s": w, "write_samples_per_s": n / w,
                "read_s": r_vec, "read_samples_per_s": n / r_vec,
                "read_typestore_s": r_ts, "read_typestore_samples_per_s": n / r_ts,
            }
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    results["machine"] = {"python": platform.python_version(), "machine": platform.machine(),
                          "processor": platform.processor() or platform.machine()}
    results["quick"] = quick
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller inputs, one repeat (not written)")
    args = parser.parse_args()
    res = bench(args.quick)
    print(f"{'CSV import':<28}{'rows':>10}{'wall [s]':>10}{'rows/s':>12}")
    for name, r in res["csv_import"].items():
        print(f"{name:<28}{r['rows']:>10}{r['wall_s']:>10.3f}{r['rows_per_s']:>12,.0f}")
    print(f"\n{'bag (samples = 3 msgs)':<24}{'samples':>9}{'MB':>7}{'write/s':>11}{'read/s':>11}"
          f"{'read/s ts':>11}")
    for name, r in res["bag"].items():
        print(f"{name:<24}{r['samples']:>9}{r['bytes'] / 1e6:>7.1f}{r['write_samples_per_s']:>11,.0f}"
              f"{r['read_samples_per_s']:>11,.0f}{r['read_typestore_samples_per_s']:>11,.0f}")
    if not args.quick:
        OUT.parent.mkdir(exist_ok=True)
        OUT.write_text(json.dumps(res, indent=2) + "\n")
        print(f"\nwrote {OUT}")


if __name__ == "__main__":
    main()
