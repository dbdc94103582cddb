"""Sim-to-real gap, part 3: run the whole diagnosis and report it (JSON, HTML, terminal).

:func:`run_gap` is the pipeline behind the ``gap`` command:

1. **where** — :func:`aeropend_ident.gap.where.locate_gap` of the nominal rig on the *fit*
   recordings (equation errors per subsystem, regions, bands, residual tests);
2. **which** — :func:`aeropend_ident.gap.which.diagnose_effects` screens, fits and ranks the
   catalog's unmodelled effects (:mod:`aeropend_ident.gap.effects`). It fits on the *fit core*
   and ranks / chooses on a *validation* part, both carved out of the fit recordings
   (:func:`validation_split`: train / validation / test), because the ranking itself selects on
   the data it is given;
3. **after** — the corrected rig is replayed on the **held-out** recordings, which neither step
   has seen (overlay and before/after NRMSE, :func:`aeropend_ident.gap.which.gap_metrics`), and
   :func:`~aeropend_ident.gap.where.locate_gap` is run again there, for the nominal and the
   corrected rig (does the residual become white, does the flagged equation clear?).

:func:`write_report` writes ``report.json`` (everything, machine-readable), ``report.html``
(one self-contained page: matplotlib PNGs embedded as base64), ``corrected_rig.yaml`` (loadable
by :func:`aeropend_sim.params.load_rig`) and the figures as PNG files; :func:`terminal_summary`
is the one-screen text summary.

No rclpy import; matplotlib is used with the Agg backend.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import json
import math
import platform
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy
import yaml

from aeropend_ident.errors import GapInputError
from aeropend_ident.gap.where import EQUATIONS, WhereReport, locate_gap
from aeropend_ident.greybox.fit import THETA_OFFSET, error_metrics
from aeropend_ident.io.jsonutil import jsonable
from aeropend_ident.io.split import (
    VALIDATION_FRACTION,
    validation_split,
)
from aeropend_sim.params import Rig, rig_to_dict
from aeropend_sim.recording import Recording

#: Most held-out recordings drawn in the overlay figure.
MAX_OVERLAYS = 3


@dataclass
class GapResult:
    """Everything :func:`run_gap` computed.

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
        :class:`aeropend_ident.gap.which.EffectDiagnosis`.
    overlays : list[dict]
        Per held-out recording: ``source``, ``t``, ``duty``, ``theta``, ``nominal``,
        ``corrected`` (arrays, recording frame) and their ``metrics``.
    fit_core, validation : list[Recording]
        What the effect diagnosis saw: it fits on ``fit_core`` and chooses / ranks the effects on
        ``validation`` (both carved from ``fit``); the held-out recordings stay unseen.
    test : list[dict]
        Held-out gap of the nominal rig (``effects`` = []) and of the corrected rig
        (:func:`aeropend_ident.gap.which.gap_metrics`: ``nrmse`` = mean over recordings, ...).
    prediction : dict, optional
        Predicted held-out θ NRMSE of the corrected rig with its 80 % interval, made from the fit
        data before the held-out replay (:func:`aeropend_ident.gap.drift.predict_heldout`).
    prediction_check : dict, optional
        The prediction against the actual held-out NRMSE (``inside`` the interval or not).
    attainable : list of dict, optional
        Per held-out recording: oracle fits and the split of its gap
        (:func:`aeropend_ident.gap.drift.attainable`).
    sessions : dict, optional
        Leave-one-session-out diagnosis and drift table
        (:func:`aeropend_ident.gap.drift.session_analysis`).
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

    # ------------------------------------------------------------------ headline
    def headline(self) -> dict[str, Any]:
        """Held-out (test) NRMSE before/after: mean over held-out recordings of
        RMS(θ_sim − θ_meas)/range(θ_meas), the nominal and the corrected rig."""
        before = float(self.test[0]["nrmse"])
        after = float(self.test[-1]["nrmse"])
        d = self.diagnosis
        ch0, ch1 = self.test[0].get("channel_nrmse", {}), self.test[-1].get("channel_nrmse", {})
        return {
            "significant_gap": bool(self.where.significant or d.significant),
            "where_subsystem": self.where.subsystem,
            "effects_chosen": list(d.chosen),
            "heldout_nrmse_nominal": before,
            "heldout_nrmse_corrected": after,
            "heldout_shrink": (1.0 - after / before) if before > 0 else math.nan,
            "heldout_channel_nrmse_nominal": dict(ch0),
            "heldout_channel_nrmse_corrected": dict(ch1),
            "heldout_channel_shrink": {c: (1.0 - ch1[c] / v) if v > 0 else math.nan
                                       for c, v in ch0.items() if c in ch1},
            "explained": getattr(d, "explained", {}).get("verdict", ""),
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
                "after": {
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


# --------------------------------------------------------------------------- pipeline
def _shift(rec: Recording, offset: float) -> Recording:
    """The recording with θ moved into the model frame (θ_model = θ_recorded + offset)."""
    if offset == 0.0:
        return rec
    ch = {**rec.channels, "theta": rec.channels["theta"] + offset}
    return Recording(
        t=rec.t, duty=rec.duty, channels=ch, source=rec.source, stamp0_ns=rec.stamp0_ns, meta=dict(rec.meta)
    )


def _overlay(rig: Rig, diag: Any, rec: Recording, offset: float) -> dict[str, Any]:
    """Held-out replay of the nominal and the corrected rig (the diagnosis' own replay, so the
    numbers match its shrink table), θ in the recording's frame."""
    from aeropend_ident.gap.effects import MeasurementMap
    from aeropend_ident.gap.which import prepare as which_prepare
    from aeropend_ident.gap.which import replay

    shifted = _shift(rec, offset)
    prep = which_prepare([shifted], frozenset({"theta"}))[0]
    nom = replay(rig, MeasurementMap(), prep)["theta"] - offset
    cor = replay(diag.corrected_rig, diag.measurement, prep)["theta"] - offset
    theta = rec.channels["theta"]
    return {
        "source": rec.source,
        "t": rec.t - rec.t[0],
        "duty": rec.duty,
        "theta": theta,
        "nominal": nom,
        "corrected": cor,
        "metrics": {"nominal": error_metrics(theta, nom), "corrected": error_metrics(theta, cor)},
    }


def run_gap(
    rig: Rig,
    fit: Sequence[Recording],
    held_out: Sequence[Recording],
    *,
    rig_ref: str = "",
    theta_offset: float = 0.0,
    split_rule: str = "",
    max_effects: int = 2,
    horizon: float = 0.2,
    seed: int = 0,
    validation_fraction: float = VALIDATION_FRACTION,
    validation: Sequence[Recording] | None = None,
    progress: Callable[[str], None] | None = None,
    sessions: Sequence[Sequence[Recording]] | None = None,
    session_labels: Sequence[str] | None = None,
    predict: bool = True,
    oracle: bool = False,
    drift_sigma: Mapping[str, float] | None = None,
) -> GapResult:
    """Where + which + after (module doc) for a nominal rig and fit / held-out recordings.

    Parameters
    ----------
    rig : Rig
        Nominal simulator.
    fit, held_out : sequence of Recording
        Recordings used to find the effects, and recordings used only to check them.
    rig_ref : str
        Rig name or path (provenance).
    theta_offset : float
        θ_model − θ_recorded [rad] (see :func:`aeropend_ident.greybox.fit.rig_theta_offset`).
    split_rule : str
        How the held-out set was chosen (provenance).
    max_effects : int
        Most effects added to the corrected rig (1, 2 or 3: each one after the first by the
        forward-selection step of :func:`aeropend_ident.gap.which.diagnose_effects`).
    horizon : float
        Short-horizon prediction length [s] of the where-analysis.
    seed : int
        Seed of the effect ranking's resampling.
    validation_fraction : float
        Share of the fit data the diagnosis uses to choose and rank the effects
        (:func:`validation_split`); the held-out recordings are then never seen before the final
        before/after. 0 hands the held-out recordings to the diagnosis as its validation set
        (then they also choose the effects: an optimistic before/after).
    validation : sequence of Recording, optional
        Explicit validation recordings (a different experiment than the fit recordings); then
        the whole fit recordings are the fit core and ``validation_fraction`` is ignored.
    progress : callable, optional
        Receives one-line progress messages.
    sessions : sequence of sequences of Recording, optional
        The fit recordings grouped by session (each recording of ``fit`` in exactly one group):
        adds the leave-one-session-out diagnosis and the drift table, whose measured drift then
        replaces the drift prior of the prediction (:mod:`aeropend_ident.gap.drift`).
    session_labels : sequence of str, optional
        Names of the sessions.
    predict : bool
        Predict the held-out NRMSE from the fit data before the held-out replay.
    oracle : bool
        Fit the best catalog set on each held-out recording (attainable shrink; the chosen set is
        refitted there in any case; the command line does this unless --no-oracle).
    drift_sigma : mapping, optional
        σ of the session-to-session log change per drift-prone parameter (default: the measured
        one with ``sessions``, else :data:`aeropend_ident.gap.drift.DRIFT_PRIOR`).

    Returns
    -------
    GapResult

    Raises
    ------
    aeropend_ident.gap.effects.GapError, aeropend_ident.gap.where.GapInputError
        Unusable recordings (no θ, NaNs, too short, constant input) or rig.
    """
    from aeropend_ident.gap.effects import MeasurementMap
    from aeropend_ident.gap.where import timing_lag_seen
    from aeropend_ident.gap.which import TIMING_EFFECTS, diagnose_effects, gap_metrics
    from aeropend_ident.gap.which import prepare as which_prepare

    say = progress or (lambda _msg: None)
    fit, held_out = list(fit), list(held_out)
    if not fit or not held_out:
        raise GapInputError(
            f"need fit and held-out recordings (got {len(fit)} fit, {len(held_out)} held out)"
        )
    say(f"where: nominal {rig.name} on {len(fit)} fit recording(s)")
    where = locate_gap(rig, fit, horizon=horizon, theta_offset=theta_offset)
    if validation is not None:
        fit_core, validation = fit, list(validation)
        if not validation:
            raise GapInputError("validation recordings given but empty")
    elif validation_fraction > 0.0:
        fit_core, validation = validation_split(fit, validation_fraction)
    else:
        fit_core, validation = fit, held_out
    say(
        f"which: screening and fitting the effect catalog ({len(fit_core)} fit / {len(validation)} "
        "validation recording(s))"
    )
    # the diagnosis works in the model's angle frame: shift θ by the rig's recording-frame offset
    # a clear lead/lag of the simulated response (alignment lag) asks the diagnosis to confirm
    # the timing effects even when the θ̈-equation screening does not shortlist them
    timing = any(timing_lag_seen(r.alignment) for r in where.recordings)
    diag = diagnose_effects(
        rig,
        [_shift(r, theta_offset) for r in fit_core],
        [_shift(r, theta_offset) for r in validation],
        max_effects=max_effects,
        seed=seed,
        progress=progress,
        also_confirm=TIMING_EFFECTS if timing else (),
    )
    corrected = diag.corrected_rig
    from aeropend_ident.gap.drift import attainable, predict_heldout, session_analysis

    sess = None
    if sessions is not None:
        say(f"sessions: {len(sessions)} sessions, leave-one-session-out and drift table")
        sess = session_analysis(rig, [[_shift(r, theta_offset) for r in g] for g in sessions], diag.chosen,
                                labels=session_labels, channels=diag.channels or ("theta",),
                                max_effects=max_effects, seed=seed, progress=progress)
        if drift_sigma is None and sess["drift_sigma"]:
            drift_sigma = sess["drift_sigma"]
    prediction = None
    if predict:
        say("predict: held-out NRMSE of the corrected rig from the fit data")
        prediction = predict_heldout(rig, diag, [_shift(r, theta_offset) for r in validation],
                                     drift_sigma=drift_sigma, seed=seed)
        if sess is not None and drift_sigma is sess["drift_sigma"]:
            prediction["drift_source"] = "sessions"
        prediction["saw_heldout"] = validation is held_out
    say("after: replaying the held-out recordings")
    overlays = [_overlay(rig, diag, r, theta_offset) for r in held_out]
    preps = which_prepare([_shift(r, theta_offset) for r in held_out], frozenset(diag.channels or ("theta",)))
    test = [{"effects": [], **gap_metrics(rig, MeasurementMap(), preps)}]
    if diag.chosen:
        test.append({"effects": list(diag.chosen), **gap_metrics(corrected, diag.measurement, preps)})
    w_nom = locate_gap(rig, held_out, horizon=horizon, theta_offset=theta_offset)
    # the corrected rig's where-analysis in the model frame of the diagnosis (sensor offset included)
    meas = getattr(diag, "measurement", None)
    off_c = theta_offset + (float(meas.theta_offset) if meas is not None else 0.0)
    w_cor = locate_gap(corrected, held_out, horizon=horizon, theta_offset=off_c)
    check = None
    if prediction is not None:
        actual = float(test[-1]["nrmse"])
        lo, hi = prediction["interval"]
        check = {"predicted": prediction["predicted"], "interval": [lo, hi], "actual": actual,
                 "inside": bool(lo <= actual <= hi),
                 "verdict": ("inside the predicted 80 % interval" if lo <= actual <= hi else
                             f"OUTSIDE the predicted 80 % interval ({'above' if actual > hi else 'below'})")}
    say("after: attainable shrink (correction and best catalog set fitted on each held-out recording)")
    attain = attainable(rig, diag, [_shift(r, theta_offset) for r in held_out], max_effects=max_effects,
                        seed=seed, best_set=oracle, fit=[_shift(r, theta_offset) for r in fit],
                        progress=progress)
    return GapResult(
        rig=rig,
        rig_ref=rig_ref or rig.name,
        theta_offset=theta_offset,
        fit=fit,
        held_out=held_out,
        fit_core=fit_core,
        validation=validation,
        test=test,
        split_rule=split_rule,
        where=where,
        where_heldout_nominal=w_nom,
        where_heldout_corrected=w_cor,
        diagnosis=diag,
        overlays=overlays,
        agreement=where_which_agreement(where, diag),
        prediction=prediction,
        prediction_check=check,
        attainable=attain,
        sessions=sess,
    )


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
    chosen = [c for c in getattr(diag, "chosen", []) if c != "quantisation"]
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
    """The corrected rig in the rig-file format; the changed numbers' sources name the diagnosis."""
    rig, nominal = result.diagnosis.corrected_rig, result.rig
    data = rig_to_dict(rig)
    base = rig_to_dict(nominal)
    chosen = ", ".join(result.diagnosis.chosen) or "none"
    data["name"] = f"{nominal.name}_corrected"
    data["description"] = (
        f"{nominal.description} -- corrected by the gap diagnosis (aeropend_ident gap): "
        f"effects added: {chosen}"
    )
    fits = ", ".join(_label(r.source) or "recording" for r in result.fit)
    for section, fields in data.items():
        if not isinstance(fields, dict) or section == "effects":
            continue
        for key, node in fields.items():
            old = base.get(section, {}).get(key)
            if isinstance(node, dict) and isinstance(old, dict) and node.get("value") != old.get("value"):
                node["source"] = (
                    f"gap diagnosis ({chosen}) fitted on {fits}; nominal {old.get('value')!r} "
                    f"({old.get('source', '')})"
                )
    # the diagnosis' sensor map acts on θ_recorded + nominal offset: θ_rec + off_n = s·(θ_model − off_d),
    # i.e. θ_rec = s·(θ_model − (off_d + off_n/s)) in the rig file's convention
    meas = result.diagnosis.measurement
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


# --------------------------------------------------------------------------- figures
def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    _plt().close(fig)
    return buf.getvalue()


def fig_overlay(result: GapResult) -> bytes:
    """Held-out recordings: measured θ, nominal and corrected free run; duty below."""
    plt = _plt()
    ovs = result.overlays[:MAX_OVERLAYS]
    fig, axes = plt.subplots(
        2 * len(ovs),
        1,
        figsize=(11, 3.6 * len(ovs)),
        squeeze=False,
        height_ratios=[3, 1] * len(ovs),
        constrained_layout=True,
    )
    for j, o in enumerate(ovs):
        ax, axu = axes[2 * j, 0], axes[2 * j + 1, 0]
        ax.plot(o["t"], o["theta"], color="black", lw=1.2, label="recorded (held out)")
        ax.plot(o["t"], o["nominal"], color="tab:orange", lw=1.0, ls="--", label="nominal simulator")
        ax.plot(o["t"], o["corrected"], color="tab:blue", lw=1.0, label="corrected simulator")
        m = o["metrics"]
        ax.set_title(
            f"{_label(o['source'])}: NRMSE nominal {m['nominal']['nrmse']:.4f} -> corrected "
            f"{m['corrected']['nrmse']:.4f}",
            fontsize=9,
        )
        ax.set_ylabel("θ [rad]")
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3)
        axu.step(o["t"], o["duty"], where="post", color="tab:green", lw=1.0)
        axu.set_ylabel("duty τ [1]")
        axu.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time t [s] (from the held-out part's start)")
    return _png(fig)


def fig_equations(where: WhereReport) -> bytes:
    """Relative equation residual per state equation (bars) and the residual time series."""
    plt = _plt()
    rec = where.recordings[0]
    checked = [e for e in rec.equations if e.checked]
    fig, axes = plt.subplots(
        1 + len(checked), 1, figsize=(11, 2.4 * (1 + len(checked))), squeeze=False, constrained_layout=True
    )
    ax = axes[0, 0]
    names = [f"{r['equation']}\n({r['subsystem']})" for r in where.located]
    vals = [r["relative"] for r in where.located]
    colors = ["tab:red" if r["flagged"] else "tab:gray" for r in where.located]
    ax.bar(names, vals, color=colors)
    for k, r in enumerate(where.located):
        ax.text(k, vals[k], f" {vals[k]:.1%}\n top: {r['top_group']}", ha="center", va="bottom", fontsize=8)
    miss = ", ".join(nc["equation"] for nc in where.not_checked)
    ax.set_title(
        "equation residual / driving term (red = flagged)" + (f"; not checked: {miss}" if miss else ""),
        fontsize=9,
    )
    ax.set_ylabel("relative residual [1]")
    ax.set_ylim(0, max([*vals, 0.01]) * 1.5)
    for j, e in enumerate(checked, start=1):
        a = axes[j, 0]
        a.plot(rec.t, e.residual, lw=0.7, color="tab:red" if e.flagged else "tab:gray")
        a.axhline(0, color="black", lw=0.5)
        a.set_ylabel(f"{e.equation}\n[{e.unit}]")
        a.set_title(
            f"{e.equation} equation residual on {_label(rec.source)} (RMS {e.rms:.3g} {e.unit}, "
            f"method floor {e.method_floor:.3g}, noise floor {e.noise_floor:.3g})",
            fontsize=8,
        )
        a.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time t [s]")
    return _png(fig)


def fig_regions(where: WhereReport) -> bytes:
    """Free-run residual per θ, duty and |θ̇| bin, transient vs steady, and per frequency band."""
    plt = _plt()
    rec = where.recordings[0]
    reg = rec.regions
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), constrained_layout=True)
    for ax, key, label in (
        (axes[0, 0], "theta_bins", "θ [rad]"),
        (axes[0, 1], "duty_bins", "duty τ [1]"),
        (axes[0, 2], "rate_bins", "|θ̇| [rad/s]"),
    ):
        bins = reg[key]
        centres = [0.5 * (b["lower"] + b["upper"]) for b in bins]
        width = [(b["upper"] - b["lower"]) * 0.9 or 0.01 for b in bins]
        rms = [b["rms_residual"] or 0.0 for b in bins]
        mean = [b["mean_residual"] or 0.0 for b in bins]
        ax.bar(centres, rms, width=width, color="tab:orange", alpha=0.6, label="RMS")
        ax.bar(centres, mean, width=[w * 0.5 for w in width], color="tab:blue", label="mean")
        ax.set_xlabel(label)
        ax.set_ylabel("residual θ_sim − θ_meas [rad]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    mo = reg["motion"]
    ax = axes[1, 0]
    ax.bar(
        ["transient", "steady"],
        [mo["transient"]["rms_residual"] or 0.0, mo["steady"]["rms_residual"] or 0.0],
        color="tab:orange",
    )
    ax.set_ylabel("RMS residual [rad]")
    ax.set_title(f"|θ̇| threshold {reg['rate_threshold']} rad/s", fontsize=9)
    ax = axes[1, 1]
    bands = [b for b in rec.bands if "residual_power_fraction" in b]
    ax.bar(
        [f"{b['band']}\n{b['f_lo_hz']:.2g}-{b['f_hi_hz']:.2g} Hz" for b in bands],
        [b["residual_power_fraction"] for b in bands],
        color="tab:purple",
    )
    ax.set_ylabel("share of residual power")
    ax.tick_params(axis="x", labelsize=7)
    ax = axes[1, 2]
    holds = rec.holds
    if holds:
        ax.plot([h["duty"] for h in holds], [h["theta_meas_ss"] for h in holds], "ko", label="recorded")
        ax.plot(
            [h["duty"] for h in holds],
            [h["theta_sim_ss"] for h in holds],
            "x",
            color="tab:orange",
            label="nominal",
        )
        ax.set_xlabel("duty τ [1]")
        ax.set_ylabel("steady θ [rad]")
        ax.legend(fontsize=8)
        ax.set_title("steady state per constant-duty hold", fontsize=9)
    else:
        ax.text(0.5, 0.5, "no constant-duty hold >= 1 s", ha="center", va="center")
    ax.grid(alpha=0.3)
    fig.suptitle(f"free-run residual by operating region: {_label(rec.source)}", fontsize=10)
    return _png(fig)


def fig_tests(where: WhereReport) -> bytes:
    """Residual autocorrelation (Ljung-Box) and input-residual cross-correlation with bounds."""
    plt = _plt()
    rec = where.recordings[0]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 3.4), constrained_layout=True)
    acf = rec.whiteness["acf"]
    n = rec.t.size
    a1.bar(np.arange(1, len(acf) + 1), acf, color="tab:blue")
    b = 2.58 / math.sqrt(n)
    a1.axhline(b, color="red", ls=":")
    a1.axhline(-b, color="red", ls=":")
    a1.set_title(
        f"residual autocorrelation: Ljung-Box Q = {rec.whiteness['q']:.3g}, "
        f"p = {rec.whiteness['p_value']:.3g}",
        fontsize=9,
    )
    a1.set_xlabel("lag [samples]")
    xc = rec.input_xcorr
    if xc["lags"]:
        a2.plot(np.array(xc["lags"]) * rec.dt, xc["rho"], color="tab:green")
        a2.axhline(xc["bound"], color="red", ls=":")
        a2.axhline(-xc["bound"], color="red", ls=":")
        a2.axvline(xc["peak_lag_s"], color="black", lw=0.8)
    a2.set_title(
        f"input-residual cross-correlation (prewhitened): peak {xc['max_abs']:.3f} at "
        f"{xc['peak_lag_s']} s, p = {xc['p_value']:.3g}",
        fontsize=9,
    )
    a2.set_xlabel("lag [s] (> 0: residual follows input)")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    return _png(fig)


