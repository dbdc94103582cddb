"""Identify a sparse model from a contract bag: ``python -m aeropend_ident.identify BAG --rig RIG``.

Plain command (no ROS needed): bag + rig file + method in, results folder out
(``model.yaml``, ``summary.json``). The equations identified are those the recorded channels
support: θ̈ when θ is recorded (θ̇ estimated when not recorded), di_a/dt when i_a, ω₁ and v_a are,
dω₁/dt when i_a and ω₁ are; v_a is computed from the duty cycle with the rig's map (thesis
Eq. 4.3) when it was not recorded. Derivatives: cross-validated Savitzky-Golay; split: first
75 % to fit, last 25 % held out; λ by BIC over a sweep; free-run NRMSE on the held-out part.

Errors (bag without the needed topics, NaNs, too short or unexcited data) are reported with the
message of the failing step and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.bags import BagError, read_bag
from aeropend_ident.libraries import CandidateLibrary, physics_library, structured_library, thesis_library
from aeropend_ident.preprocess import add_derivatives, differentiate
from aeropend_ident.sindy import (
    IdentData,
    IdentificationError,
    free_run,
    save_model,
    select_threshold,
    sweep_threshold,
)
from aeropend_sim.model import PlantModel
from aeropend_sim.params import Rig, RigFileError, load_rig
from aeropend_sim.recording import Recording, RecordingError

LAMBDAS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5)


def data_from_recording(rec: Recording, rig: Rig | None = None) -> IdentData:
    """Identification variables from a recording (θ̇ estimated and v_a mapped when missing).

    Raises
    ------
    IdentificationError
        If θ is missing, or v_a is missing and no rig is given for the duty -> voltage map.
    """
    ch = rec.channels
    if "theta" not in ch:
        raise IdentificationError(f"{rec.source}: no angle θ recorded; nothing to identify")
    v: dict[str, np.ndarray] = {k: np.asarray(x, dtype=float) for k, x in ch.items()
                                if k in ("theta", "theta_dot", "i_a", "omega_rotor", "v_a")}
    if "theta_dot" not in v:
        v["theta_dot"] = differentiate(rec.t, v["theta"], method="savgol").dydt
    if "v_a" not in v and ("i_a" in v or "omega_rotor" in v):
        if rig is None:
            raise IdentificationError(
                f"{rec.source}: v_a not recorded; give a rig for the duty -> v_a map"
            )
        m = PlantModel(rig)
        v["v_a"] = np.array([m.armature_voltage(float(u)) for u in rec.duty])
    v["duty"] = np.asarray(rec.duty, dtype=float)
    return IdentData(t=rec.t - rec.t[0], variables=v, source=rec.source)


def supported_targets(data: IdentData) -> list[str]:
    """Equations the recorded channels support (see the module docstring)."""
    have = set(data.variables)
    out = ["theta_dot"]
    if {"i_a", "omega_rotor", "v_a"} <= have:
        out.append("i_a")
    if {"i_a", "omega_rotor"} <= have:
        out.append("omega_rotor")
    return out


def _library(
    name: str, data: IdentData, targets: list[str]
) -> CandidateLibrary | dict[str, CandidateLibrary]:
    variables = [v for v in ("theta", "theta_dot", "i_a", "omega_rotor", "v_a") if v in data.variables]
    if name == "thesis":
        return thesis_library(variables)
    if name == "physics":
        return physics_library(variables)
    libs = structured_library(variables)
    missing = [tg for tg in targets if tg not in libs]
    if missing:
        raise IdentificationError(
            f"structured library has no equation for {missing} with variables {variables}"
        )
    return {tg: libs[tg] for tg in targets}


def identify(bag: Path, out: Path, rig: Rig | None, method: str = "weak", library: str = "structured",
             namespace: str = "") -> dict[str, Any]:
    """Run the whole pipeline; returns the summary written to ``out/summary.json``."""
    t0 = time.perf_counter()
    rec = read_bag(bag, namespace=namespace)
    data = data_from_recording(rec, rig)
    targets = supported_targets(data)
    data = add_derivatives(data, targets=targets, method="savgol")
    train, test = data.split(0.75)
    lib = _library(library, data, targets)
    kw: dict[str, Any] = {"method": method, "exclude_input_steps": 3}
    if method == "weak":
        kw.update(K=300, H_xt=min(0.05, 0.2 * (train.t[-1] - train.t[0])))
    pts, models = sweep_threshold(train, test, lib, LAMBDAS, targets=targets, **kw)
    best = select_threshold(pts, "bic")
    model = models[best.threshold]
    fr = free_run(model, test, substeps=1)
    out.mkdir(parents=True, exist_ok=True)
    gear = rig.motor.gear_ratio if rig is not None else None
    l_j = rig.pendulum.L_over_J if rig is not None else None
    save_model(out / "model.yaml", model, gear_ratio=gear, L_over_J=l_j, test_mse=best.test_mse,
               free_run_nrmse=fr.nrmse, provenance={"bag": str(bag), "rig": rig.name if rig else None,
                                                    "library": library, "samples": len(data)})
    summary = {
        "bag": str(bag), "samples": len(data), "targets": targets, "method": model.method,
        "library": library, "threshold": best.threshold, "equations": model.equations(),
        "test_mse": best.test_mse, "free_run_nrmse": fr.nrmse,
        "sweep": [{"threshold": p.threshold, "n_terms": p.n_terms, "bic": p.bic} for p in pts],
        "wall_time_s": round(time.perf_counter() - t0, 3),
    }
    text = json.dumps(summary, indent=1, ensure_ascii=False) + "\n"
    (out / "summary.json").write_text(text, encoding="utf-8")
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="identify", description=__doc__.splitlines()[0]
    )
    ap.add_argument("bag", type=Path)
    ap.add_argument("--rig", help="rig name or YAML file (for the duty -> v_a map and K_q)")
    ap.add_argument("--method", default="weak", choices=("sindy", "ensemble", "weak"))
    ap.add_argument("--library", default="structured", choices=("structured", "physics", "thesis"))
    ap.add_argument("--namespace", default="")
    ap.add_argument("--out", type=Path, default=Path("ident_results"))
    args = ap.parse_args(argv)
    try:
        rig = load_rig(args.rig) if args.rig else None
        summary = identify(args.bag, args.out, rig, args.method, args.library, args.namespace)
    except (BagError, RecordingError, IdentificationError, RigFileError) as exc:
        print(f"identify: {exc}", file=sys.stderr)
        return 2
    print("\n".join(summary["equations"]))
    print(f"λ = {summary['threshold']:g}; results in {args.out} ({summary['wall_time_s']} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
