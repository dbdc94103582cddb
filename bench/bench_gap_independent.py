"""Independent blind benchmark of the gap diagnosis (issue 14) on a plant aeropend did not write.

The hidden plants come from :mod:`truth_plant` (``bench/fixtures/truth_plant.py``), which shares no code
with ``aeropend_sim`` or the gap catalog: the thesis' simulated equations written out by hand,
effects implemented from their physics, integrated by its own fixed-step Runge-Kutta scheme. The
diagnosis gets what a lab has: a rig file of its nominal simulator (the thesis' simulated plant
with an ideal drive, or a variant with other physical parameters, written as a rig file) and
the recordings (fit and held-out, θ, i_a, v_a, ω₁ with 40-60 dB noise at 490 Hz). It runs the
whole ``gap`` pipeline (:func:`aeropend_ident.gap.run.run_gap`: where, which, held-out
before/after) exactly as the command does with ``--held-out``.

Cases (seeds fixed here):

* every in-catalog effect alone, magnitudes drawn in physical units over lab-plausible ranges
  (:data:`RANGES`), both excitation designs (fit on Latin-hypercube steps / held out on APRBS, and
  the reverse), two draws each;
* two-effect cases (effects of different subsystems);
* effects outside aeropend's catalog (angle-dependent thrust loss, drifting sensor offset,
  quadratic rod drag): must be reported as unexplained (no effect with status "named" and
  presence >= 0.5);
* effect-free plants: must give "no significant gap".

Scoring happens after the diagnosis, from its report only: names (first chosen effect; a
confusable set counts only when the report names it for that effect), held-out θ NRMSE before and
after, and the fitted physical magnitude against the truth (error relative to the effect size
|true − nominal|).

Actuator families (``--family``, issue 35): ``dc_hbridge`` is the thesis plant above; ``esc`` and
``voltage_amplifier`` take their hidden plants from :mod:`truth_plant` too (an ESC-driven brushless
rig at 100 Hz recording θ and the ESC's rotor speed; a Quanser-Aero-style amplifier rig at 500 Hz
recording θ, i_a and ω₁), with the lab's rig file of that family (:mod:`gap_families`). Which
truth effects a family's cases contain is the registry's business: a truth effect that is not a
hypothesis of the family's catalog (``aeropend_ident.gap.effects.catalog``) and not one of the
out-of-catalog effects is refused, never dropped by a list here.

Writes ``bench/results/gap_independent.json`` and ``.md`` (``gap_independent_<family>`` for the
other families).

Usage: ``python -m bench.bench_gap_independent [--family esc] [--workers 2] [--quick] [--only EFFECT ...]
[--skip-effect NAME ...]``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bench.fixtures.gap_families import AMPLIFIER, ESC, FamilyCases
from bench.fixtures.truth_plant import (
    CHANNELS,
    DT,
    GEAR,
    OUT_OF_CATALOG,
    PlantParams,
    TruthPlant,
    aprbs,
    lhs_steps,
    record,
)

RESULTS = Path(__file__).resolve().parent / "results"
#: Shipped rig file whose format and provenance fields the per-case rig files start from.
BASE_RIG = Path(__file__).resolve().parents[1] / "src/aeropend_sim/aeropend_sim/rigs/thesis_sim.yaml"
FIT_DURATION = 40.0
HELD_DURATION = 30.0
SNR_RANGE = (40.0, 60.0)

#: Truth magnitudes: effect -> intervals (one drawn, then uniform inside). Scale effects: the factor.
RANGES: dict[str, list[tuple[float, float]]] = {
    "hbridge_drop": [(0.15, 0.45)],                       # V
    "dead_zone": [(0.04, 0.15)],                          # duty fraction
    "actuator_lag": [(0.03, 0.15)],                       # s
    "input_delay": [(0.012, 0.06)],                       # s (whole samples)
    "back_emf": [(0.6, 0.85), (1.2, 1.6)],
    "armature_resistance": [(0.7, 0.85), (1.2, 1.5)],
    "armature_inductance": [(0.3, 0.6), (1.7, 3.0)],
    "torque_constant": [(0.75, 0.9), (1.12, 1.3)],
    "rotor_friction": [(0.6, 0.85), (1.2, 1.6)],
    "motor_time_constant": [(0.4, 0.7), (1.5, 3.0)],
    "propeller_drag": [(1.0, 5.0)],                       # K_d/J_m [1/rad]; K_d = this × J_m
    "thrust_coefficient": [(0.75, 0.9), (1.1, 1.25)],
    "thrust_law": [(1.75, 1.9), (2.1, 2.25)],             # exponent on ω₁
    "gravity": [(0.75, 0.9), (1.12, 1.25)],
    "inertia": [(0.75, 0.88), (1.15, 1.35)],
    "viscous_friction": [(0.5, 0.75), (1.35, 2.0)],
    "coulomb_friction": [(0.6, 3.0)],                     # rad/s²
    "end_stops": [(0.65, 0.85)],                          # fraction of the largest nominal angle
    "sensor_offset": [(-0.1, -0.02), (0.02, 0.1)],        # rad
    "sensor_scale": [(0.85, 0.94), (1.06, 1.15)],
    # outside the catalog
    "angle_thrust_loss": [(0.2, 0.4)],
    "offset_drift": [(-3e-3, -1e-3), (1e-3, 3e-3)],       # rad/s
    "rod_air_drag": [(0.8, 2.5)],                         # 1/rad
}
PAIRS = [
    ("dead_zone", "viscous_friction"), ("input_delay", "gravity"), ("actuator_lag", "coulomb_friction"),
    ("hbridge_drop", "sensor_offset"), ("thrust_coefficient", "viscous_friction"),
    ("propeller_drag", "coulomb_friction"), ("back_emf", "gravity"), ("armature_resistance", "sensor_scale"),
    ("motor_time_constant", "gravity"), ("rotor_friction", "inertia"),
]


# ------------------------------------------------------------------------------ plants and rig files
def variant_params(rng: np.random.Generator) -> PlantParams:
    """A nominal plant other than the thesis' numbers: every physical parameter drawn around them.

    The thrust path (L/J·K_q) is set so that full duty holds the rod at sin θ in [0.55, 0.8].
    """
    base = PlantParams()
    p = base.scaled(mgd_over_J=rng.uniform(0.6, 1.3), c_over_J=rng.uniform(0.5, 1.5),
                    R_a=rng.uniform(0.7, 1.4), L_a=rng.uniform(0.5, 1.5), J_m=rng.uniform(0.7, 1.4),
                    B_m=rng.uniform(0.7, 1.4))
    k = rng.uniform(0.8, 1.2)
    p = p.scaled(K_omega=k, K_t=k)
    # steady state at τ = 1: i = V/(R + K_ω K_t/B_m), ω₁ = K_t i/B_m, θ̈ term (L/J)·K_q·(N ω₁)²
    w = p.K_t * p.v_supply / (p.R_a * p.B_m + p.K_omega * p.K_t)
    target = rng.uniform(0.55, 0.8) * p.mgd_over_J
    return p.scaled(L_over_J=target / (p.L_over_J * p.K_q * (GEAR * w) ** 2))


def rig_dict(params: PlantParams, name: str) -> dict[str, Any]:
    """The lab's rig file for a nominal plant: the shipped thesis_sim format, values replaced."""
    doc = yaml.safe_load(BASE_RIG.read_text(encoding="utf-8"))
    src = "independent benchmark nominal plant (bench/fixtures/truth_plant.py parameters)"

    def put(section: str, key: str, value: float) -> None:
        doc[section][key]["value"] = float(value)
        doc[section][key]["source"] = src

    doc["name"] = name
    doc["description"] = "nominal simulator of the independent blind benchmark (ideal drive)"
    put("actuator", "v_supply", params.v_supply)
    for k in ("R_a", "L_a", "K_omega", "K_t", "J_m", "B_m"):
        put("motor", k, getattr(params, k))
    put("motor", "gear_ratio", 1.0 / GEAR)
    put("thrust", "K_q", params.K_q)
    put("pendulum", "mgd_over_J", params.mgd_over_J)
    put("pendulum", "c_over_J", params.c_over_J)
    put("pendulum", "L_over_J", params.L_over_J)
    doc["effects"]["hbridge_map"] = False
    return doc


