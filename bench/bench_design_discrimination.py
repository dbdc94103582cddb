"""Does one designed recording finish the diagnoses the lab benchmark left unfinished? (issue 63)

For a handful of the lab benchmark's cases (:mod:`bench.bench_gap_lab`: triples whose three
effects `gap` did not all name, and effect-free plants that must stay clean), each case is rebuilt
from its seed and:

1. ``gap`` runs as the lab benchmark runs it (fit session 1, held-out session 2, three effects at
   most): the **before** diagnosis;
2. the candidates are built from that diagnosis and fitted on the fit session
   (:func:`aeropend_ident.design.candidates.candidate_sets`,
   :func:`~aeropend_ident.design.candidates.fit_candidates` with the diagnosis' own answer kept and
   the sets one swap away from the best fit added),
   and a sequence of :data:`DURATION` s at the case's logging rate is designed to separate them
   (:func:`aeropend_ident.design.discriminate.design_discrimination`, seed 0, its default
   number of evaluations: reproducible from the seed whatever the load) inside the default limits
   (command 0 … the fit session's largest command, slew 20 /s, the fit session's angle range ± 0.15 rad);
3. the designed sequence is recorded on the case's **independent truth plant**
   (:class:`bench.fixtures.truth_plant.TruthPlant`, session-1 parameters and effects) with the
   case's noise σ (the same sensors as its fit session), angle quantum, logging rate, stamp
   jitter and dropped rows, open loop from rest, and checked against every limit (command range,
   slew, angle range on the truth's recorded angle), and the candidates are replayed on it without
   refit: what it names (:func:`aeropend_ident.design.discriminate.evidence` and its verdict; exactly
   the truth set counts, nothing named or another set does not);
4. ``gap`` runs again with the fit session **and** the designed recording as fit recordings (same
   held-out session): the **after** diagnosis; and once more with the fit session as the fit
   recording and the designed recording as the **validation** recording, the one on which the
   diagnosis chooses its effects (``gap FIT --validation DESIGNED --held-out HELD``): the effects
   are fitted on the earlier data and chosen where the design makes the candidates differ.

Control: the seeded APRBS the search started from (same length, limits, levels and hold range), recorded
on the truth plant the same way and given to ``gap`` the same two ways: what a new recording without
the design buys.

Scored: "all truth effects named" before / after (the lab benchmark's rule: each truth effect
chosen or in a chosen effect's ``ambiguous_with``), effect-free plants clean before / after, the
design time, the design's predicted probability that each candidate ranks first when it is the
truth (:func:`~aeropend_ident.design.discriminate.rank_first_probability`) against the seeded
APRBS of the same length, and whether the truth set was among the candidates.

Usage: ``python -m bench.bench_design_discrimination [--only 87,90] [--workers 1] [-q]`` ->
``bench/results/design_discrimination.{json,md}``.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.fixtures.provenance import git_commit

RESULTS = Path(__file__).resolve().parent / "results"
#: Length of every designed recording [s] (the issue's cap is 60 s).
DURATION = 40.0
#: Cases run at once by default: one, so a case's design time is what a lab running one design on this
#: machine waits (the issue's per-case figure); two at once on the 2 cores each took about twice as
#: long (on 2026-12-01, case 80: 116.1 s beside another case, 51.2 s alone; case 84: 63.5 s, 31.3 s).
WORKERS = 1
#: Default cases: unresolved triples of the lab benchmark (open and closed loop, 50-490 Hz, with
#: and without every channel) and two effect-free plants.
DEFAULT_CASES = (73, 80, 81, 84, 87, 90, 93, 95, 76, 86, 0, 2)


def _sigma(case: dict[str, Any], spec: dict[str, Any]) -> dict[str, float]:
    """The noise σ per channel of the case's sensors, as the lab benchmark set it for session 1."""
    from bench import bench_gap_lab as lab
    from bench.bench_gap_closed_loop import closed_loop
    from bench.fixtures.lab_logging import hold_every
    from bench.fixtures.truth_plant import CHANNELS, TruthPlant, aprbs, lhs_steps, noise_sigma

    chans = CHANNELS if spec["channels"] == "all" else ("theta",)
    k, seed = spec["every"], spec["seed"]
    if spec["mode"] == "open":
        gen = lhs_steps if spec["design"] == "steps_fit" else aprbs
        fit_d = hold_every(gen(lab.FIT_DURATION, seed=seed + 1), k)
        true = TruthPlant(case["params"], case["effects"]).simulate(fit_d)
        return noise_sigma(true, case["snr_db"], chans)
    probe = closed_loop(TruthPlant(case["params"]), case["nominal"], seed, 10.0, every=k, sigma={})
    return noise_sigma(probe, case["snr_db"], chans)


