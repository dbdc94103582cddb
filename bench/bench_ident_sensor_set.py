"""Chapter-5 identification on the rig's real sensor set, three protocols side by side (issue 18).

Truth: the independent plant ``bench/fixtures/truth_plant.py`` (no aeropend code; thesis equations, own
RK4, ideal drive v_a = 2.32 V·τ), driven by the project's identifiability excitation
``density_prbs`` (120 s, seed 5: ``excitation --signal density_prbs --duration 120 --seed 5``),
white noise σ = RMS/10^(SNR/20) on every recorded channel, written as a lab's CSV log and read
back through ``csv_import`` into ``identify`` (the command's own Python entry point) with the
matching rig file (``thesis_sim`` with the ideal 2.32 V drive):

* (a) the thesis' protocol: θ, **θ̇**, i_a, v_a, ω₁ recorded (θ̇ with noise at the same SNR);
  ``--method weak-iv --library physics --output-error`` (the estimator of the README's chapter-5
  table, θ̈ in the first-order weak form on the measured θ̇);
* (b) the rig's sensor set: θ, i_a, v_a, ω₁ (no θ̇); ``--method weak-iv --output-error`` with the
  default physics-structured library (θ̈ in the second-order weak form from θ alone), and, with
  ``--today``, the estimator of (a) on the same record (θ̇ estimated by Savitzky-Golay);
* (c) angle and duty only: θ and τ (partial-state path, first-order thrust map), held-out
  free-run NRMSE of θ only.

Per run: the equations, false positives / negatives per equation, the largest relative
coefficient error per equation, K_q error, R_a/L_a, held-out free-run NRMSE(range) of θ, λ and
wall time; for every spurious term the held-out free-run NRMSE of θ with the term removed
(coefficient set to zero). Writes ``bench/results/ident_sensor_set.{json,md}``.

Usage::

    .venv/bin/python -m bench.bench_ident_sensor_set --snr 50 30 20 --seeds 1 2 3 4 5 --protocols a b c
    .venv/bin/python -m bench.bench_ident_sensor_set --md-only       # table from the stored JSON
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from aeropend_ident.io import csv_import
from aeropend_ident.io.csv_import import CsvSpec
from aeropend_ident.sindy.identify import identify
from aeropend_sim.excitation import density_modulated_prbs
from aeropend_sim.params import load_rig
from bench.fixtures import truth_plant as tp
from bench.fixtures.truth_rig import lab_rig_doc, write_rig

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent

RESULTS = BENCH / "results"
DURATION = 120.0
EXCITATION_SEED = 5
#: CSV columns of the recorded channels.
COLUMNS = {"theta_dot": "theta_dot_rad_s", "i_a": "i_a_A", "v_a": "v_a_V", "omega_rotor": "omega_rad_s"}
#: Recorded channels per protocol (θ always).
PROTOCOL_CHANNELS = {"a": ("theta", "theta_dot", "i_a", "v_a", "omega_rotor"),
                     "b": ("theta", "i_a", "v_a", "omega_rotor"),
                     "b_today": ("theta", "i_a", "v_a", "omega_rotor"),
                     "b_pendulum": ("theta", "i_a", "v_a", "omega_rotor"), "c": ("theta",)}
PROTOCOL_DOC = {
    "a": "thesis: θ, θ̇, i_a, v_a, ω₁; weak-iv / physics + OE (θ̈ first-order weak form on measured θ̇)",
    "b": "rig sensor set: θ, i_a, v_a, ω₁; weak-iv / physics-structured + OE (θ̈ second-order weak form)",
    "b_today": "rig sensor set, today's estimator: weak-iv / physics + OE on a Savitzky-Golay θ̇",
    "b_pendulum": "rig sensor set, θ̈ only: the same CSV read by csv_import, second_order.fit_pendulum on "
                  "the training part, held-out free run of θ driven by the measured ω₁ (minutes instead "
                  "of the full identify run on a loaded machine)",
    "c": "angle and duty only: θ, τ; partial-state path (first-order thrust map)",
}


def truth_terms() -> dict[str, dict[str, float]]:
    """The true equations from the truth plant's physical parameters (names as aeropend's libraries)."""
    p = tp.PlantParams()
    return {
        "theta_dot": {"θ̇": -p.c_over_J, "sin(θ)": -p.mgd_over_J, "ω₁²": p.L_over_J * p.K_q * tp.GEAR**2},
        "i_a": {"i_a": -p.R_a / p.L_a, "ω₁": -p.K_omega / p.L_a, "v_a": 1.0 / p.L_a},
        "omega_rotor": {"i_a": p.K_t / p.J_m, "ω₁": -p.B_m / p.J_m},
    }


def rig_file(folder: Path) -> Path:
    """thesis_sim with the ideal 2.32 V drive (the truth plant's drive) as a lab writes it."""
    return write_rig(lab_rig_doc(), folder / "rig.yaml")


def write_log(path: Path, true: dict[str, np.ndarray], channels: tuple[str, ...], snr: float,
              seed: int) -> None:
    """CSV log of the measured channels (noise σ = RMS/10^(SNR/20) per channel, truth_plant.add_noise)."""
    meas = tp.add_noise(true, snr, seed, channels)
    cols = ["time_s", "duty", "theta_rad"] + [COLUMNS[c] for c in channels if c != "theta"]
    rest = [meas[c] for c in channels if c != "theta"]
    data = np.column_stack([true["t"], true["duty"], meas["theta"], *rest])
    np.savetxt(path, data, delimiter=",", header=",".join(cols), comments="", fmt="%.9g")


def register_preset(name: str, channels: tuple[str, ...]) -> str:
    csv_import.PRESETS[name] = CsvSpec(
        angle_col="theta_rad", angle_unit="rad", time_col="time_s", time_unit="s", input_col="duty",
        input_kind="duty", channels={c: (COLUMNS[c], 1.0) for c in channels if c != "theta"})
    return name


def _score(model_yaml: dict[str, Any], truth: dict[str, dict[str, float]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for tg, terms in truth.items():
        if tg not in model_yaml["equations"]:
            continue
        found = {n: e["coefficient"] for n, e in model_yaml["equations"][tg]["terms"].items()}
        rel = {n: (found.get(n, 0.0) - c) / abs(c) for n, c in terms.items()}
        out[tg] = {"false_positive": sorted(set(found) - set(terms)),
                   "false_negative": sorted(set(terms) - set(found)),
                   "max_rel_error": max(abs(v) for v in rel.values()),
                   "rel_error": rel, "coefficients": found}
    return out


def _removal_effects(out: Path, model_yaml: dict[str, Any], spurious: dict[str, list[str]],
                     base_nrmse: float) -> list[dict[str, Any]]:
    """Held-out free-run NRMSE(range) of θ with each spurious term's coefficient set to zero."""
    from aeropend_ident.io.recording_input import load_recording
    from aeropend_ident.sindy.identify import data_from_recording
    from aeropend_ident.sindy.libraries import CandidateLibrary, physics_library, physics_structured_library
    from aeropend_ident.sindy.model import SindyModel, free_run
    from aeropend_ident.sindy.partial import nrmse_range

    names = model_yaml["library"]
    pool = physics_library(extras=("omega_abs", "sign_theta_dot"))
    for lib in physics_structured_library().values():
        pool = pool + lib
    lib = CandidateLibrary(tuple(next(c for c in pool.candidates if c.name == n) for n in names))
    targets = list(model_yaml["equations"])
    coef = np.zeros((len(targets), len(names)))
    for i, tg in enumerate(targets):
        for n, e in model_yaml["equations"][tg]["terms"].items():
            coef[i, names.index(n)] = e["coefficient"]
    prov = model_yaml["provenance"]
    rec = load_recording(Path(prov["inputs"][0]), prov.get("preset"), "")
    data = data_from_recording(rec, load_rig(prov["rig_file"]))
    held = data.split(prov["train_fraction"])[1]
    effects = []
    for tg, terms in spurious.items():
        for n in terms:
            c = coef.copy()
            c[targets.index(tg), names.index(n)] = 0.0
            m = SindyModel(method="check", targets=targets, feature_names=names, coef=c, threshold=0.0,
                           library=lib)
            fr = free_run(m, held, substeps=1)
            nr = nrmse_range(held.variables["theta"], fr.states["theta"])
            effects.append({"equation": tg, "term": n, "nrmse_without": nr,
                            "relative_change": (nr - base_nrmse) / base_nrmse})
    return effects


def run_pendulum(log: Path, preset: str, rig_path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """θ̈ alone on a recorded CSV: (model-file-like dict, summary-like dict)."""
    from aeropend_ident.io.recording_input import load_recording
    from aeropend_ident.sindy.identify import data_from_recording
    from aeropend_ident.sindy.model import free_run, model_to_dict
    from aeropend_ident.sindy.partial import nrmse_range
    from aeropend_ident.sindy.second_order import fit_pendulum

    rec = load_recording(log, preset, "")
    data = data_from_recording(rec, load_rig(str(rig_path)))
    train, held = data.split(0.75)
    fit = fit_pendulum(train)
    fr = free_run(fit.model, held, substeps=1)
    summary = {"equations": fit.model.equations(), "threshold": fit.threshold,
               "heldout": [{"nrmse_range": nrmse_range(held.variables["theta"], fr.states["theta"])}],
               "pendulum": {"threshold": fit.threshold, "pruning": fit.pruning}}
    doc = model_to_dict(fit.model)
    doc["provenance"] = {}
    return doc, summary


def run_one(protocol: str, snr: float, seed: int, true: dict[str, np.ndarray], work: Path) -> dict[str, Any]:
    channels = PROTOCOL_CHANNELS[protocol]
    folder = work / f"{protocol}_{snr:g}_{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    log = folder / "log.csv"
    write_log(log, true, channels, snr, seed)
    preset = register_preset(f"_bench_sensor_set_{protocol}", channels)
    rig_path = rig_file(folder)
    rig = load_rig(str(rig_path))
    kw: dict[str, Any] = {"plots": False, "preset": preset}
    if protocol in ("a", "b_today"):
        kw.update(method="weak-iv", library="physics", output_error=True)
    elif protocol == "b":
        kw.update(method="weak-iv", library="physics-structured", output_error=True)
    t0 = time.perf_counter()
    if protocol == "b_pendulum":
        model_doc, summary = run_pendulum(log, preset, rig_path)
    else:
        summary = identify([log], folder / "res", rig, **kw)
    wall = time.perf_counter() - t0
    row: dict[str, Any] = {"protocol": protocol, "snr_db": snr, "noise_seed": seed, "wall_time_s": wall,
                           "equations": summary["equations"], "threshold": summary["threshold"],
                           "heldout_nrmse_range": summary["heldout"][0]["nrmse_range"]}
    if protocol == "c":
        row["thrust_map"] = {k: summary["thrust_map"][k] for k in ("time_constant_s", "delay_samples")}
        return row
    if protocol == "b_pendulum":
        model_yaml = model_doc
    else:
        model_yaml = yaml.safe_load((folder / "res" / "model.yaml").read_text(encoding="utf-8"))
        model_yaml["provenance"].update(preset=preset, rig_file=str(rig_path))
    truth = truth_terms()
    sc = _score(model_yaml, truth)
    row["scores"] = sc
    row["K_q_error"] = sc["theta_dot"]["rel_error"]["ω₁²"]
    row["R_a_over_L_a"] = -sc["i_a"]["coefficients"].get("i_a", 0.0) if "i_a" in sc else float("nan")
    if "pendulum" in summary:
        row["pendulum_threshold"] = summary["pendulum"]["threshold"]
        row["pendulum_pruned"] = [p["removed"] for p in summary["pendulum"]["pruning"] if p["removed"]]
    spurious = {tg: s["false_positive"] for tg, s in sc.items() if s["false_positive"]}
    if spurious and protocol != "b_pendulum":
        row["spurious_removal"] = _removal_effects(folder / "res", model_yaml, spurious,
                                                   row["heldout_nrmse_range"])
    return row


def load_average() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _span(values: list[float], fmt: str) -> str:
    if not values:
        return "—"
    lo, hi = min(values), max(values)
    return format(lo, fmt) if lo == hi else f"{format(lo, fmt)} … {format(hi, fmt)}"


def summary_table(rows: list[dict[str, Any]]) -> str:
    """Per protocol and SNR: exact structures / seeds, K_q error, max coefficient errors, NRMSE, wall time."""
    lines = ["| protocol | SNR | seeds | θ̈ exact | K_q error | di_a/dt exact, max err | "
             "dω₁/dt exact, max err | "
             "held-out NRMSE θ | wall [s] (load) |", "|---|---|---|---|---|---|---|---|---|"]
    order = {"a": 0, "b": 1, "b_pendulum": 2, "b_today": 3, "c": 4}
    groups: dict[tuple[str, float], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["protocol"], r["snr_db"]), []).append(r)
    for (p, snr), rs in sorted(groups.items(), key=lambda kv: (-kv[0][1], order[kv[0][0]])):
        seeds = ",".join(str(r["noise_seed"]) for r in sorted(rs, key=lambda r: r["noise_seed"]))
        wall = _span([r["wall_time_s"] for r in rs], ".0f")
        loads = _span([float(r["load"].split()[0]) for r in rs if r.get("load")], ".1f")
        nr = _span([r["heldout_nrmse_range"] for r in rs], ".4f")

        def eq(tg: str, rs: list[dict[str, Any]] = rs) -> str:
            sc = [r["scores"][tg] for r in rs if tg in r.get("scores", {})]
            if not sc:
                return "—"
            exact = sum(1 for s in sc if not s["false_positive"] and not s["false_negative"])
            return f"{exact}/{len(sc)}, {_span([100 * s['max_rel_error'] for s in sc], '.2f')} %"

        kq = _span([100 * r["K_q_error"] for r in rs if "K_q_error" in r], "+.2f")
        th = eq("theta_dot").split(",")[0] if p != "c" else "—"
        kq = kq + " %" if kq != "—" else kq
        lines.append(f"| ({p}) | {snr:g} dB | {seeds} | {th} | {kq} | {eq('i_a')} | "
                     f"{eq('omega_rotor')} | {nr} | {wall} ({loads}) |")
    return "\n".join(lines)


def markdown(rows: list[dict[str, Any]], meta: dict[str, Any]) -> str:
    lines = ["# Identification with the rig's sensor set (issue 18)", "",
             f"Truth: independent plant `bench/fixtures/truth_plant.py`, `density_prbs` {DURATION:g} s (seed "
             f"{EXCITATION_SEED}), 75 % fitted, 25 % held out; CSV -> `csv_import` -> `identify` with "
             "thesis_sim (ideal 2.32 V drive). Max relative coefficient error per equation; "
             "FP = spurious terms, FN = missed terms. Command: `bench/bench_ident_sensor_set.py` "
             "(see its docstring).", "",
             f"Machine: {meta.get('machine', '')}", "", "Protocols:", ""]
    lines += [f"* ({p}) {d}" for p, d in PROTOCOL_DOC.items()]
    lines += ["", "Summary (ranges over the noise seeds; exact = no spurious and no missed term):", "",
              summary_table(rows), "", "Per seed:", "",
              "| protocol | SNR | seed | θ̈ FP/FN, max err | K_q err | di_a/dt FP/FN, max err | R_a/L_a | "
              "dω₁/dt FP/FN, max err | held-out NRMSE θ | λ (θ̈ / el.) | wall [s] | load |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def eq(r: dict[str, Any], tg: str) -> str:
        s = r["scores"].get(tg)
        if s is None:
            return "—"
        fp = ", ".join(s["false_positive"]) or "0"
        fn = ", ".join(s["false_negative"]) or "0"
        return f"{fp}/{fn}, {100 * s['max_rel_error']:.2f} %"

    order = {"a": 0, "b": 1, "b_pendulum": 2, "b_today": 3, "c": 4}
    for r in sorted(rows, key=lambda r: (-r["snr_db"], order[r["protocol"]], r["noise_seed"])):
        if r["protocol"] == "c":
            lines.append(f"| (c) | {r['snr_db']:g} dB | {r['noise_seed']} | — | — | — | — | — | "
                         f"{r['heldout_nrmse_range']:.4f} | {r['threshold']:g} | {r['wall_time_s']:.1f} | "
                         f"{r.get('load', '')} |")
            continue
        lam = f"{r.get('pendulum_threshold', r['threshold']):g} / {r['threshold']:g}"
        lines.append(f"| ({r['protocol']}) | {r['snr_db']:g} dB | {r['noise_seed']} | {eq(r, 'theta_dot')} | "
                     f"{100 * r['K_q_error']:+.2f} % | {eq(r, 'i_a')} | {r['R_a_over_L_a']:.3f} | "
                     f"{eq(r, 'omega_rotor')} | {r['heldout_nrmse_range']:.4f} | {lam} | "
                     f"{r['wall_time_s']:.1f} | {r.get('load', '')} |")
    spur = [(r, e) for r in rows for e in r.get("spurious_removal", [])]
    if spur:
        lines += ["", "Spurious terms and the held-out free-run NRMSE of θ without them "
                  "(coefficient zeroed):",
                  "", "| protocol | SNR | seed | equation | term | NRMSE with | without | change |",
                  "|---|---|---|---|---|---|---|---|"]
        for r, e in spur:
            lines.append(f"| ({r['protocol']}) | {r['snr_db']:g} dB | {r['noise_seed']} | {e['equation']} | "
                         f"{e['term']} | {r['heldout_nrmse_range']:.4f} | {e['nrmse_without']:.4f} | "
                         f"{100 * e['relative_change']:+.2f} % |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--snr", type=float, nargs="+", default=[50.0, 30.0, 20.0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--protocols", nargs="+", default=["a", "b", "c"], choices=sorted(PROTOCOL_CHANNELS))
    ap.add_argument("--out", type=Path, default=RESULTS / "ident_sensor_set.json")
    ap.add_argument("--md-only", action="store_true", help="rewrite the table from the stored JSON")
    args = ap.parse_args(argv)
    md = args.out.with_suffix(".md")
    stored: dict[str, Any] = {"rows": [], "meta": {}}
    if args.out.exists():
        stored = json.loads(args.out.read_text(encoding="utf-8"))
    if args.md_only:
        md.write_text(markdown(stored["rows"], stored["meta"]), encoding="utf-8")
        return 0
    duty = density_modulated_prbs(DURATION, seed=EXCITATION_SEED).duty
    true = tp.TruthPlant().simulate(duty)
    rev = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                         text=True).stdout.strip()
    stored["meta"] = {"machine": f"{os.cpu_count()} cores, commit {rev}", "duration_s": DURATION,
                      "excitation": f"density_prbs seed {EXCITATION_SEED}"}
    with tempfile.TemporaryDirectory() as tmp:
        for snr in args.snr:
            for seed in args.seeds:
                for protocol in args.protocols:
                    load = load_average()
                    row = run_one(protocol, snr, seed, true, Path(tmp))
                    row["load"] = load
                    key = (protocol, snr, seed)
                    stored["rows"] = [r for r in stored["rows"]
                                      if (r["protocol"], r["snr_db"], r["noise_seed"]) != key] + [row]
                    text = json.dumps(stored, indent=1, ensure_ascii=False, default=float) + "\n"
                    args.out.write_text(text, encoding="utf-8")
                    md.write_text(markdown(stored["rows"], stored["meta"]), encoding="utf-8")
                    k = "" if protocol == "c" else f" K_q {100 * row['K_q_error']:+.2f} %"
                    print(f"({protocol}) {snr:g} dB seed {seed}: {row['equations']}{k} held-out "
                          f"{row['heldout_nrmse_range']:.4f} ({row['wall_time_s']:.1f} s, load {load})",
                          flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
