"""Is the design's predicted probability that the truth ranks first calibrated? (issue 63, bar 2)

:func:`aeropend_ident.design.discriminate.rank_first_probability` predicts, before any recording,
the probability that each candidate ranks first on the designed recording when it is the truth.
This benchmark checks that figure against outcomes on plants the candidates do not come from.

For lab-benchmark cases with catalog effects (:mod:`bench.bench_gap_lab`: singles and triples),
each rebuilt from its seed:

1. the candidates are the truth's effect set and its confusable rivals (each truth effect swapped
   for an effect it is ``confusable_with``, and the set without it), fitted on the case's fit
   session by the design's own fit (:func:`aeropend_ident.design.candidates.fit_candidates`, at
   most six kept, best fit first). Every rival is kept whether or not the fit session already
   refutes it (the design drops those beyond 1.25× the best fit): the predictions then span the
   whole range, from rivals the session already rules out to rivals it cannot tell from the truth.
   The predicted figure is the probability *given* that the truth is a candidate;
2. a sequence of :data:`DURATION` s is designed to separate them (seed 0, default evaluations) and
   the predicted probability that the truth set ranks first is read off (200 noise draws);
3. the sequence is recorded on the case's **independent truth plant**
   (:func:`bench.bench_design_discrimination.designed_recording`: its noise, quantum, rate, jitter
   and dropped rows), and the candidates are ranked on it by their free runs
   (:func:`~aeropend_ident.design.discriminate.evidence`, no refit): the outcome is whether the
   truth set ranks first.

Scored: a reliability table of predicted probability (deciles) against the observed frequency;
the bar is agreement within 10 points in every decile with ten cases or more. Also the Brier score
of the predictions and the time per case.

Usage: ``python -m bench.bench_design_calibration [--only 24,73] [--workers N] [-q]`` (default: every
single and triple) ->
``bench/results/design_calibration.{json,md}``.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
#: Length of every designed recording [s].
DURATION = 40.0
#: Noise draws of each prediction.
DRAWS = 200


def rival_sets(truth: list[str], family: str) -> list[tuple[str, ...]]:
    """The truth set, then each truth effect swapped for each effect of ``family``'s catalog it is
    confusable with (when the set stays compatible) and the set without it: the explanations a
    recording must tell apart."""
    from aeropend_ident.gap.effects import catalog, get_effect
    from aeropend_ident.gap.which.ranking import excluded_with

    own = {e.name for e in catalog(family)}
    t = tuple(sorted(truth))
    sets = [t]
    for e in t:
        rest = tuple(x for x in t if x != e)
        for c in get_effect(e).confusable_with:
            if c in own and c not in excluded_with(rest):
                sets.append(tuple(sorted((*rest, c))))
        sets.append(rest)
    return list(dict.fromkeys(sets))


def run_case(job: dict[str, Any]) -> dict[str, Any]:
    """One case (module doc)."""
    from aeropend_ident.design.candidates import channel_noise, fit_candidates, label
    from aeropend_ident.design.discriminate import design_discrimination, evidence, rank_first_probability
    from aeropend_ident.design.sequence import AprbsShape, Limits
    from bench import bench_gap_lab as lab
    from bench.bench_design_discrimination import designed_recording
    from bench.fixtures.truth_plant import OUT_OF_CATALOG

    spec = lab.case_list()[job["index"]]
    case = lab.build_case(spec)
    fit, _held = lab.prepared(case, spec)
    truth = sorted(t for t in case["effects"] if t not in OUT_OF_CATALOG)
    row: dict[str, Any] = {"index": spec["index"], "kind": spec["kind"], "mode": spec["mode"],
                           "rate_hz": spec["rate_hz"], "channels": spec["channels"], "truth": truth}
    t0 = time.perf_counter()
    sets = rival_sets(truth, case["nominal"].family)
    cands, _rows = fit_candidates(case["nominal"], fit, sets, keep_factor=math.inf)
    row["candidates"] = [c.name for c in cands]
    name = label(truth)
    row["truth_kept"] = name in row["candidates"]
    if not row["truth_kept"] or len(cands) < 2:
        row["scored"] = False
        row["why_not"] = ("the truth set could not be fitted (or is over six candidates)"
                          if not row["truth_kept"] else "no rival could be fitted: nothing to separate")
        row["s"] = time.perf_counter() - t0
        return row
    channels = sorted(set(fit[0].channels) & {"theta", "i_a", "v_a", "omega_rotor"})
    sigma = channel_noise(fit, channels)
    limits = Limits.from_recordings([fit[0].channels["theta"]], [fit[0].duty], fit[0].dt,
                                    quantum=case["quantum"])
    d = design_discrimination(cands, sigma, limits, AprbsShape.for_duration(DURATION), seed=0)
    pred = rank_first_probability(cands, d.duty, sigma, limits, draws=DRAWS)
    rec, _truth = designed_recording(case, spec, d.duty)
    ev = evidence(cands, rec.duty, rec.channels, sigma, rec.dt)
    row.update(scored=True, predicted=pred["per_candidate"][name], observed=ev["first"] == name,
               first=ev["first"], chi2=ev["chi2"], s=time.perf_counter() - t0)
    return row


def reliability(rows: list[dict[str, Any]], tolerance: float = 0.10, min_cases: int = 10) -> dict[str, Any]:
    """Deciles of the predicted probability: cases, mean predicted, observed frequency, and whether
    they agree within ``tolerance`` (checked where a decile holds ``min_cases`` or more)."""
    scored = [r for r in rows if r.get("scored") and np.isfinite(r["predicted"])]
    table = []
    for k in range(10):
        lo, hi = k / 10, (k + 1) / 10
        inside = [r for r in scored if lo <= r["predicted"] < hi or (k == 9 and r["predicted"] == 1.0)]
        if not inside:
            continue
        p = float(np.mean([r["predicted"] for r in inside]))
        o = float(np.mean([r["observed"] for r in inside]))
        table.append({"decile": f"{lo:.1f}-{hi:.1f}", "cases": len(inside), "predicted": p, "observed": o,
                      "checked": len(inside) >= min_cases,
                      "agrees": abs(p - o) <= tolerance if len(inside) >= min_cases else None})
    brier = float(np.mean([(r["predicted"] - r["observed"]) ** 2 for r in scored])) if scored else None
    checked = [t for t in table if t["checked"]]
    return {"scored": len(scored), "table": table, "brier": brier,
            "observed_first": sum(bool(r["observed"]) for r in scored),
            "mean_predicted": float(np.mean([r["predicted"] for r in scored])) if scored else None,
            "largest_decile": max(table, key=lambda t: t["cases"]) if table else None,
            "calibrated": bool(checked) and all(t["agrees"] for t in checked),
            "deciles_checked": len(checked)}


def write_md(path: Path, doc: dict[str, Any]) -> None:
    m, s = doc["meta"], doc["summary"]
    rows = doc["cases"]
    lines = [
        "# Calibration of the design's predicted P(truth ranks first) (issue 63)",
        "",
        f"`python -m bench.bench_design_calibration` at {m['commit']}, {m['wall_s']:.0f} s wall on "
        f"{m['workers']} worker(s); designs of {DURATION:g} s, {DRAWS} noise draws per prediction. What it "
        "does: its module docstring.",
        "",
        f"- cases: {len(rows)}; scored (truth set kept as a candidate, a rival left) {s['scored']}; truth "
        f"set not among the fitted candidates {sum(1 for r in rows if not r['truth_kept'])}",
        f"- observed: the truth set ranked first in {s['observed_first']} of {s['scored']}; mean predicted "
        f"{s['mean_predicted'] if s['mean_predicted'] is not None else float('nan'):.2f}",
        f"- Brier score {s['brier']:.3f}" if s["brier"] is not None else "- Brier score: —",
        f"- calibrated within 10 points in every decile with ≥ 10 cases: "
        f"**{'yes' if s['calibrated'] else 'no'}** ({s['deciles_checked']} decile(s) with ≥ 10 cases)",
        "",
        "| predicted decile | cases | mean predicted | observed frequency | agrees (≥ 10 cases) |",
        "|---|---|---|---|---|",
        *[f"| {t['decile']} | {t['cases']} | {t['predicted']:.2f} | {t['observed']:.2f} | "
          f"{'—' if t['agrees'] is None else ('yes' if t['agrees'] else 'no')} |" for t in s["table"]],
        "",
        "| case | kind | mode | Hz | channels | truth | candidates | predicted | ranked first | s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        pred = f"{r['predicted']:.2f}" if r.get("scored") else "—"
        first = (r["first"] + (" (truth)" if r["observed"] else "")) if r.get("scored") \
            else r.get("why_not", "—")
        lines.append(f"| {r['index']} | {r['kind']} | {r['mode']} | {r['rate_hz']} | {r['channels']} | "
                     f"{', '.join(r['truth'])} | {len(r['candidates'])} | {pred} | {first} | {r['s']:.1f} |")
    lines.append("")
    path.write_text("\n".join(lines))


def default_cases() -> list[int]:
    """Every lab-benchmark case with catalog effects (singles and triples)."""
    from bench import bench_gap_lab as lab

    return [c["index"] for c in lab.case_list() if c["kind"] in ("single", "triple")]


def main(argv: list[str] | None = None) -> int:
    from bench.bench_design_discrimination import lab_case_bench

    return lab_case_bench(__doc__.split("\n", 1)[0], run_case, reliability, write_md, default=default_cases(),
                          out=RESULTS / "design_calibration", desc="calibration",
                          meta={"duration_s": DURATION, "draws": DRAWS}, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
