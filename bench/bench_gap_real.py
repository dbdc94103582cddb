"""Sim-to-real gap diagnosis on real third-party rigs and on the thesis' own gap.

Cases (real data read from ``../shared/data/real``, never copied into the repository):

* ``jahoyosr_hoja3`` — see-saw rig, nominal model ``jahoyosr_rig`` (stated parameters) vs the
  Hoja3 open-loop PWM staircase; time-ordered split 70 % / 30 %.
* ``aeroshield`` — AeroShield identification run, nominal ``aeroshield_rig`` (the repository's
  grey-box initial guesses); time-ordered split 70 % / 30 % (the split of the grey-box
  baseline, ``test/ident/greybox/test_baseline_real.py``).
* ``etchepareborda`` — BA-Etchepareborda rig, nominal ``etchepareborda_rig`` (stated m and Ts,
  assumed arm and motor, one-point static calibration); fit on the PWM 0/100/180 step cycle,
  held out: the separate PWM 0/100/130 step-cycle recording.
* ``thesis_gap`` — the thesis' simulated pendulum (``thesis_sim``: c/J = 13.82 s⁻¹,
  mgd/J = 131.75 s⁻²) vs recordings synthesised from ``thesis_rig``, whose pendulum was fitted to
  the rig's own open-loop step (τ = 43.14 %: tr 0.43 s, tp 0.84 s, ts 3.53 s, θss 0.54 rad;
  docs/parameters.md). Fit: that step (10 s, 50 dB noise, sampled at 10 ms) and the same test
  switched off again (43.14 % -> 0, the diagnosis' validation recording); held out: a
  different excitation of the same synthetic rig (a staircase 0 → 40 → 43.14 → 46 % and back),
  i.e. an extrapolation of the rig model beyond the one measured step, stated as such.
* ``aeroshield_cross_run`` — fit on the whole AeroShield identification run, held out: the
  independent run ``Identification_Data2`` (another session, 10 ms sampling).
* pre-registered confirmation (docs/gap.md, written before these runs): ``etchepareborda_confirm``
  (``_str``), ``jahoyosr_confirm``, ``aeroshield_confirm`` repeat the fit and validation data of
  ``etchepareborda_all``, ``jahoyosr_hoja3_moving_blocks`` and ``aeroshield_blocks`` and replace
  the held-out data by recordings no case had replayed (the closed-loop runs, the
  ``datosEscalones`` staircases, ``Identification_Data2``); ``aeroshield2_blocks`` applies the
  12 s block protocol within ``Identification_Data2``.
* pre-registered cross-validation (docs/gap.md, written before these runs): ``*_fold<k>`` rotate
  the roles of the blocks (``aeroshield_blocks``, ``jahoyosr_hoja3_moving_blocks``: the held-out
  blocks start at block k) or of the four runs (``etchepareborda_all``: leave-one-run-out), so that
  over the folds every block / run is held out once; the markdown pools them (:data:`FOLDS`).

Each case runs :func:`aeropend_ident.gap.run.run_gap` (where + which + after) exactly as the
``gap`` command does. Results: ``bench/results/gap_real.json`` and ``.md``; figures
``docs/results/gap_<case>_overlay.png`` / ``_where.png`` / ``_effects.png``.

Run: ``python -m bench.bench_gap_real [--max-effects 3] [case ...]`` (≈ 1–3 min per case on two
cores); ``--markdown`` only rewrites ``gap_real.md`` from the stored JSON. ``--max-effects 3``
lets the diagnosis add a third effect by the same forward-selection step as the second (results
under ``<case>_3eff``); the default is 2, as the ``gap`` command.
"""

from __future__ import annotations

import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.cli.gap import resolve_rig
from aeropend_ident.gap.figures import fig_effects, fig_equations, fig_overlay
from aeropend_ident.gap.report import write_report
from aeropend_ident.gap.run import run_gap
from aeropend_ident.io.csv_import import import_csv, import_csv_runs
from aeropend_ident.io.jsonutil import jsonable
from aeropend_ident.io.resampling import uniform_recording
from aeropend_ident.io.split import informative, interleaved_blocks, time_ordered
from aeropend_sim.model import PlantModel
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"
RESULTS = ROOT / "bench" / "results"
FIGS = ROOT / "docs" / "results"

