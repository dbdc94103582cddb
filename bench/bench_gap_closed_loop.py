"""Gap diagnosis on closed-loop recordings: the duty changes every sample, only θ and τ are logged.

What labs record most: the rod held at set-points by a feedback loop, the log holding the angle and
the controller's duty. Each case is a hidden plant of :mod:`truth_plant` (``bench/fixtures/truth_plant.py``:
the thesis' simulated equations written outside aeropend, no shared code) stepped one 2.048 ms
sample at a time (:class:`truth_plant.TruthStepper`, θ measured with noise) under a PD loop with
gravity feed-forward, written here from the nominal rig file's equilibrium:

    τ_k = τ_eq(r_k) + k_p·(r_k − θ_k) − k_d·θ̇_k,  θ̇_k an exponentially smoothed difference of θ,

r a staircase of set-points in [0.15, 0.75] rad held 2-4 s (seeded). The measurement noise makes
the duty change at every sample, as in a real loop. The first 40 s are the fit recording, the next
30 s the held-out one (``gap --held-out``), both with the channels θ and τ only. The lab's rig file
is the truth's nominal simulator (:func:`bench_gap_independent.rig_dict`); the truth adds one
effect of the catalog (drawn as the independent benchmark draws it) or none.

Measured per case: the whole ``gap`` pipeline (:func:`aeropend_ident.gap.run.run_gap`, as the
command runs it with ``--held-out``) wall and CPU time (issue 37's bar: median ≤ 10 s; LSODA needed
331-1358 s per case), and the diagnosis scored as the independent benchmark scores it
(:func:`bench_gap_independent.score`: first named effect, held-out θ NRMSE shrink, magnitude).
The cases run as independent cases of a Dask cluster (:func:`aeropend_ident.parallel.run_cases`).

Writes ``bench/results/gap_closed_loop.json`` and ``.md``.

Usage: ``python -m bench.bench_gap_closed_loop [--workers 2] [--scheduler ADDRESS] [-q]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.bench_gap_independent import THESIS, rig_dict, score, to_recording, truth_effects
from bench.fixtures.truth_plant import DT, PlantParams, TruthPlant, TruthStepper

RESULTS = Path(__file__).resolve().parent / "results"
FIT_DURATION = 40.0
HELD_DURATION = 30.0
#: PD gains [1/rad], [s/rad] and the smoothing time [s] of the rate estimate.
KP, KD, RATE_SMOOTHING = 0.35, 0.04, 0.02
#: θ noise σ [rad] (an encoder-class sensor, ≈ 50 dB on a 1 rad swing).
SIGMA_THETA = 3e-3
#: Set-points [rad] and their hold times [s].
SETPOINTS, HOLD = (0.15, 0.75), (2.0, 4.0)
#: Cases: (truth effects, seed); one plant per case, half of them on a non-default nominal plant.
CASES = [([], 37000), (["viscous_friction"], 37001), (["gravity"], 37002),
         (["thrust_coefficient"], 37003), (["dead_zone"], 37004), (["input_delay"], 37005),
         (["coulomb_friction"], 37006), (["sensor_offset"], 37007)]


def closed_loop(plant: TruthPlant, nominal: Any, seed: int, duration: float, *, every: int = 1,
                dither: float = 0.0, sigma: dict[str, float] | None = None,
                quantum: float = 0.0) -> dict[str, np.ndarray]:
    """The PD loop (module doc) on the truth plant: sample times, duty and measured channels (M,).

    Parameters
    ----------
    plant : TruthPlant
    nominal : Rig
        The lab's rig file (feed-forward and the set-point range).
    seed : int
    duration : float
        Length [s] of the run.
    every : int
        The controller (and the logger) runs every ``every``-th truth sample (a lower rate); its
        duty is held over the whole period (zero-order hold). 1: every 2.048 ms sample.
    dither : float
        Largest random duty added to the controller output (uniform in ±dither, held 0.05-0.3 s,
        from its own generator); 0: none.
    sigma : dict, optional
        Noise σ per measured channel (:class:`TruthStepper`); default θ only, :data:`SIGMA_THETA`.
    quantum : float
        Angle lattice q [rad] of the sensor: the loop sees and logs q·round(θ/q) (0: none).

    Returns
    -------
    dict
        ``t``, ``duty``, ``theta`` (what the loop saw) and ``i_a``, ``v_a``, ``omega_rotor`` (noise
        only where ``sigma`` gives it) at the controller instants, M = round(duration/DT) // every.
    """
    from aeropend_sim.model import PlantModel
    from bench.fixtures.lab_logging import quantise

    rng = np.random.default_rng(seed)
    model = PlantModel(nominal)
    top = min(SETPOINTS[1], 0.85 * _reach(model))
    n = round(duration / DT)
    ref = np.empty(n)
    k = 0
    while k < n:
        hold = round(rng.uniform(*HOLD) / DT)
        ref[k:k + hold] = rng.uniform(SETPOINTS[0], top)
        k += hold
    ff = {float(r): float(model.equilibrium(float(r))[1]) for r in np.unique(ref)}
    st = TruthStepper(plant, sigma={"theta": SIGMA_THETA} if sigma is None else sigma, seed=seed + 1)
    m = n // every
    out = {c: np.empty(m) for c in ("duty", "theta", "i_a", "v_a", "omega_rotor")}
    s = st.sample()
    rate, prev = 0.0, quantise(s["theta"], quantum)
    dt_c = every * DT
    a = dt_c / (RATE_SMOOTHING + dt_c)
    d_rng = np.random.default_rng(seed + 2) if dither > 0.0 else None
    dith, left = 0.0, 0
    for j in range(m):
        th = quantise(s["theta"], quantum)
        rate += a * ((th - prev) / dt_c - rate)
        prev = th
        r = ref[j * every]
        d = ff[float(r)] + KP * (r - th) - KD * rate
        if d_rng is not None:
            if left <= 0:
                dith, left = d_rng.uniform(-dither, dither), round(d_rng.uniform(0.05, 0.3) / dt_c)
            d += dith
            left -= 1
        d = min(max(d, 0.0), 1.0)
        out["theta"][j], out["duty"][j] = th, d
        for c in ("i_a", "v_a", "omega_rotor"):
            out[c][j] = s[c]
        for _ in range(every):
            s = st.step(d)
    return {"t": np.arange(m) * dt_c, **out}


def _reach(model: Any, headroom: float = 0.9) -> float:
    """Largest angle [rad] the nominal rig holds with a duty of at most ``headroom``."""
    from aeropend_sim.model import ModelError

    best = 0.0
    for theta in np.arange(0.05, 1.5, 0.01):
        try:
            if model.equilibrium(float(theta))[1] > headroom:
                break
        except ModelError:
            break
        best = float(theta)
    return best


class _Trace:
    """A recorded stretch in the shape :func:`bench_gap_independent.to_recording` takes."""

    def __init__(self, run: dict[str, np.ndarray], a: int, b: int) -> None:
        self.t = run["t"][a:b] - run["t"][a]
        self.duty = run["duty"][a:b]
        self.channels = {"theta": run["theta"][a:b]}


def build_case(spec: dict[str, Any]) -> dict[str, Any]:
    """Hidden plant, the closed-loop fit / held-out recordings and the lab's rig file of one case."""
    from aeropend_sim.params import rig_from_dict

    rng = np.random.default_rng(spec["seed"])
    params = THESIS.variant(rng) if spec["variant"] else PlantParams()
    doc = rig_dict(params, f"closed_loop_nominal_{spec['seed']}")
    nominal = rig_from_dict(doc, where=f"case {spec['seed']}")
    probe = closed_loop(TruthPlant(params, {}), nominal, spec["seed"], 10.0)
    effects = truth_effects(spec["effects"], rng, params, float(np.max(probe["theta"])))
    run = closed_loop(TruthPlant(params, effects), nominal, spec["seed"] + 10,
                      FIT_DURATION + HELD_DURATION)
    k = round(FIT_DURATION / DT)
    changes = float(np.mean(np.diff(run["duty"]) != 0.0))
    return {"params": params, "effects": effects, "snr_db": float("nan"), "rig": doc, "nominal": nominal,
            "fit": _Trace(run, 0, k), "held": _Trace(run, k, run["t"].size),
            "duty_changes": changes}