def draw(name: str, rng: np.random.Generator, ranges: dict[str, list[tuple[float, float]]] = RANGES) -> float:
    lo, hi = ranges[name][int(rng.integers(len(ranges[name])))]
    return float(rng.uniform(lo, hi))


def truth_effects(names: list[str], rng: np.random.Generator, params: Any,
                  max_angle: float, fam: FamilyCases | None = None) -> dict[str, float]:
    """Truth magnitudes in truth_plant units (delay in whole samples, the thesis plant's drag as K_d,
    stop angle in rad); ``fam``: another family's ranges and sample period."""
    ranges, dt = (RANGES, DT) if fam is None else (fam.ranges, fam.dt)
    out = {}
    for n in names:
        v = draw(n, rng, ranges)
        if n == "input_delay":
            v = round(v / dt) * dt
        elif n == "propeller_drag" and fam is None:
            v = v * params.J_m
        elif n == "end_stops":
            v = v * max_angle
        out[n] = v
    return out


#: The thesis family's cases (the functions above), beside the other families' (gap_families).
THESIS = FamilyCases(
    family="dc_hbridge", dt=DT, channels=CHANNELS, ranges=RANGES, pairs=PAIRS, nominal=PlantParams,
    variant=variant_params, plant=TruthPlant, rig=rig_dict, expected=lambda e, m, p: expected(e, m, p),
    base_delay=lambda p: 0.0,
)
FAMILIES: dict[str, FamilyCases] = {f.family: f for f in (THESIS, ESC, AMPLIFIER)}