MIN_RANGE = 0.02  # rad: blocks / pieces whose angle moves less are the rod resting on a stop
THESIS_STEP = {"duty": 0.4314, "tr": 0.43, "tp": 0.84, "ts": 3.53, "theta_ss": 0.54}


def _csv(rel: str, preset: str) -> Recording:
    return uniform_recording(import_csv(REAL / rel, preset))


def _split(rec: Recording, frac: float = 0.7) -> tuple[list[Recording], list[Recording], str]:
    fit, held, _rule = time_ordered([rec], frac)
    return fit, held, f"time-ordered split: first {frac:.0%} to fit, the rest held out"


def _blocks(
    rec: Recording, block_s: float, every: int = 3, min_range: float = 0.0, offset: int = 1
) -> tuple[list[Recording], list[Recording], str]:
    """Interleaved held-out blocks (:func:`aeropend_ident.io.split.interleaved_blocks`): fit and
    held-out blocks cover the same operating range (interpolation), unlike the time-ordered split."""
    return interleaved_blocks([rec], block_s, every, min_range, offset)


def case_jahoyosr() -> dict[str, Any]:
    rec = _csv("jahoyosr__Aeropendulum/sheet_Hoja3_pwm_steps_openloop.csv", "jahoyosr_hoja3")
    return {"rig": "jahoyosr_rig", "split": _split(rec)}


def case_jahoyosr_blocks() -> dict[str, Any]:
    rec = _csv("jahoyosr__Aeropendulum/sheet_Hoja3_pwm_steps_openloop.csv", "jahoyosr_hoja3")
    return {"rig": "jahoyosr_rig", "split": _blocks(rec, 20.0)}


def case_jahoyosr_moving_blocks(offset: int = 1) -> dict[str, Any]:
    rec = _csv("jahoyosr__Aeropendulum/sheet_Hoja3_pwm_steps_openloop.csv", "jahoyosr_hoja3")
    return {"rig": "jahoyosr_rig", "split": _blocks(rec, 20.0, min_range=MIN_RANGE, offset=offset)}


def case_aeroshield_blocks(offset: int = 1) -> dict[str, Any]:
    rec = _csv("gergelytakacs__AutomationShield/AeroShield/Identification_Data.csv", "aeroshield_ident")
    return {"rig": "aeroshield_rig", "split": _blocks(rec, 12.0, offset=offset)}


def case_aeroshield() -> dict[str, Any]:
    rec = _csv("gergelytakacs__AutomationShield/AeroShield/Identification_Data.csv", "aeroshield_ident")
    return {"rig": "aeroshield_rig", "split": _split(rec)}


def case_aeroshield_cross_run() -> dict[str, Any]:
    d = "gergelytakacs__AutomationShield/AeroShield/"
    fit = _csv(d + "Identification_Data.csv", "aeroshield_ident")
    held = _csv(d + "Identification_Data2.csv", "aeroshield_ident2")
    return {"rig": "aeroshield_rig",
            "split": ([fit], [held], "fit: Identification_Data (all 72 s, 15 ms); held out: the independent "
                                     "run Identification_Data2 (2023-08, 50 s, 10 ms)")}


def case_etchepareborda() -> dict[str, Any]:
    d = "BA-Etchepareborda__adaptive-control-aeropendulum/"
    fit = _csv(d + "openloop_steps_0_100_180.csv", "etchepareborda_openloop")
    held = _csv(d + "openloop_steps_0_100_130.csv", "etchepareborda_openloop")
    return {
        "rig": "etchepareborda_rig",
        "split": ([fit], [held], "separate held-out file: openloop_steps_0_100_130.csv"),
    }


