"""Study (issue 37 item 1): compiled simulator backends measured against today's LSODA `simulate`.

The thesis rig with every dynamic effect on (``bench/backends/study.py``) is replayed for 60 s at
490 Hz on step, APRBS and per-sample (closed-loop-like) inputs by a fixed-step RK4 with sub-steps,
compiled by numba, JAX and CasADi (virtual machine and gcc-compiled C), from the same physics
functions (``bench/backends/components.py``). Measured in-process as CPU time
(``time.process_time``, plus the children's CPU for CasADi's gcc), medians of repeats: first-call
(compile) and cached-call cost, a batch of 64 parameter sets, a Jacobian d θ(t)/d p for 5
parameters (exact where the backend differentiates, and by forward differences), accuracy against
the LSODA reference, installed size. Writes ``bench/results/sim_backends.json``.

Needs the study's libraries in the venv (not in requirements.txt):
``.venv/bin/pip install numba jax jaxlib casadi diffrax``.

Run: ``.venv/bin/python bench/bench_sim_backends.py`` (≈ 6 min on 2 shared cores);
``--replay {lsoda,numba} --n N`` only replays the per-sample input N times (for timing the whole
process from outside, e.g. with ``/usr/bin/time -v``).
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from backends import components as comp  # noqa: E402
from backends.study import JAC_PARAMS, SPAN, all_effects_rig, inputs, reference  # noqa: E402

OUT = HERE / "results" / "sim_backends.json"
#: Sub-steps per sample (at most dt/K each): the smallest K with θ within 1e-6 rad of LSODA on all
#: three inputs for the all-effects rig (see the accuracy sweep in the results).
K = 6
K_SWEEP = (1, 2, 3, 4, 6, 8, 16)
BATCH = 64
#: Distributions whose installed files make up each candidate (beyond numpy/scipy, already there).
INSTALL_GROUPS = {
    "numba": ("numba", "llvmlite"),
    "jax": ("jax", "jaxlib", "ml_dtypes", "opt_einsum"),
    "diffrax (on top of jax)": ("diffrax", "equinox", "lineax", "optimistix", "jaxtyping", "wadler_lindig"),
    "casadi": ("casadi",),
}


def cpu() -> float:
    """CPU seconds of this process and its finished children (CasADi's gcc runs as a child)."""
    t = os.times()
    return time.process_time() + t.children_user + t.children_system


def timed(fn, repeats: int) -> tuple[float, list[float]]:
    """Median CPU seconds of ``fn()`` over ``repeats`` calls, and all the figures."""
    out = []
    for _ in range(repeats):
        t0 = cpu()
        fn()
        out.append(cpu() - t0)
    return statistics.median(out), out


def installed_mb(dists: tuple[str, ...]) -> float:
    total = 0
    for name in dists:
        for f in md.files(name) or []:
            p = f.locate()
            if p.is_file():
                total += p.stat().st_size
    return total / 2**20


def perturbed(p: np.ndarray, n: int, seed: int = 1) -> np.ndarray:
    """n parameter sets around p (±5 % log-normal), shape (n, len(p))."""
    rng = np.random.default_rng(seed)
    return p * np.exp(0.05 * rng.standard_normal((n, p.size)))


class Case:
    """The rig, its composed model, the inputs and the LSODA references."""

    def __init__(self, rig) -> None:
        self.rig = rig
        self.dt = rig.sample_period
        self.built = comp.build(rig)
        self.whole, self.frac = comp.delay_split(rig, self.dt)
        self.duty = inputs(self.dt)
        self.u = {name: comp.delayed_pairs(d, self.whole) for name, d in self.duty.items()}
        self.ref = {name: reference(rig, d) for name, d in self.duty.items()}
        names = self.built.param_names
        self.jac_index = tuple(names.index(n) for n in JAC_PARAMS if n in names)

    def err(self, name: str, theta: np.ndarray) -> float:
        return float(np.max(np.abs(np.asarray(theta) - self.ref[name][:, 0])))


def bench_lsoda(case: Case, repeats: int) -> dict:
    out = {}
    for name, d in case.duty.items():
        med, runs = timed(lambda d=d: reference(case.rig, d), repeats)
        out[name] = {"cpu_s": med, "runs": runs, "x_realtime": SPAN / med}
    return out


def accuracy_sweep(label_rigs: dict, cache: Path) -> dict:
    """max |Δθ| (rad) of numba RK4 against LSODA for each K, per rig variant and input."""
    from backends import nb

    out = {}
    for label, rig in label_rigs.items():
        case = Case(rig)
        mod = nb.module_for(case.built, cache)
        out[label] = {}
        for name in case.duty:
            ua, ub = case.u[name]
            runs = {k: nb.replay(mod, case.built, ua, ub, k, case.frac, case.dt)[:, 0] for k in K_SWEEP}
            out[label][name] = {str(k): case.err(name, theta) for k, theta in runs.items()}
    return out


def adaptive_diffrax(case: Case) -> dict:
    """diffrax's adaptive explicit Tsit5 and implicit Kvaerno5 (rtol 1e-8) restarted per piece."""
    import jax.numpy as jnp
    from backends import jx

    out = {}
    for solver, names in (("Tsit5", tuple(case.duty)), ("Kvaerno5", ("aprbs",))):
        rep = jx.make_adaptive_replay(case.built, case.frac, case.dt, solver=solver)
        p = jnp.asarray(case.built.p)
        res = {}
        for name in names:
            ua, ub = case.u[name]
            t0 = cpu()
            rep(jnp.zeros(5), ua, ub, p)[0].block_until_ready()
            first = cpu() - t0
            def again(ua=ua, ub=ub, rep=rep, p=p):
                rep(jnp.zeros(5), ua, ub, p)[0].block_until_ready()

            med, _ = timed(again, 2)
            xs, steps = rep(jnp.zeros(5), ua, ub, p)
            res[name] = {"first_call_s": first, "cpu_s": med, "x_realtime": SPAN / med,
                         "max_abs_dtheta": case.err(name, np.asarray(xs)[:, 0]),
                         "steps_per_sample": float(np.mean(np.asarray(steps)))}
        out[solver] = res
    return out


def _per_input(case: Case, run, repeats: int) -> dict:
    out = {}
    for name in case.duty:
        ua, ub = case.u[name]
        med, _ = timed(lambda ua=ua, ub=ub: run(ua, ub), repeats)
        out[name] = {"cpu_s": med, "x_realtime": SPAN / med, "max_abs_dtheta": case.err(name, run(ua, ub))}
    return out


def bench_numba(case: Case, repeats: int) -> dict:
    from backends import nb

    cold = Path(tempfile.mkdtemp(prefix="aeropend_numba_cold_"))
    name = "per_sample"
    ua, ub = case.u[name]
    sub = comp.pieces(case.frac, K, case.dt)
    x0 = np.zeros(5)
    t0 = cpu()
    mod = nb.module_for(case.built, cold)
    mod.sim(x0, ua, ub, case.built.p, *sub)
    compile_s = cpu() - t0
    warm = subprocess.run([sys.executable, __file__, "--numba-warm", str(cold)], capture_output=True,
                          text=True, check=True)
    res = {"versions": nb.versions(), "compile_first_call_s": compile_s,
           "fresh_process_with_disk_cache_first_call_s": json.loads(warm.stdout)["first_call_s"]}
    res["per_input"] = _per_input(case, lambda a, b: mod.sim(x0, a, b, case.built.p, *sub)[:, 0], repeats)
    P = perturbed(case.built.p, BATCH)
    mod.sim_batch(x0, ua, ub, P[:2], *sub)  # compile the parallel loop
    med, _ = timed(lambda: mod.sim_batch(x0, ua, ub, P, *sub), 3)
    res["batch64"] = {"cpu_s": med, "per_replay_s": med / BATCH, "how": "prange over parameter sets",
                      "numba_threads": numba_threads()}
    def theta(p):
        return mod.sim(x0, ua, ub, p, *sub)[:, 0]

    fd_med, _ = timed(lambda: _fd(theta, case.built.p, case.jac_index), 3)
    res["jacobian"] = {"exact": None, "fd_cpu_s": fd_med}
    return res


def numba_threads() -> int:
    import numba

    return numba.get_num_threads()


def _fd(theta, p: np.ndarray, index: tuple[int, ...]) -> np.ndarray:
    """Forward-difference d θ / d p[index] (relative step 1e-6): 1 + len(index) replays."""
    base = np.asarray(theta(p))
    cols = []
    for i in index:
        q = p.copy()
        h = 1e-6 * max(abs(p[i]), 1e-8)
        q[i] += h
        cols.append((np.asarray(theta(q)) - base) / h)
    return np.stack(cols, axis=1)


def _numba_warm(cache: str) -> None:
    """Child process: first call of the cached generated module in a fresh interpreter."""
    from backends import nb

    case_rig = all_effects_rig()
    built = comp.build(case_rig)
    whole, frac = comp.delay_split(case_rig, case_rig.sample_period)
    duty = np.full(round(SPAN / case_rig.sample_period), 0.5)
    t0 = cpu()
    mod = nb.module_for(built, Path(cache))
    sub = comp.pieces(frac, K, case_rig.sample_period)
    mod.sim(np.zeros(5), *comp.delayed_pairs(duty, whole), built.p, *sub)
    print(json.dumps({"first_call_s": cpu() - t0}))


def bench_jax(case: Case, repeats: int) -> dict:
    import jax.numpy as jnp
    from backends import jx

    single, batch, jac = jx.make_jitted(case.built, K, case.frac, case.dt, case.jac_index)
    x0, p = jnp.zeros(5), jnp.asarray(case.built.p)
    ua, ub = case.u["per_sample"]
    t0 = cpu()
    single(x0, ua, ub, p).block_until_ready()
    res = {"versions": jx.versions(), "compile_first_call_s": cpu() - t0}
    res["per_input"] = _per_input(case, lambda a, b: single(x0, a, b, p)[:, 0].block_until_ready(), repeats)
    P = jnp.asarray(perturbed(case.built.p, BATCH))
    t0 = cpu()
    batch(x0, ua, ub, P).block_until_ready()
    first = cpu() - t0
    med, _ = timed(lambda: batch(x0, ua, ub, P).block_until_ready(), 3)
    res["batch64"] = {"compile_first_call_s": first, "cpu_s": med, "per_replay_s": med / BATCH}
    t0 = cpu()
    J = np.asarray(jac(x0, ua, ub, p))
    first = cpu() - t0
    med, _ = timed(lambda: jac(x0, ua, ub, p).block_until_ready(), 3)
    fd_med, _ = timed(lambda: _fd(lambda q: single(x0, ua, ub, jnp.asarray(q))[:, 0], case.built.p,
                                  case.jac_index), 3)
    fd = _fd(lambda q: np.asarray(single(x0, ua, ub, jnp.asarray(q))[:, 0]), case.built.p, case.jac_index)
    res["jacobian"] = {"exact": "jax.jacfwd", "compile_first_call_s": first, "cpu_s": med, "fd_cpu_s": fd_med,
                       "rel_diff_exact_vs_fd": float(np.max(np.abs(J - fd)) / np.max(np.abs(J)))}
    return res


def bench_casadi(case: Case, repeats: int, jit: bool) -> dict:
    from backends import cas

    n = case.duty["per_sample"].size
    workdir = Path(tempfile.mkdtemp(prefix="aeropend_casadi_"))
    here = Path.cwd()
    os.chdir(workdir)  # CasADi's JIT writes its C and .so files to the working directory
    try:
        w0, t0 = time.perf_counter(), cpu()
        F = cas.make_functions(case.built, K, case.frac, case.dt, n, case.jac_index, jit=jit, batch=BATCH)
        res = {"versions": cas.versions(), "mode": "gcc -O2 JIT" if jit else "virtual machine",
               "build_s": cpu() - t0, "build_wall_s": time.perf_counter() - w0}
        x0, p = np.zeros(5), case.built.p
        U = {name: cas.as_inputs(*case.u[name]) for name in case.duty}
        t0 = cpu()
        F["replay"](x0, U["per_sample"], p)
        res["compile_first_call_s"] = res["build_s"] + cpu() - t0
        per = {}
        for name in case.duty:
            med, _ = timed(lambda name=name: F["replay"](x0, U[name], p), repeats)
            per[name] = {"cpu_s": med, "x_realtime": SPAN / med,
                         "max_abs_dtheta": case.err(name, np.array(F["replay"](x0, U[name], p))[0])}
        res["per_input"] = per
        P = perturbed(p, BATCH).T
        med, _ = timed(lambda: F["batch"](x0, U["per_sample"], P), 2)
        res["batch64"] = {"cpu_s": med, "per_replay_s": med / BATCH, "how": "Function.map (serial)"}
        q = p[list(case.jac_index)]
        J = np.array(F["jac"](x0, U["per_sample"], p, q))
        med, _ = timed(lambda: F["jac"](x0, U["per_sample"], p, q), 2)
        fd_med, _ = timed(lambda: _fd(lambda pp: np.array(F["replay"](x0, U["per_sample"], pp))[0], p,
                                      case.jac_index), 2)
        fd = _fd(lambda pp: np.array(F["replay"](x0, U["per_sample"], pp))[0], p, case.jac_index)
        res["jacobian"] = {"exact": "CasADi AD (jacobian of the mapaccum graph)", "cpu_s": med,
                           "fd_cpu_s": fd_med,
                           "rel_diff_exact_vs_fd": float(np.max(np.abs(J - fd)) / np.max(np.abs(J)))}
    finally:
        os.chdir(here)
    return res


def install_sizes() -> dict:
    out = {}
    for group, dists in INSTALL_GROUPS.items():
        try:
            out[group] = {"dists": {d: md.version(d) for d in dists},
                          "installed_mb": round(installed_mb(dists), 1)}
        except md.PackageNotFoundError as exc:
            out[group] = {"missing": str(exc)}
    return out


def run(repeats: int, out: Path) -> dict:
    """Every measurement; the report is rewritten to ``out`` after each section."""
    report = {"machine": platform.processor() or platform.machine(), "python": platform.python_version(),
              "numpy": np.__version__, "span_s": SPAN, "k_substeps": K, "batch": BATCH,
              "jac_params": JAC_PARAMS,
              "timing": "CPU seconds (process + children), median of repeats", "install": install_sizes()}
    variants = {"all_effects": all_effects_rig(), "no_dry_friction": all_effects_rig(coulomb=False),
                "end_stop_contact": all_effects_rig(contact=True)}
    case = Case(variants["all_effects"])
    report["samples"] = int(case.duty["per_sample"].size)
    sections = {
        "accuracy_sweep_numba_rk4": lambda: accuracy_sweep(
            variants, Path(tempfile.mkdtemp(prefix="aeropend_numba_sweep_"))),
        "diffrax_adaptive_end_stop_contact": lambda: adaptive_diffrax(Case(variants["end_stop_contact"])),
        "lsoda": lambda: bench_lsoda(case, max(2, repeats // 2)),
        "numba": lambda: bench_numba(case, repeats),
        "jax": lambda: bench_jax(case, repeats),
        "casadi_vm": lambda: bench_casadi(case, repeats, jit=False),
        "casadi_jit": lambda: bench_casadi(case, repeats, jit=True),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    for name, section in sections.items():
        report[name] = section()
        out.write_text(json.dumps(report, indent=2))
        print(f"{name} done", flush=True)
    return report


def replay_only(backend: str, n: int) -> None:
    """``n`` replays of the per-sample input (nothing else), for whole-process timing."""
    rig = all_effects_rig()
    duty = inputs(rig.sample_period)["per_sample"]
    if backend == "lsoda":
        for _ in range(n):
            reference(rig, duty)
        return
    from backends import nb

    built = comp.build(rig)
    whole, frac = comp.delay_split(rig, rig.sample_period)
    mod = nb.module_for(built, Path(tempfile.gettempdir()) / "aeropend_numba_study")
    ua, ub = comp.delayed_pairs(duty, whole)
    for _ in range(n):
        mod.sim(np.zeros(5), ua, ub, built.p, *comp.pieces(frac, K, rig.sample_period))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7, help="timed repeats per figure (median quoted)")
    ap.add_argument("--replay", choices=("lsoda", "numba"), help="only replay the per-sample input")
    ap.add_argument("--n", type=int, default=1, help="replays for --replay")
    ap.add_argument("--numba-warm", metavar="CACHE", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.numba_warm:
        _numba_warm(args.numba_warm)
        return 0
    if args.replay:
        replay_only(args.replay, args.n)
        return 0
    run(args.repeats, OUT)
    print(f"written {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