def catalog_cases(fam: FamilyCases, skip: list[str] | None = None) -> list[str]:
    """The family's truth effects that are hypotheses of its catalog (the registry's), in the order
    of its ranges, less ``skip``.

    Raises
    ------
    SystemExit
        If a truth effect is neither in the family's catalog nor out of catalog on purpose.
    """
    from aeropend_ident.gap.effects import catalog

    names = {e.name for e in catalog(fam.family)}
    stray = [e for e in fam.ranges if e not in names and e not in OUT_OF_CATALOG]
    if stray:
        raise SystemExit(f"truth effects {stray} are not hypotheses of the {fam.family} catalog")
    return [e for e in fam.ranges if e in names and e not in (skip or [])]


# ------------------------------------------------------------------------------ cases
def case_list(quick: bool = False, only: list[str] | None = None,
              groups: list[str] | None = None, family: str = "dc_hbridge",
              skip: list[str] | None = None) -> list[dict[str, Any]]:
    """Every case: effects, seed, excitation design ("steps_fit" or "aprbs_fit"), plant variant."""
    fam = FAMILIES[family]
    cases: list[dict[str, Any]] = []
    draws = 1 if quick else 2
    seed = 14000
    for e in catalog_cases(fam, skip):
        for design in ("steps_fit", "aprbs_fit"):
            for _ in range(draws):
                cases.append({"effects": [e], "seed": seed, "design": design, "group": "single"})
                seed += 1
    if not quick:
        for k, pair in enumerate(fam.pairs):
            for j, design in enumerate(("steps_fit", "aprbs_fit")):
                cases.append({"effects": list(pair), "seed": 15000 + 2 * k + j, "design": design,
                              "group": "pair"})
    for k, e in enumerate(OUT_OF_CATALOG):
        for j in range(2 if quick else 5):
            cases.append({"effects": [e], "seed": 16000 + 10 * k + j,
                          "design": ("steps_fit", "aprbs_fit")[j % 2], "group": "out of catalog"})
    for j in range(2 if quick else 6):
        cases.append({"effects": [], "seed": 17000 + j, "design": ("steps_fit", "aprbs_fit")[j % 2],
                      "group": "no effect"})
    if only:
        cases = [c for c in cases if set(c["effects"]) & set(only) or (not c["effects"] and "none" in only)]
    if groups:
        cases = [c for c in cases if c["group"] in groups]
    cases = [c for c in cases if not set(c["effects"]) & set(skip or [])]
    for c in cases:
        c["variant"] = c["seed"] % 2 == 1  # half the cases on a non-default nominal plant
        c["family"] = family
    return cases