def run_case(spec: dict[str, Any]) -> dict[str, Any]:
    """Build one case, run the gap pipeline on it, time and score it."""
    from aeropend_ident.gap.run import run_gap

    case = build_case(spec)
    fit = [to_recording(case["fit"], f"closed-loop-{spec['seed']}-fit")]
    held = [to_recording(case["held"], f"closed-loop-{spec['seed']}-held")]
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        result = run_gap(case["nominal"], fit, held, rig_ref=case["nominal"].name, seed=0, max_effects=2,
                         split_rule="separate held-out recording")
    except Exception as exc:  # a refusal is a failure of the case, recorded with its message
        return {"case": f"{'+'.join(spec['effects']) or 'none'}@{spec['seed']}", "error": f"{exc}",
                "pass": False, "elapsed_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}
    s = score(spec, case, result)
    s.update(elapsed_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0,
             duty_changes_per_sample=case["duty_changes"], samples=len(fit[0]) + len(held[0]))
    return s


def write_md(path: Path, doc: dict[str, Any]) -> None:
    m, s = doc["meta"], doc["summary"]
    lines = ["# Gap diagnosis on closed-loop recordings (bench/bench_gap_closed_loop.py)", "",
             f"{s['cases']} cases, PD loop on `bench/fixtures/truth_plant.py` at 490 Hz, θ and τ only, "
             f"40 s fit + 30 s held out; {m['workers']} Dask worker(s), {m['wall_s']:.0f} s wall; "
             f"load average {m['load_before']} before, {m['load_after']} after; commit {m['commit']}.", "",
             f"Median per case: **{s['median_case_s']:.1f} s wall**, {s['median_case_cpu_s']:.1f} s CPU "
             f"(max {s['max_case_s']:.1f} s wall); bar ≤ 10 s. Duty changes at "
             f"{100 * s['duty_changes_per_sample']:.1f} % of the samples.", "",
             "| case | named first | pass | held-out θ NRMSE before → after | magnitude error | wall s "
             "| CPU s |",
             "|---|---|---|---|---|---|---|"]
    for c in doc["cases"]:
        mags = [v.get("relative_error") for v in (c.get("magnitude") or {}).values()]
        mag = ", ".join(f"{100 * x:.2f} %" for x in mags if x is not None) or "—"
        before, after = c.get("nrmse_before"), c.get("nrmse_after")
        nrmse = f"{before:.4g} → {after:.4g}" if before is not None else c.get("error", "")
        lines.append(f"| {c['case']} | {(c.get('chosen') or ['none'])[0]} | {c.get('pass')} | {nrmse} | "
                     f"{mag} | {c['elapsed_s']:.1f} | {c['cpu_s']:.1f} |")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2, help="workers of the local Dask cluster")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS", help="a running Dask cluster instead")
    ap.add_argument("--out", default=str(RESULTS / "gap_closed_loop"), help="output stem")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    from aeropend_ident.parallel import engine_label, run_cases

    specs = [{"effects": e, "seed": seed, "variant": seed % 2 == 1, "design": "closed_loop",
              "group": "single" if e else "no effect", "family": "dc_hbridge"} for e, seed in CASES]
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    done = {}
    for i, s in run_cases(run_case, specs, workers=args.workers, scheduler=args.scheduler,
                          desc="gap_closed_loop", quiet=args.quiet):
        done[i] = s
        print(f"[{len(done)}/{len(specs)}] {s['case']:32s} pass={s.get('pass')} chosen={s.get('chosen')} "
              f"({s['elapsed_s']:.1f} s wall, {s['cpu_s']:.1f} s CPU) {s.get('error', '')}", flush=True)
    cases = [done[i] for i in sorted(done)]
    wall = time.perf_counter() - t0
    times = [c["elapsed_s"] for c in cases]
    summary = {"cases": len(cases), "passed": sum(bool(c.get("pass")) for c in cases),
               "median_case_s": float(np.median(times)), "max_case_s": float(np.max(times)),
               "median_case_cpu_s": float(np.median([c["cpu_s"] for c in cases])),
               "duty_changes_per_sample": float(np.median([c.get("duty_changes_per_sample", 0.0)
                                                           for c in cases]))}
    meta = {"workers": args.workers, "engine": engine_label(args.workers, args.scheduler), "wall_s": wall,
            "load_before": [round(x, 2) for x in load_before],
            "load_after": [round(x, 2) for x in os.getloadavg()],
            "machine": f"{os.cpu_count()} cores, {platform.platform()}", "python": platform.python_version(),
            "commit": os.popen(f"git -C {Path(__file__).parent} rev-parse --short HEAD 2>/dev/null")
            .read().strip()}
    doc = {"summary": summary, "meta": meta, "cases": cases}
    out = Path(args.out)
    out.with_suffix(".json").write_text(json.dumps(doc, indent=1, default=float), encoding="utf-8")
    write_md(out.with_suffix(".md"), doc)
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