def fig_effects(result: GapResult) -> bytes:
    """Ranked effects (score and validation explained) and the before/after NRMSE per effect set."""
    plt = _plt()
    d = result.diagnosis
    rank = list(d.ranking)[:8]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 3.8), constrained_layout=True)
    if rank:
        names = [r["effect"] for r in rank][::-1]
        expl = [float(r.get("validation_explained") or 0.0) for r in rank][::-1]
        conf = [float(r.get("confidence") or 0.0) for r in rank][::-1]
        y = np.arange(len(names))
        a1.barh(y, expl, color="tab:blue", label="validation explained")
        a1.scatter(conf, y, color="black", marker="D", label="confidence", zorder=3)
        a1.set_yticks(y, names, fontsize=8)
        a1.set_xlabel("fraction [1]")
        a1.legend(fontsize=8)
    a1.set_title("ranked effects (best on top)", fontsize=9)
    rows = [("validation", r) for r in d.validation] + [("HELD OUT", r) for r in result.test]
    if rows:
        labels = [
            f"{part}\n" + ("nominal" if not r["effects"] else "+" + "+".join(r["effects"]))
            for part, r in rows
        ]
        colors = [("tab:orange" if not r["effects"] else "tab:blue") for _, r in rows]
        alpha = [0.45 if part == "validation" else 1.0 for part, _ in rows]
        bars = a2.bar(labels, [r["nrmse"] for _, r in rows], color=colors)
        for b, al in zip(bars, alpha, strict=True):
            b.set_alpha(al)
        a2.set_ylabel("NRMSE [1]")
        a2.tick_params(axis="x", labelsize=7)
    a2.set_title("NRMSE as effects are added: validation (chooses) and held out (never seen)", fontsize=9)
    for a in (a1, a2):
        a.grid(alpha=0.3)
    return _png(fig)