def case_etchepareborda_val() -> dict[str, Any]:
    d = "BA-Etchepareborda__adaptive-control-aeropendulum/"
    fit = _csv(d + "openloop_steps_0_100_180.csv", "etchepareborda_openloop")
    val = _csv(d + "openloop_gaussian_pwm.csv", "etchepareborda_openloop")
    held = _csv(d + "openloop_steps_0_100_130.csv", "etchepareborda_openloop")
    return {
        "rig": "etchepareborda_rig",
        "split": (
            [fit],
            [held],
            "separate held-out file: openloop_steps_0_100_130.csv; validation file: "
            "openloop_gaussian_pwm.csv",
        ),
        "validation": [val],
    }


ETCH_OPENLOOP = (  # the four open-loop runs, in the order of the fold rotation
    ("openloop_steps_0_100_180.csv", "the 0/100/180 step cycle"),
    ("openloop_random_binary_80_120.csv", "the 80/120 random-binary run"),
    ("openloop_gaussian_pwm.csv", "the Gaussian-PWM run"),
    ("openloop_steps_0_100_130.csv", "the 0/100/130 step cycle"),
)


def case_etchepareborda_all(fold: int = 0) -> dict[str, Any]:
    """All four open-loop runs: fit runs ``fold``, ``fold + 1``, validation ``fold + 2``, held
    out ``fold + 3`` (mod 4, in :data:`ETCH_OPENLOOP` order). Fold 0 is the reported
    configuration; folds 0-3 hold out each run once (leave-one-run-out, pre-registered)."""
    d = "BA-Etchepareborda__adaptive-control-aeropendulum/"
    runs = [ETCH_OPENLOOP[(fold + k) % 4] for k in range(4)]
    fit, val, held = ([_csv(d + f, "etchepareborda_openloop") for f, _ in part]
                      for part in (runs[:2], runs[2:3], runs[3:]))
    return {
        "rig": "etchepareborda_rig",
        "split": (
            fit,
            held,
            f"fit: {runs[0][1]} and {runs[1][1]}; validation: {runs[2][1]}; held out: {runs[3][1]} "
            "(all four open-loop runs)",
        ),
        "validation": val,
    }


# ------------------------------------------------------------------ pre-registered confirmation
# (docs/gap.md "Pre-registered confirmation"): each case repeats the fit and validation data of a
# reported configuration and replaces its held-out data by recordings no gap case had replayed.
ETCH = "BA-Etchepareborda__adaptive-control-aeropendulum/"
JAHO = "jahoyosr__Aeropendulum/"
AERO = "gergelytakacs__AutomationShield/AeroShield/"


def escalones_pieces() -> list[Recording]:
    """The jahoyosr ``datosEscalones`` staircases: the A-B pieces (split at the file's ``block``
    column) and the S-T run, each a separate recording, pieces without information dropped."""
    pieces = import_csv_runs(REAL / JAHO / "sheet_datosEscalones_colsAB_pwm_steps_no_time.csv",
                             "jahoyosr_escalones", "block", min_samples=200)
    st = _csv(JAHO + "sheet_datosEscalones_colsST_pwm_steps_no_time.csv", "jahoyosr_escalones")
    return [r for r in (*pieces, st) if informative(r, MIN_RANGE)]


def _confirm(case: Any, held: Any, rule: str) -> Any:
    """``case`` with its held-out recordings replaced by ``held()`` (the fit/validation unchanged)."""

    def run() -> dict[str, Any]:
        spec = case()
        fit, _held, _rule = spec["split"]
        spec["split"] = (fit, held(), f"{_rule}; held out instead: {rule}")
        return spec

    return run


def _aeroshield2_blocks() -> dict[str, Any]:
    rec = _csv(AERO + "Identification_Data2.csv", "aeroshield_ident2")
    return {"rig": "aeroshield_rig", "split": _blocks(rec, 12.0)}


