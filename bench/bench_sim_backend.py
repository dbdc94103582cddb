"""Benchmark (issue 37's bar): the compiled simulator backend against LSODA, side by side in one run.

The thesis rig with every dynamic effect on (the study's rig, ``bench/backends/study.py``), 60 s
at 490 Hz of Latin-hypercube steps, APRBS and a duty that changes every sample (closed-loop-like):

* the CPU time of one ``simulate()`` call per backend and input (median of ``--repeats``; LSODA's
  per-sample input fewer, it takes seconds), as a real-time factor, with the slowest and fastest
  compiled call (this shared machine moves by a third between calls); bar: ≥ 1000× on one core
  for the three inputs alike;
* the compiled replay's agreement with LSODA, max |Δθ| over 60 s, also with the upper end stop at
  0.65 rad (in contact 10-30 % of the time);
* a batch of 64 parameter sets (±5 % log-normal on five parameters, per-sample input) with 1 and 2
  threads, and the stepper's per-call cost;
* the compile cost: a fresh process with an empty cache folder, then one with the cache filled
  (each family's five kernels), run as subprocesses of this file (``--compile-probe``).

Writes ``bench/results/sim_backend.json``; ``--table`` prints the tables of docs/model.md from it.

Run: ``.venv/bin/python -m bench.bench_sim_backend`` (≈ 2 min here), then ``--table``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from aeropend_sim.compiled.plant import compiled_plant
from aeropend_sim.simulation import PlantStepper, simulate, simulate_batch
from bench.backends import study

OUT = Path(__file__).resolve().parent / "results" / "sim_backend.json"
#: Parameters the batch varies (the study's Jacobian parameters).
BATCH_KEYS = ("pendulum.mgd_over_J", "pendulum.c_over_J", "pendulum.L_over_J", "pendulum.coulomb_over_J",
              "motor.K_d")
BATCH_SIZE = 64


def _times(fn, repeats: int) -> tuple[list[float], list[float]]:
    """CPU and wall seconds of each of ``repeats`` calls of ``fn()``."""
    cpu, wall = [], []
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return cpu, wall


def _cpu(fn, repeats: int) -> tuple[float, float]:
    """Median CPU and wall seconds of ``fn()`` over ``repeats`` calls."""
    cpu, wall = _times(fn, repeats)
    return float(np.median(cpu)), float(np.median(wall))


def speed_and_agreement(repeats: int) -> dict:
    """Real-time factors of both backends and max |Δθ| per input, plain and with stop contact."""
    out: dict = {}
    for variant, contact in (("all_effects", False), ("end_stop_contact", True)):
        rig = study.all_effects_rig(contact=contact)
        inputs = study.inputs(rig.sample_period)
        simulate(rig, inputs["step"][:100])  # compile or load outside the timing
        rows = {}
        for name, duty in inputs.items():
            span = duty.size * rig.sample_period
            ref = simulate(rig, duty, backend="lsoda")
            got = simulate(rig, duty)
            row = {"span_s": span, "max_abs_dtheta_rad": float(np.abs(got.theta - ref.theta).max()),
                   "contact_fraction": float(np.mean(ref.theta > rig.pendulum.theta_max))}
            if variant == "all_effects":
                lsoda_reps = 1 if name == "per_sample" else max(1, repeats // 2)
                c_cpus, c_walls = _times(lambda r=rig, d=duty: simulate(r, d), repeats)
                c_cpu, c_wall = float(np.median(c_cpus)), float(np.median(c_walls))
                l_cpu, l_wall = _cpu(lambda r=rig, d=duty: simulate(r, d, backend="lsoda"), lsoda_reps)
                row.update(compiled_cpu_s=c_cpu, compiled_wall_s=c_wall, compiled_x_realtime=span / c_cpu,
                           compiled_x_realtime_range=[span / max(c_cpus), span / min(c_cpus)],
                           lsoda_cpu_s=l_cpu, lsoda_wall_s=l_wall, lsoda_x_realtime=span / l_cpu,
                           speedup=l_cpu / c_cpu)
            rows[name] = row
            print(f"{variant:17s} {name:10s} " + ", ".join(f"{k} {np.round(v, 4)}" for k, v in row.items()),
                  flush=True)
        out[variant] = rows
    return out


def batch(repeats: int) -> dict:
    """64 parameter sets on the per-sample input, 1 and 2 threads; against 64 single replays."""
    rig = study.all_effects_rig()
    duty = study.inputs(rig.sample_period)["per_sample"]
    plant = compiled_plant(rig)
    base = np.array([rig.value(k) for k in BATCH_KEYS])
    values = base * np.exp(np.random.default_rng(0).normal(0.0, 0.05, (BATCH_SIZE, len(BATCH_KEYS))))
    p = plant.vectors(BATCH_KEYS, values)
    simulate_batch(plant, duty[:100], p[:2])  # compile or load outside the timing
    out = {"size": BATCH_SIZE, "keys": list(BATCH_KEYS)}
    for threads in (1, 2):
        cpu, wall = _cpu(lambda t=threads: simulate_batch(plant, duty, p, threads=t), max(1, repeats // 3))
        out[f"threads_{threads}"] = {"cpu_s": cpu, "wall_s": wall,
                                     "cpu_ms_per_replay": 1e3 * cpu / BATCH_SIZE,
                                     "wall_ms_per_replay": 1e3 * wall / BATCH_SIZE}
    cpu, wall = _cpu(lambda: [plant.replay(duty, np.zeros(5), p=row) for row in p], 1)
    out["loop_of_single"] = {"cpu_s": cpu, "wall_s": wall}
    print("batch " + json.dumps(out), flush=True)
    return out


def stepper(n: int = 3000) -> dict:
    """Per-call cost of PlantStepper.step on both backends (the lock-step sim node's step)."""
    rig = study.all_effects_rig()
    out = {}
    for backend in ("compiled", "lsoda"):
        s = PlantStepper(rig, backend=backend)
        s.step(0.5)
        costs = []
        for u in np.random.default_rng(1).uniform(0.3, 1.0, n):
            t0 = time.perf_counter()
            s.step(float(u))
            costs.append(time.perf_counter() - t0)
        c = np.array(costs) * 1e6
        out[backend] = {"p50_us": float(np.percentile(c, 50)), "p99_us": float(np.percentile(c, 99)),
                        "x_realtime": rig.sample_period / (np.mean(c) * 1e-6)}
    print("stepper " + json.dumps(out), flush=True)
    return out


def compile_probe() -> dict:
    """CPU seconds to compile (or load) each family's kernels in this process (run in a subprocess)."""
    c00 = time.process_time()
    from bench.fixtures.component_rigs import (
        rig as family_rig,  # the minimal rigs of each family (their one home)
    )

    out: dict = {}
    for family in ("dc_hbridge", "voltage_amplifier", "esc"):
        rig = study.all_effects_rig() if family == "dc_hbridge" else family_rig(family)
        duty = np.full(100, 0.5)
        out[family] = _compile_family(rig, duty)
    out["process_cpu_s"] = time.process_time() - c00
    return out


def _compile_family(rig, duty: np.ndarray) -> dict[str, float]:
    r = {}
    c0 = time.process_time()
    plant = compiled_plant(rig)
    r["module_and_jacobians"] = time.process_time() - c0
    calls = (("replay", lambda: plant.replay(duty, np.zeros(5))),
             ("outputs", lambda: plant.outputs(np.zeros((2, 5)), np.zeros(2))),
             ("step", lambda: plant.step(np.zeros(5), 0.5, 0.5)),
             ("replay_batch", lambda: simulate_batch(plant, duty, plant.p[None, :])))
    for name, call in calls:
        c0 = time.process_time()
        call()
        r[name] = time.process_time() - c0
    r["total"] = sum(r.values())
    return r


def compile_cost() -> dict:
    """:func:`compile_probe` in a fresh process with an empty cache folder, then with it filled."""
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "AEROPEND_CACHE_DIR": cache}
        for label in ("empty_cache", "filled_cache"):
            c0 = time.time()
            res = subprocess.run([sys.executable, __file__, "--compile-probe"], env=env, capture_output=True,
                                 text=True, timeout=900, check=True)
            out[label] = json.loads(res.stdout.strip().splitlines()[-1])
            out[label]["wall_s"] = time.time() - c0
    print("compile " + json.dumps(out), flush=True)
    return out