def figures(result: GapResult) -> dict[str, bytes]:
    """All report figures as PNG bytes, keyed by file stem."""
    return {
        "overlay": fig_overlay(result),
        "equations": fig_equations(result.where),
        "regions": fig_regions(result.where),
        "tests": fig_tests(result.where),
        "effects": fig_effects(result),
    }


# --------------------------------------------------------------------------- text
def _fmt(v: Any, spec: str = ".4g") -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return format(v, spec) if math.isfinite(v) else "–"
    return str(v)


def terminal_summary(result: GapResult) -> str:
    """One-screen summary: verdict, located subsystem, ranked effects, before/after."""
    h = result.headline()
    d = result.diagnosis
    lines = [
        f"gap: nominal rig {result.rig.name}; {h['n_fit_recordings']} fit / "
        f"{h['n_heldout_recordings']} held-out recording(s) ({result.split_rule})",
        f"  significant gap: {'yes' if h['significant_gap'] else 'no'}",
        "  WHERE (nominal on fit recordings):",
    ]
    for row in result.where.located:
        mark = "!" if row["flagged"] else " "
        lines.append(
            f"   {mark} {row['equation']:9s} ({row['subsystem']:10s}) residual {row['relative']:7.1%} "
            f"of driving term; top terms: {row['top_group']}"
        )
    for nc in result.where.not_checked:
        lines.append(f"     {nc['equation']:9s} not checked: {nc['reason']}")
    r0 = result.where.recordings[0]
    lines.append(
        f"    free-run NRMSE {r0.free_run['nrmse']:.4f}, {result.where.recordings[0].horizon:g} s-ahead "
        f"NRMSE {r0.short_horizon['nrmse']:.4f}; Ljung-Box p {r0.whiteness['p_value']:.2g}; "
        f"alignment lag {r0.alignment['lag_s']:.3f} s"
    )
    lines.append("  WHICH (ranked effects; 'validation' = the part of the fit data that chooses them):")
    for r in list(d.ranking)[:5]:
        lines.append(
            f"    {r['effect']:22s} {r.get('subsystem', ''):12s} score {_fmt(r.get('score'), '.3g'):>8s} "
            f"validation explained {_fmt(r.get('validation_explained'), '.2f'):>5s} "
            f"confidence {_fmt(r.get('confidence'), '.2f')}"
        )
        if r.get("ambiguous_with"):
            lines.append(f"      not separated by these data from: {', '.join(r['ambiguous_with'])}")
    for ni in list(d.not_identifiable)[:4]:
        lines.append(f"    (not identifiable: {ni['effect']}: {ni['reason'][:70]})")
    lines.append(f"  chosen: {', '.join(d.chosen) or 'none'}")
    if getattr(d, "explained", None):
        lines.append(f"  explained: {d.explained['verdict']}")
    if result.agreement:
        lines.append(f"  WHERE vs WHICH: {result.agreement['explanation']}")
    lines.append("  VALIDATION (carved from the fit data; chooses the effects):")
    for row in d.validation:
        lines.append(f"    {('+'.join(row['effects']) or 'nominal'):40s} NRMSE {row['nrmse']:.4f}")
    if result.sessions:
        lines.append("  SESSIONS (leave one session out: effects chosen on the others, θ NRMSE on it):")
        for row in result.sessions["leave_one_out"]:
            lines.append(f"    {row['left_out'][:30]:30s} {'+'.join(row['chosen_on_others']) or 'none':32s} "
                         f"{row['nrmse_nominal']:.4f} -> {row['nrmse_corrected']:.4f} ({row['shrink']:.1%})")
        lines += _drift_lines(result.sessions["drift"])
    pr = result.prediction
    if pr:
        # one line, the screen is full: the NRMSE change of each drift-prone parameter alone at -σ / +σ
        sens = pr.get("sensitivity") or {}
        alone = ("; alone at -σ/+σ: " + ", ".join(f"{k} {a:.4f}/{b:.4f}" for k, (a, b) in sens.items())
                 if sens else "")
        lines.append(
            f"  PREDICTED held-out θ NRMSE of the corrected rig (fit data only): {pr['predicted']:.4f}, 80 % "
            f"interval [{pr['interval'][0]:.4f}, {pr['interval'][1]:.4f}] (within session "
            f"{pr['within_session']:.4f}, session drift {pr['drift_part']:.4f} from the "
            f"{pr['drift_source']}{alone})")
    lines.append("  HELD OUT (never seen by the diagnosis), NRMSE per recorded channel:")
    for row in result.test:
        per = "  ".join(f"{c} {v:.4f}" for c, v in row.get("channel_nrmse", {}).items())
        lines.append(f"    {('+'.join(row['effects']) or 'nominal'):40s} {per}")
    lines.append(
        f"  held-out NRMSE θ {h['heldout_nrmse_nominal']:.4f} -> {h['heldout_nrmse_corrected']:.4f} "
        f"(shrink {h['heldout_shrink']:.1%})"
        + "".join(f"; {c} {v:.1%}" for c, v in h["heldout_channel_shrink"].items() if c != "theta")
    )
    chk = result.prediction_check
    if chk:
        lines.append(f"  prediction check: actual {chk['actual']:.4f} {chk['verdict']}")
    for a in result.attainable or []:
        sp = a["split"]
        lines.append(
            f"  ATTAINABLE on {_label(a['source'] or 'held-out')[:40]}: nominal {a['nominal']:.4f}, "
            f"corrected {a['corrected']:.4f}, best constant-parameter fit there {a['oracle']:.4f}, "
            f"noise floor {a['noise_floor']:.4f}")
        lines.append(
            f"    held-out gap: removed {sp['removed']:.0%}, removable but not removed (session drift or "
            f"off parameters) {sp['removable_not_removed']:.0%}, not removable by the catalog "
            f"{sp['not_removable']:.0%}")
        if a.get("drift"):
            lines += _drift_lines(a["drift"])
    return "\n".join(lines)


