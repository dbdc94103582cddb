"""Motor heating in the gap diagnosis (issue 64 item 3): named where the winding heats, not elsewhere.

What it measures: :func:`aeropend_ident.gap.run.run_gap` (as ``gap --held-out`` runs it:
``max_effects=2``, no oracle) on two-session cases of the independent benchmark's hidden plant
(:class:`bench.fixtures.truth_plant.TruthPlant`: its own equations and RK4, its winding heating
written there from the physics, R_a(T) = R_a·(1 + α·T), C·Ṫ = R_a(T)·i_a² − T/R_th with copper's α
and a fixed heat capacity :data:`~bench.fixtures.truth_plant.WINDING_HEAT_CAPACITY`), the lab's
rig file being the nominal plant without heating (:func:`bench_gap_independent.rig_dict`):

* heated: R_th drawn in 30-80 K/W (thermal time constants 15-40 s), on the thesis' nominal
  parameters or a variant drawn around them (:func:`bench_gap_independent.variant_params`);
* clean: the same plants without heating (the catalog's new hypothesis must not be named there).

Recordings: a fit session of ``--fit`` s (APRBS, duty 0.25-0.95) and a held-out session of
``--held`` s (Latin-hypercube steps), every channel (θ, i_a, v_a, ω₁) at 488 Hz with the sensor
noise at 40-60 dB SNR (:func:`truth_plant.record`), the same seeds per case whatever the code.

Scored from the report: heated: ``motor_heating`` chosen (or a chosen effect's ``ambiguous_with``
holds it), its fitted R_th against the truth; clean: no significant gap, or nothing chosen.
Writes ``bench/results/gap_heating.{json,md}``.

Usage: ``python -m bench.bench_gap_heating [--cases N] [--fit S] [--held S]``
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.bench_gap_independent import rig_dict, to_recording, variant_params
from bench.fixtures.truth_plant import PlantParams, TruthPlant, aprbs, lhs_steps, record

RESULTS = Path(__file__).resolve().parent / "results"
R_TH_RANGE = (30.0, 80.0)  # K/W: a small brushed motor's winding to ambient
SNR_RANGE = (40.0, 60.0)
CHANNELS = ("theta", "i_a", "v_a", "omega_rotor")


def case(seed: int, heated: bool, fit_s: float, held_s: float) -> dict[str, Any]:
    """Hidden plant, recordings and rig file of one case (seeded; the truth stays in the dict)."""
    rng = np.random.default_rng(seed)
    params = variant_params(rng) if seed % 2 else PlantParams()
    r_th = float(rng.uniform(*R_TH_RANGE))
    plant = TruthPlant(params, {"motor_heating": r_th} if heated else {})
    snr = float(rng.uniform(*SNR_RANGE))
    fit_d = aprbs(fit_s, seed=seed + 1)
    held_d = lhs_steps(held_s, seed=seed + 2)
    return {"seed": seed, "heated": heated, "R_th": r_th if heated else None, "snr_db": snr,
            "variant": bool(seed % 2), "rig": rig_dict(params, f"heating_nominal_{seed}"),
            "fit": record(plant, fit_d, snr, seed + 3, CHANNELS),
            "held": record(plant, held_d, snr, seed + 4, CHANNELS)}


def run(c: dict[str, Any]) -> dict[str, Any]:
    """Diagnose one case and score it (module doc)."""
    from aeropend_ident.gap.run import run_gap
    from aeropend_sim.params import rig_from_dict

    rig = rig_from_dict(c["rig"], where=f"case {c['seed']}")
    t0 = time.perf_counter()
    res = run_gap(rig, [to_recording(c["fit"], f"heat-{c['seed']}-fit")],
                  [to_recording(c["held"], f"heat-{c['seed']}-held")], rig_ref=rig.name,
                  split_rule="separate held-out recording", seed=0, max_effects=2)
    d = res.diagnosis
    ranking = d.as_dict()["ranking"]
    chosen = list(d.chosen) if d.significant else []
    amb = {a for r in ranking if r["effect"] in chosen for a in r.get("ambiguous_with", [])}
    row = next((r for r in ranking if r["effect"] == "motor_heating"), {})
    est = (row.get("rig_values") or {}).get("motor.R_th")
    out = {"seed": c["seed"], "heated": c["heated"], "variant": c["variant"], "snr_db": c["snr_db"],
           "R_th_true": c["R_th"], "R_th_fitted": est, "significant": bool(d.significant), "chosen": chosen,
           "ranked": [r["effect"] for r in ranking[:4]], "elapsed_s": time.perf_counter() - t0,
           "nrmse_before": float(res.test[0]["nrmse"]), "nrmse_after": float(res.test[-1]["nrmse"])}
    if c["heated"]:
        out["named"] = "motor_heating" in chosen or "motor_heating" in amb
        out["first"] = bool(chosen) and chosen[0] == "motor_heating"
        out["R_th_relative_error"] = abs(est - c["R_th"]) / c["R_th"] if est is not None else None
        out["pass"] = out["named"]
    else:
        out["heating_named"] = "motor_heating" in chosen
        out["pass"] = not chosen
    return out


def _num(v: float | None) -> str:
    return "—" if v is None or not math.isfinite(v) else f"{v:.1f}"


def _pct(v: float | None) -> str:
    return "—" if v is None else f"{100 * v:.0f} %"


def write(rows: list[dict[str, Any]], args: argparse.Namespace, wall: float) -> None:
    heated = [r for r in rows if r["heated"]]
    clean = [r for r in rows if not r["heated"]]
    errs = [r["R_th_relative_error"] for r in heated
            if r.get("named") and r["R_th_relative_error"] is not None]
    doc = {"cases": len(rows), "fit_s": args.fit, "held_s": args.held, "wall_s": wall,
           "heated_named": sum(r["named"] for r in heated), "heated": len(heated),
           "heated_first": sum(r["first"] for r in heated),
           "clean_pass": sum(r["pass"] for r in clean), "clean": len(clean),
           "clean_heating_named": sum(r["heating_named"] for r in clean),
           "median_R_th_relative_error": float(np.median(errs)) if errs else None,
           "machine": platform.platform(), "rows": rows}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "gap_heating.json").write_text(json.dumps(doc, indent=1, default=str), encoding="utf-8")
    lines = ["# gap: motor heating (bench/bench_gap_heating.py)", "",
             f"{len(rows)} cases ({len(heated)} heated, {len(clean)} clean), fit {args.fit:g} s + held out "
             f"{args.held:g} s, every channel at 488 Hz, SNR 40-60 dB; {wall:.0f} s wall on "
             f"{platform.platform()}.", "",
             "| measure | value |", "|---|---|",
             f"| heated: motor_heating named | {doc['heated_named']} / {len(heated)} |",
             f"| heated: motor_heating first | {doc['heated_first']} / {len(heated)} |",
             "| heated and named: median relative error of R_th | "
             f"{_pct(doc['median_R_th_relative_error'])} |",
             f"| clean: nothing named | {doc['clean_pass']} / {len(clean)} |",
             f"| clean: motor_heating named | {doc['clean_heating_named']} / {len(clean)} |", "",
             "| seed | heated | R_th true | R_th fitted | chosen | ranked | NRMSE before → after | s |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['seed']} | {'yes' if r['heated'] else 'no'} | {_num(r['R_th_true'])} | "
                     f"{_num(r['R_th_fitted'])} | {', '.join(r['chosen']) or '—'} | "
                     f"{', '.join(r['ranked'])} | "
                     f"{r['nrmse_before']:.4f} → {r['nrmse_after']:.4f} | {r['elapsed_s']:.1f} |")
    (RESULTS / "gap_heating.md").write_text("\n".join(lines) + "\n", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=8, help="heated cases (as many clean ones)")
    ap.add_argument("--fit", type=float, default=60.0, help="fit session length [s]")
    ap.add_argument("--held", type=float, default=40.0, help="held-out session length [s]")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    rows = []
    for k in range(args.cases):
        for heated in (True, False):
            r = run(case(47_000 + k, heated, args.fit, args.held))
            rows.append(r)
            print(f"{r['seed']} heated={heated} pass={r['pass']} chosen={r['chosen']} R_th={r['R_th_true']} "
                  f"-> {r['R_th_fitted']} ({r['elapsed_s']:.1f} s)", flush=True)
    write(rows, args, time.perf_counter() - t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
