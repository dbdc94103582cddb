"""Sparse identification on real recordings, validated on held-out data (issue 4, item 10).

Runs :mod:`bench.fixtures.real_cases` on the AeroShield APRBS run, the four BA-Etchepareborda open-loop
runs and the YangZhu Quanser AERO pitch step (data read from ``../shared/data/real``,
never copied), and the grey-box baseline on AeroShield for comparison. Writes
``bench/results/ident_real.json`` and ``.md`` and plots ``docs/results/ident_<case>_{coef,deriv,
freerun}.png``. About 3-4 minutes on two cores.

Usage: ``python -m bench.bench_ident_real [--real DIR] [--quick]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.io.jsonutil import jsonable
from aeropend_ident.sindy.plots import plot_coefficients, plot_derivatives, plot_free_run
from bench.fixtures.real_cases import (
    ETCHEPAREBORDA_RUNS,
    CaseResult,
    aeroshield_case,
    default_real_dir,
    etchepareborda_case,
    yangzhu_case,
)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
PLOTS = ROOT / "docs" / "results"


def _log(msg: str) -> None:
    print(f"[bench_ident_real] {msg}", file=sys.stderr, flush=True)


def _plots(res: CaseResult) -> dict[str, str]:
    name = res.name
    out = {}
    out["coef"] = plot_coefficients(res.model, PLOTS / f"ident_{name}_coef.png",
                                    title=f"{name}: coefficients ({res.model.method})")
    out["deriv"] = plot_derivatives(res.model, res.heldout, PLOTS / f"ident_{name}_deriv.png",
                                    title=f"{name}: held-out derivatives, model vs estimate")
    t = np.concatenate([res.train.t, res.heldout.t])
    states = [s for s in ("theta", "omega_rotor") if s in res.heldout_run.states]
    meas = {s: np.concatenate([res.train.variables[s], res.heldout.variables[s]]) for s in states}
    sim = {s: np.concatenate([res.train_run.states[s], res.heldout_run.states[s]]) for s in states}
    extra = None
    if "author" in res.extra:
        extra = {"repository author's model": res.extra["author"]}
    out["freerun"] = plot_free_run(t, meas, sim, PLOTS / f"ident_{name}_freerun.png",
                                   t_split=float(res.heldout.t[0]), states=states, extra=extra,
                                   title=f"{name}: free run (training | held out from the dotted line)")
    return {k: str(Path(v).relative_to(ROOT)) for k, v in out.items()}


def _case_entry(res: CaseResult, seconds: float) -> dict[str, Any]:
    s = dict(res.summary)
    s["heldout_derivative_mse"] = res.model.test_mse(res.heldout)
    s["seconds"] = round(seconds, 1)
    s["plots"] = _plots(res)
    return s


def _baseline_aeroshield(real: Path) -> dict[str, Any]:
    from aeropend_ident.greybox.baseline import run_baseline
    from aeropend_ident.io.csv_import import import_csv
    from bench.fixtures.real_cases import AEROSHIELD

    rec = import_csv(real / AEROSHIELD, "aeroshield_ident")
    rep = run_baseline(rec, "aeroshield_rig")
    return {"summary": rep.get("summary"), "parameters": rep.get("parameters")}


def _thesis_sim_reference() -> dict[str, Any]:
    """60 s APRBS of thesis_sim at 490 Hz, 50 dB, as a contract bag through ``identify`` (weak,
    structured library); its coefficient heat-map is the counterpart of thesis Figs. 5.3/5.4."""
    import shutil
    import tempfile

    from aeropend_ident.io.bag_writer import write_bag
    from aeropend_ident.sindy.identify import identify
    from aeropend_sim.excitation import aprbs
    from aeropend_sim.params import load_rig
    from aeropend_sim.recording import Recording
    from aeropend_sim.simulation import simulate

    rig = load_rig("thesis_sim")
    noisy = rig.with_effects(sensor_noise=True).with_params("sensors", snr_db=50)
    tr = simulate(noisy, aprbs(60.0, lo=0.2, hi=0.9, min_hold=0.02, max_hold=0.3, seed=1).duty, seed=3)
    with tempfile.TemporaryDirectory() as tmp:
        bag = write_bag(Recording.from_trajectory(tr), Path(tmp) / "bag")
        summ = identify(bag, Path(tmp) / "out", rig, library="structured", progress=_log)
        for name in ("coefficients", "free_run"):
            shutil.copy(Path(tmp) / "out" / f"{name}.png", PLOTS / f"ident_thesis_sim_{name}.png")
    return {"equations": summ["equations"], "heldout": summ["heldout"], "derived_parameters":
            summ["derived_parameters"], "threshold": summ["threshold"], "wall_time_s": summ["wall_time_s"],
            "plots": ["docs/results/ident_thesis_sim_coefficients.png",
                      "docs/results/ident_thesis_sim_free_run.png"]}


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, (list, tuple)):
        return "–".join(_fmt(x) for x in v)
    if isinstance(v, str):
        return v
    return f"{v:.4g}"


def write_markdown(doc: dict[str, Any], path: Path) -> None:
    lines = ["# Sparse identification on real recordings (held-out validation)", "",
             "Generated by `bench/bench_ident_real.py`; see `docs/identification_real.md` for the protocol.",
             "NRMSE(range) = RMS(θ_sim − θ_meas)/(max − min θ_meas), the grey-box baseline's figure; "
             "NRMSE(std) divides by the standard deviation instead. Free runs start from the part's first "
             "measured state and use the measured inputs only.", "",
             "| case | train | held-out | method | selected map | train NRMSE(range) | held-out NRMSE(range) "
             "| held-out NRMSE(std) | held-out RMS [rad] |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, c in doc["cases"].items():
        sp = c["split"]
        sel = c.get("selection")
        smap = f"T = {sel['time_constant_s']:g} s, d = {sel['delay_samples']}" if sel else "ω₁² (tach)"
        method = c.get("model", {}).get("method", c.get("method", ""))
        lines.append(
            f"| {name} | {sp['train_samples']} | {sp['heldout_samples']} (from {sp['t_split_s']:.2f} s) | "
            f"{method} | {smap} | {_fmt(c['train']['nrmse_range'])} | "
            f"**{_fmt(c['heldout']['nrmse_range'])}** | "
            f"{_fmt(c['heldout']['nrmse_std'])} | {_fmt(c['heldout']['rms_rad'])} |")
    lines += ["", "## Equations", ""]
    for name, c in doc["cases"].items():
        lines.append(f"* **{name}**: " + "; ".join(f"`{e}`" for e in c["equations"]))
    lines += ["", "## Identified vs stated parameters", ""]
    for name, c in doc["cases"].items():
        lines += [f"### {name}", "",
                  "| parameter | unit | identified | stated | source of the stated value |",
                  "|---|---|---|---|---|"]
        for p in c["parameters"]:
            st = _fmt(p.get("stated"))
            if p.get("stated_manual") is not None:
                st += f" (manual {_fmt(p['stated_manual'])})"
            idv = "0 (term dropped)" if p["identified"] == 0 else _fmt(p["identified"])
            lines.append(f"| {p['name']} | {p['unit']} | {idv} | {st} | "
                         f"{p['stated_source']} |")
        if "cross_run" in c:
            lines += ["", "Replayed on the other runs (whole run, free run): " + ", ".join(
                f"{k}: NRMSE(range) {_fmt(v['nrmse_range'])}" for k, v in c["cross_run"].items())]
        if "author_model_heldout" in c:
            a = c["author_model_heldout"]
            lines += ["", f"The repository author's logged model on the same held-out part: NRMSE(range) "
                          f"{_fmt(a['nrmse_range'])}, RMS {_fmt(a['rms_rad'])} rad."]
        lines += ["", "Not supported by the data:", ""] + [f"* {n}" for n in c["notes"]] + [""]
    if "thesis_sim_reference" in doc:
        r = doc["thesis_sim_reference"]
        lines += ["## Reference: full-state thesis_sim bag (60 s APRBS, 50 dB) through `identify`", "",
                  *[f"* `{e}`" for e in r["equations"]], "",
                  f"λ = {r['threshold']}, held-out free-run NRMSE(range) of θ "
                  f"{_fmt(r['heldout'][0]['nrmse_range'])}, {r['wall_time_s']} s; heat-map "
                  "`docs/results/ident_thesis_sim_coefficients.png` (as thesis Figs. 5.3/5.4).", ""]
    if "baseline_aeroshield" in doc:
        b = doc["baseline_aeroshield"].get("summary") or {}
        lines += ["## Grey-box baseline on AeroShield (same 70/30 split)", "", "```",
                  json.dumps(jsonable(b), indent=1, ensure_ascii=False), "```", ""]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", type=Path, default=None)
    ap.add_argument("--quick", action="store_true", help="AeroShield and YangZhu only, no baseline")
    args = ap.parse_args(argv)
    real = args.real or default_real_dir()
    if not real.is_dir():
        _log(f"real data folder {real} missing; nothing to do")
        return 2
    doc: dict[str, Any] = {"machine": platform.platform(), "python": platform.python_version(),
                           "real_dir": str(real), "cases": {}}
    t_all = time.perf_counter()
    runs: list[tuple[str, Any]] = [("aeroshield", lambda: aeroshield_case(real, progress=_log)),
                                   ("yangzhu", lambda: yangzhu_case(real, progress=_log))]
    if not args.quick:
        runs += [(r, lambda r=r: etchepareborda_case(r, real, progress=_log)) for r in ETCHEPAREBORDA_RUNS]
    for label, fn in runs:
        _log(f"case {label}")
        t0 = time.perf_counter()
        res = fn()
        entry = _case_entry(res, time.perf_counter() - t0)
        doc["cases"][res.name] = entry
        _log(f"{res.name}: held-out NRMSE(range) {entry['heldout']['nrmse_range']:.4f} "
             f"({entry['seconds']} s)")
    if not args.quick:
        _log("grey-box baseline on AeroShield")
        doc["baseline_aeroshield"] = _baseline_aeroshield(real)
    if not args.quick:
        _log("reference: full-state thesis_sim bag through the identify command (coefficient heat-map)")
        doc["thesis_sim_reference"] = _thesis_sim_reference()
    doc["wall_time_s"] = round(time.perf_counter() - t_all, 1)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "ident_real.json").write_text(json.dumps(jsonable(doc), indent=1, ensure_ascii=False) + "\n",
                                             encoding="utf-8")
    write_markdown(jsonable(doc), RESULTS / "ident_real.md")
    _log(f"wrote {RESULTS / 'ident_real.json'} and .md in {doc['wall_time_s']} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