CONFIRM = {
    "etchepareborda_confirm": _confirm(
        case_etchepareborda_all,
        lambda: [_csv(ETCH + "closedloop_IMC_reference_steps.csv", "etchepareborda_openloop")],
        "the closed-loop IMC run (its recorded PWM replayed open loop), never used by a gap case",
    ),
    "etchepareborda_confirm_str": _confirm(
        case_etchepareborda_all,
        lambda: [_csv(ETCH + "closedloop_STR_load_change.csv", "etchepareborda_openloop")],
        "the closed-loop STR run with a load change (secondary: the load change is not in any model)",
    ),
    "jahoyosr_confirm": _confirm(
        case_jahoyosr_moving_blocks,
        escalones_pieces,
        "the datosEscalones staircases of another session (70 Hz assumed), pieces on a stop dropped",
    ),
    "aeroshield_confirm": _confirm(
        case_aeroshield_blocks,
        lambda: [_csv(AERO + "Identification_Data2.csv", "aeroshield_ident2")],
        "the whole run Identification_Data2 (another session; held out before in aeroshield_cross_run)",
    ),
    "aeroshield2_blocks": _aeroshield2_blocks,
}


# ------------------------------------------------------------------ pre-registered block folds
# (docs/gap.md "Pre-registered cross-validation"): the reported within-experiment configurations
# with the roles of their blocks / runs rotated, so that over all folds every block / run is held
# out exactly once. Fold 1 of the blocks and fold 0 of the runs are the reported cases.
FOLDS = {
    "aeroshield_blocks": ["aeroshield_blocks_fold0", "aeroshield_blocks", "aeroshield_blocks_fold2"],
    "jahoyosr_hoja3_moving_blocks": [
        "jahoyosr_hoja3_moving_blocks_fold0",
        "jahoyosr_hoja3_moving_blocks",
        "jahoyosr_hoja3_moving_blocks_fold2",
    ],
    "etchepareborda_all": [
        "etchepareborda_all",
        "etchepareborda_all_fold1",
        "etchepareborda_all_fold2",
        "etchepareborda_all_fold3",
    ],
}
FOLD_CASES = {
    "aeroshield_blocks_fold0": lambda: case_aeroshield_blocks(0),
    "aeroshield_blocks_fold2": lambda: case_aeroshield_blocks(2),
    "jahoyosr_hoja3_moving_blocks_fold0": lambda: case_jahoyosr_moving_blocks(0),
    "jahoyosr_hoja3_moving_blocks_fold2": lambda: case_jahoyosr_moving_blocks(2),
    **{f"etchepareborda_all_fold{k}": (lambda k=k: case_etchepareborda_all(k)) for k in (1, 2, 3)},
}


def cross_validation(results: dict[str, Any], folds: list[str], max_effects: int) -> dict[str, Any] | None:
    """Pooled held-out NRMSE over the folds of one configuration (every block / run held out once).

    Returns None unless every fold has a result. ``shrink`` = 1 − mean corrected / mean nominal over
    all held-out recordings of all folds; ``fold_shrinks`` per fold, in ``folds`` order;
    ``*_sane`` the same over the held-out recordings whose nominal NRMSE is ≤ 1 (the nominal free
    run neither flips over the pivot nor onto a stop; information only, docs/gap.md).
    """
    rows = [results["cases"].get(result_key(f, max_effects)) for f in folds]
    if any(r is None or "error" in r for r in rows):
        return None
    nominal = np.array([x for r in rows for x in r["test"][0]["per_recording"]])
    corrected = np.array([x for r in rows for x in r["test"][-1]["per_recording"]])
    sane = nominal <= 1.0
    return {
        "folds": [result_key(f, max_effects) for f in folds],
        "n_held_out": len(nominal),
        "nrmse_nominal": float(np.mean(nominal)),
        "nrmse_corrected": float(np.mean(corrected)),
        "shrink": 1.0 - float(np.mean(corrected)) / float(np.mean(nominal)),
        "fold_shrinks": [r["headline"]["heldout_shrink"] for r in rows],
        "fold_effects": [r["headline"]["effects_chosen"] for r in rows],
        "n_held_out_sane": int(sane.sum()),
        "shrink_sane": 1.0 - float(np.mean(corrected[sane])) / float(np.mean(nominal[sane])),
    }