def build_case(spec: dict[str, Any]) -> dict[str, Any]:
    """Hidden plant, recordings and rig file of one case (truth stays in the returned dict)."""
    fam = FAMILIES[spec.get("family", "dc_hbridge")]
    rng = np.random.default_rng(spec["seed"])
    params = fam.variant(rng) if spec["variant"] else fam.nominal()
    steps_d = lhs_steps(FIT_DURATION if spec["design"] == "steps_fit" else HELD_DURATION,
                        seed=spec["seed"] + 1, dt=fam.dt)
    aprbs_d = aprbs(FIT_DURATION if spec["design"] == "aprbs_fit" else HELD_DURATION,
                    seed=spec["seed"] + 2, dt=fam.dt)
    fit_d, held_d = (steps_d, aprbs_d) if spec["design"] == "steps_fit" else (aprbs_d, steps_d)
    nominal = fam.plant(params, {})
    max_angle = float(np.max(nominal.simulate(fit_d)["theta"]))
    effects = truth_effects(spec["effects"], rng, params, max_angle, None if fam is THESIS else fam)
    plant = fam.plant(params, effects)
    snr = float(rng.uniform(*SNR_RANGE))
    fit = record(plant, fit_d, snr, spec["seed"] + 3, fam.channels)
    held = record(plant, held_d, snr, spec["seed"] + 4, fam.channels)
    return {"params": params, "effects": effects, "snr_db": snr, "fit": fit, "held": held,
            "rig": fam.rig(params, f"indep_nominal_{spec['seed']}")}


def to_recording(tr: Any, source: str) -> Any:
    from aeropend_sim.recording import Recording

    return Recording(t=tr.t, duty=tr.duty, channels=dict(tr.channels), source=source,
                     meta={"synthetic": True})


# ------------------------------------------------------------------------------ scoring
def expected(effect: str, magnitude: float, params: PlantParams) -> tuple[str, float, float]:
    """(physical quantity the diagnosis should report, true value, nominal value) of a truth.

    The quantity is a rig field ``section.field`` (or ``measurement.*``, or the fitted parameter
    ``effect.parameter`` where the rig stores a combination), read from the diagnosis'
    ``rig_values``; what the truth changes follows from its physics.
    """
    p = params
    table: dict[str, tuple[str, float, float]] = {
        "hbridge_drop": ("hbridge_drop.V_drop", magnitude, 0.0),
        "dead_zone": ("actuator.dead_zone", magnitude, 0.0),
        "actuator_lag": ("actuator.lag_time_constant", magnitude, 0.0),
        "input_delay": ("actuator.input_delay", magnitude, 0.0),
        "back_emf": ("motor.K_omega", p.K_omega * magnitude, p.K_omega),
        "armature_resistance": ("motor.R_a", p.R_a * magnitude, p.R_a),
        "armature_inductance": ("motor.L_a", p.L_a * magnitude, p.L_a),
        "torque_constant": ("motor.K_t", p.K_t * magnitude, p.K_t),
        "rotor_friction": ("motor.B_m", p.B_m * magnitude, p.B_m),
        "motor_time_constant": ("motor.J_m", p.J_m * magnitude, p.J_m),
        "propeller_drag": ("motor.K_d", magnitude, 0.0),
        "thrust_coefficient": ("thrust.K_q", p.K_q * magnitude, p.K_q),
        "thrust_law": ("thrust.exponent", magnitude, 2.0),
        "gravity": ("pendulum.mgd_over_J", p.mgd_over_J * magnitude, p.mgd_over_J),
        "inertia": ("pendulum.L_over_J", p.L_over_J / magnitude, p.L_over_J),
        "viscous_friction": ("pendulum.c_over_J", p.c_over_J * magnitude, p.c_over_J),
        "coulomb_friction": ("pendulum.coulomb_over_J", magnitude, 0.0),
        "end_stops": ("pendulum.theta_max", magnitude, math.inf),
        "sensor_offset": ("measurement.theta_offset", -magnitude, 0.0),
        "sensor_scale": ("measurement.theta_scale", magnitude, 1.0),
    }
    return table[effect]


