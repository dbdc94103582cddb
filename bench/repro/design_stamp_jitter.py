"""Reproducer: logger stamp jitter made a designed recording unexplained (issue 63, lab case 49).

Lab case 49 (a motor time constant, the angle alone at 50 Hz, stamp jitter σ 3.06 % of the
period). Until 8209bd1 the designed recording was missed by every candidate by about 9 times the
noise RMS, the verdict named the nominal rig, and ``gap`` given it found no significant effect;
the same case with the logger's stamp jitter set to 0 (everything else, seeds included, as it is)
named the motor time constant, its best candidate at 0.60 times the noise RMS (measured at 08c3e29).

The cause: ``uniform_recording`` took the duty of the row stamped within dt/2 of each grid instant
(the rows belong to the rig's regular sampling instants, the stamps scatter about them), but
interpolated the measured channels linearly at the grid instants from the jittered stamps, which
moved each θ by about θ̇ times its stamp's error beside a command kept in its slot; the designed
sequence switches fast. Since 8209bd1 each row goes to the regular instant its stamp scatters
about, with its command and its measurements (:func:`aeropend_ident.io.resampling.regular_sampling`).
Measured at 293d5c8, both runs give the same: candidates the motor time constant and the nominal
rig, the verdict names the motor time constant, its error RMS 0.60 times the noise's; ``gap`` with
the recording still chooses nothing (its validation parts are at the noise floor).

Prints, for the case as it is and without jitter: the candidates, the verdict, the best
candidate's error RMS over the noise, and what ``gap`` with the recording as a fit recording
chooses (about 2 min per run on two cores)::

    .venv/bin/python -m bench.repro.design_stamp_jitter [--case 49]
"""

from __future__ import annotations

import argparse
import sys


def run(index: int, jitter: float | None) -> dict[str, object]:
    """One case (``jitter`` None: as the lab benchmark has it): gap, candidates, design, the
    recording on the truth plant, its verdict, gap again with it."""
    from aeropend_ident.design.candidates import channel_noise, diagnosis_candidates
    from aeropend_ident.design.discriminate import design_discrimination, evidence
    from aeropend_ident.design.sequence import AprbsShape, Limits
    from bench import bench_design_discrimination as bd
    from bench import bench_gap_lab as lab

    spec = dict(lab.case_list()[index])
    if jitter is not None:
        spec["jitter"] = jitter
    case = lab.build_case(spec)
    fit, held = lab.prepared(case, spec)
    before = lab.lab_gap(case, fit, held)
    cands, _rows = diagnosis_candidates(before.diagnosis.as_dict(), case["nominal"], fit,
                                        max_effects=lab.MAX_EFFECTS)
    sigma = channel_noise(fit, ["theta"])
    limits = Limits.from_recordings([fit[0].channels["theta"]], [fit[0].duty], fit[0].dt,
                                    quantum=case["quantum"])
    d = design_discrimination(cands, sigma, limits, AprbsShape.for_duration(bd.DURATION), seed=0)
    rec, _truth = bd.designed_recording(case, spec, d.duty)
    ev = evidence(cands, rec.duty, rec.channels, sigma, rec.dt)
    after = lab.lab_gap(case, [*fit, rec], held).diagnosis.as_dict()
    return {"jitter": spec["jitter"], "candidates": [c.name for c in cands], "named": ev["named"],
            "best_rms_over_noise": round(float(ev["best_rms_over_noise"]), 2),
            "gap_after_chosen": after.get("chosen"), "gap_after_reason": after.get("reason")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--case", type=int, default=49, help="lab benchmark case index")
    args = ap.parse_args(argv)
    for jitter in (None, 0.0):
        print(run(args.case, jitter), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