def designed_recording(case: dict[str, Any], spec: dict[str, Any], duty: np.ndarray) -> tuple[Any, dict]:
    """The designed sequence (logging grid) recorded on the case's truth plant (module doc, step 3):
    the Recording and the truth's noise-free recorded angle on the logging grid."""
    from bench import bench_gap_lab as lab
    from bench.bench_gap_independent import to_recording
    from bench.fixtures.lab_logging import keep_every, quantise
    from bench.fixtures.truth_plant import CHANNELS, DT, TruthPlant, record

    k = spec["every"]
    chans = CHANNELS if spec["channels"] == "all" else ("theta",)
    fast = np.repeat(duty, k)
    plant = TruthPlant(case["params"], case["effects"])
    rec = record(plant, fast, case["snr_db"], spec["seed"] + 7, chans, _sigma(case, spec))
    kept = keep_every({"duty": rec.duty, **rec.channels}, k)
    kept["theta"] = quantise(kept["theta"], case["quantum"])
    t = np.arange(kept["duty"].size) * k * DT
    log = lab.logged(t, kept.pop("duty"), kept, spec, 2)
    from aeropend_ident.io.resampling import uniform_recording

    truth_theta = np.asarray(rec.true["theta_recorded"])[::k]
    return uniform_recording(to_recording(log, f"lab-{spec['id']}-designed")), {"theta": truth_theta}


def _named(spec: dict[str, Any], case: dict[str, Any], res: Any) -> dict[str, Any]:
    from bench import bench_gap_lab as lab

    s = lab.score_case(spec, case, res)
    return {"chosen": s["chosen"], "pass": bool(s["pass"]), "significant": s["significant"],
            "named_per_effect": s.get("named_per_effect")}


def case_and_candidates(index: int) -> tuple[Any, ...]:
    """Steps 1-2 of the module doc for lab case ``index`` (shared with
    :mod:`bench.bench_design_reference`):
    ``(spec, case, fit, held, row, candidates, sigma, t_design_start)``; ``row`` holds the case's
    description, the before diagnosis and the candidates (with their fit rows)."""
    from aeropend_ident.design.candidates import channel_noise, diagnosis_candidates
    from bench import bench_gap_lab as lab
    from bench.fixtures.truth_plant import OUT_OF_CATALOG

    spec = lab.case_list()[index]
    case = lab.build_case(spec)
    fit, held = lab.prepared(case, spec)
    row: dict[str, Any] = {"index": spec["index"], "kind": spec["kind"], "mode": spec["mode"],
                           "rate_hz": spec["rate_hz"], "channels": spec["channels"],
                           "truth": sorted(t for t in case["effects"] if t not in OUT_OF_CATALOG),
                           "quantum": case["quantum"], "snr_db": case["snr_db"]}
    t0 = time.perf_counter()
    before = lab.lab_gap(case, fit, held)
    row["gap_before_s"] = time.perf_counter() - t0
    row["before"] = _named(spec, case, before)
    td = time.perf_counter()
    cands, rows = diagnosis_candidates(before.diagnosis.as_dict(), case["nominal"], fit,
                                       max_effects=lab.MAX_EFFECTS)
    row["candidate_fits_s"] = time.perf_counter() - td
    row["candidates"] = [c.name for c in cands]
    row["candidate_rows"] = rows
    row["truth_among_candidates"] = any(set(c.effects) == set(row["truth"]) for c in cands)
    channels = sorted(set(fit[0].channels) & {"theta", "i_a", "v_a", "omega_rotor"})
    return spec, case, fit, held, row, cands, channel_noise(fit, channels), td


