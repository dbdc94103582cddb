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

Run: ``.venv/bin/python -m bench.bench_sim_backends`` (≈ 6 min on 2 shared cores);
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

from bench.backends import components as comp
from bench.backends.study import (
    JAC_PARAMS,
    SPAN,
    all_effects_rig,
    inputs,
    ramped_stops_in_model,
    reference,
)

HERE = Path(__file__).resolve().parent

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

    def __init__(self, rig, ramped_stops: bool = False) -> None:
        self.rig = rig
        self.dt = rig.sample_period
        self.built = comp.build(rig, ramped_stops)
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
    """max |Δθ| (rad) of numba RK4 against LSODA for each K, per rig variant and input; a label
    ending in ``_ramped`` takes the continuous contact law in both (``study.ramped_stops_in_model``)."""
    from bench.backends import nb

    out = {}
    for label, rig in label_rigs.items():
        if label.endswith("_ramped"):
            with ramped_stops_in_model():
                case = Case(rig, ramped_stops=True)
        else:
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

    from bench.backends import jx

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
    from bench.backends import nb

    cold = tempfile.mkdtemp(prefix="aeropend_numba_cold_")
    first = [json.loads(subprocess.run([sys.executable, __file__, "--numba-first", cold], capture_output=True,
                                       text=True, check=True).stdout)["first_call_s"] for _ in range(2)]
    res = {"versions": nb.versions(), "compile_first_call_s": first[0],
           "fresh_process_with_disk_cache_first_call_s": first[1],
           "note": "first calls in fresh processes: an empty numba cache, then the cache the first one wrote"}
    name = "per_sample"
    ua, ub = case.u[name]
    sub = comp.pieces(case.frac, K, case.dt)
    x0 = np.zeros(5)
    mod = nb.module_for(case.built, Path(cold))
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


def _numba_first(cache: str) -> None:
    """Child process: CPU time of the first replay in a fresh interpreter with the numba cache ``cache``
    (compiles and fills it when empty, loads from it otherwise)."""
    from bench.backends import nb

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

    from bench.backends import jx

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
    from bench.backends import cas

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


