"""``rig fit`` on one recording predicts another of the same rig (issue 60's bar), and how long it takes.

Per family (ESC, voltage amplifier, H-bridge), independent rigs drawn from physics
(:func:`bench.fixtures.family_lab.draw_rigs` on the hidden plants of ``bench/fixtures/truth_plant.py``:
no aeropend code), each logged twice with one unchanged rig, angle only, by two loggers:

* **100 Hz** (a microcontroller's period: the command held over each 10 ms, one row per period);
* **~600 Hz, uneven**: the plant stepped every 1 ms, a row written after 1, 2 or 3 ms
  (probabilities 0.4 / 0.4 / 0.2: 556 rows/s on average), as a PC logging over USB does.

Recording A is a **step log** (1 s at rest, four 6 s holds: 25 s); recording B an **APRBS** (30 s,
levels held 0.2-1.5 s). The angle carries the lab's sensor (12-bit encoder or 10-bit potentiometer
ADC: its lattice and noise, :data:`bench.fixtures.family_lab.SENSORS`).

For each rig and logger: ``rig new --actuator FAMILY --stated ...`` with what the lab states
(:func:`bench.fixtures.family_lab.stated`), then ``rig fit START A`` and ``rig fit START B`` (each
timed, wall clock, in this process). Each fitted rig is replayed on the other recording with the one
free run (:func:`aeropend_ident.greybox.replay.free_run`, the figure every command prints); the
oracle of a recording is ``rig fit``'s own figure on it. Ratio = cross figure / oracle.

Bar (issue 60): every ratio ≤ 1.5; ``rig fit`` median ≤ 20 s, slowest ≤ 60 s per fit on this machine.

Writes ``bench/results/rig_fit_cross.{json,md}``.

Usage: ``python -m bench.bench_rig_fit_cross [--rigs 3] [--families esc,voltage_amplifier,dc_hbridge]``
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.fixtures import family_lab as fl
from bench.fixtures import truth_plant as tp
from bench.fixtures.lab_logging import quantise
from bench.fixtures.provenance import run_meta
from bench.fixtures.rig_lab import CSV_HEADER, PRESET

RESULTS = Path(__file__).resolve().parent / "results"
#: The fast logger: the plant's step [s] and the row intervals (in steps) with their probabilities.
FAST_DT = 0.001
FAST_STEPS = (1, 2, 3)
FAST_P = (0.4, 0.4, 0.2)
#: Plant sub-steps per FAST_DT (RK4 step ≤ the plant's own: ESC 1.25 ms, amplifier 0.5 ms).
FAST_SUBSTEPS = {"esc": 1, "voltage_amplifier": 2}
#: Angles [rad] of the step log's holds, and its timing [s].
STEP_ANGLES = (0.3, 0.75, 0.45, 0.95)
REST_S, HOLD_S = 1.0, 6.0
APRBS_S = 30.0
#: The APRBS levels hold the rod between 0.15 rad and this [rad] at rest (higher, its swings pass the top)
APRBS_TOP = 0.8
RATIO_BAR = 1.5
MEDIAN_BAR_S, SLOWEST_BAR_S = 20.0, 60.0


def _commands(rig: fl.LabRig, dt: float, seed: int) -> dict[str, np.ndarray]:
    """The two command sequences (one value per ``dt``): ``steps`` and ``aprbs``."""
    p = rig.plant
    steps = np.concatenate([np.zeros(round(REST_S / dt))]
                           + [np.full(round(HOLD_S / dt), fl.command_for(p, a)) for a in STEP_ANGLES])
    lo, hi = fl.command_for(p, 0.15), fl.command_for(p, APRBS_TOP)
    aprbs = tp.aprbs(APRBS_S, seed=seed, lo=lo, hi=hi, min_hold=0.2, max_hold=1.5, rest=0.5, dt=dt)
    return {"steps": steps, "aprbs": np.asarray(aprbs, dtype=float)}


def _log(rig: fl.LabRig, command: np.ndarray, dt: float, seed: int, fast: bool
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, τ, θ measured) rows of a logger: every step (100 Hz) or after 1-3 fast steps (uneven)."""
    plant = rig.plant
    if isinstance(plant, tp.TruthPlant):  # the H-bridge plant: 20 RK4 steps per 10 ms, as family_lab
        st: Any = tp.TruthStepper(plant, dt=dt, substeps=max(1, round(20 * dt / fl.PERIOD)))
    else:
        if fast:  # the hidden plant stepped at the fast logger's 1 ms (a copy: the rig keeps its own)
            plant = type(plant).__new__(type(plant))
            plant.__dict__.update(rig.plant.__dict__)
            plant.dt, plant.substeps = FAST_DT, FAST_SUBSTEPS[rig.family]
        st = tp.RodStepper(plant, dt)
    rng = np.random.default_rng(seed)
    due = 0
    t, u, y = [], [], []
    for k, c in enumerate(command):
        if k == due:
            t.append(k * dt)
            u.append(float(c))
            reading = float(st.sample()["theta"]) if isinstance(st, tp.TruthStepper) else st.reading()
            y.append(float(quantise(reading + rig.sigma * rng.standard_normal(), rig.quantum)))
            due += int(rng.choice(FAST_STEPS, p=FAST_P)) if fast else 1
        st.step(float(c))
    return np.array(t), np.array(u), np.array(y)


