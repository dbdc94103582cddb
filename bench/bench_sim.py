"""Benchmark: batch simulation speed as a multiple of real time (goal >= 200x).

Runs :func:`aeropend_sim.simulation.simulate` (its default backend, recorded in the results) on the
thesis rig at 490 Hz for three excitation types (thesis Latin-hypercube steps, APRBS with 50 ms
minimum hold, per-sample random input) and the per-sample :class:`PlantStepper`, and writes
``bench/results/sim.json``. ``bench_sim_backend.py`` measures issue 37's bar (every effect on,
both backends side by side).

Run: ``.venv/bin/python -m bench.bench_sim``
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np

from aeropend_sim.params import load_rig
from aeropend_sim.simulation import DEFAULT_BACKEND, PlantStepper, simulate

OUT = Path(__file__).resolve().parent / "results" / "sim.json"


def _lhs_steps(rng: np.random.Generator, n: int, dt: float) -> np.ndarray:
    levels = rng.uniform(0.3, 1.0, 40)
    holds = rng.uniform(0.5, 3.0, 40)
    return np.concatenate([np.full(round(h / dt), lv) for lv, h in zip(levels, holds, strict=True)])[:n]


def _aprbs(rng: np.random.Generator, n: int, dt: float) -> np.ndarray:
    out, k = [], 0
    while k < n:
        hold = rng.integers(round(0.05 / dt), round(0.5 / dt))
        out.append(np.full(hold, rng.uniform(0.3, 1.0)))
        k += hold
    return np.concatenate(out)[:n]


def bench(repeats: int = 3) -> dict:
    rig = load_rig("thesis_rig")
    dt = rig.sample_period
    rng = np.random.default_rng(0)
    n = round(60.0 / dt)
    inputs = {
        "lhs_steps_60s": _lhs_steps(rng, n, dt),
        "aprbs_60s": _aprbs(rng, n, dt),
        "per_sample_random_10s": rng.uniform(0.3, 1.0, round(10.0 / dt)),
    }
    results = {}
    for name, duty in inputs.items():
        best = min(_timed(lambda d=duty: simulate(rig, d)) for _ in range(repeats))
        sim_time = duty.size * dt
        results[name] = {"sim_time_s": sim_time, "wall_s": best, "x_realtime": sim_time / best}
    stepper = PlantStepper(rig)
    costs = []
    for u in rng.uniform(0.3, 1.0, 2000):
        t0 = time.perf_counter()
        stepper.step(float(u))
        costs.append(time.perf_counter() - t0)
    c = np.array(costs) * 1e6
    results["stepper"] = {"p50_us": float(np.percentile(c, 50)), "p99_us": float(np.percentile(c, 99)),
                          "x_realtime": dt / (np.mean(c) * 1e-6)}
    return {"rig": rig.name, "backend": DEFAULT_BACKEND, "sample_period_s": dt,
            "machine": platform.processor() or platform.machine(),
            "python": platform.python_version(), "results": results}


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


if __name__ == "__main__":
    report = bench()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(report, indent=2))
    for name, r in report["results"].items():
        print(f"{name:>24s}: " + ", ".join(f"{k} {v:.4g}" for k, v in r.items()))
    print(f"written {OUT}")
