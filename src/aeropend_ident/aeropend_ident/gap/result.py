"""Sim-to-real gap: the result of one diagnosis (:class:`GapResult`) and what is read from it.

:func:`aeropend_ident.gap.run.run_gap` builds a :class:`GapResult` from its stages; this module
holds the result and its derived views: the headline figures and ``report.json``
(:meth:`GapResult.headline`, :meth:`GapResult.as_dict`), the agreement of the where- and the
which-analysis (:func:`where_which_agreement`) and the corrected rig file
(:func:`corrected_rig_dict`). :mod:`aeropend_ident.gap.report` writes them,
:mod:`aeropend_ident.gap.figures` draws them.

No rclpy import, no matplotlib.
"""

from __future__ import annotations

import datetime as _dt
import math
import platform
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy

from aeropend_ident.gap.where_report import WhereReport
from aeropend_ident.greybox.parameters import THETA_OFFSET
from aeropend_ident.io.jsonutil import jsonable
from aeropend_sim.params import Rig, rig_to_dict
from aeropend_sim.recording import Recording


@dataclass
class GapResult:
    """Everything :func:`aeropend_ident.gap.run.run_gap` computed.

    Attributes
    ----------
    rig : Rig
        Nominal rig.
    rig_ref : str
        Rig name or file given (provenance).
    theta_offset : float
        θ_model − θ_recorded [rad].
    fit, held_out : list[Recording]
        Recordings used to find the effects / to prove them.
    split_rule : str
        How the held-out recordings were chosen.
    where : WhereReport
        Nominal rig on the fit recordings.
    where_heldout_nominal, where_heldout_corrected : WhereReport
        Nominal and corrected rig on the held-out recordings.
    diagnosis : Any
        :class:`aeropend_ident.gap.which.diagnosis.EffectDiagnosis`.
    overlays : list[dict]
        Per held-out recording: ``source``, ``t``, ``duty``, ``theta``, ``nominal``,
        ``corrected`` (arrays, recording frame) and their ``metrics``.
    fit_core, validation : list[Recording]
        What the effect diagnosis saw: it fits on ``fit_core`` and chooses / ranks the effects on
        ``validation`` (both carved from ``fit``); the held-out recordings stay unseen.
    test : list[dict]
        Held-out gap of the nominal rig (``effects`` = []) and of the corrected rig
        (:func:`aeropend_ident.gap.which.metrics.gap_metrics`: ``nrmse`` = mean over recordings, ...).
    prediction : dict, optional
        Predicted held-out θ NRMSE of the corrected rig with its 80 % interval, made from the fit
        data and the held-out duty (and its first second, where a replay's start is estimated)
        before the held-out replay (:func:`aeropend_ident.gap.drift.predict_heldout`).
    prediction_check : dict, optional
        The prediction against the actual held-out NRMSE (``inside`` the interval or not).
    attainable : list of dict, optional
        Per held-out recording: oracle fits and the split of its gap
        (:func:`aeropend_ident.gap.sessions.attainable`).
    sessions : dict, optional
        Leave-one-session-out diagnosis and drift table
        (:func:`aeropend_ident.gap.sessions.session_analysis`).
    refit : dict, optional
        The corrected rig against a plain refit of the nominal parameters on the held-out
        recordings (:func:`aeropend_ident.gap.drift.refit_comparison`).
    not_computed : dict
        Optional sections (sessions, prediction, refit comparison, attainable shrink) that could
        not be computed, with the reason; the rest of the result stands.
    bound_notes : list of str
        Parameters ``rig fit`` left at a search bound and the effects confirmed for them
        (:func:`aeropend_ident.gap.run.bound_effects`).
    tables : list of dict
        Static tables given beside the recordings (balance / thrust tables, as ``rig fit`` takes
        them), each checked against the nominal and the corrected rig
        (:func:`aeropend_ident.gap.run.static_table_check`).
    """

    rig: Rig
    rig_ref: str
    theta_offset: float
    fit: list[Recording]
    held_out: list[Recording]
    split_rule: str
    where: WhereReport
    where_heldout_nominal: WhereReport
    where_heldout_corrected: WhereReport
    diagnosis: Any
    overlays: list[dict[str, Any]]
    fit_core: list[Recording] = field(default_factory=list)
    validation: list[Recording] = field(default_factory=list)
    test: list[dict[str, Any]] = field(default_factory=list)
    agreement: dict[str, Any] = field(default_factory=dict)
    prediction: dict[str, Any] | None = None
    prediction_check: dict[str, Any] | None = None
    attainable: list[dict[str, Any]] | None = None
    sessions: dict[str, Any] | None = None
    refit: dict[str, Any] | None = None
    not_computed: dict[str, str] = field(default_factory=dict)
    tables: list[dict[str, Any]] = field(default_factory=list)
    bound_notes: list[str] = field(default_factory=list)

    # ------------------------------------------------------------------ headline
    def significance_why(self) -> str:
        """Why the gap is (not) significant, from both analyses, so that a "yes" beside a
        where-analysis that flags no equation says which analysis found it (issue 60)."""
        w, d = self.where, self.diagnosis
        flagged = [r["equation"] for r in w.located if r["flagged"]]
        if w.significant and flagged:
            where = (f"the free-run residual is not white beyond the noise floor and the "
                     f"{', '.join(flagged)} equation(s) miss part of their driving term")
        elif w.significant:
            where = ("the free-run residual is not white beyond the noise floor, but no equation misses "
                     "enough of its driving term to be flagged (a gap too small or too spread to locate)")
        else:
            where = "the free-run residual is white or within the noise/resolution floor"
        which = d.reason or ("a candidate effect explains part of the validation error" if d.significant
                             else "no candidate effect explains the validation error beyond its noise")
        return f"where-analysis: {where}; effect screening: {which}"

    def headline(self) -> dict[str, Any]:
        """Held-out (test) NRMSE before/after: mean over held-out recordings of
        RMS(θ_sim − θ_meas)/range(θ_meas), the nominal and the corrected rig."""
        before = float(self.test[0]["nrmse"])
        after = float(self.test[-1]["nrmse"])
        # a run that diverges on held-out data: its NRMSE measures how far it went, so no shrink
        rows = (("nominal", self.test[0]), ("corrected", self.test[-1]))
        gone = {label: row.get("diverges") for label, row in rows if row.get("diverges")}
        d = self.diagnosis
        ch0, ch1 = self.test[0].get("channel_nrmse", {}), self.test[-1].get("channel_nrmse", {})
        return {
            "significant_gap": bool(self.where.significant or d.significant),
            "significant_gap_why": self.significance_why(),
            "where_subsystem": self.where.subsystem,
            "effects_chosen": list(d.chosen),
            "detected": dict(getattr(d, "detected", {})),
            # the one free run's figures (greybox.replay.free_run): none for a run that diverges
            "heldout_nrmse_nominal": None if "nominal" in gone else before,
            "heldout_nrmse_corrected": None if "corrected" in gone else after,
            "heldout_shrink": None if gone else ((1.0 - after / before) if before > 0 else math.nan),
            # the NRMSE a perfect model would have on these held-out recordings: their measured θ
            # noise over their ranges (a decay come to rest is pure noise: NRMSE ~ 1/range in σ)
            "heldout_noise_floor_nrmse": self.test[0].get("noise_floor_nrmse"),
            "heldout_divergence": gone,
            "heldout_free_run": {label: row.get("free_run", []) for label, row in rows},
            "heldout_channel_nrmse_nominal": dict(ch0),
            "heldout_channel_nrmse_corrected": dict(ch1),
            "heldout_channel_shrink": {} if gone else {c: (1.0 - ch1[c] / v) if v > 0 else math.nan
                                                       for c, v in ch0.items() if c in ch1},
            "explained": getattr(d, "explained", {}).get("verdict", ""),
            "completeness": getattr(d, "explained", {}).get("completeness"),
            "refit": ({k: self.refit[k] for k in ("refit_nrmse", "corrected_nrmse", "worse_than_refit")}
                      if self.refit else None),
            "where_which_agree": self.agreement.get("agree"),
            "n_fit_recordings": len(self.fit),
            "n_heldout_recordings": len(self.held_out),
            "heldout_never_seen_by_diagnosis": bool(self.validation is not self.held_out),
        }

    def as_dict(self) -> dict[str, Any]:
        """What ``report.json`` holds."""
        return jsonable(
            {
                "tool": "aeropend_ident gap",
                "headline": self.headline(),
                "where": self.where.as_dict(),
                "which": self.diagnosis.as_dict(),
                "where_which": self.agreement,
                "sessions": self.sessions,
                "prediction": self.prediction,
                "not_computed": self.not_computed,
                "static_tables": self.tables,
                "rig_fit_bound_flags": self.bound_notes,
                "after": {
                    "refit": self.refit,
                    "prediction_check": self.prediction_check,
                    "attainable": self.attainable,
                    "heldout_nominal": _where_brief(self.where_heldout_nominal),
                    "heldout_corrected": _where_brief(self.where_heldout_corrected),
                    "overlay_metrics": [{"source": o["source"], **o["metrics"]} for o in self.overlays],
                    "test": self.test,
                },
                "inputs": {
                    "rig": {
                        "ref": self.rig_ref,
                        "name": self.rig.name,
                        "description": self.rig.description,
                        "effects": dict(vars(self.rig.effects)),
                    },
                    "theta_offset_rad": self.theta_offset,
                    "split_rule": self.split_rule,
                    "fit": [_rec_info(r) for r in self.fit],
                    "held_out": [_rec_info(r) for r in self.held_out],
                    "diagnosis_fit": [_rec_info(r) for r in self.fit_core],
                    "diagnosis_validation": [_rec_info(r) for r in self.validation],
                },
                "provenance": {
                    "created_utc": _dt.datetime.now(_dt.UTC).isoformat(),
                    "versions": {
                        "python": platform.python_version(),
                        "numpy": np.__version__,
                        "scipy": scipy.__version__,
                    },
                },
            }
        )