def run(repeats: int, out: Path, only: set[str] | None = None) -> dict:
    """Every measurement (or the sections in ``only``, updating the report already in ``out``); the
    report is rewritten to ``out`` after each section."""
    report = {"machine": platform.processor() or platform.machine(), "python": platform.python_version(),
              "numpy": np.__version__, "span_s": SPAN, "k_substeps": K, "batch": BATCH,
              "jac_params": JAC_PARAMS,
              "timing": "CPU seconds (process + children), median of repeats", "install": install_sizes()}
    variants = {"all_effects": all_effects_rig(), "no_dry_friction": all_effects_rig(coulomb=False),
                "end_stop_contact": all_effects_rig(contact=True),
                "end_stop_contact_ramped": all_effects_rig(contact=True)}
    case = Case(variants["all_effects"])
    report["samples"] = int(case.duty["per_sample"].size)
    sections = {
        "accuracy_sweep_numba_rk4": lambda: accuracy_sweep(
            variants, Path(tempfile.mkdtemp(prefix="aeropend_numba_sweep_"))),
        "diffrax_adaptive_end_stop_contact": lambda: adaptive_diffrax(Case(all_effects_rig(contact=True))),
        "lsoda": lambda: bench_lsoda(case, max(2, repeats // 2)),
        "numba": lambda: bench_numba(case, repeats),
        "jax": lambda: bench_jax(case, repeats),
        "casadi_vm": lambda: bench_casadi(case, repeats, jit=False),
        "casadi_jit": lambda: bench_casadi(case, repeats, jit=True),
    }
    if only:
        unknown = sorted(only - set(sections))
        if unknown:
            raise SystemExit(f"unknown section(s) {unknown}; expected some of {sorted(sections)}")
        report = {**json.loads(out.read_text()), **{k: v for k, v in report.items() if k not in sections}}
    out.parent.mkdir(parents=True, exist_ok=True)
    for name, section in sections.items():
        if only and name not in only:
            continue
        report[name] = section()
        out.write_text(json.dumps(report, indent=2))
        print(f"{name} done", flush=True)
    return report


def table(report: dict) -> str:
    """The findings table (markdown) of a report."""
    inst = report["install"]
    size = {"lsoda": "0 (scipy)", "numba": inst["numba"]["installed_mb"], "jax": inst["jax"]["installed_mb"],
            "casadi_vm": inst["casadi"]["installed_mb"], "casadi_jit": inst["casadi"]["installed_mb"]}
    head = ("| backend | version | installed MB | compile / first call s | × real time step / APRBS / "
            "per-sample | batch of 64, s (per replay ms) | Jacobian 5 params: exact / FD s | "
            "max abs Δθ rad step / APRBS / per-sample |")
    lines = [head, "|" + "---|" * 8]
    ls = report["lsoda"]
    lines.append(f"| LSODA `simulate` (today) | scipy | {size['lsoda']} | 0 | "
                 + " / ".join(f"{ls[n]['x_realtime']:.0f}" for n in ("step", "aprbs", "per_sample"))
                 + " | — | — / ≈ 6 replays | reference |")
    for key in ("numba", "jax", "casadi_vm", "casadi_jit"):
        r = report[key]
        ver = ", ".join(f"{k} {v}" for k, v in r["versions"].items())
        per = r["per_input"]
        xs = " / ".join(f"{per[n]['x_realtime']:.0f}" for n in ("step", "aprbs", "per_sample"))
        err = " / ".join(f"{per[n]['max_abs_dtheta']:.1e}" for n in ("step", "aprbs", "per_sample"))
        b = r["batch64"]
        j = r["jacobian"]
        exact = f"{j['cpu_s']:.2f}" if j.get("exact") else "none"
        name = {"numba": "numba (njit)", "jax": "JAX (jit, lax.scan)", "casadi_vm": "CasADi VM",
                "casadi_jit": "CasADi C (gcc JIT)"}[key]
        comp_s = f"{r['compile_first_call_s']:.1f}"
        if key == "numba":
            comp_s += f" (disk cache, new process: {r['fresh_process_with_disk_cache_first_call_s']:.2f})"
        if key == "casadi_jit":
            comp_s += f" (wall {r['build_wall_s']:.0f})"
        lines.append(f"| {name} | {ver} | {size[key]} | {comp_s} | {xs} | {b['cpu_s']:.2f} "
                     f"({1e3 * b['per_replay_s']:.1f}) | {exact} / {j['fd_cpu_s']:.2f} | {err} |")
    return "\n".join(lines)


def sweep_table(report: dict) -> str:
    """The accuracy sweep (markdown): max |Δθ| per rig variant, input and K."""
    sweep = report["accuracy_sweep_numba_rk4"]
    lines = ["| rig variant | input | " + " | ".join(f"K = {k}" for k in K_SWEEP) + " |",
             "|---|---|" + "---|" * len(K_SWEEP)]
    for variant, per in sweep.items():
        for name, errs in per.items():
            cells = " | ".join(f"{errs[str(k)]:.1e}" for k in K_SWEEP)
            lines.append(f"| {variant} | {name} | {cells} |")
    return "\n".join(lines)


def replay_only(backend: str, n: int) -> None:
    """``n`` replays of the per-sample input (nothing else), for whole-process timing."""
    rig = all_effects_rig()
    duty = inputs(rig.sample_period)["per_sample"]
    if backend == "lsoda":
        for _ in range(n):
            reference(rig, duty)
        return
    from bench.backends import nb

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
    ap.add_argument("--table", action="store_true", help="print the findings table of the last results")
    ap.add_argument("--only", help="comma-separated sections to re-measure into the existing results")
    ap.add_argument("--numba-first", metavar="CACHE", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.numba_first:
        _numba_first(args.numba_first)
        return 0
    if args.replay:
        replay_only(args.replay, args.n)
        return 0
    if args.table:
        report = json.loads(OUT.read_text())
        print(table(report) + "\n\n" + sweep_table(report))
        return 0
    run(args.repeats, OUT, set(args.only.split(",")) if args.only else None)
    print(f"written {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