def _drift_html(result: GapResult) -> str:
    """HTML of the prediction, its check, the attainable shrink and the drift tables."""
    parts = []
    pr, chk = result.prediction, result.prediction_check
    if pr:
        rows = [["predicted (fit data only)", _fmt(pr["predicted"]),
                 f"[{_fmt(pr['interval'][0])}, {_fmt(pr['interval'][1])}]", _fmt(pr["within_session"]),
                 f"{_fmt(pr['drift_part'])} ({pr['drift_source']})",
                 _fmt(chk["actual"]) if chk else "–", chk["verdict"] if chk else "–"]]
        parts.append("<h3>Predicted vs actual held-out θ NRMSE of the corrected rig</h3>" + _table(
            rows, ["", "predicted", "80 % interval", "within session", "session drift", "actual", "check"]))
    if result.attainable:
        rows = [[_label(a["source"] or "held-out"), _fmt(a["nominal"]), _fmt(a["corrected"]),
                 _fmt(a["oracle"]), _fmt(a["noise_floor"]), f"{a['split']['removed']:.0%}",
                 f"{a['split']['removable_not_removed']:.0%}", f"{a['split']['not_removable']:.0%}"]
                for a in result.attainable]
        parts.append("<h3>Attainable shrink: the held-out gap split</h3>" + _table(
            rows, ["recording", "nominal", "corrected", "best constant-parameter fit there", "noise floor",
                   "removed", "removable, not removed", "not removable"]))
    tables = [a["drift"] for a in result.attainable or [] if a.get("drift")]
    if result.sessions:
        tables.insert(0, result.sessions["drift"])
    for t in tables:
        rows = [[f"{r['effect']}.{r['parameter']}", " / ".join(
            f"{v:.4g} ± {sd:.2g}" for v, sd in zip(r["values"], r["std"], strict=True)), r["unit"],
            _change(r), _fmt(r["z"], ".1f"), "yes" if r["drifts"] else ""] for r in t["rows"]]
        parts.append(f"<h3>Parameter drift: {' vs '.join(_label(x) for x in t['sessions'])}</h3>" + _table(
            rows, ["parameter", "values ± std", "unit", "change", "z", "drifts"]))
    return "\n".join(parts)