def _label(source: str) -> str:
    """Short label of a recording source: the file name for files (and their slices), else as is."""
    return Path(source).name if Path(source.split("[")[0]).exists() else source


def _rec_info(r: Recording) -> dict[str, Any]:
    return {
        "source": r.source,
        "n_samples": len(r),
        "duration_s": float(r.t[-1] - r.t[0]),
        "dt_s": r.dt,
        "channels": sorted(r.channels),
    }


def _where_brief(w: WhereReport) -> dict[str, Any]:
    return {
        "significant": w.significant,
        "subsystem": w.subsystem,
        "located": w.located,
        "verdict": w.verdict(),
        "recordings": [
            {
                "source": r.source,
                "free_run": r.free_run,
                "short_horizon": r.short_horizon,
                "whiteness_p": r.whiteness["p_value"],
                "input_xcorr_p": r.input_xcorr["p_value"],
                "significant": r.significant,
            }
            for r in w.recordings
        ],
    }


#: Where-analysis equation of each state equation a catalog effect's signature reaches.
_EQUATION_OF_TERM = {"v_a": "actuator", "i_a": "armature", "omega_rotor": "rotor", "theta_dot": "pendulum"}


def where_which_agreement(where: WhereReport, diag: Any) -> dict[str, Any]:
    """Do the where-analysis (equation errors) and the which-analysis (chosen effects) agree?

    They agree when an equation the where-analysis flags is one whose right-hand side the first
    chosen effect changes (its catalog term group). Otherwise the returned ``explanation`` says
    why they may disagree (nothing flagged: a gap below the equation-error floors that the free-run
    output error still resolves; a sensor effect, which distorts the recorded angle rather than an
    equation; an upstream effect seen downstream through simulated signals).

    Returns
    -------
    dict
        ``agree`` (bool or None when nothing was chosen), ``where_equations`` (flagged),
        ``which_effect``, ``which_equations`` (equations its signature reaches), ``explanation``.
    """
    from aeropend_ident.gap.effects import get_effect

    flagged = [r["equation"] for r in where.located if r["flagged"]]
    chosen = list(getattr(diag, "chosen", []))
    if not chosen:
        note = (f"; the where-analysis flags {', '.join(flagged)}: a gap no catalog effect removes "
                "significantly") if flagged else ""
        return {"agree": None, "where_equations": flagged, "which_effect": None, "which_equations": [],
                "explanation": "no effect chosen" + note}
    eff = get_effect(chosen[0])
    eqs = [_EQUATION_OF_TERM[k] for k in eff.terms if k in _EQUATION_OF_TERM]
    agree = any(f in eqs for f in flagged)
    if agree:
        why = (f"the where-analysis flags the {', '.join(f for f in flagged if f in eqs)} equation, which "
               f"{eff.name} changes")
    elif not flagged:
        why = ("the where-analysis flags no equation (each residual is within its noise and method floors); "
               f"{eff.name} was found from the free-run output error, which integrates a small equation "
               "error")
    elif eff.kind == "measurement":
        why = (f"{eff.name} distorts the recorded angle, so every equation evaluated on it shows a residual "
               f"(flagged: {', '.join(flagged)})")
    else:
        why = (f"the where-analysis flags {', '.join(flagged)}, {eff.name} acts on {', '.join(eqs)}: the "
               "located equation sees the effect only through simulated upstream signals, or the effect "
               "stands in for one the catalog lacks")
    return {"agree": agree, "where_equations": flagged, "which_effect": eff.name, "which_equations": eqs,
            "explanation": why}


