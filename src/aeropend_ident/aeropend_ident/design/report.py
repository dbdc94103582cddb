"""The design's files: the command CSV, ``design.json``, ``design.md``, the candidate rig files,
and the comparison of the prediction with the outcome once the designed recording exists.

Folder written by :func:`write_design`:

``design.csv``
    ``t,duty``: time [s] from 0 at the logging period and the command [1]; the format
    ``excitation --signal file --file design.csv`` plays (and ``excitation --print`` writes), and a
    lab's own controller can load (two numeric columns, one header line). A reference design
    (``--mode reference``) writes ``t,reference`` instead: the set point [rad] (angle frame of the
    controller: 0 with the rod hanging) at each logging instant.
``design_controller.yaml``
    A reference design's set points as the controller node's ``steps`` parameter (a ROS 2
    parameters file: ``controller --ros-args --params-file LAB.yaml --params-file
    design_controller.yaml``), with the strategy and pole pattern the prediction assumed.
``design.json``
    Kind (``discrimination`` or ``parameters``), limits, shape, seed, channels and noise σ, the
    prediction (and the seeded APRBS's, for comparison), the limit check on every candidate's
    predicted angle, the candidates (effects, fitted values, measurement map) or parameters.
``design.md``
    The same in a few lines.
``candidates/NN_<name>.yaml``
    Each candidate's rig file (discrimination), reloaded by :func:`compare_outcome`.

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from aeropend_ident.design.candidates import Candidate, diagnosis_view
from aeropend_ident.design.discriminate import UNEXPLAINED_RMS
from aeropend_ident.gap.effects import MeasurementMap
from aeropend_ident.gap.which.ranking import MIN_EXPLAINED_SECOND
from aeropend_ident.io.jsonutil import jsonable
from aeropend_sim.params import load_rig, rig_to_dict

#: What :func:`write_design` writes at the folder's top level (``--overwrite`` replaces only a
#: folder holding one of them).
DESIGN_FILES = ("design.csv", "design.json", "design.md", "candidates", "design_controller.yaml")


def csv_text(duty: np.ndarray, dt: float, column: str = "duty") -> str:
    """``t,<column>`` CSV of a sequence on the grid k·dt (with ``duty``, the format of
    :meth:`aeropend_sim.excitation.ExcitationSignal.to_csv`)."""
    lines = [f"t,{column}"] + [f"{k * dt:.9g},{u:.9g}" for k, u in enumerate(np.asarray(duty, dtype=float))]
    return "\n".join(lines) + "\n"


def controller_params(steps: Sequence[tuple[float, float]], controller: Mapping[str, Any]) -> str:
    """The controller node's ROS 2 parameters file of a reference design: ``steps`` (t0, θ0, t1,
    θ1, ... [s, rad]) and the controller settings the prediction assumed."""
    from aeropend_ident.design.reference import CONTROLLER_NODE

    keep = {k: controller[k] for k in ("rig", "strategy", "omega_n", "zeta", "rho", "allocator", "estimator")
            if controller.get(k) is not None}
    flat = [round(float(v), 9) for pair in steps for v in pair]
    doc = {f"/**/{CONTROLLER_NODE}": {"ros__parameters": {**jsonable(keep), "steps": flat}}}
    head = ("# A reference design (excitation_design --mode reference): the set points as the controller "
            "node's steps.\n# controller --ros-args --params-file YOUR_CONTROLLER.yaml --params-file "
            "design_controller.yaml\n# The strategy and pole pattern below are those the prediction assumed: "
            "run the loop with them.\n")
    return head + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)


def _safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "_+-" else "_" for ch in name)[:80]


def write_design(out: Path, doc: Mapping[str, Any], duty: np.ndarray, dt: float,
                 candidates: Sequence[Candidate] = (), *, column: str = "duty",
                 steps: Sequence[tuple[float, float]] | None = None) -> dict[str, Path]:
    """Write the design folder (module doc) into ``out`` (created if missing).

    The command writes into a fresh folder (:meth:`aeropend_sim.output_folder.OutputFolder.write`);
    files of the same name in ``out`` are replaced.

    Parameters
    ----------
    out : Path
    doc : mapping
        What ``design.json`` holds (:func:`aeropend_ident.design.cli` builds it).
    duty : ndarray, shape (N,)
        Designed commands.
    dt : float
        Logging period [s].
    candidates : sequence of Candidate
        Written as rig files (discrimination designs).
    column : str
        Name of ``duty``'s column in ``design.csv`` (``reference`` for a reference design's set points).
    steps : sequence of (float, float), optional
        A reference design's set-point breakpoints: written as ``design_controller.yaml`` with
        ``doc["controller"]``.

    Returns
    -------
    dict
        Name -> path of every file written.
    """
    out.mkdir(parents=True, exist_ok=True)
    paths = {"csv": out / "design.csv", "json": out / "design.json", "md": out / "design.md"}
    paths["csv"].write_text(csv_text(duty, dt, column), encoding="utf-8")
    if steps is not None:
        paths["controller"] = out / "design_controller.yaml"
        paths["controller"].write_text(controller_params(steps, doc.get("controller", {})), encoding="utf-8")
    if candidates:
        (out / "candidates").mkdir(exist_ok=True)
    files = []
    for i, c in enumerate(candidates):
        p = out / "candidates" / f"{i:02d}_{_safe(c.name)}.yaml"
        p.write_text(yaml.safe_dump(jsonable(rig_to_dict(c.rig)), sort_keys=False, allow_unicode=True),
                     encoding="utf-8")
        files.append(p.relative_to(out).as_posix())
    full = dict(doc)
    if files:
        full["candidate_files"] = files
    paths["json"].write_text(json.dumps(jsonable(full), indent=1, allow_nan=False), encoding="utf-8")
    paths["md"].write_text(markdown(full), encoding="utf-8")
    return paths


def _pct(x: Any) -> str:
    return "—" if x is None or not math.isfinite(float(x)) else f"{100 * float(x):.1f} %"


def _stopped(why: Any) -> str:
    """What ended the search, for a reader: whether the same seed gives the same design elsewhere."""
    if why == "budget":
        return ("the search was cut by its wall-time budget (--budget), so another machine or load gives "
                "another design from this seed; a smaller --max-evaluations makes it reproducible")
    if why == "converged":
        return "the search converged: the same seed gives the same design on any machine"
    return "the search ran its --max-evaluations: the same seed gives the same design on any machine"


def _slew(lim: Mapping[str, Any], controllers: Sequence[str]) -> str:
    """The slew limit in words (a reference design's controller sets its own unless the lab stated one)."""
    return "slew: the controller's own" if "max_slew" in controllers else f"slew ≤ {lim['max_slew']:g} /s"


def markdown(doc: Mapping[str, Any]) -> str:
    """The short ``design.md`` of a design document."""
    lim = doc["limits"]
    ref = doc.get("mode") == "reference"
    base = "seeded set points of the same length" if ref else "seeded APRBS of the same length"
    lines = [f"# Experiment design ({doc['kind']}{', closed loop' if ref else ''})", "",
             f"From `{doc.get('design_for', '?')}`; {doc['duration_s']:g} s at {1 / lim['dt']:.4g} Hz "
             f"(`design.csv`, {'t,reference: set points [rad]' if ref else 't,duty'}), seed {doc['seed']}, "
             f"{doc['evaluations']} sequences simulated in "
             f"{doc['elapsed_s']:.1f} s; {_stopped(doc.get('stopped_by'))}.",
             f"Limits: command {lim['duty_min']:.3g} … {lim['duty_max']:.3g}, "
             f"{_slew(lim, doc.get('controller', {}).get('sets', ()) if ref else ())}, "
             f"angle {lim['theta_min']:.3g} … {lim['theta_max']:.3g} rad (every candidate's predicted angle: "
             f"{'inside' if doc['limits_check']['ok'] else 'OUTSIDE'}).", ""]
    if ref:
        c = doc["controller"]
        lines += [f"Closed loop: {len(doc['steps']) - 1} set points for the lab's controller "
                  f"({c['strategy']} on {c['rig']}, ω_n {c['omega_n']:.3g} rad/s, ζ {c['zeta']:.3g}; "
                  "`design_controller.yaml`). "
                  "Every prediction is that controller's loop on the candidate; the command and the angle "
                  "limits above are checked on each candidate's loop.", ""]
    if doc["kind"] == "discrimination":
        pr, pb = doc["predicted"], doc.get("predicted_baseline_aprbs")
        lines += ["Predicted probability that each candidate ranks first when it is the truth (Monte-Carlo, "
                  f"{pr['draws']} noise draws each, no refit):", "",
                  f"| candidate | designed |{f' {base} |' if pb else ''}",
                  "|---|---|" + ("---|" if pb else "")]
        for name, p in pr["per_candidate"].items():
            other = f" {_pct(pb['per_candidate'].get(name))} |" if pb else ""
            lines.append(f"| {name} | {_pct(p)} |{other}")
        lines += ["", f"Smallest pairwise divergence Σ(Δy/σ)²: designed {doc['min_divergence']:.3g}, "
                  f"{'seeded set points (the loop on the best candidate)' if ref else 'APRBS'} "
                  f"{doc['baseline_min_divergence']:.3g}."]
    else:
        if doc.get("angle_margin_rad"):
            lines += [f"The predicted angle keeps up to {doc['angle_margin_rad']:.3g} rad from the angle "
                      "limits (its 1σ under what the earlier recordings leave uncertain, at most a tenth "
                      "of the range, and the recorded angle's noise and quantum)"
                      + ("." if doc.get("angle_limits_assured", True) else
                         f"; **the limits are not assured**: the angle depends by up to "
                         f"{doc['angle_spread_rad']:.3g} rad (1σ) on parameters the earlier recordings do "
                         "not determine."), ""]
        lines += ["Predicted relative 1σ per parameter (Cramér-Rao, unit prior; a lower bound):", "",
                  f"| parameter | before | after the design | after the {base} |", "|---|---|---|---|"]
        for k in doc["parameters"]:
            lines.append(f"| {k} | {_pct(doc['sd_before'][k])} | {_pct(doc['sd_after'][k])} | "
                         f"{_pct(doc['sd_after_baseline'][k])} |")
    play = ("`controller --ros-args --params-file YOUR_CONTROLLER.yaml --params-file design_controller.yaml` "
            "with the rig and the recorder running (the set points start at the controller's first sample)"
            if ref else "`excitation --signal file --file design.csv --mode realtime` (or load the CSV on "
            "the lab's own controller)")
    lines += ["", f"Play it: {play}, record, then rerun `gap` / `rig fit` with the recording beside the "
              "earlier ones; `excitation_design --outcome NEW_GAP_REPORT --design THIS_FOLDER` compares.", ""]
    return "\n".join(lines)


def load_candidates(folder: Path) -> list[Candidate]:
    """The candidates of a discrimination design folder (rig files and measurement maps)."""
    doc = json.loads((folder / "design.json").read_text(encoding="utf-8"))
    out = []
    for row, rel in zip(doc["candidates"], doc.get("candidate_files", []), strict=True):
        meas = MeasurementMap(float(row["theta_offset"]), float(row["theta_scale"]))
        out.append(Candidate(row["name"], tuple(row["effects"]), load_rig(folder / rel), meas,
                             float(row["fit_sse"]) if row.get("fit_sse") is not None else math.nan,
                             row.get("values") or {}))
    return out


def compare_outcome(design: Mapping[str, Any], gap_report: Mapping[str, Any],
                    evidence: Mapping[str, Any] | None = None,
                    refit: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The design's prediction against what the rerun diagnosis (and the recording) showed.

    Parameters
    ----------
    design : mapping
        ``design.json`` of a discrimination design.
    gap_report : mapping
        ``report.json`` of ``gap`` rerun with the designed recording among its fit recordings.
    evidence : mapping, optional
        :func:`aeropend_ident.design.discriminate.evidence` of the candidates on the designed
        recording.

    Returns
    -------
    dict
        ``chosen_after`` (effects), ``matching_candidate`` (the candidate with exactly those
        effects, or None), ``predicted_first`` (its predicted probability of ranking first),
        ``chosen_before``, ``changed`` (the chosen set changed), ``separated`` (candidates the new
        diagnosis excludes), and with ``evidence`` the candidate the recording ranks first, the
        χ² per candidate, and its verdict (:func:`aeropend_ident.design.discriminate.verdict`):
        ``recording_names`` (the effects the recording names, None when the survivors are not
        separated), ``not_separated`` (the candidates it does not refute), ``refuted_p`` and
        ``recording_best_rms_over_noise`` and ``recording_unexplained`` (far above 1: a gap no
        candidate explains, refit with ``gap``; above
        :data:`~aeropend_ident.design.discriminate.UNEXPLAINED_RMS` the recording names nothing
        as sized and a ``note`` says why). With ``refit`` (the candidates refitted on the earlier
        recordings and the designed one,
        :func:`~aeropend_ident.design.discriminate.refit_evidence`, or ``{"skipped": why}``):
        ``refit`` holds what it names, its survivors, refutations and misfit, and
        ``recording_names`` becomes its answer (``recording_names_as_sized`` keeps the first).
        ``special_case_note`` says why, when the answer is a special case named over survivors
        whose richer effect nests it (the verdict's ``gave_way``).
    """
    chosen, _ranking = diagnosis_view(gap_report)
    refitted = refit is not None and "skipped" not in refit
    cands = design["candidates"]
    match = next((c["name"] for c in cands if set(c["effects"]) == set(chosen)), None)
    pred = design["predicted"]["per_candidate"]
    before = list(cands[0]["effects"]) if design.get("chosen_first", True) and cands else []
    out: dict[str, Any] = {
        "chosen_before": design.get("chosen_before", before), "chosen_after": chosen,
        "matching_candidate": match, "predicted_first": pred.get(match) if match else None,
        "changed": set(chosen) != set(design.get("chosen_before", before)),
        "separated": [c["name"] for c in cands if c["name"] != match],
    }
    if evidence is not None:
        out["recording_first"] = evidence["first"]
        out["recording_chi2"] = dict(evidence["chi2"])
        out["recording_agrees_with_gap"] = evidence["first"] == match if match else None
        out["recording_names"] = evidence.get("named_effects")
        out["not_separated"] = list(evidence.get("survivors") or [])
        out["refuted_p"] = dict(evidence.get("refuted_p") or {})
        rms = evidence.get("best_rms_over_noise")
        out["recording_best_rms_over_noise"] = rms
        out["recording_unexplained"] = bool(evidence.get("unexplained"))
        if rms is not None and math.isfinite(rms) and rms > UNEXPLAINED_RMS:
            step = ("Refitted on the earlier recordings and the designed one: see refit" if refitted else
                    "Refit: run gap with the designed recording among the fit recordings")
            out["note"] = (f"every candidate, as fitted on the earlier recordings, misses the designed "
                           f"recording by {rms:.1f}x its noise RMS or more: it shows a gap none of them "
                           f"explains as sized, so it names none of them. {step}")
    if refit is not None:
        out["refit"] = _refit_summary(refit)
        if refitted:
            out["recording_names_as_sized"] = out.get("recording_names")
            out["recording_names"] = refit.get("named_effects")
    answer = refit if refitted else evidence
    note = _special_case_note(answer) if answer is not None else None
    if note:
        out["special_case_note"] = note
    return out


def _special_case_note(verdict: Mapping[str, Any]) -> str | None:
    """Why a verdict named a special case over survivors whose richer effect nests it (None when
    it did not)."""
    named = verdict.get("named")
    richer = [r for r, s in (verdict.get("gave_way") or {}).items() if s == named]
    if not named or not richer:
        return None
    share = 100 * MIN_EXPLAINED_SECOND
    return (f"{', '.join(richer)} also explains the recording, but a richer effect refutes the special "
            f"case it nests only by removing {share:.0f} % of its error second by second, and it did "
            f"not: the special case {named} is named")


def _refit_summary(refit: Mapping[str, Any]) -> dict[str, Any]:
    """``compare_outcome``'s ``refit`` entry."""
    if "skipped" in refit:
        return {"skipped": refit["skipped"]}
    return {"names": refit.get("named_effects"), "first": refit.get("first"),
            "not_separated": list(refit.get("survivors") or []),
            "refuted_p": dict(refit.get("refuted_p") or {}),
            "best_rms_over_noise": refit.get("best_rms_over_noise"),
            "unexplained": bool(refit.get("unexplained")),
            "free_settings": list(refit.get("refit_free_settings") or []),
            "sets_fitted": list(refit.get("refit_rows") or [])}