def run_case(job: dict[str, Any]) -> dict[str, Any]:
    """One case (module doc): before, design, truth recording and limit check, after."""
    from aeropend_ident.design.discriminate import design_discrimination, rank_first_probability
    from aeropend_ident.design.sequence import AprbsShape, Limits, check_limits
    from bench import bench_gap_lab as lab

    spec, case, fit, held, row, cands, sigma, td = case_and_candidates(job["index"])
    limits = Limits.from_recordings([fit[0].channels["theta"]], [fit[0].duty], fit[0].dt,
                                    quantum=case["quantum"])
    row["limits"] = limits.as_dict()
    shape = AprbsShape.for_duration(DURATION)
    baseline = None
    if len(cands) >= 2:
        d = design_discrimination(cands, sigma, limits, shape, seed=0)
        duty, baseline = d.duty, d.baseline
        row["design"] = {"evaluations": d.evaluations, "stopped_by": d.stopped_by, "search_s": d.elapsed_s,
                         "value": d.value, "baseline_value": d.baseline_value,
                         "min_divergence": d.min_divergence,
                         "baseline_min_divergence": d.baseline_min_divergence}
        row["predicted"] = rank_first_probability(cands, duty, sigma, limits, draws=100)
        row["predicted_baseline_aprbs"] = rank_first_probability(cands, d.baseline, sigma, limits, draws=100)
    else:  # one candidate: nothing to separate; the seeded APRBS is recorded (said in the row)
        from aeropend_ident.design.sequence import aprbs_vector, sequence

        duty = sequence(aprbs_vector(shape, 0), shape, limits)
        row["design"] = {"note": "one candidate left: nothing to separate, the seeded APRBS is recorded"}
    row["design_s"] = time.perf_counter() - td
    rec, truth = designed_recording(case, spec, duty)
    row["limits_on_truth"] = check_limits(duty, limits, truth["theta"])
    if len(cands) >= 2:  # the outcome: which candidate the designed recording itself ranks first (no refit)
        from aeropend_ident.design.discriminate import evidence

        ev = evidence(cands, rec.duty, rec.channels, sigma, rec.dt)
        truth_name = next((c.name for c in cands if set(c.effects) == set(row["truth"])), None)
        row["outcome"] = {**ev, "truth_candidate": truth_name,
                          "truth_first": (ev["first"] == truth_name) if truth_name else None}
        named = ev["named_effects"]
        row["recording_named_as_sized"] = named
        if ev["unexplained"]:  # no candidate explains it as sized: refit on it (excitation_design --outcome)
            row["refit"], row["refit_s"] = refit_row(case["nominal"], fit, rec, cands, sigma, row["truth"])
            named = row["refit"]["named_effects"]
    else:  # the earlier recordings leave one candidate: that is what they name
        named = list(cands[0].effects)
    row["recording_named"] = named
    row["recording_named_truth"] = named is not None and set(named) == set(row["truth"])
    t1 = time.perf_counter()
    after = lab.lab_gap(case, [*fit, rec], held)
    row["gap_after_s"] = time.perf_counter() - t1
    row["after"] = _named(spec, case, after)
    # the other way to use it: the designed recording chooses the effects (gap --validation DESIGNED)
    from aeropend_ident.gap.run import run_gap

    t2 = time.perf_counter()
    after_v = run_gap(case["nominal"], fit, held, rig_ref=case["nominal"].name, seed=0,
                      max_effects=lab.MAX_EFFECTS, split_rule="separate held-out recording", validation=[rec])
    row["gap_after_validation_s"] = time.perf_counter() - t2
    row["after_validation"] = _named(spec, case, after_v)
    # the control: the seeded APRBS the search started from, recorded and used the same two ways
    if baseline is not None:
        rec_b, _ = designed_recording(case, spec, baseline)
        row["aprbs_after"] = _named(spec, case, lab.lab_gap(case, [*fit, rec_b], held))
        row["aprbs_after_validation"] = _named(spec, case, run_gap(
            case["nominal"], fit, held, rig_ref=case["nominal"].name, seed=0, max_effects=lab.MAX_EFFECTS,
            split_rule="separate held-out recording", validation=[rec_b]))
    return row


def refit_row(nominal: Any, fit: list[Any], rec: Any, cands: list[Any], sigma: dict[str, float],
              truth: list[str]) -> tuple[dict[str, Any], float]:
    """What ``excitation_design --outcome`` does with a recording no candidate explains as sized:
    the candidates refitted on the earlier recordings and it together
    (:func:`aeropend_ident.design.discriminate.refit_evidence`); the row's summary and its time [s]."""
    from aeropend_ident.design.discriminate import refit_evidence

    t = time.perf_counter()
    ref = refit_evidence(nominal, fit, rec, [c.effects for c in cands], sigma)
    out = {k: ref[k] for k in ("named", "named_effects", "survivors", "first", "unexplained",
                               "best_rms_over_noise", "refit_free_settings")}
    out["sets"] = len(ref["chi2"])
    fitted = [x for x in ref["refit_rows"] if "fit_sse" in x]
    out["sets_fitted"] = len(fitted)
    out["truth_fitted"] = any(set(x["effects"]) == set(truth) for x in fitted)
    return out, time.perf_counter() - t