# --------------------------------------------------------------------------- corrected rig file
def corrected_rig_dict(result: GapResult) -> dict[str, Any]:
    """The corrected rig in the rig-file format; the changed numbers' sources name the diagnosis.

    When the data do not separate a chosen sensor-frame effect from a plant-side one
    (``diagnosis.plant_side``, :func:`aeropend_ident.gap.which.ranking.plant_side_alternative`), the file
    holds the plant-side alternative, jointly fitted with the other chosen effects, and the
    nominal sensor frame: a controller designed on it then holds the angle the nominal rig file
    would, never one off by an unconfirmed sensor gain. The description says so.
    """
    diag, nominal = result.diagnosis, result.rig
    side = diag.plant_side
    rig, meas = (side["rig"], side["measurement"]) if side else (diag.corrected_rig, diag.measurement)
    data = rig_to_dict(rig)
    base = rig_to_dict(nominal)
    names = [side["by"] if side and n == side["replaces"] else n for n in diag.chosen]
    chosen = ", ".join(names) or "none"
    data["name"] = f"{nominal.name}_corrected"
    data["description"] = (
        f"{nominal.description} -- corrected by the gap diagnosis (aeropend_ident gap): "
        f"effects added: {chosen}"
        + (f" ({side['by']} written for {side['replaces']}, which these data do not separate from it: "
           f"sensor frame kept nominal; check the angle sensor's calibration)" if side else "")
    )
    fits = ", ".join(_label(r.source) or "recording" for r in result.fit)
    from aeropend_ident.gap.effects import get_effect

    detected = dict(getattr(diag, "detected", {}))
    by_detection = {p.rig_field: name for name in detected for p in get_effect(name).parameters}
    if detected:
        data["description"] += "; detected from the recorded values (not fitted): " + ", ".join(
            f"{name} ({', '.join(f'{k} = {v:.6g}' for k, v in vals.items())})"
            for name, vals in detected.items())
    for section, fields in data.items():
        if not isinstance(fields, dict) or section == "effects":
            continue
        for key, node in fields.items():
            old = base.get(section, {}).get(key)
            if isinstance(node, dict) and isinstance(old, dict) and node.get("value") != old.get("value"):
                field_ = f"{section}.{key}"
                how = (f"gap diagnosis: {by_detection[field_]} detected from the recorded values of"
                       if field_ in by_detection else f"gap diagnosis ({chosen}) fitted on")
                node["source"] = f"{how} {fits}; nominal {old.get('value')!r} ({old.get('source', '')})"
    # the diagnosis' sensor map acts on θ_recorded + nominal offset: θ_rec + off_n = s·(θ_model − off_d),
    # i.e. θ_rec = s·(θ_model − (off_d + off_n/s)) in the rig file's convention
    scale = float(meas.theta_scale)
    offset = float(meas.theta_offset) + result.theta_offset / scale
    frame: dict[str, Any] = {}
    if offset != 0.0:
        frame[THETA_OFFSET] = {"value": offset, "unit": "rad", "source": (
            "gap diagnosis: fitted sensor offset" if meas.theta_offset != 0.0 else "nominal rig file")}
    if scale != 1.0:
        frame["theta_scale"] = {"value": scale, "unit": "1", "source": "gap diagnosis: fitted sensor gain"}
    if frame:
        data["recording_frame"] = frame
    return data
