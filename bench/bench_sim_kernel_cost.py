"""Benchmark (issue 37's simulation bar): what one compiled replay costs, and whether fewer
right-hand-side evaluations could keep the agreement with LSODA.

The thesis rig with every effect on (``bench/backends/study.py``), 60 s at 490 Hz of the three
inputs of ``bench/bench_sim_backend.py`` (steps, APRBS, per-sample), LSODA as the reference:

* **libm**: ns per call of the functions the compiled right-hand side calls (numba loops over 10⁶
  values: ``pow`` at α = 1.9, ``tanh`` off saturation, ``exp``, ``sin``; an add for scale);
* **the right-hand side's machine code** (the generated module's ``rhs``, as numba compiled it):
  instructions, libm calls, divisions, stack accesses;
* **RK4 with K sub-steps** (the product kernel, ``compiled_plant(rig, substeps=K)``, K = 4-8): the
  sub-steps a sample (the input delay splits one piece in two), max |Δθ| against LSODA, CPU ms a
  replay (median of ``--repeats``);
* **fixed-step Dormand-Prince 5** (a prototype here, 6 evaluations a step; 1-2 steps in each of
  the two pieces of a sample): evaluations a sample and max |Δθ|;
* **adaptive Dormand-Prince 5(4)** (a prototype here: embedded error estimate, restarted at every
  input change, tolerance 1e-6 and 1e-7 on the state scaled by (1 rad, 10 rad/s, 1 A, 300 rad/s,
  1)): evaluations a sample, rejected steps and max |Δθ|.

The prototypes call the product's compiled ``rhs`` but allocate per stage, so only their
evaluation counts and errors are compared, not their time. Writes
``bench/results/sim_kernel_cost.json`` (``--out``); docs/findings/simulator_backends.md,
"The 1000× bar on a slow day", reads it.

Run: ``.venv/bin/python -m bench.bench_sim_kernel_cost`` (≈ 2 min here).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from numba import njit

from aeropend_sim.compiled.plant import CompiledPlant, compiled_plant
from aeropend_sim.simulation import simulate
from bench.backends import study
from bench.bench_sim_backend import _times

OUT = Path(__file__).resolve().parent / "results" / "sim_kernel_cost.json"
#: Scale of each state in the adaptive prototype's error norm (θ, θ̇, i_a, ω₁, τ_f).
STATE_SCALE = np.array([1.0, 10.0, 1.0, 300.0, 1.0])

# Dormand-Prince 5(4): stages, 5th-order weights (the 7th stage is the next step's first), and the
# difference to the embedded 4th-order weights.
DP_A = np.zeros((7, 7))
DP_A[1, :1] = [1 / 5]
DP_A[2, :2] = [3 / 40, 9 / 40]
DP_A[3, :3] = [44 / 45, -56 / 15, 32 / 9]
DP_A[4, :4] = [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729]
DP_A[5, :5] = [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656]
DP_A[6, :6] = [35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84]
DP_E = DP_A[6] - np.array([5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40])


# ------------------------------------------------------------------ libm
def _summed(op):
    """A compiled loop summing ``op(v, a)`` over ``x``: the time of one ``op`` call, inlined."""
    fn = njit(inline="always")(op)

    @njit
    def loop(x, a):
        s = 0.0
        for v in x:
            s += fn(v, a)
        return s

    return loop


#: name -> (the operation, its parameter a): pow at α = 1.9, tanh off saturation (v·0.01 in
#: 0.005-3), exp and sin of v·0.01, and an add for scale.
LIBM_LOOPS = {"pow": (lambda v, a: v**a, 1.9), "tanh": (lambda v, a: math.tanh(v * a), 0.01),
              "exp": (lambda v, a: math.exp(-v * a), 0.01), "sin": (lambda v, a: math.sin(v * a), 0.01),
              "add": (lambda v, a: v * a, 0.01)}


def libm_ns() -> dict[str, float]:
    """Fastest of 7 timings of each loop, ns per call (values 0.5-300; tanh's argument 0.005-3,
    off its saturation)."""
    x = np.random.default_rng(0).uniform(0.5, 300.0, 1_000_000)
    out = {}
    for name, (op, a) in LIBM_LOOPS.items():
        fn = _summed(op)
        fn(x, a)
        best = min(_times(lambda f=fn, a_=a: f(x, a_), 7)[0])
        out[name] = 1e9 * best / x.size
    return out


# ------------------------------------------------------------------ the right-hand side's code
def rhs_code(plant: CompiledPlant) -> dict:
    """Instruction counts of the native ``rhs`` function numba compiled for the rig's family."""
    rhs = plant.module.rhs
    rhs(0.1, 0.2, 0.3, 300.0, 0.5, 0.5, plant.p)
    asm = rhs.inspect_asm(rhs.signatures[0])
    bodies: dict[str, list[str]] = {}
    name = None
    for line in asm.splitlines():
        label = re.match(r"^(\S+):", line)
        if label and not label.group(1).startswith(".L"):
            name = label.group(1)
            bodies[name] = []
        elif name and line.startswith("\t") and not line.strip().startswith("."):
            bodies[name].append(line.strip())
    native = next(v for k, v in bodies.items()
                  if "rhs" in k and "cpython" not in k and not k.startswith("cfunc"))
    libm = [m.group(1) for line in native for m in [re.match(r"movabsq\s+\$(\w+), ", line)]
            if m and m.group(1) in ("sin", "cos", "tanh", "exp", "pow", "log", "sqrt")]
    return {"instructions": len(native), "calls": sum(line.startswith("call") for line in native),
            "libm_functions": sorted(libm), "divisions": sum("div" in line.split()[0] for line in native),
            "stack_accesses": sum("(%rsp)" in line for line in native)}


