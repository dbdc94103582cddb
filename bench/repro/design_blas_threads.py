"""Reproducer (2026-12-01): the design's verdict on lab case 73 depended on how many threads the BLAS
library ran.

``bench_design_discrimination`` at 1429826 ran its cases in two Dask worker processes, whose BLAS runs
on one thread (:data:`aeropend_ident.parallel.WORKER_ENV`); at d0ee4bd it ran them one after the
other in its own process, where OpenBLAS had one thread per core (2). The design code was the same,
and case 73's refitted verdict (``excitation_design --outcome``) went from the Stribeck set
(sensor offset, Stribeck friction, thrust law; its fit error on the earlier and designed recordings
6.2e-6) to the truth (Coulomb friction for the Stribeck curve; the Stribeck set's fit ended at 1.0e-5
with 2 threads). The fits are least-squares solves whose SVDs and products OpenBLAS splits over its
threads, summing in another order: the rounding differs, and on these ill-conditioned fits a
different rounding ends in a different local minimum. ``run_gap``, ``fit_rig`` and the grey-box fit
already ran with one BLAS thread (:func:`aeropend_ident.greybox.batch.single_blas`); the design's
entry points did not. They do now (``fit_candidates``, ``diagnosis_candidates``,
``design_discrimination``, ``evidence``, ``refit_evidence``, ``rank_first_probability``,
``design_parameters``, ``design_reference``), so a design is the same from the command
line, from Python and in a worker, whatever the machine's core count.

This script rebuilds case 73 (its before diagnosis, candidates, design and designed recording on the
truth plant) and its refit twice, in two processes: BLAS on one thread (``OPENBLAS_NUM_THREADS=1``)
and BLAS left as the machine sets it. Before the fix the two named different sets (the Stribeck set
and the truth); with it both name the Stribeck set, with the same fit errors to the last digit.
About 2 min per process on 2 cores.

Usage: ``python -m bench.repro.design_blas_threads [CASE]`` (default 73)
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

CHILD = """
import json, sys
from bench.bench_design_discrimination import DURATION, case_and_candidates, designed_recording
from aeropend_ident.design.discriminate import design_discrimination, refit_evidence
from aeropend_ident.design.sequence import AprbsShape, Limits
spec, case, fit, held, row, cands, sigma, td = case_and_candidates(int(sys.argv[1]))
limits = Limits.from_recordings([fit[0].channels["theta"]], [fit[0].duty], fit[0].dt, quantum=case["quantum"])
d = design_discrimination(cands, sigma, limits, AprbsShape.for_duration(DURATION), seed=0)
rec, _ = designed_recording(case, spec, d.duty)
ref = refit_evidence(case["nominal"], fit, rec, [c.effects for c in cands], sigma)
print(json.dumps({"named": ref["named"], "fit_sse": {"+".join(r["effects"]): r["fit_sse"]
                  for r in ref["refit_rows"] if "fit_sse" in r}}))
"""


def run(case: int, one_thread: bool) -> dict:
    env = dict(os.environ)
    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.pop(k, None)
        if one_thread:
            env[k] = "1"
    out = subprocess.run([sys.executable, "-c", CHILD, str(case)], env=env, capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    case = int(sys.argv[1]) if len(sys.argv) > 1 else 73
    one, default = run(case, True), run(case, False)
    same = one == default
    print(f"case {case}: BLAS on 1 thread names {one['named']}; as the machine sets it {default['named']}")
    print("the same verdict and fit errors" if same else "DIFFERENT: the design depends on the BLAS threads")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