def _change(row: dict[str, Any]) -> str:
    """A drift-table change: relative where the reference is a size, else absolute in the unit."""
    c = row.get("change")
    if c is not None and math.isfinite(c):
        return f"{c:+.1%}"
    return f"{row['abs_change']:+.4g} {row['unit']}"


def _drift_lines(table: dict[str, Any], top: int = 4) -> list[str]:
    """Terminal lines of a drift table (most significant rows)."""
    out = [f"    drift table ({' vs '.join(_label(x)[:24] for x in table['sessions'])}):"]
    for r in table["rows"][:top]:
        vals = " / ".join(f"{v:.4g}" for v in r["values"])
        out.append(f"      {'!' if r['drifts'] else ' '} {r['effect']}.{r['parameter']:14s} {vals} "
                   f"{r['unit']} change {_change(r)} (z {r['z']:.1f})")
    return out


def _step_text(sm: dict[str, Any]) -> str:
    """'simulated (recorded)' step metrics of the diagnosis' first step, or the flat entries."""
    sim, rec = sm.get("simulated"), sm.get("recorded")
    if isinstance(sim, dict) and isinstance(rec, dict):
        parts = [f"{k.replace('_', ' ')} {_fmt(sim.get(k), '.3g')} ({_fmt(rec.get(k), '.3g')})" for k in sim]
        t0 = sm.get("t_start")
        return (
            (f"step at {t0:.3g} s: " if isinstance(t0, (int, float)) else "")
            + ", ".join(parts)
            + " — simulated (recorded)"
        )
    return ", ".join(f"{k} {_fmt(v, '.3g')}" for k, v in sm.items() if not isinstance(v, dict))