def score(spec: dict[str, Any], case: dict[str, Any], result: Any) -> dict[str, Any]:
    """Score one diagnosis against its hidden truth (see the module docstring)."""
    d = result.diagnosis
    dd = d.as_dict()
    chosen = list(d.chosen) if d.significant else []
    ranking = dd["ranking"]
    truth = list(case["effects"])
    first = ranking[0] if (ranking and d.significant) else None
    named_conf = ([r["effect"] for r in ranking
                   if r.get("status") == "named" and (r.get("presence") or 0.0) >= 0.5]
                  if d.significant else [])
    out: dict[str, Any] = {
        "case": f"{'+'.join(truth) or 'none'}@{spec['seed']}", "group": spec["group"],
        "design": spec["design"],
        "variant": spec["variant"], "truth": case["effects"], "snr_db": case["snr_db"],
        "significant": bool(d.significant), "chosen": chosen, "ranked": [r["effect"] for r in ranking[:5]],
        "presence": {r["effect"]: r.get("presence") for r in ranking[:5]},
        "status": {r["effect"]: r.get("status") for r in ranking[:5]},
        "ambiguous_with": (first or {}).get("ambiguous_with", []), "reason": d.reason,
        "explained": {k: dd.get("explained", {}).get(k) for k in ("completeness", "worst_channel",
                                                                  "residual_over_noise")},
    }
    before = float(result.test[0]["nrmse"])
    after = float(result.test[-1]["nrmse"])
    out["nrmse_before"], out["nrmse_after"] = before, after
    out["shrink"] = 1.0 - after / before if before > 0 else 0.0
    out["channel_nrmse_before"] = result.test[0].get("channel_nrmse")
    out["channel_nrmse_after"] = result.test[-1].get("channel_nrmse")
    if spec["group"] == "no effect":
        out["pass"] = not d.significant
    elif spec["group"] == "out of catalog":
        out["pass"] = not named_conf
        out["named_with_presence"] = named_conf
    else:
        in_cat = [t for t in truth if t not in OUT_OF_CATALOG]
        out["top1"] = bool(chosen) and chosen[0] in in_cat
        out["top1_pair_named"] = bool(chosen) and (
            chosen[0] in in_cat or any(t in out["ambiguous_with"] for t in in_cat))
        out["all_named"] = all(t in chosen for t in in_cat)
        amb_all = {a for r in ranking if r["effect"] in chosen for a in r.get("ambiguous_with", [])}
        out["all_named_or_not_separated"] = all(t in chosen or t in amb_all for t in in_cat)
        mags = {}
        for t in in_cat:
            fam = FAMILIES[spec.get("family", "dc_hbridge")]
            field_, true_v, nom_v = fam.expected(t, case["effects"][t], case["params"])
            row = next((r for r in ranking if r["effect"] == t), None)
            est = None
            if row is not None:
                est = (row.get("rig_values") or {}).get(field_)
            size = abs(true_v - nom_v) if math.isfinite(nom_v) else abs(true_v)
            mags[t] = {"field": field_, "true": true_v, "nominal": nom_v, "estimate": est,
                       "relative_error": (abs(est - true_v) / size if est is not None and size > 0 else None),
                       "relative_size": (abs(true_v - nom_v) / abs(nom_v)
                                         if math.isfinite(nom_v) and nom_v != 0 else None)}
        out["magnitude"] = mags
        out["pass"] = out["top1_pair_named"] if spec["group"] == "single" else out["all_named"]
    return out