def _heldout_selects(case: Any) -> Any:
    """The same case with ``validation_fraction = 0``: the held-out data also choose the effects
    (the diagnosis' own protocol; optimistic, reported for comparison only)."""

    def run() -> dict[str, Any]:
        spec = case()
        spec["validation_fraction"] = 0.0
        fit, held, rule = spec["split"]
        spec["split"] = (fit, held, rule + " [held-out data also choose the effects: optimistic]")
        return spec

    return run


def step_metrics(t: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """Rise (10–90 %), peak and 2 % settling time [s] and final value of a step from rest
    (python-control ``step_info``; final value = mean of the last second)."""
    import control

    yss = float(np.mean(y[t > t[-1] - 1.0]))
    info = control.step_info(y, timepts=t, final_output=yss)
    return {
        "tr": float(info["RiseTime"]),
        "tp": float(info["PeakTime"]),
        "ts": float(info["SettlingTime"]),
        "theta_ss": yss,
        "overshoot_pct": float(info["Overshoot"]),
    }


def thesis_recordings(dt: float = 0.01) -> tuple[list[Recording], list[Recording], dict[str, Any]]:
    """Synthetic 'rig' recordings from thesis_rig (50 dB noise on θ, θ only)."""
    rig = load_rig("thesis_rig").with_effects(sensor_noise=True)
    n = round(10.0 / dt)
    duty = np.full(n, THESIS_STEP["duty"])
    duty[: round(0.5 / dt)] = 0.0
    tr = simulate(rig, duty, dt=dt, seed=11)
    step = Recording.from_trajectory(tr, channels=("theta",), source="synthetic thesis_rig step τ = 43.14 %")
    k0 = round(0.5 / dt)
    metrics = step_metrics(tr.t[k0:] - tr.t[k0], tr.true["theta"][k0:])
    # the same open-loop test switched off again (from the equilibrium at 43.14 % back to 0): the
    # diagnosis chooses its effects on it (validation), the staircase below stays held out
    x_eq, _ = PlantModel(rig).equilibrium(float(np.mean(tr.true["theta"][-round(1.0 / dt) :])))
    off = np.full(n, THESIS_STEP["duty"])
    off[round(0.5 / dt) :] = 0.0
    tr_off = simulate(rig, off, x0=x_eq, dt=dt, seed=13)
    step_off = Recording.from_trajectory(
        tr_off, channels=("theta",), source="synthetic thesis_rig step 43.14 % -> 0"
    )
    levels = [0.0, 0.40, 0.4314, 0.46, 0.4314, 0.40, 0.0]
    stair = np.concatenate([np.full(round(4.0 / dt), v) for v in levels])
    tr2 = simulate(rig, stair, dt=dt, seed=12)
    held = Recording.from_trajectory(
        tr2, channels=("theta",), source="synthetic thesis_rig staircase 0/40/43.14/46 %"
    )
    return [step, step_off], [held], {"synthetic_step_metrics": metrics, "target_step_metrics": THESIS_STEP}


def case_thesis() -> dict[str, Any]:
    fit, held, extra = thesis_recordings()
    return {
        "rig": "thesis_sim",
        "split": (
            fit,
            held,
            "fit: the synthesised step up (fit core) and step down (validation); "
            "held out: synthesised staircase",
        ),
        "extra": extra,
    }


CASES = {
    "jahoyosr_hoja3": case_jahoyosr,
    "jahoyosr_hoja3_blocks": case_jahoyosr_blocks,
    "jahoyosr_hoja3_moving_blocks": case_jahoyosr_moving_blocks,
    "aeroshield": case_aeroshield,
    "aeroshield_blocks": case_aeroshield_blocks,
    "aeroshield_cross_run": case_aeroshield_cross_run,
    "etchepareborda": case_etchepareborda,
    "etchepareborda_val": case_etchepareborda_val,
    "etchepareborda_all": case_etchepareborda_all,
    "thesis_gap": case_thesis,
}
CASES.update(CONFIRM)
CASES.update(FOLD_CASES)
CASES["etchepareborda_heldout_selects"] = _heldout_selects(case_etchepareborda)
CASES["jahoyosr_hoja3_blocks_heldout_selects"] = _heldout_selects(case_jahoyosr_blocks)
NEEDS_REAL = {
    "jahoyosr_hoja3",
    "jahoyosr_hoja3_blocks",
    "jahoyosr_hoja3_moving_blocks",
    "aeroshield",
    "aeroshield_blocks",
    "aeroshield_cross_run",
    "etchepareborda",
    "etchepareborda_val",
    "etchepareborda_all",
    "etchepareborda_heldout_selects",
    "jahoyosr_hoja3_blocks_heldout_selects",
    *CONFIRM,
    *FOLD_CASES,
}


def run_case(name: str, max_effects: int = 2) -> dict[str, Any]:
    spec = CASES[name]()
    rig, offset = resolve_rig(spec["rig"])
    fit, held, rule = spec["split"]
    t0 = time.perf_counter()
    res = run_gap(
        rig,
        fit,
        held,
        rig_ref=spec["rig"],
        theta_offset=offset,
        split_rule=rule,  # type: ignore[arg-type]
        validation=spec.get("validation"),
        validation_fraction=spec.get("validation_fraction", 0.3),
        max_effects=max_effects,
        progress=lambda m: print(f"  [{name}] {m}", flush=True),
    )
    elapsed = time.perf_counter() - t0
    key = result_key(name, max_effects)
    out = Path("/tmp") / f"gap_bench_{key}"
    write_report(res, out)
    FIGS.mkdir(parents=True, exist_ok=True)
    (FIGS / f"gap_{key}_overlay.png").write_bytes(fig_overlay(res))
    (FIGS / f"gap_{key}_where.png").write_bytes(fig_equations(res.where))
    (FIGS / f"gap_{key}_effects.png").write_bytes(fig_effects(res))
    d = res.diagnosis
    h = res.headline()
    row: dict[str, Any] = {
        "rig": spec["rig"],
        "max_effects": max_effects,
        "split_rule": rule,
        "elapsed_s": elapsed,
        "fit": [{"source": r.source, "n": len(r), "dt_s": r.dt} for r in fit],
        "held_out": [{"source": r.source, "n": len(r), "dt_s": r.dt} for r in held],
        "diagnosis_fit": [{"source": r.source, "n": len(r)} for r in res.fit_core],
        "diagnosis_validation": [{"source": r.source, "n": len(r)} for r in res.validation],
        "test": res.test,
        "headline": h,
        "meets_bar_50pct": bool(
            h["heldout_shrink"] is not None and h["heldout_shrink"] >= 0.5 and d.chosen
            and h["heldout_never_seen_by_diagnosis"]
        ),
        "where": {
            "significant": res.where.significant,
            "subsystem": res.where.subsystem,
            "located": res.where.located,
            "not_checked": res.where.not_checked,
            "verdict": res.where.verdict(),
            "recordings": [
                {
                    "source": r.source,
                    "free_run_nrmse": r.free_run["nrmse"],
                    "short_horizon_nrmse": r.short_horizon["nrmse"],
                    "ljung_box_p": r.whiteness["p_value"],
                    "xcorr_peak_lag_s": r.input_xcorr["peak_lag_s"],
                    "alignment_lag_s": r.alignment["lag_s"],
                    "holds": r.holds[:12],
                }
                for r in res.where.recordings
            ],
        },
        "which": {
            "significant": d.significant,
            "reason": getattr(d, "reason", ""),
            "chosen": d.chosen,
            "ranking": [
                {
                    k: r.get(k)
                    for k in (
                        "effect",
                        "subsystem",
                        "validation_explained",
                        "bic_delta",
                        "presence",
                        "status",
                        "parameters",
                    )
                }
                for r in d.ranking[:6]
            ],
            "not_identifiable": [n["effect"] for n in d.not_identifiable],
            "validation": d.validation,
        },
        "after": {
            "heldout_corrected_significant": res.where_heldout_corrected.significant,
            "heldout_corrected_ljung_box_p": [
                r.whiteness["p_value"] for r in res.where_heldout_corrected.recordings
            ],
        },
        "report_folder": str(out),
    }
    if "extra" in spec:
        row.update(spec["extra"])
        row["nominal_vs_rig_pendulum"] = {
            k: {
                "thesis_sim": getattr(rig.pendulum, k),
                "thesis_rig": getattr(load_rig("thesis_rig").pendulum, k),
            }
            for k in ("mgd_over_J", "c_over_J", "L_over_J")
        }
        row["corrected_pendulum"] = {
            k: getattr(d.corrected_rig.pendulum, k)
            for k in ("mgd_over_J", "c_over_J", "L_over_J", "coulomb_over_J")
        }
    return row


def result_key(name: str, max_effects: int) -> str:
    """Result / figure key of a case: the case name, with ``_3eff`` when up to 3 effects are added."""
    return name if max_effects == 2 else f"{name}_{max_effects}eff"


def markdown(results: dict[str, Any]) -> str:
    lines = [
        "# Sim-to-real gap diagnosis on real rigs and the thesis gap (bench/bench_gap_real.py)",
        "",
        "Held-out NRMSE = mean over held-out recordings of RMS(θ_sim − θ_meas)/range(θ_meas); the held-out "
        "recordings/parts were never used to locate, choose or fit the effects (train / validation / test: "
        "the diagnosis fits on the fit core and chooses on the validation data, both from the fit "
        "recordings). Bar: shrink ≥ 50 % with the effects named.",
        "",
        "| case | nominal rig | where (subsystem) | effects chosen | held-out NRMSE nominal | corrected | "
        "shrink | bar |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in results["cases"].items():
        if "error" in r:
            lines.append(f"| {name} | {r.get('rig', '')} | error: {r['error']} | | | | | |")
            continue
        h = r["headline"]
        lines.append(
            f"| {name} | {r['rig']} | {r['where']['subsystem']} | {', '.join(h['effects_chosen']) or '–'} | "
            f"{h['heldout_nrmse_nominal']:.4f} | {h['heldout_nrmse_corrected']:.4f} | "
            + ("diverges" if h["heldout_shrink"] is None else f"{100 * h['heldout_shrink']:.1f} %")
            + f" | {'yes' if r['meets_bar_50pct'] else 'no'} |"
        )
    cv_rows = [
        (name, cv)
        for name, folds in FOLDS.items()
        for m in (2, 3)
        if (cv := cross_validation(results, folds, m)) is not None
    ]
    if cv_rows:
        lines += [
            "",
            "## Cross-validation over folds (pre-registered, docs/gap.md)",
            "",
            "Every block / run held out exactly once over the folds; pooled = mean over all held-out "
            "recordings of all folds.",
            "",
            "| configuration | folds | held-out recordings | pooled NRMSE nominal → corrected "
            "| pooled shrink | without nominal NRMSE > 1 | shrink per fold | effects per fold |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for name, cv in cv_rows:
            lines.append(
                f"| {name} | {', '.join(cv['folds'])} | {cv['n_held_out']} | {cv['nrmse_nominal']:.4f} → "
                f"{cv['nrmse_corrected']:.4f} | {100 * cv['shrink']:.1f} % | "
                f"{100 * cv['shrink_sane']:.1f} % ({cv['n_held_out_sane']} rec.) | "
                f"{', '.join(f'{100 * x:.1f} %' for x in cv['fold_shrinks'])} | "
                f"{'; '.join('+'.join(e) or '–' for e in cv['fold_effects'])} |"
            )
    for name, r in results["cases"].items():
        if "error" in r:
            continue
        lines += ["", f"## {name}", "", f"Split: {r['split_rule']}. Run time {r['elapsed_s']:.0f} s.", ""]
        lines += [f"* where: {v}" for v in r["where"]["verdict"]]
        lines.append(
            f"* which (chosen on the validation data; its 'held-out' is that validation set): "
            f"{r['which']['reason']}"
        )
        lines.append(
            f"* diagnosis fit on {len(r.get('diagnosis_fit', []))} part(s), validation "
            f"{len(r.get('diagnosis_validation', []))} part(s); the held-out data were never seen"
        )
        lines.append("")
        lines.append("| rank | effect | subsystem | validation explained | ΔBIC | presence | parameters |")
        lines.append("|---|---|---|---|---|---|---|")
        for k, e in enumerate(r["which"]["ranking"], start=1):
            pars = "; ".join(
                f"{n} = {p['value']:.4g}"
                for n, p in (e.get("parameters") or {}).items()
                if p.get("value") is not None
            )
            hx = e.get("validation_explained", e.get("held_out_explained"))
            bic = e.get("bic_delta")
            lines.append(
                f"| {k} | {e['effect']} | {e['subsystem']} | {'–' if hx is None else f'{hx:.3f}'} | "
                f"{'–' if bic is None else f'{bic:.1f}'} | {e.get('presence') or 0:.2f} "
                f"{e.get('status') or ''} | {pars} |"
            )
        lines.append("")
        lines.append("| data | effects | NRMSE |")
        lines.append("|---|---|---|")
        for s in r["which"].get("validation", r["which"].get("shrink", [])):
            lines.append(f"| validation | {'+'.join(s['effects']) or 'nominal'} | {s['nrmse']:.4f} |")
        for s in r.get("test", []):
            lines.append(f"| **held out** | {'+'.join(s['effects']) or 'nominal'} | {s['nrmse']:.4f} |")
        if "synthetic_step_metrics" in r:
            m, tg = r["synthetic_step_metrics"], r["target_step_metrics"]
            lines += [
                "",
                f"Synthesised step (thesis_rig): tr {m['tr']:.2f} s, tp {m['tp']:.2f} s, ts {m['ts']:.2f} s, "
                f"θss {m['theta_ss']:.3f} rad (rig: tr {tg['tr']}, tp {tg['tp']}, ts {tg['ts']}, θss "
                f"{tg['theta_ss']}).",
                "",
                f"Pendulum nominal (thesis_sim) vs rig model (thesis_rig): {r['nominal_vs_rig_pendulum']}; "
                f"corrected: {r['corrected_pendulum']}.",
            ]
    lines += [
        "",
        f"Figures: docs/results/gap_<case>_overlay.png, _where.png, _effects.png. Host: {results['host']}.",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    max_effects = 2
    if "--max-effects" in argv:
        k = argv.index("--max-effects")
        max_effects = int(argv[k + 1])
        argv = argv[:k] + argv[k + 2:]
    path = RESULTS / "gap_real.json"
    results = json.loads(path.read_text()) if path.exists() else {"cases": {}}
    if argv == ["--markdown"]:  # rewrite gap_real.md from the stored results, run nothing
        (RESULTS / "gap_real.md").write_text(markdown(results))
        return 0
    names = argv or list(CASES)
    results["host"] = {
        "python": platform.python_version(),
        "cpus": __import__("os").cpu_count(),
        "load_avg": list(__import__("os").getloadavg()),
    }
    for name in names:
        if name in NEEDS_REAL and not REAL.is_dir():
            print(f"skip {name}: {REAL} missing")
            continue
        print(f"case {name}", flush=True)
        key = result_key(name, max_effects)
        try:
            results["cases"][key] = run_case(name, max_effects)
        except ValueError as exc:  # a diagnosis that cannot run is a result too
            results["cases"][key] = {"rig": name, "error": str(exc)}
            print(f"  [{name}] error: {exc}")
        RESULTS.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(jsonable(results), indent=2, allow_nan=False))
        (RESULTS / "gap_real.md").write_text(markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