def _table(rows: list[list[Any]], head: list[str]) -> str:
    th = "".join(f"<th>{html.escape(str(c))}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_fmt(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def html_page(result: GapResult, figs: dict[str, bytes]) -> str:
    """The self-contained HTML report (figures embedded as base64 PNG)."""
    h = result.headline()
    d = result.diagnosis
    w = result.where

    def img(key: str, alt: str) -> str:
        return f'<img alt="{alt}" src="data:image/png;base64,{base64.b64encode(figs[key]).decode()}">'

    verdict = "".join(f"<li>{html.escape(v)}</li>" for v in w.verdict())
    eq_rows = [
        [
            r["equation"],
            r["subsystem"],
            f"{r['relative']:.2%}",
            "yes" if r["flagged"] else "no",
            r["top_group"],
            r["top_group_subsystem"],
        ]
        for r in w.located
    ]
    eq_rows += [[nc["equation"], "", "not checked", "", nc["reason"], ""] for nc in w.not_checked]
    rec_rows = [
        [
            _label(r.source),
            r.free_run["nrmse"],
            r.short_horizon["nrmse"],
            r.whiteness["p_value"],
            r.input_xcorr["p_value"],
            r.input_xcorr["peak_lag_s"],
            r.alignment["lag_s"],
            "yes" if r.significant else "no",
        ]
        for r in w.recordings
    ]
    rank_rows = [
        [
            k + 1,
            r["effect"],
            r.get("subsystem"),
            r.get("score"),
            r.get("validation_explained"),
            r.get("bic_delta"),
            r.get("confidence"),
            "; ".join(
                f"{n} = {_fmt(p.get('value'))} ± {_fmt(p.get('std'), '.2g')} {p.get('unit', '')}"
                for n, p in (r.get("parameters") or {}).items()
            ),
        ]
        for k, r in enumerate(d.ranking)
    ]
    ni_rows = [[n["effect"], n["reason"]] for n in d.not_identifiable]
    shrink_rows = []
    for part, row in [("held out", r) for r in result.test] + [("validation", r) for r in d.validation]:
        sm = row.get("step_metrics") or {}
        shrink_rows.append(
            [
                part,
                "+".join(row["effects"]) or "nominal",
                row.get("nrmse"),
                row.get("max_error"),
                row.get("steady_state_error"),
                _step_text(sm),
            ]
        )
    after_rows = [
        [
            _label(o["source"]),
            o["metrics"]["nominal"]["nrmse"],
            o["metrics"]["corrected"]["nrmse"],
            o["metrics"]["nominal"]["max_abs_error"],
            o["metrics"]["corrected"]["max_abs_error"],
        ]
        for o in result.overlays
    ]
    chans = list(result.test[0].get("channel_nrmse", {}))
    channel_rows = [["+".join(row["effects"]) or "nominal", *[row["channel_nrmse"].get(c) for c in chans]]
                    for row in result.test]
    amb_rows = [[r["effect"], ", ".join(r["ambiguous_with"]),
                 "; ".join(f"{k}: validation explained {_fmt(v.get('validation_explained'), '.3f')}, "
                           + (f"first in {v['bootstrap_first']:.0%} of resamples" if v.get("bootstrap_first")
                              is not None else "as good in the joint fit with the other chosen effects")
                           for k, v in r.get("ambiguity", {}).items())]
                for r in d.ranking if r.get("ambiguous_with")]
    explained = getattr(d, "explained", {}) or {}
    wc = result.where_heldout_corrected
    wn = result.where_heldout_nominal
    white_rows = [
        [
            _label(a.source),
            a.whiteness["p_value"],
            b.whiteness["p_value"],
            "yes" if a.significant else "no",
            "yes" if b.significant else "no",
        ]
        for a, b in zip(wn.recordings, wc.recordings, strict=True)
    ]
    css = (
        "body{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em;color:#222}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;padding:3px 7px;"
        "font-size:13px}th{background:#eee}img{max-width:100%}.big{font-size:1.2em}"
    )
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>aeropend gap report: {html.escape(result.rig.name)}</title>
<style>{css}</style></head><body>
<h1>Sim-to-real gap report: {html.escape(result.rig.name)}</h1>
<p class="big">Held-out NRMSE <b>{h["heldout_nrmse_nominal"]:.4f}</b> (nominal) &rarr;
<b>{h["heldout_nrmse_corrected"]:.4f}</b> (corrected with {html.escape(", ".join(d.chosen) or "no effect")}):
shrink <b>{h["heldout_shrink"]:.1%}</b>. Significant gap: {"yes" if h["significant_gap"] else "no"};
located in: <b>{html.escape(str(h["where_subsystem"]))}</b>.</p>
<p>Rig {html.escape(result.rig_ref)}; {len(result.fit)} fit recording(s), {len(result.held_out)} held-out
recording(s) ({html.escape(result.split_rule)}). The held-out recordings were used neither to locate the gap
nor to choose or fit the effects: the diagnosis fitted on {len(result.fit_core)} part(s) of the fit recordings
and chose the effects on {len(result.validation)} validation part(s) carved from them.</p>
<h2>1. Before / after on held-out recordings</h2>
{img("overlay", "overlay")}
{
        _table(
            after_rows,
            [
                "recording",
                "NRMSE nominal",
                "NRMSE corrected",
                "max |e| nominal [rad]",
                "max |e| corrected [rad]",
            ],
        )
    }
{
        _table(
            shrink_rows,
            [
                "data",
                "effects added",
                "NRMSE (mean over recordings)",
                "max error [rad]",
                "steady-state error [rad]",
                "step metrics",
            ],
        )
    }
<h3>Held-out NRMSE per recorded channel</h3>
{_table(channel_rows, ["effects added", *[f"NRMSE {c}" for c in chans]])}
<h3>Residual tests on held-out data, nominal vs corrected</h3>
{
        _table(
            white_rows,
            ["recording", "Ljung-Box p nominal", "Ljung-Box p corrected", "gap nominal", "gap corrected"],
        )
    }
{_drift_html(result)}
<h2>2. Where: residual per state equation (fit recordings)</h2>
<ul>{verdict}</ul>
<p>Each state equation is evaluated on the measured signals; its residual is shown relative to the equation's
driving term (v<sub>a</sub> for the armature, K<sub>t</sub>i<sub>a</sub> for the rotor, (L/J)f for the
pendulum). The "top terms" column is the term group whose regressors explain most of the residual (R²).
Equations whose channels were not recorded cannot be checked.</p>
{_table(eq_rows, ["equation", "subsystem", "residual / driving term", "flagged", "top terms", "points to"])}
{img("equations", "equation residuals")}
{
        _table(
            rec_rows,
            [
                "recording",
                "free-run NRMSE",
                f"{w.recordings[0].horizon:g} s-ahead NRMSE",
                "Ljung-Box p",
                "input xcorr p",
                "xcorr peak lag [s]",
                "alignment lag [s]",
                "significant",
            ],
        )
    }
<h2>3. Where: residual by operating region, frequency band, residual tests</h2>
{img("regions", "regions")}
{img("tests", "residual tests")}
<h2>4. Which: ranked unmodelled effects</h2>
{img("effects", "effects")}
{
        _table(
            rank_rows,
            [
                "rank",
                "effect",
                "subsystem",
                "score",
                "validation explained",
                "ΔBIC",
                "confidence",
                "parameters",
            ],
        )
    }
<p>How completely the chosen effects explain the gap: {html.escape(explained.get("verdict", "–"))}
(worst channel {html.escape(str(explained.get("worst_channel", "–")))}: share of its above-noise
validation gap removed {_fmt(explained.get("share_above_noise"), ".3f")},
validation residual / its noise part: {_fmt(explained.get("residual_over_noise"), ".3g")}).</p>
<p>Where vs which: {html.escape(result.agreement.get("explanation", "–"))}.</p>
<h3>Effects these data do not separate</h3>
{_table(amb_rows, ["effect", "not separated from", "evidence"])}
<h3>Not identifiable from these recordings</h3>
{_table(ni_rows, ["effect", "reason"])}
<h2>5. Definitions</h2>
<ul>
<li>NRMSE = RMS(θ<sub>sim</sub> − θ<sub>meas</sub>) / (max θ<sub>meas</sub> − min θ<sub>meas</sub>),
free run from the recording's first samples, driven by the recorded duty cycle only.</li>
<li>Significant gap: the free-run residual fails the Ljung-Box whiteness test (p &lt; 0.01), its RMS exceeds
3&times; the measurement noise and the NRMSE exceeds 0.01.</li>
<li>Validation: the part of the fit recordings on which the diagnosis chooses and ranks the effects
("validation explained" = share of the nominal validation error an effect removes). Held out: the
recordings only replayed here, at the end.</li>
<li>Confidence: how often the effect comes first (or, for an added effect, passes its threshold) when the
validation segments are resampled, times the completeness of the chosen set (1 when it leaves the noise
level, 0 when more than a quarter of the gap above noise remains) (0..1).</li>
<li>Corrected rig: <code>corrected_rig.yaml</code> next to this page (load with
<code>aeropend_sim.params.load_rig</code>); the full numbers are in <code>report.json</code>.</li>
</ul>
</body></html>
"""


def write_report(result: GapResult, outdir: str | Path) -> dict[str, Path]:
    """Write ``report.json``, ``report.html``, ``corrected_rig.yaml`` and ``figures/*.png``.

    Returns
    -------
    dict
        Paths keyed ``report``, ``html``, ``corrected_rig`` and ``fig_<name>``.
    """
    out = Path(outdir)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    figs = figures(result)
    paths: dict[str, Path] = {}
    for k, png in figs.items():
        p = out / "figures" / f"{k}.png"
        p.write_bytes(png)
        paths[f"fig_{k}"] = p
    paths["report"] = out / "report.json"
    paths["report"].write_text(json.dumps(result.as_dict(), indent=2, allow_nan=False), encoding="utf-8")
    paths["html"] = out / "report.html"
    paths["html"].write_text(html_page(result, figs), encoding="utf-8")
    paths["corrected_rig"] = out / "corrected_rig.yaml"
    paths["corrected_rig"].write_text(
        yaml.safe_dump(jsonable(corrected_rig_dict(result)), sort_keys=False, allow_unicode=True),
        encoding="utf-8",
    )
    return paths


__all__ = [
    "EQUATIONS",
    "GapResult",
    "corrected_rig_dict",
    "figures",
    "html_page",
    "run_gap",
    "terminal_summary",
    "write_report",
]