def run_case(spec: dict[str, Any]) -> dict[str, Any]:
    from aeropend_ident.gap.run import run_gap
    from aeropend_sim.params import rig_from_dict

    case = build_case(spec)
    rig = rig_from_dict(case["rig"], where=f"case {spec['seed']}")
    fit = [to_recording(case["fit"], f"indep-{spec['seed']}-fit")]
    held = [to_recording(case["held"], f"indep-{spec['seed']}-held")]
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        result = run_gap(rig, fit, held, rig_ref=rig.name, split_rule="separate held-out recording",
                         seed=0, max_effects=2, skip=spec.get("skip", []))
    except Exception as exc:  # a refusal is a failure of the case, recorded with its message
        return {"case": f"{'+'.join(spec['effects']) or 'none'}@{spec['seed']}", "group": spec["group"],
                "design": spec["design"], "variant": spec["variant"], "truth": case["effects"],
                "snr_db": case["snr_db"], "error": f"{type(exc).__name__}: {exc}", "pass": False,
                "top1": False, "top1_pair_named": False, "all_named": False,
                "elapsed_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}
    s = score(spec, case, result)
    s["elapsed_s"] = time.perf_counter() - t0
    s["cpu_s"] = time.process_time() - c0
    return s


# ------------------------------------------------------------------------------ summary
def _frac(xs: list[bool]) -> float | None:
    return float(np.mean(xs)) if xs else None


def _med(xs: list[float]) -> float | None:
    xs = [x for x in xs if x is not None and math.isfinite(x)]
    return float(np.median(xs)) if xs else None


def summarise(scores: list[dict[str, Any]]) -> dict[str, Any]:
    single = [s for s in scores if s["group"] == "single"]
    pair = [s for s in scores if s["group"] == "pair"]
    ooc = [s for s in scores if s["group"] == "out of catalog"]
    none = [s for s in scores if s["group"] == "no effect"]
    correct = [s for s in single if s.get("top1")]
    mag_single = [m["relative_error"] for s in single for m in s.get("magnitude", {}).values()
                  if s.get("top1")]
    per: dict[str, Any] = {}
    for s in single:
        e = next(iter(s["truth"]))
        per.setdefault(e, []).append(s)
    per_effect = {e: {"cases": len(v), "top1": _frac([bool(x.get("top1")) for x in v]),
                      "top1_pair_named": _frac([bool(x.get("top1_pair_named")) for x in v]),
                      "median_shrink": _med([x.get("shrink") for x in v]),
                      "median_magnitude_error": _med([m["relative_error"] for x in v
                                                      for m in x.get("magnitude", {}).values()]),
                      "first_named": [x["chosen"][0] if x.get("chosen") else "none" for x in v]}
                  for e, v in per.items()}
    # by effect size: terciles of the nominal held-out θ NRMSE over the noise-free floor
    sizes = sorted(s["nrmse_before"] for s in single if "nrmse_before" in s)
    bins = {}
    if sizes:
        q1, q2 = np.quantile(sizes, [1 / 3, 2 / 3])
        for lab, lo, hi in (("small", -1, q1), ("medium", q1, q2), ("large", q2, 1e9)):
            sub = [s for s in single if "nrmse_before" in s and lo < s["nrmse_before"] <= hi]
            bins[lab] = {"nominal_nrmse_range": [float(min((s["nrmse_before"] for s in sub), default=0)),
                                                 float(max((s["nrmse_before"] for s in sub), default=0))],
                         "cases": len(sub), "top1": _frac([bool(s.get("top1")) for s in sub]),
                         "median_shrink": _med([s.get("shrink") for s in sub])}
    return {
        "cases": len(scores),
        "errors": [s["case"] + ": " + s["error"] for s in scores if "error" in s],
        "single": {"cases": len(single), "top1": _frac([bool(s.get("top1")) for s in single]),
                   "top1_pair_named": _frac([bool(s.get("top1_pair_named")) for s in single]),
                   "median_shrink_correct": _med([s.get("shrink") for s in correct]),
                   "median_shrink_all": _med([s.get("shrink") for s in single]),
                   "median_magnitude_error": _med(mag_single)},
        "pair": {"cases": len(pair), "both_named": _frac([bool(s.get("all_named")) for s in pair]),
                 "both_named_or_not_separated": _frac([bool(s.get("all_named_or_not_separated"))
                                                       for s in pair]),
                 "median_shrink": _med([s.get("shrink") for s in pair])},
        "out_of_catalog": {"cases": len(ooc), "unexplained": _frac([bool(s.get("pass")) for s in ooc])},
        "no_effect": {"cases": len(none), "no_gap": _frac([bool(s.get("pass")) for s in none])},
        "per_effect": per_effect,
        "by_size": bins,
        "median_case_s": _med([s["elapsed_s"] for s in scores]),
        "median_case_cpu_s": _med([s["cpu_s"] for s in scores]),
    }


def _pct(x: float | None, digits: int = 1) -> str:
    return "—" if x is None else f"{100 * x:.{digits}f} %"


def write_md(path: Path, doc: dict[str, Any]) -> None:
    s, m = doc["summary"], doc["meta"]
    lines = [
        "# Independent blind benchmark of the gap diagnosis (bench/bench_gap_independent.py)",
        "",
        f"Actuator family `{m.get('family', 'dc_hbridge')}`"
        + (f", catalog without {', '.join(m['skipped'])}" if m.get("skipped") else "") + ". "
        f"{s['cases']} cases; hidden plants from `bench/fixtures/truth_plant.py` (no aeropend_sim code); "
        f"{m['workers']} worker(s), {m['wall_s']:.0f} s wall, median {s['median_case_s']:.1f} s wall / "
        f"{s['median_case_cpu_s']:.1f} s CPU per case, load average {m['load_before']} before and "
        f"{m['load_after']} after, on {m['machine']}. Commit {m.get('commit', '?')}."
        + "".join(f" Re-run and merged at commit {x['commit']}: {', '.join(x['cases'])}."
                  for x in m.get("merged", [])),
        "",
        "| bar (issue 14) | measured |",
        "|---|---|",
        f"| single in-catalog effects: top-1 ≥ 95 % | {_pct(s['single']['top1'])} "
        f"(confusable set named: {_pct(s['single']['top1_pair_named'])}) of {s['single']['cases']} |",
        "| median held-out θ-NRMSE shrink (correctly named) ≥ 90 % | "
        f"{_pct(s['single']['median_shrink_correct'])} "
        f"(all single cases {_pct(s['single']['median_shrink_all'])}) |",
        "| median magnitude error ≤ 10 % of the effect size | "
        f"{_pct(s['single']['median_magnitude_error'], 3)} |",
        f"| two-effect cases: both named ≥ 85 % | {_pct(s['pair']['both_named'])} of {s['pair']['cases']} "
        f"(named or reported as not separated from a chosen one: "
        f"{_pct(s['pair'].get('both_named_or_not_separated'))}) |",
        f"| out-of-catalog reported unexplained ≥ 80 % | {_pct(s['out_of_catalog']['unexplained'])} of "
        f"{s['out_of_catalog']['cases']} |",
        f"| effect-free: no significant gap 100 % | {_pct(s['no_effect']['no_gap'])} of "
        f"{s['no_effect']['cases']} |",
        f"| no valid recording refused | {len(s['errors'])} refused |",
        f"| median wall time per case ≤ 30 s | {s['median_case_s']:.1f} s |",
        "",
        "## Per effect (single-effect cases)",
        "",
        "| effect | cases | top-1 | confusable set named | median shrink | median magnitude error "
        "| named first |",
        "|---|---|---|---|---|---|---|",
    ]
    for e, v in s["per_effect"].items():
        lines.append(f"| {e} | {v['cases']} | {_pct(v['top1'])} | {_pct(v['top1_pair_named'])} | "
                     f"{_pct(v['median_shrink'])} | {_pct(v['median_magnitude_error'], 2)} | "
                     f"{', '.join(v['first_named'])} |")
    lines += ["", "## By effect size (single-effect cases, terciles of the nominal held-out θ NRMSE)", "",
              "| size | nominal NRMSE | cases | top-1 | median shrink |", "|---|---|---|---|---|"]
    for k, v in s["by_size"].items():
        r = v["nominal_nrmse_range"]
        lines.append(f"| {k} | {r[0]:.3f}–{r[1]:.3f} | {v['cases']} | {_pct(v['top1'])} | "
                     f"{_pct(v['median_shrink'])} |")
    lines += ["", "## Cases not passed", ""]
    for c in doc["cases"]:
        if not c.get("pass"):
            why = c.get("error") or (f"chose {c.get('chosen')} (presence {c.get('presence')}); "
                                     f"{c.get('reason', '')[:160]}")
            lines.append(f"- `{c['case']}` ({c['group']}, {c['design']}, "
                         f"{'variant' if c['variant'] else 'thesis'} plant, {c['snr_db']:.0f} dB): {why}")
    if errors := s["errors"]:
        lines += ["", "## Refused", "", *[f"- {e}" for e in errors]]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2, help="workers of the local Dask cluster")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="run the cases on a running Dask cluster (tcp://host:8786) instead of a local one")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    ap.add_argument("--quick", action="store_true",
                    help="one draw per effect and design, fewer special cases")
    ap.add_argument("--only", nargs="+", default=None,
                    help="only cases containing these effects ('none': effect-free)")
    ap.add_argument("--group", nargs="+", default=None,
                    choices=("single", "pair", "out of catalog", "no effect"), help="only these case groups")
    ap.add_argument("--family", default="dc_hbridge", choices=sorted(FAMILIES),
                    help="actuator family of the hidden plants and the rig file (default: the thesis')")
    ap.add_argument("--skip-effect", nargs="+", default=[], metavar="NAME",
                    help="catalog effects left out of the diagnosis (and of the cases)")
    ap.add_argument("--out", default=None,
                    help="output stem (default bench/results/gap_independent[_<family>])")
    ap.add_argument("--render", action="store_true", help="only re-write the .md from the .json")
    ap.add_argument("--merge", action="store_true",
                    help="replace the selected cases in the existing .json (same case ids) and re-summarise")
    args = ap.parse_args(argv)
    stem = "gap_independent" + ("" if args.family == "dc_hbridge" else f"_{args.family}")
    out = Path(args.out) if args.out else RESULTS / stem
    if args.render:
        write_md(out.with_suffix(".md"), json.loads(out.with_suffix(".json").read_text(encoding="utf-8")))
        return 0
    specs = case_list(args.quick, args.only, args.group, args.family, args.skip_effect)
    for spec in specs:
        spec["skip"] = list(args.skip_effect)
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    from aeropend_ident.parallel import run_cases

    done: dict[int, dict[str, Any]] = {}
    for i, s in run_cases(run_case, specs, workers=args.workers, scheduler=args.scheduler,
                          desc="gap_independent", quiet=args.quiet):
        done[i] = s
        print(f"[{len(done)}/{len(specs)}] {s['case']:42s} {s['group']:15s} pass={s.get('pass')} "
              f"chosen={s.get('chosen')} shrink={s.get('shrink', float('nan')):.3f} "
              f"({s['elapsed_s']:.1f} s) {s.get('error', '')}", flush=True)
        if len(done) < len(specs) and not args.merge:  # a run stopped early keeps what it measured
            _write(out, args, [done[k] for k in sorted(done)], time.perf_counter() - t0, load_before,
                   partial=f"{len(done)} of {len(specs)} cases")
    _write(out, args, [done[i] for i in sorted(done)], time.perf_counter() - t0, load_before)
    return 0