def _write(path: Path, t: np.ndarray, u: np.ndarray, y: np.ndarray) -> str:
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header=CSV_HEADER, comments="", fmt="%.9g")
    return str(path)


def _quiet(fn, argv: list[str]) -> tuple[int, str]:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        rc = fn(argv)
    return rc, buf.getvalue()


def _figure(rig_path: Path, spec: str) -> dict[str, Any]:
    """The one free run of a rig file on a recording (as ``rig check`` and ``compare`` print it)."""
    from aeropend_ident.greybox.replay import free_run
    from aeropend_ident.greybox.rig_inputs import fit_grid, read_inputs
    from aeropend_sim.params import load_rig

    rig = load_rig(rig_path)
    _, (ser,) = read_inputs([spec], None, grid=fit_grid(rig))
    d = ser.replayed
    run = free_run(rig, d.t, d.duty, d.theta, source=d.source)
    return {"nrmse": run.nrmse, "divergence": run.divergence}


def run_rig(job: dict[str, Any]) -> dict[str, Any]:
    """One rig and one logger: two recordings, two fits, four figures."""
    from aeropend_ident.cli.rig import main as rig_main

    rig = fl.draw_rigs(job["family"], job["index"] + 1, seed=job["seed"])[job["index"]]
    fast = job["logger"] == "600Hz_uneven"
    dt = FAST_DT if fast else fl.PERIOD
    out: dict[str, Any] = {"rig": rig.name, "family": rig.family, "sensor": rig.sensor,
                           "logger": job["logger"], "truth": rig.truth}
    with tempfile.TemporaryDirectory(prefix="rigfit_cross_") as tmp:
        folder = Path(tmp)
        (folder / "lab_log.yaml").write_text(PRESET, encoding="utf-8")
        specs: dict[str, str] = {}
        for i, (name, cmd) in enumerate(_commands(rig, dt, job["seed"] + 7).items()):
            t, u, y = _log(rig, cmd, dt, job["seed"] + 11 + i, fast)
            specs[name] = f"{_write(folder / f'{name}.csv', t, u, y)}:{folder / 'lab_log.yaml'}"
            out.setdefault("rows", {})[name] = int(t.size)
        start = folder / "start.yaml"
        rc, text = _quiet(rig_main, ["new", "--actuator", rig.family, "--stated", *fl.stated(rig),
                                     "--name", rig.name, "-o", str(start)])
        if rc != 0:
            return {**out, "failed": f"rig new: {text.strip()[-400:]}"}
        fitted: dict[str, Path] = {}
        out["fit_s"], out["own"], out["cross"], out["ratio"] = {}, {}, {}, {}
        for name, spec in specs.items():
            fitted[name] = folder / f"fitted_{name}.yaml"
            t0 = time.perf_counter()
            rc, text = _quiet(rig_main, ["fit", str(start), spec, "-o", str(fitted[name]), "-q"])
            out["fit_s"][name] = time.perf_counter() - t0
            if rc != 0:
                return {**out, "failed": f"rig fit {name}: {text.strip()[-400:]}"}
        for name, spec in specs.items():
            other = next(k for k in specs if k != name)
            own = _figure(fitted[name], spec)
            cross = _figure(fitted[other], spec)
            out["own"][name], out["cross"][name] = own, cross
            out["ratio"][name] = (cross["nrmse"] / own["nrmse"]
                                  if cross["nrmse"] is not None and own["nrmse"] else math.inf)
    return out


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per family and logger: ratios (the bar) and fit times."""
    out: dict[str, Any] = {}
    times = [s for r in rows for s in r.get("fit_s", {}).values()]
    for key in sorted({(r["family"], r["logger"]) for r in rows}):
        sel = [r for r in rows if (r["family"], r["logger"]) == key]
        ratios = [x for r in sel for x in r.get("ratio", {}).values()]
        fits = [s for r in sel for s in r.get("fit_s", {}).values()]
        out[f"{key[0]} {key[1]}"] = {
            "rigs": len(sel), "failed": sum("failed" in r for r in sel),
            "ratios": len(ratios), "within_bar": sum(x <= RATIO_BAR for x in ratios),
            "ratio_median": float(np.median(ratios)) if ratios else math.nan,
            "ratio_max": max(ratios) if ratios else math.nan,
            "fit_median_s": float(np.median(fits)) if fits else math.nan,
            "fit_max_s": max(fits) if fits else math.nan}
    ratios = [x for r in rows for x in r.get("ratio", {}).values()]
    out["all"] = {"ratios": len(ratios), "within_bar": sum(x <= RATIO_BAR for x in ratios),
                  "fits": len(times), "fit_median_s": float(np.median(times)) if times else math.nan,
                  "fit_max_s": max(times) if times else math.nan,
                  "bar_met": bool(ratios) and all(x <= RATIO_BAR for x in ratios) and bool(times)
                  and float(np.median(times)) <= MEDIAN_BAR_S and max(times) <= SLOWEST_BAR_S}
    return out


def _f(x: Any, fmt: str = ".3g") -> str:
    return "—" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def write_md(path: Path, doc: dict[str, Any]) -> None:
    s, m = doc["summary"], doc["meta"]
    lines = [
        "# rig fit: one recording predicts another of the same rig (issue 60)", "",
        "Independent ESC, voltage-amplifier and H-bridge rigs drawn from physics "
        "(`bench/fixtures/family_lab.py`, hidden plants of `bench/fixtures/truth_plant.py`), each logged "
        "twice with one unchanged rig: a "
        f"25 s step log (A) and a {APRBS_S:g} s APRBS (B), angle only, by a 100 Hz logger and by an uneven "
        "~600 Hz one (rows after 1, 2 or 3 ms). `rig new` with the stated constants, `rig fit` on each "
        "recording alone; each fitted rig replayed on the other recording with the one free run. Ratio = "
        "that figure / `rig fit`'s own figure on the recording (the oracle). "
        f"Bar: every ratio ≤ {RATIO_BAR:g}; rig fit median ≤ {MEDIAN_BAR_S:g} s, slowest ≤ "
        f"{SLOWEST_BAR_S:g} s.", "",
        f"Commit `{m['commit']}`, {m['machine']}, one fit at a time, load before {m['load_before']}, "
        f"{m['wall_s']:.0f} s in all.", "",
        "| family, logger | rigs | ratios ≤ 1.5 | median ratio | largest | rig fit median / slowest [s] |",
        "|---|---|---|---|---|---|"]
    for k, v in s.items():
        if k == "all":
            continue
        lines.append(f"| {k} | {v['rigs']} ({v['failed']} failed) | {v['within_bar']}/{v['ratios']} | "
                     f"{_f(v['ratio_median'])} | {_f(v['ratio_max'])} | {_f(v['fit_median_s'], '.0f')} / "
                     f"{_f(v['fit_max_s'], '.0f')} |")
    a = s["all"]
    lines += ["", f"All: {a['within_bar']}/{a['ratios']} ratios within {RATIO_BAR:g}; rig fit median "
              f"{_f(a['fit_median_s'], '.1f')} s, slowest {_f(a['fit_max_s'], '.1f')} s over "
              f"{a['fits']} fits; bar met: {'yes' if a['bar_met'] else 'no'}.", "",
              "| rig | sensor | logger | rows A / B | own A / B | cross on A / on B | ratio A / B "
              "| fit A / B [s] |",
              "|---|---|---|---|---|---|---|---|"]
    for r in doc["rigs"]:
        if "failed" in r:
            lines.append(f"| {r['rig']} | {r['sensor']} | {r['logger']} | FAILED: {r['failed'][:160]} |||||")
            continue

        def fig(d: dict[str, Any]) -> str:
            return _f(d["nrmse"], ".4f") if d["nrmse"] is not None else "diverges"
        lines.append(
            f"| {r['rig']} | {r['sensor']} | {r['logger']} | {r['rows']['steps']} / {r['rows']['aprbs']} | "
            f"{fig(r['own']['steps'])} / {fig(r['own']['aprbs'])} | {fig(r['cross']['steps'])} / "
            f"{fig(r['cross']['aprbs'])} | {_f(r['ratio']['steps'], '.2f')} / "
            f"{_f(r['ratio']['aprbs'], '.2f')} | "
            f"{r['fit_s']['steps']:.0f} / {r['fit_s']['aprbs']:.0f} |")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rigs", type=int, default=3, help="rigs per family")
    ap.add_argument("--families", default=",".join(fl.FAMILIES))
    ap.add_argument("--loggers", default="100Hz,600Hz_uneven")
    ap.add_argument("--seed", type=int, default=60000, help="seed of the drawn rigs")
    ap.add_argument("--out", default=str(RESULTS / "rig_fit_cross"))
    ap.add_argument("--render", action="store_true", help="only re-write the .md from the .json")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.render:
        write_md(out.with_suffix(".md"), json.loads(out.with_suffix(".json").read_text(encoding="utf-8")))
        return 0
    jobs = [{"family": f, "index": i, "seed": args.seed, "logger": lg}
            for f in args.families.split(",") if f for i in range(args.rigs)
            for lg in args.loggers.split(",") if lg]
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    rows = []
    for k, job in enumerate(jobs):
        r = run_rig(job)
        rows.append(r)
        got = "failed: " + r["failed"][:160] if "failed" in r else \
            f"ratios {r['ratio']['steps']:.2f} / {r['ratio']['aprbs']:.2f}, fits " \
            f"{r['fit_s']['steps']:.0f} / {r['fit_s']['aprbs']:.0f} s"
        print(f"[{k + 1}/{len(jobs)}] {r['rig']} {r['logger']}: {got}", flush=True)
    meta = run_meta(t0, load_before, argv)
    doc = {"summary": summarise(rows), "meta": meta, "rigs": rows}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(doc, indent=1, default=float), encoding="utf-8")
    write_md(out.with_suffix(".md"), doc)
    print(json.dumps(doc["summary"]["all"], indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
