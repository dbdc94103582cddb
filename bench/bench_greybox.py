"""Benchmark: wall time per grey-box fit (:func:`aeropend_ident.greybox.fit.fit_greybox`).

Cases (training part = first 70 % where a recording is split):

* ``synthetic``: thesis rig (quasi-static armature) at 100 Hz, 1 s rest + 40 s APRBS, θ only,
  default parameter set started 30 % off; with and without the dead zone.
* ``aeroshield``: AeroShield Identification_Data (67 Hz, 50.5 s of training data), default set.
* ``hoja3``: jahoyosr Hoja3 staircase (70 Hz, 155.5 s of training data), default set (6
  parameters incl. the see-saw offset), with the multiple-shooting initialiser (2 s windows,
  the baseline default), without it, and decimated by 2.

Real logs are read from ``../shared/data/real`` (skipped when absent). Reports wall time,
simulations (residual evaluations incl. finite-difference Jacobians are counted as
``nfev + njev·n_params``) and time per simulation. Writes ``bench/results/greybox.json``.
Run: ``/tmp/venv/bin/python -m bench.bench_greybox`` (``--quick`` skips Hoja3).
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.greybox.fit import fit_greybox
from aeropend_ident.greybox.fit_result import GreyBoxResult
from aeropend_ident.greybox.parameters import default_parameters, rig_theta_offset
from aeropend_sim.excitation import aprbs
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import simulate

ROOT = Path(__file__).resolve().parent
OUT = ROOT / "results" / "greybox.json"
REAL = ROOT.parents[1] / "shared" / "data" / "real"
AEROSHIELD = REAL / "gergelytakacs__AutomationShield" / "AeroShield" / "Identification_Data.csv"
HOJA3 = REAL / "jahoyosr__Aeropendulum" / "sheet_Hoja3_pwm_steps_openloop.csv"


def _row(case: str, res: GreyBoxResult, n_train: int) -> dict[str, Any]:
    sims = res.nfev + res.njev * len(res.parameters)
    return {
        "case": case, "seconds": round(res.elapsed, 2), "n_params": len(res.parameters),
        "n_samples": n_train, "nfev": res.nfev, "njev": res.njev, "simulations": sims,
        "ms_per_simulation": round(1e3 * res.elapsed / max(sims, 1), 1), "train_nrmse": res.nrmse,
    }


def synthetic(dead_zone: bool) -> dict[str, Any]:
    rig = load_rig("thesis_rig").with_effects(armature_inductance="quasi_static", dead_zone=dead_zone)
    if dead_zone:
        rig = rig.with_params("actuator", dead_zone=0.2)
    dt = 0.01
    duty = np.concatenate([np.zeros(100), aprbs(40.0, lo=0.3, hi=0.9, min_hold=0.5, max_hold=3.0,
                                                 seed=3, dt=dt).duty])
    traj = simulate(rig, duty, dt=dt)
    rec = Recording(t=traj.t, duty=duty, channels={"theta": traj.theta}, source="synthetic")
    names = default_parameters(rig)
    start = {n: getattr(getattr(rig, n.split(".")[0]), n.split(".")[1]) * 1.3 for n in names}
    res = fit_greybox(rec, rig, initial=start)
    return _row("synthetic" + ("+dead_zone" if dead_zone else ""), res, len(rec))


def real(path: Path, preset: str, rig_name: str, label: str, **kw: Any) -> dict[str, Any]:
    from aeropend_ident.io.csv_import import import_csv

    rec = import_csv(path, preset)
    train, _ = rec.split(0.7)
    res = fit_greybox(train, load_rig(rig_name), theta_offset=rig_theta_offset(rig_name), **kw)
    return _row(label, res, len(train) // kw.get("decimate", 1))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="skip the Hoja3 cases")
    args = ap.parse_args()
    rows = [synthetic(False), synthetic(True)]
    if AEROSHIELD.is_file():
        rows.append(real(AEROSHIELD, "aeroshield_ident", "aeroshield_rig", "aeroshield", init_horizon=2.0))
    if HOJA3.is_file() and not args.quick:
        for label, kw in (("hoja3 init_horizon=2", {"init_horizon": 2.0}),
                          ("hoja3 free run only", {}),
                          ("hoja3 decimate=2", {"init_horizon": 2.0, "decimate": 2})):
            rows.append(real(HOJA3, "jahoyosr_hoja3", "jahoyosr_rig", label, **kw))
    print(f"{'case':24s} {'s':>7s} {'params':>6s} {'samples':>8s} {'sims':>6s} {'ms/sim':>7s} {'NRMSE':>8s}")
    for r in rows:
        print(f"{r['case']:24s} {r['seconds']:7.2f} {r['n_params']:6d} {r['n_samples']:8d} "
              f"{r['simulations']:6d} {r['ms_per_simulation']:7.1f} {r['train_nrmse']:8.4f}")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"machine": platform.platform(), "python": platform.python_version(),
                               "cases": rows}, indent=2))
    print(f"written {OUT}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
