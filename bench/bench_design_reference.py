"""Closed-loop designs on the lab benchmark's unfinished cases: set points for the lab's controller.

The cases and the first two steps are :mod:`bench.bench_design_discrimination`'s (the lab
benchmark's case rebuilt from its seed, ``gap`` before, the candidates from that diagnosis fitted on
the fit session). Then, for a lab that runs its rig only under feedback:

3. the lab's controller is the controller node's default strategy designed on the case's nominal
   rig file (:func:`aeropend_ident.design.reference.lab_controller`, at the case's logging rate),
   and :data:`DURATION` s of set points are designed to separate the candidates in closed loop
   (:func:`aeropend_ident.design.reference.design_reference`, seed 0, its default number of
   sequences, each generation's loops in :func:`aeropend_control.design_gains.design_workers`
   processes, as ``excitation_design --mode reference`` runs them) inside its default limits (the
   fit session's angle range ± 0.15 rad; the command range and slew the controller's own);
4. the set points are recorded **in closed loop on the case's independent truth plant**: the same
   controller reads the truth plant's measured channels (the case's noise σ, angle quantum) at the
   logging rate and drives it (:func:`bench.fixtures.truth_loop.drive_truth`), the log gets the
   case's stamp jitter and dropped rows; the limits are checked on the truth's recorded angle and on
   the logged commands, and the candidates are replayed on the logged command without refit: what
   the recording names (:func:`aeropend_ident.design.discriminate.evidence` and its verdict;
   exactly the truth set counts); where no candidate explains it as sized, what it names once the
   candidates are refitted on the fit session and it together, as ``excitation_design --outcome``
   does (:func:`aeropend_ident.design.discriminate.refit_evidence`).

Control: the seeded set-point sequence the search starts from (same length, range and holds),
recorded and judged the same way. No ``gap`` after (the open-loop bench measures that).

Usage: ``python -m bench.bench_design_reference [--only 87,90] [--workers N] [-q]`` ->
``bench/results/design_reference.{json,md}``.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.bench_design_discrimination import (
    DEFAULT_CASES,
    RESULTS,
    _sigma,
    case_and_candidates,
    lab_case_bench,
    limits_cell,
    refit_row,
)

#: Length of every designed set-point sequence [s].
DURATION = 40.0


def closed_loop_recording(case: dict[str, Any], spec: dict[str, Any], loop: Any,
                          steps: list[tuple[float, float]], n: int, salt: int) -> tuple[Any, dict[str, Any]]:
    """The set points recorded in closed loop on the case's truth plant (module doc, step 4): the
    uniform Recording and the raw run (commands, noise-free recorded angle)."""
    from aeropend_ident.io.resampling import uniform_recording
    from bench import bench_gap_lab as lab
    from bench.bench_gap_independent import to_recording
    from bench.fixtures.truth_loop import drive_truth
    from bench.fixtures.truth_plant import DT, TruthPlant

    k = spec["every"]
    sigma = _sigma(case, spec)
    run = drive_truth(TruthPlant(case["params"], case["effects"]), loop, steps, n, every=k, sigma=sigma,
                      quantum=case["quantum"], seed=spec["seed"] + 7 + salt)
    chans = ("theta", "i_a", "v_a", "omega_rotor") if spec["channels"] == "all" else ("theta",)
    m = run["duty"].size
    log = lab.logged(np.arange(m) * k * DT, run["duty"], {c: run["channels"][c] for c in chans}, spec,
                     2 + salt)
    return uniform_recording(to_recording(log, f"lab-{spec['id']}-reference-{salt}")), run


def _judge(cands: list[Any], rec: Any, run: dict[str, Any], sigma: dict[str, float], limits: Any,
           truth: list[str], nominal: Any, fit: list[Any]) -> dict[str, Any]:
    from aeropend_ident.design.discriminate import evidence
    from aeropend_ident.design.sequence import check_limits

    out: dict[str, Any] = {"limits_on_truth": check_limits(run["duty"], limits, run["theta_recorded"]),
                           "diverged": bool(run["diverged"])}
    if out["diverged"]:
        out["limits_on_truth"]["ok"] = False
        return {**out, "named": None, "named_truth": False}
    ev = evidence(cands, rec.duty, rec.channels, sigma, rec.dt)
    truth_name = next((c.name for c in cands if set(c.effects) == set(truth)), None)
    named = ev["named_effects"]
    out.update({"outcome": {**ev, "truth_candidate": truth_name,
                            "truth_first": (ev["first"] == truth_name) if truth_name else None},
                "named_as_sized": named})
    if ev["unexplained"]:  # nothing explains it as sized: refit on it, as excitation_design --outcome does
        out["refit"], out["refit_s"] = refit_row(nominal, fit, rec, cands, sigma, truth)
        named = out["refit"]["named_effects"]
    out.update({"named": named, "named_truth": named is not None and set(named) == set(truth)})
    return out


def run_case(job: dict[str, Any]) -> dict[str, Any]:
    """One case (module doc)."""
    from aeropend_ident.design.reference import (
        design_reference,
        lab_controller,
        lab_predictor,
        rank_first_probability,
        reference_shape,
    )
    from aeropend_ident.design.sequence import Limits
    from aeropend_sim.params import save_rig

    spec, case, fit, _held, row, cands, sigma, td = case_and_candidates(job["index"])
    dt = fit[0].dt
    limits = Limits.from_recordings([fit[0].channels["theta"]], [fit[0].duty], dt, quantum=case["quantum"],
                                    stated={"duty_min": 0.0, "duty_max": 1.0, "max_slew": 1.0 / dt})
    row["limits"] = limits.as_dict()
    with tempfile.TemporaryDirectory() as tmp:  # the lab's rig file, as the controller node reads it
        rig_file = Path(tmp) / "nominal.yaml"
        save_rig(case["nominal"], rig_file)
        loop = lab_controller(str(rig_file), {}, dt)
    row["controller"] = {"strategy": loop.settings.strategy, "omega_n": loop.settings.spec.omega_n,
                         "zeta": loop.settings.spec.zeta, "reach_rad": loop.reach}
    if len(cands) < 2:
        row["design"] = {"note": "one candidate left: nothing to separate"}
        row["design_s"] = time.perf_counter() - td
        return row
    shape = reference_shape(DURATION)
    # as `excitation --design-for ... --mode reference` runs it: the loops in design_workers() processes
    with lab_predictor(cands, loop, sigma, limits, shape) as pred:
        n, workers = pred.n, pred.workers
        d = design_reference(cands, loop, sigma, limits, shape, seed=0, predictor=pred)
        row["design"] = {"evaluations": d.evaluations, "stopped_by": d.stopped_by, "search_s": d.elapsed_s,
                         "value": d.value, "baseline_value": d.baseline_value,
                         "min_divergence": d.min_divergence,
                         "baseline_min_divergence": d.baseline_min_divergence,
                         "set_points": len(d.steps) - 1, "workers": workers}
        row["predicted"] = rank_first_probability(cands, loop, d.steps, n, sigma, limits, draws=100,
                                                  predictor=pred)
    row["design_s"] = time.perf_counter() - td
    for key, steps, salt in (("designed", d.steps, 0), ("baseline", d.baseline_steps, 1)):
        rec, run = closed_loop_recording(case, spec, loop, steps, n, salt)
        row[key] = _judge(cands, rec, run, sigma, limits, row["truth"], case["nominal"], fit)
    return row


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    done = [r for r in rows if "designed" in r]
    tri = [r for r in done if r["kind"] == "triple"]
    clean = [r for r in done if r["kind"] == "none"]

    def count(rs: list[dict[str, Any]], key: str, what: str) -> int:
        return sum(bool(r[key].get(what)) for r in rs)

    return {
        "cases": len(rows), "designed": len(done), "triples": len(tri), "effect_free": len(clean),
        "triples_named_designed": count(tri, "designed", "named_truth"),
        "triples_named_baseline": count(tri, "baseline", "named_truth"),
        "triples_named_designed_as_sized": sum(_as_sized(r["designed"], r["truth"]) for r in tri),
        "triples_named_baseline_as_sized": sum(_as_sized(r["baseline"], r["truth"]) for r in tri),
        "triples_refit_designed": sum("refit" in r["designed"] for r in tri),
        "triples_unexplained_after_refit_designed": sum(
            bool(r["designed"].get("refit", {}).get("unexplained")) for r in tri),
        "triples_nothing_designed": sum(r["designed"]["named"] is None for r in tri),
        "triples_unexplained_designed": sum(bool((r["designed"].get("outcome") or {}).get("unexplained"))
                                            for r in tri),
        "truth_among_candidates": sum(r["truth_among_candidates"] for r in tri),
        "truth_first_designed": sum(bool((r["designed"].get("outcome") or {}).get("truth_first"))
                                    for r in tri),
        "effect_free_clean_designed": count(clean, "designed", "named_truth"),
        "effect_free_clean_baseline": count(clean, "baseline", "named_truth"),
        "limits_held_designed": sum(bool(r["designed"]["limits_on_truth"]["ok"]) for r in done),
        "limits_held_baseline": sum(bool(r["baseline"]["limits_on_truth"]["ok"]) for r in done),
        "design_s_median": float(np.median([r["design_s"] for r in done])) if done else float("nan"),
        "design_s_max": max((r["design_s"] for r in done), default=float("nan")),
        "search_s_max": max((r["design"]["search_s"] for r in done), default=float("nan")),
    }


def _as_sized(j: dict[str, Any], truth: list[str]) -> bool:
    """The candidates as fitted on the fit session, without the refit, named exactly the truth."""
    n = j.get("named_as_sized", j.get("named"))
    return n is not None and set(n) == set(truth)


def _cell(j: dict[str, Any]) -> str:
    if j.get("diverged"):
        return "the loop diverged"
    o = j.get("outcome") or {}
    if "refit" in j:  # no candidate explained it as sized: what the refit named
        ref = j["refit"]
        head = f"refit ({o['best_rms_over_noise']:.1f}× the noise RMS as sized, {ref['sets']} sets): "
        return head + _named_text(j["named"], j["named_truth"], ref)
    return _named_text(j["named"], j["named_truth"], o)


def _named_text(n: list[str] | None, truth: bool, o: dict[str, Any]) -> str:
    if n is None and o.get("unexplained"):
        return f"nothing: no candidate explains it ({o['best_rms_over_noise']:.1f}× the noise RMS)"
    if n is None:
        return "not separated: " + ", ".join(o.get("survivors") or [])
    return f"{', '.join(n) or 'no effect'} ({'yes' if truth else 'no'})"


def write_md(path: Path, doc: dict[str, Any]) -> None:
    s, m = doc["summary"], doc["meta"]
    lines = [
        "# Closed-loop designs on the lab benchmark's unfinished cases (issue 63, item 4)", "",
        f"`python -m bench.bench_design_reference` at {m['commit']}, {m['wall_s']:.0f} s wall on "
        f"{m['workers']} worker(s). What it does: its module docstring. {DURATION:g} s of set points for the "
        "controller node's default strategy (designed on the case's nominal rig file), seed 0, each search "
        "ended by its default number of sequences; recorded in closed loop on the independent truth plant.",
        "",
        "- triples: all truth effects named by the closed-loop recording's verdict "
        f"**{s['triples_named_designed']}/{s['triples']}** designed, "
        f"{s['triples_named_baseline']}/{s['triples']} with the seeded set points "
        f"the search starts from (as sized, without the refit: {s['triples_named_designed_as_sized']} / "
        f"{s['triples_named_baseline_as_sized']}); no candidate explains the designed recording as sized in "
        f"{s['triples_unexplained_designed']}, refitted (as `excitation_design --outcome` does) in "
        f"{s['triples_refit_designed']}, still unexplained after the refit in "
        f"{s['triples_unexplained_after_refit_designed']}; nothing named {s['triples_nothing_designed']}; "
        "the truth set a candidate in "
        f"{s['truth_among_candidates']}/{s['triples']}, first on the designed recording in "
        f"{s['truth_first_designed']}",
        f"- effect-free plants clean: designed {s['effect_free_clean_designed']}/{s['effect_free']}, seeded "
        f"{s['effect_free_clean_baseline']}/{s['effect_free']}",
        f"- limits (the logged commands in range and slew, the truth's recorded angle in the stated range): "
        f"designed {s['limits_held_designed']}/{s['designed']}, seeded "
        f"{s['limits_held_baseline']}/{s['designed']}",
        f"- design time (candidate fits + search + prediction): median {s['design_s_median']:.1f} s, max "
        f"{s['design_s_max']:.1f} s (search alone at most {s['search_s_max']:.1f} s)",
        "",
        "| case | kind | Hz | channels | truth | chosen before | candidates | truth a candidate | sequences "
        "| predicted P(first) | min divergence designed / seeded | named (designed) "
        "| named (seeded) | limits designed / seeded | design s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in doc["cases"]:
        if "designed" not in r:
            lines.append(f"| {r['index']} | {r['kind']} | {r['rate_hz']} | {r['channels']} | "
                         f"{', '.join(r['truth']) or '—'} | {', '.join(r['before']['chosen']) or '—'} | "
                         f"{len(r['candidates'])} | — | — | — | — | {r['design'].get('note')} | — | — | — |")
            continue
        d, pr = r["design"], r["predicted"]
        cells = [str(r["index"]), r["kind"], str(r["rate_hz"]), r["channels"], ", ".join(r["truth"]) or "—",
                 ", ".join(r["before"]["chosen"]) or "—", str(len(r["candidates"])),
                 "yes" if r["truth_among_candidates"] else "no", str(d["evaluations"]),
                 f"{100 * pr['mean']:.0f} %",
                 f"{d['min_divergence']:.3g} / {d['baseline_min_divergence']:.3g}",
                 _cell(r["designed"]), _cell(r["baseline"]),
                 f"{limits_cell(r['designed']['limits_on_truth'])} / "
                 f"{limits_cell(r['baseline']['limits_on_truth'])}", f"{r['design_s']:.1f}"]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    path.write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    return lab_case_bench(__doc__.split("\n", 1)[0], run_case, summarise, write_md, default=DEFAULT_CASES,
                          out=RESULTS / "design_reference", desc="reference designs",
                          meta={"duration_s": DURATION}, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