# ------------------------------------------------------------------ prototypes
@njit
def _f(rhs, x, u, p):
    return np.array(rhs(x[0], x[1], x[2], x[3], x[4], u, p))


@njit
def _dp5_step(rhs, x, u, p, h, k1, A, E):
    """One Dormand-Prince step: the 5th-order end, the scaled-free error vector and the 7 stages."""
    K = np.empty((7, 5))
    K[0] = k1
    for s in range(1, 7):
        y = x.copy()
        for r in range(s):
            if A[s, r] != 0.0:
                y += h * A[s, r] * K[r]
        K[s] = _f(rhs, y, u, p)
    y5 = x.copy()
    for r in range(6):
        y5 += h * A[6, r] * K[r]
    err = np.zeros(5)
    for r in range(7):
        err += h * E[r] * K[r]
    return y5, err, K


@njit
def _piece(rhs, x, u, p, length, h, scale, tol, A, E, counts):
    """Integrate one constant-input piece; tol ≤ 0: fixed steps, ``h`` = the piece / their number."""
    k1 = _f(rhs, x, u, p)
    counts[0] += 1
    t = 0.0
    while length - t > 1e-12 * length:
        h = min(h, length - t)
        y5, err, K = _dp5_step(rhs, x, u, p, h, k1, A, E)
        counts[0] += 6
        if tol <= 0.0:
            x, k1, t = y5, K[6], t + h
            continue
        e = np.max(np.abs(err) / scale) / tol
        if e <= 1.0:
            x, k1, t = y5, K[6], t + h
            h *= min(5.0, 0.9 * e**-0.2) if e > 0.0 else 5.0
        else:
            counts[1] += 1
            h *= max(0.2, 0.9 * e**-0.2)
    return x, h