def _write(out: Path, args: argparse.Namespace, scores: list[dict[str, Any]], wall: float,
           load_before: tuple[float, ...], partial: str = "") -> None:
    """Write the results (.json and .md), merged into the existing ones with ``--merge``."""
    from aeropend_ident.parallel import engine_label

    git = f"git -C {Path(__file__).parent} rev-parse --short HEAD 2>/dev/null"
    commit = os.popen(git).read().strip()
    meta = {"workers": args.workers, "engine": engine_label(args.workers, args.scheduler),
            "wall_s": wall, "load_before": [round(x, 2) for x in load_before],
            "load_after": [round(x, 2) for x in os.getloadavg()], "machine": f"{os.cpu_count()} cores, "
            f"{platform.platform()}", "python": platform.python_version(), "commit": commit,
            "argv": sys.argv[1:], "family": args.family, "skipped": list(args.skip_effect),
            **({"partial": partial} if partial else {})}
    if args.merge:
        old = json.loads(out.with_suffix(".json").read_text(encoding="utf-8"))
        new_ids = {s["case"] for s in scores}
        scores = [s for s in old["cases"] if s["case"] not in new_ids] + scores
        meta = {**old["meta"], "merged": [*old["meta"].get("merged", []), {**meta, "cases": sorted(new_ids)}]}
    doc = {"summary": summarise(scores), "meta": meta, "cases": scores}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(doc, indent=1, default=float), encoding="utf-8")
    write_md(out.with_suffix(".md"), doc)
    if not partial:
        brief = {k: v for k, v in doc["summary"].items() if k != "per_effect"}
        print(json.dumps(brief, indent=1, default=float))


if __name__ == "__main__":
    sys.exit(main())