def _versions() -> dict:
    import llvmlite
    import numba

    return {"numba": numba.__version__, "llvmlite": llvmlite.__version__, "numpy": np.__version__,
            "python": platform.python_version()}


def table(report: dict) -> str:
    """Markdown tables of docs/model.md ("Simulation backends") from a report."""
    r = report["speed"]["all_effects"]
    lines = ["| input (60 s at 490 Hz) | compiled × real time (slowest-fastest call) | LSODA × real time | "
             "speed-up | max abs Δθ rad | with stop contact: max abs Δθ rad (time in contact) |",
             "|---|---|---|---|---|---|"]
    for name, row in r.items():
        c = report["speed"]["end_stop_contact"][name]
        spread = row.get("compiled_x_realtime_range")  # files before 2026-11-28 lack it
        spread = f" ({spread[0]:.0f}-{spread[1]:.0f})" if spread else ""
        lines.append(f"| {name} | {row['compiled_x_realtime']:.0f}{spread} | "
                     f"{row['lsoda_x_realtime']:.1f} | "
                     f"{row['speedup']:.1f} | {row['max_abs_dtheta_rad']:.1e} | "
                     f"{c['max_abs_dtheta_rad']:.1e} ({100 * c['contact_fraction']:.0f} %) |")
    b = report["batch"]
    one = b["threads_1"]
    lines += ["", f"Batch of {b['size']} parameter sets (per-sample input): 1 thread "
              f"{one['cpu_s']:.2f} s CPU ({one['cpu_ms_per_replay']:.1f} ms per replay), "
              f"2 threads {b['threads_2']['wall_s']:.2f} s wall; a loop of single replays "
              f"{b['loop_of_single']['cpu_s']:.2f} s CPU. Stepper: compiled "
              f"{report['stepper']['compiled']['p50_us']:.0f} µs per call (median), LSODA "
              f"{report['stepper']['lsoda']['p50_us']:.0f} µs.", "",
              "| compile, CPU s | dc_hbridge | voltage_amplifier | esc | whole process |",
              "|---|---|---|---|---|"]
    for label in ("empty_cache", "filled_cache"):
        c = report["compile"][label]
        lines.append(f"| {label.replace('_', ' ')} | {c['dc_hbridge']['total']:.2f} | "
                     f"{c['voltage_amplifier']['total']:.2f} | {c['esc']['total']:.2f} | "
                     f"{c['process_cpu_s']:.2f} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7, help="timing repeats of the compiled backend")
    ap.add_argument("--table", action="store_true", help="print the docs tables from the last results")
    ap.add_argument("--compile-probe", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.compile_probe:
        print(json.dumps(compile_probe()))
        return
    if args.table:
        print(table(json.loads(OUT.read_text())))
        return
    load = os.getloadavg()[0]
    report = {"rig": "thesis_rig, every effect on (bench/backends/study.py)", "versions": _versions(),
              "machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
              "load_average_1min_at_start": load, "compile": compile_cost(),
              "speed": speed_and_agreement(args.repeats), "batch": batch(args.repeats), "stepper": stepper()}
    report["load_average_1min_at_end"] = os.getloadavg()[0]
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(report, indent=2))
    print(table(report))
    print(f"written {OUT}")


if __name__ == "__main__":
    main()