@njit
def _replay_dp5(rhs, duty, whole, frac, dt, n_a, n_b, p, scale, tol, A, E):
    """θ (N,) of a Dormand-Prince replay with the product's delay split, and (evaluations,
    rejected steps)."""
    th = np.empty(duty.size)
    x = np.zeros(5)
    counts = np.zeros(2, np.int64)
    h = dt
    for j in range(duty.size):
        th[j] = x[0]
        ua = duty[j - whole - 1] if j - whole - 1 >= 0 else 0.0
        ub = duty[j - whole] if j - whole >= 0 else 0.0
        if frac > 0.0:
            h_a = frac * dt / n_a if tol <= 0.0 else h
            x, h = _piece(rhs, x, ua, p, frac * dt, h_a, scale, tol, A, E, counts)
        h_b = (1.0 - frac) * dt / n_b if tol <= 0.0 else h
        x, h = _piece(rhs, x, ub, p, (1.0 - frac) * dt, h_b, scale, tol, A, E, counts)
    return th, counts


# ------------------------------------------------------------------ measurements
def accuracy(repeats: int) -> dict:
    rig = study.all_effects_rig()
    inputs = study.inputs(rig.sample_period)
    ref = {k: simulate(rig, d, backend="lsoda").theta for k, d in inputs.items()}
    x0 = np.zeros(5)
    rk4 = {}
    for k in range(4, 9):
        plant = compiled_plant(rig, substeps=k)
        plan = plant.plan
        row = {"substeps_a_sample": int(plan.n_a[0] + plan.n_b[0]),
               "evaluations_a_sample": 4 * int(plan.n_a[0] + plan.n_b[0])}
        for name, duty in inputs.items():
            theta = plant.replay(duty, x0)[0][:, 0]
            row[f"{name}_max_abs_dtheta_rad"] = float(np.abs(theta - ref[name]).max())
            cpu, _ = _times(lambda d=duty, pl=plant: pl.replay(d, x0), repeats)
            row[f"{name}_cpu_ms"] = 1e3 * float(np.median(cpu))
        rk4[str(k)] = row
        print("rk4", k, row, flush=True)
    plant = compiled_plant(rig)
    whole = int(plant.plan.whole[0])
    frac = rig.actuator.input_delay / plant.dt - whole
    first_second = round(1.0 / plant.dt)
    theta = plant.replay(inputs["step"], x0)[0][:, 0]
    split = {"first_second": float(np.abs(theta - ref["step"])[:first_second].max()),
             "after": float(np.abs(theta - ref["step"])[first_second:].max())}
    dp5: dict = {}
    for label, n_a, n_b, tol in (("fixed_1_1", 1, 1, 0.0), ("fixed_1_2", 1, 2, 0.0), ("fixed_2_3", 2, 3, 0.0),
                                 ("adaptive_tol_1e-6", 1, 1, 1e-6), ("adaptive_tol_1e-7", 1, 1, 1e-7)):
        row = {}
        for name, duty in inputs.items():
            theta, counts = _replay_dp5(plant.module.rhs, duty, whole, frac, plant.dt, n_a, n_b, plant.p,
                                        STATE_SCALE, tol, DP_A, DP_E)
            row[f"{name}_max_abs_dtheta_rad"] = float(np.abs(theta - ref[name]).max())
            row[f"{name}_evaluations_a_sample"] = float(counts[0] / duty.size)
            row[f"{name}_rejected_steps"] = int(counts[1])
        dp5[label] = row
        print("dp5", label, row, flush=True)
    return {"rk4_substeps": rk4, "rk4_step_input_error_by_time_rad": split, "dormand_prince": dp5,
            "input_delay_fraction_of_a_sample": frac}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="timing repeats of each RK4 replay")
    ap.add_argument("--out", type=Path, default=OUT, help=f"result file (default {OUT})")
    args = ap.parse_args()
    plant = compiled_plant(study.all_effects_rig())
    report = {"date": datetime.now(UTC).isoformat(timespec="seconds"),
              "rig": "thesis_rig, every effect on (bench/backends/study.py)",
              "load_average_1min_at_start": os.getloadavg()[0],
              "libm_ns_per_call": libm_ns(), "rhs_machine_code": rhs_code(plant), **accuracy(args.repeats),
              "load_average_1min_at_end": os.getloadavg()[0]}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(json.dumps({k: report[k] for k in ("libm_ns_per_call", "rhs_machine_code")}, indent=1))
    print(f"written {args.out}")


if __name__ == "__main__":
    main()