def _exact(r: dict[str, Any], key: str) -> bool:
    """The diagnosis ``key`` chose exactly the truth set (an effect only reported ambiguous with a
    chosen one is not named)."""
    return sorted(r[key]["chosen"]) == sorted(r["truth"])


def _as_sized(r: dict[str, Any]) -> bool:
    """The candidates as fitted on the earlier data, without the refit, named exactly the truth."""
    n = r.get("recording_named_as_sized", r["recording_named"])
    return n is not None and set(n) == set(r["truth"])


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    tri = [r for r in rows if r["kind"] == "triple"]
    clean = [r for r in rows if r["kind"] == "none"]
    one = [r for r in rows if r["kind"] == "single"]
    return {
        "singles": len(one),
        "singles_exact_before": sum(_exact(r, "before") for r in one),
        "singles_exact_after": sum(_exact(r, "after") for r in one),
        "singles_exact_after_validation": sum(_exact(r, "after_validation") for r in one),
        "singles_named_by_recording": sum(r["recording_named_truth"] for r in one),
        "singles_unseparated_by_recording": sum(r["recording_named"] is None for r in one),
        "singles_unexplained_by_recording": sum(bool(r["outcome"].get("unexplained")) for r in one),
        "singles_named_as_sized": sum(_as_sized(r) for r in one),
        "singles_refit": sum("refit" in r for r in one),
        "singles_unexplained_after_refit": sum(bool(r.get("refit", {}).get("unexplained")) for r in one),
        "singles_truth_among_candidates": sum(r["truth_among_candidates"] for r in one),
        "triples": len(tri),
        "triples_all_named_before": sum(r["before"]["pass"] for r in tri),
        "triples_all_named_after": sum(r["after"]["pass"] for r in tri),
        "triples_all_named_after_validation": sum(r["after_validation"]["pass"] for r in tri),
        "effect_free_clean_after_validation": sum(r["after_validation"]["pass"] for r in clean),
        "aprbs_control_cases": sum("aprbs_after" in r for r in tri),
        "aprbs_all_named_after": sum(r["aprbs_after"]["pass"] for r in tri if "aprbs_after" in r),
        "aprbs_all_named_after_validation": sum(r["aprbs_after_validation"]["pass"] for r in tri
                                                if "aprbs_after" in r),
        "design_all_named_after_validation_where_control": sum(r["after_validation"]["pass"] for r in tri
                                                               if "aprbs_after" in r),
        "truth_among_candidates": sum(r["truth_among_candidates"] for r in tri),
        "triples_named_by_recording": sum(r["recording_named_truth"] for r in tri),
        "triples_unseparated_by_recording": sum(r["recording_named"] is None for r in tri),
        "triples_unexplained_by_recording": sum(bool(r["outcome"].get("unexplained")) for r in tri),
        "triples_named_as_sized": sum(_as_sized(r) for r in tri),
        "triples_refit": sum("refit" in r for r in tri),
        "triples_unexplained_after_refit": sum(bool(r.get("refit", {}).get("unexplained")) for r in tri),
        "effect_free_clean_by_recording": sum(r["recording_named_truth"] for r in clean),
        "effect_free": len(clean),
        "effect_free_clean_before": sum(r["before"]["pass"] for r in clean),
        "effect_free_clean_after": sum(r["after"]["pass"] for r in clean),
        "truth_first_on_designed": sum(bool((r.get("outcome") or {}).get("truth_first")) for r in tri),
        "limits_held_on_truth": sum(bool(r["limits_on_truth"]["ok"]) for r in rows),
        "design_s_max": max(r["design_s"] for r in rows),
        "design_s_median": float(np.median([r["design_s"] for r in rows])),
    }


def _p(x: Any) -> str:
    return "—" if x is None else f"{100 * x:.0f} %"


def _named_cell(r: dict[str, Any]) -> str:
    n, ev = r["recording_named"], r.get("refit") or r["outcome"]
    pre = (f"refit ({r['outcome']['best_rms_over_noise']:.1f}× the noise RMS as sized, "
           f"{ev['sets']} sets): " if "refit" in r else "")
    if n is None and ev.get("unexplained"):
        return pre + f"nothing: no candidate explains it ({ev['best_rms_over_noise']:.1f}× the noise RMS)"
    if n is None:
        return pre + "not separated: " + ", ".join(ev["survivors"])
    return pre + f"{', '.join(n) or 'nothing'} ({'yes' if r['recording_named_truth'] else 'no'})"


def limits_cell(lim: dict[str, Any]) -> str:
    """A design's limit check on the truth plant in a table cell: ok, the limits violated, or
    ``diverged`` (none of them checked)."""
    if lim["ok"]:
        return "ok"
    bad = [k for k in ("command_range", "slew", "angle_range") if lim.get(k) is False]
    return ", ".join(bad) + " violated" if bad else "diverged"


def write_md(path: Path, doc: dict[str, Any]) -> None:
    s, m = doc["summary"], doc["meta"]
    lines = [
        "# One designed recording on the lab benchmark's unfinished cases (issue 63)",
        "",
        f"`python -m bench.bench_design_discrimination` at {m['commit']}, {m['wall_s']:.0f} s wall on "
        f"{m['workers']} worker(s). What it does: its module docstring. Designs of {DURATION:g} s, seed 0, "
        f"each search ended by its default number of evaluations (reproducible: "
        f"{sum(1 for r in doc['cases'] if (r.get('design') or {}).get('stopped_by') == 'budget')} cut "
        "by the wall-time safety net).",
        "",
        f"- triples (not all three named by the lab benchmark): all truth effects named **before "
        f"{s['triples_all_named_before']}/{s['triples']}, "
        f"after {s['triples_all_named_after']}/{s['triples']}**; "
        f"with the designed recording as the validation recording (`gap FIT --validation DESIGNED`) "
        f"{s['triples_all_named_after_validation']}/{s['triples']}; "
        f"the truth set was among the design's candidates in {s['truth_among_candidates']}/{s['triples']}",
        f"- named by the designed recording's own verdict (`excitation_design --outcome`: the candidates "
        f"fitted on the earlier data, replayed on it; of the best and the rivals it does not refute second "
        f"by second, the fewest effects; where none of them explains it as sized, all of them, their swap "
        f"neighbours and nested special cases refitted on the earlier data and it together, then the same "
        f"verdict): all truth effects **{s['triples_named_by_recording']}/{s['triples']}** triples "
        f"({s.get('triples_named_as_sized', s['triples_named_by_recording'])} as sized, "
        f"{s.get('triples_refit', 0)} refitted); nothing named in "
        f"{s['triples_unseparated_by_recording']} (explained by no candidate after the refit: "
        f"{s.get('triples_unexplained_after_refit', 0)}; the rest not separated); a wrong "
        f"set in {s['triples'] - s['triples_named_by_recording'] - s['triples_unseparated_by_recording']}; "
        "effect-free plants clean "
        f"{s['effect_free_clean_by_recording']}/{s['effect_free']}",
        *([f"- single effects the lab benchmark named only as ambiguous with another, or missed "
           f"(confusable pairs): the truth alone chosen **before {s['singles_exact_before']}/{s['singles']}**"
           ", "
           f"named by the designed recording's verdict **{s['singles_named_by_recording']}/{s['singles']}** "
           f"({s.get('singles_named_as_sized', s['singles_named_by_recording'])} as sized, "
           f"{s.get('singles_refit', 0)} refitted; nothing named in {s['singles_unseparated_by_recording']}, "
           f"{s.get('singles_unexplained_after_refit', 0)} of them explained by no candidate after the "
           "refit; "
           "the truth a candidate in "
           f"{s['singles_truth_among_candidates']}), chosen alone by `gap` with it as a fit recording "
           f"{s['singles_exact_after']}/{s['singles']}, as the validation recording "
           f"{s['singles_exact_after_validation']}/{s['singles']}"] if s.get("singles") else []),
        f"- control: where the design had candidates to separate ({s['aprbs_control_cases']} triples), the "
        f"seeded APRBS it started from, recorded the same way: all named {s['aprbs_all_named_after']} "
        f"as a fit recording, {s['aprbs_all_named_after_validation']} as the validation recording "
        f"(the design there: {s['design_all_named_after_validation_where_control']} as validation)",
        f"- on the designed recording itself (candidates replayed, no refit) the truth set ranks first in "
        f"{s['truth_first_on_designed']}/{s['truth_among_candidates']} of the triples where it was a "
        "candidate",
        f"- effect-free plants clean before {s['effect_free_clean_before']}/{s['effect_free']}, after "
        f"{s['effect_free_clean_after']}/{s['effect_free']} (as validation: "
        f"{s['effect_free_clean_after_validation']}/{s['effect_free']})",
        f"- limits (command range, slew, angle range on the truth plant's recorded angle) held in "
        f"{s['limits_held_on_truth']}/{len(doc['cases'])} designs",
        f"- design time (candidate fits + search + prediction): median {s['design_s_median']:.1f} s, "
        f"max {s['design_s_max']:.1f} s",
        "",
        "| case | kind | mode | Hz | channels | truth | chosen before | chosen after | named before → after "
        "| chosen with it as validation (named) | APRBS control: named as fit / as validation "
        "| candidates | truth a candidate | predicted P(first) design / APRBS "
        "| min divergence design / APRBS | first on designed recording | named by it | limits on truth "
        "| design s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in doc["cases"]:
        pr, pb = r.get("predicted") or {}, r.get("predicted_baseline_aprbs") or {}
        d = r.get("design") or {}
        md = (f"{d['min_divergence']:.3g} / {d['baseline_min_divergence']:.3g}"
              if "min_divergence" in d else "—")
        lim_s = limits_cell(r["limits_on_truth"])
        cells = [str(r["index"]), r["kind"], r["mode"], str(r["rate_hz"]), r["channels"],
                 ", ".join(r["truth"]) or "—", ", ".join(r["before"]["chosen"]) or "—",
                 ", ".join(r["after"]["chosen"]) or "—",
                 f"{'yes' if r['before']['pass'] else 'no'} → {'yes' if r['after']['pass'] else 'no'}",
                 f"{', '.join(r['after_validation']['chosen']) or '—'} "
                 f"({'yes' if r['after_validation']['pass'] else 'no'})",
                 (f"{'yes' if r['aprbs_after']['pass'] else 'no'} / "
                  f"{'yes' if r['aprbs_after_validation']['pass'] else 'no'}" if "aprbs_after" in r else "—"),
                 str(len(r["candidates"])), "yes" if r["truth_among_candidates"] else "no",
                 f"{_p(pr.get('mean'))} / {_p(pb.get('mean'))}", md,
                 (r.get("outcome") or {}).get("first") or "—", _named_cell(r), lim_s, f"{r['design_s']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    path.write_text("\n".join(lines))


def lab_case_bench(description: str, run_case: Any, summarise: Any, write_md: Any, *, default: Sequence[int],
                   out: Path, desc: str, meta: dict[str, Any], argv: list[str] | None = None,
                   workers: int = WORKERS) -> int:
    """The command line shared by the design benchmarks over lab cases: ``--only`` (lab case indices,
    default ``default``), ``--workers`` (default :data:`WORKERS`: one case at a time), ``--out``
    (stem, default ``out``), ``-q``; the cases run by :func:`aeropend_ident.parallel.run_cases`,
    sorted by index, written as ``{meta, summary, cases}``
    JSON (``meta`` gets the commit, Python, workers and wall time) and as markdown by ``write_md``."""
    from aeropend_ident.parallel import run_cases

    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--only", default=",".join(map(str, default)), help="comma-separated lab case indices")
    ap.add_argument("--workers", type=int, default=workers)
    ap.add_argument("--out", type=Path, default=out)
    ap.add_argument("-q", "--quiet", action="store_true")
    args = ap.parse_args(argv)
    jobs = [{"index": int(x)} for x in args.only.split(",") if x.strip()]
    t0 = time.perf_counter()
    rows = sorted((r for _i, r in run_cases(run_case, jobs, workers=args.workers, desc=desc,
                                             quiet=args.quiet)), key=lambda r: r["index"])
    doc = {"meta": {"commit": git_commit(), "python": platform.python_version(), "workers": args.workers,
                    "wall_s": time.perf_counter() - t0, **meta},
           "summary": summarise(rows), "cases": rows}
    args.out.with_suffix(".json").write_text(json.dumps(doc, indent=1, default=float) + "\n")
    write_md(args.out.with_suffix(".md"), doc)
    print(args.out.with_suffix(".md").read_text())
    return 0


def main(argv: list[str] | None = None) -> int:
    return lab_case_bench(__doc__.split("\n", 1)[0], run_case, summarise, write_md, default=DEFAULT_CASES,
                          out=RESULTS / "design_discrimination", desc="designs",
                          meta={"duration_s": DURATION}, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
