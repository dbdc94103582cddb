"""Sim-to-real gap, part 3: run the whole diagnosis (where, which, after).

:func:`run_gap` is the pipeline behind the ``gap`` command:

1. **where** — :func:`aeropend_ident.gap.where.locate_gap` of the nominal rig on the *fit*
   recordings (equation errors per subsystem, regions, bands, residual tests);
2. **which** — :func:`aeropend_ident.gap.which.diagnosis.diagnose_effects` screens, fits and ranks the
   catalog's unmodelled effects (:mod:`aeropend_ident.gap.effects`). It fits on the *fit core*
   and ranks / chooses on a *validation* part, both carved out of the fit recordings
   (:func:`aeropend_ident.io.split.carve_validation`: train / validation / test), because the
   ranking itself selects on the data it is given;
3. **after** — the corrected rig is replayed on the **held-out** recordings, which neither step
   has seen (overlay and before/after NRMSE, :func:`aeropend_ident.gap.which.metrics.gap_metrics`), and
   :func:`~aeropend_ident.gap.where.locate_gap` is run again there, for the nominal and the
   corrected rig (does the residual become white, does the flagged equation clear?).

The result (:class:`GapResult`, with its JSON form and :func:`corrected_rig_dict`) is written by
:mod:`aeropend_ident.gap.report` and drawn by :mod:`aeropend_ident.gap.figures`.

No rclpy import, no matplotlib.
"""

from __future__ import annotations

import datetime as _dt
import math
import platform
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy

from aeropend_ident.errors import GapInputError, IdentError
from aeropend_ident.gap.residual_tests import timing_lag_seen
from aeropend_ident.gap.where import WhereReport, locate_gap
from aeropend_ident.greybox.batch import single_blas
from aeropend_ident.greybox.fit import error_metrics
from aeropend_ident.greybox.parameters import THETA_OFFSET
from aeropend_ident.io.jsonutil import jsonable
from aeropend_ident.io.split import (
    VALIDATION_FRACTION,
    carve_validation,
)
from aeropend_sim.params import Rig, rig_to_dict
from aeropend_sim.recording import Recording


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
        (:func:`bound_effects`).
    tables : list of dict
        Static tables given beside the recordings (balance / thrust tables, as ``rig fit`` takes
        them), each checked against the nominal and the corrected rig (:func:`static_table_check`).
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


# --------------------------------------------------------------------------- pipeline
def to_model_frame(rec: Recording, offset: float) -> Recording:
    """The recording with θ moved into the model frame (θ_model = θ_recorded + offset)."""
    if offset == 0.0:
        return rec
    ch = {**rec.channels, "theta": rec.channels["theta"] + offset}
    return Recording(
        t=rec.t, duty=rec.duty, channels=ch, source=rec.source, stamp0_ns=rec.stamp0_ns, meta=dict(rec.meta)
    )


_shift = to_model_frame  # the short name of this module's calls


def _overlay(rig: Rig, diag: Any, rec: Recording, offset: float) -> dict[str, Any]:
    """Held-out replay of the nominal and the corrected rig (the one free run of every command,
    :func:`aeropend_ident.greybox.replay.free_run`, as in the held-out table), θ in the recording's frame."""
    from aeropend_ident.gap.effects import MeasurementMap
    from aeropend_ident.gap.which.data import prepare as which_prepare
    from aeropend_ident.gap.which.metrics import one_free_run

    shifted = _shift(rec, offset)
    prep = which_prepare([shifted], frozenset(diag.channels or ("theta",)))[0]
    runs = {"nominal": one_free_run(rig, MeasurementMap(), prep),
            "corrected": one_free_run(diag.corrected_rig, diag.measurement, prep)}
    theta = rec.channels["theta"]
    metrics: dict[str, Any] = {}
    for label, run in runs.items():
        m = error_metrics(theta, run.theta - offset)
        if run.diverged:  # a run that left the recorded range has no error figure: only its reason
            m = {**{k: None for k in m}, "diverges": run.divergence}
        metrics[label] = m
    return {
        "source": rec.source,
        "t": rec.t - rec.t[0],
        "duty": rec.duty,
        "theta": theta,
        "nominal": runs["nominal"].theta - offset,
        "corrected": runs["corrected"].theta - offset,
        "metrics": metrics,
    }


class _Optional:
    """Runs the optional sections of :func:`run_gap`: a section that cannot be computed is recorded
    with its reason (``not_computed``) and announced, and the run goes on; the report is written."""

    def __init__(self, say: Callable[[str], None]) -> None:
        self.say = say
        self.not_computed: dict[str, str] = {}

    def run(self, section: str, compute: Callable[[], Any]) -> Any:
        """``compute()``, or None after recording why it failed."""
        try:
            return compute()
        except Exception as exc:  # an optional section never costs the main result
            why = str(exc) if isinstance(exc, IdentError) else f"{type(exc).__name__}: {exc}"
            self.not_computed[section] = why
            self.say(f"{section}: not computed: {why}")
            return None


def _sessions_and_prediction(
    rig: Rig, diag: Any, validation: list[Recording], held_out: list[Recording], *, theta_offset: float,
    sessions: Sequence[Sequence[Recording]] | None, session_labels: Sequence[str] | None, max_effects: int,
    seed: int, progress: Callable[[str], None] | None, predict: bool, drift_sigma: Mapping[str, float] | None,
    optional: _Optional, engine: tuple[int | None, str | None] = (1, None),
) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """The session analysis (with ``sessions``, its cases run where ``engine`` = (workers,
    scheduler) says) and the held-out prediction of :func:`run_gap` (each optional: a failure is
    recorded in ``optional``)."""
    from aeropend_ident.gap.drift import predict_heldout
    from aeropend_ident.gap.sessions import session_analysis

    say = progress or (lambda _msg: None)
    sess = None
    if sessions is not None:
        say(f"sessions: {len(sessions)} sessions, leave-one-session-out and drift table")
        sess = optional.run("sessions", lambda: session_analysis(
            rig, [[_shift(r, theta_offset) for r in g] for g in sessions], diag.chosen, labels=session_labels,
            channels=diag.channels or ("theta",), max_effects=max_effects, seed=seed, progress=progress,
            workers=engine[0], scheduler=engine[1]))
        if drift_sigma is None and sess is not None and sess["drift_sigma"]:
            drift_sigma = sess["drift_sigma"]
    prediction = None
    if predict:
        say("predict: held-out NRMSE of the corrected rig from the fit data and the held-out duty")
        prediction = optional.run("prediction", lambda: predict_heldout(
            rig, diag, [_shift(r, theta_offset) for r in validation],
            targets=[_shift(r, theta_offset) for r in held_out], drift_sigma=drift_sigma, seed=seed))
        if prediction is not None:
            if sess is not None and drift_sigma is sess["drift_sigma"]:
                prediction["drift_source"] = "sessions"
            prediction["saw_heldout"] = validation is held_out
    return sess, prediction


def _replay_held_out(
    rig: Rig, diag: Any, corrected: Rig, held_out: list[Recording], theta_offset: float, horizon: float,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], WhereReport, WhereReport]:
    """The after step of :func:`run_gap`: overlays, before/after metrics and where-analyses."""
    from aeropend_ident.gap.effects import MeasurementMap
    from aeropend_ident.gap.which.data import prepare as which_prepare
    from aeropend_ident.gap.which.metrics import gap_metrics

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
    return overlays, test, w_nom, w_cor


def _refit_and_attainable(
    rig: Rig, diag: Any, fit: list[Recording], held_out: list[Recording], corrected_nrmse: float,
    optional: _Optional, *, max_effects: int, seed: int, oracle: bool, progress: Callable[[str], None] | None,
) -> tuple[dict[str, Any] | None, list[dict[str, Any]] | None]:
    """The refit comparison and the attainable shrink of :func:`run_gap` (model-frame recordings; each
    optional). The plain refit is the attainable shrink's fit-session drift fit when nothing is chosen
    (the same effect set on the same recordings): fitted once."""
    from aeropend_ident.gap.drift import refit_comparison
    from aeropend_ident.gap.sessions import attainable

    say = progress or (lambda _msg: None)
    out = optional.run("refit comparison",
                       lambda: refit_comparison(rig, diag, fit, held_out, corrected_nrmse))
    refit, fitted = out if out is not None else (None, None)
    say("after: attainable shrink (correction and best catalog set fitted on each held-out recording)")
    attain = optional.run("attainable shrink", lambda: attainable(
        rig, diag, held_out, max_effects=max_effects, seed=seed, best_set=oracle, fit=fit, progress=progress,
        fitted=fitted))
    return refit, attain


def static_table_check(rig: Rig, corrected: Rig, measurement: Any, tables: Sequence[Any],
                       theta_offset: float = 0.0) -> list[dict[str, Any]]:
    """The nominal and the corrected rig against each static table (a held-out check of the steady state).

    Parameters
    ----------
    rig, corrected : Rig
        Nominal and corrected rig.
    measurement : MeasurementMap
        The corrected rig's sensor map (recorded angle from the model's).
    tables : sequence of StaticTable
        :func:`aeropend_ident.greybox.rig_inputs.read_table` results.
    theta_offset : float
        θ_model − θ_recorded [rad].

    Returns
    -------
    list of dict
        Per table: ``source``, ``kind`` (balance / thrust), ``rows``, ``unit`` (rad or N), RMS of the
        model's steady value minus the table's for the ``nominal`` and the ``corrected`` rig, and
        ``std`` (RMS of the table's standard errors; None when it gives none).
    """
    from aeropend_ident.gap.effects import MeasurementMap
    from aeropend_ident.greybox.rig_problem import BalanceBlock, ThrustBlock

    out = []
    for t in tables:
        row: dict[str, Any] = {"source": t.source, "kind": t.kind, "rows": int(t.command.size),
                               "unit": "rad" if t.kind == "balance" else "N",
                               "std": None if t.std is None else float(np.sqrt(np.mean(t.std**2)))}
        for label, model, meas in (("nominal", rig, MeasurementMap()), ("corrected", corrected, measurement)):
            if t.kind == "balance":
                block: Any = BalanceBlock(source=t.source, label=t.label, command=t.command,
                                          angle=meas.to_model(t.value) + theta_offset)
            else:
                block = ThrustBlock(source=t.source, label=t.label, command=t.command, thrust=t.value)
            r = block.residual(model, [])
            row[label] = float(np.sqrt(np.mean(r**2))) if np.all(np.isfinite(r)) else None
        out.append(row)
    return out


#: A predicted 80 % interval wider than this (in NRMSE, i.e. in units of the recording's own θ range) is
#: no useful prediction: it allows every error from a perfect replay to one as large as the motion.
USEFUL_WIDTH = 1.0


def judge_prediction(prediction: dict[str, Any] | None) -> dict[str, Any] | None:
    """Mark a prediction ``useful`` or not (``why_not_useful``): its 80 % interval must be narrower
    than the held-out recordings' own θ range (:data:`USEFUL_WIDTH` in NRMSE). Returns it (updated)."""
    if prediction is not None:
        lo, hi = prediction["interval"]
        prediction["useful"] = bool(math.isfinite(hi - lo) and hi - lo <= USEFUL_WIDTH)
        if not prediction["useful"]:
            prediction["why_not_useful"] = (
                f"no useful prediction: the 80 % interval of the held-out θ NRMSE, [{lo:.3g}, {hi:.3g}], is "
                "wider than the recordings' own θ range (NRMSE 1): the fit data do not pin down the "
                "drift-prone parameters well enough to say how the corrected rig will do on the held-out "
                "recordings")
    return prediction


def _prediction_check(prediction: dict[str, Any] | None, test: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The predicted held-out NRMSE against the actual one (None without a prediction, or without a
    useful one: :func:`judge_prediction`)."""
    check = None
    if prediction is not None and judge_prediction(prediction)["useful"]:
        actual = float(test[-1]["nrmse"])
        lo, hi = prediction["interval"]
        check = {"predicted": prediction["predicted"], "interval": [lo, hi], "actual": actual,
                 "inside": bool(lo <= actual <= hi),
                 "verdict": ("inside the predicted 80 % interval" if lo <= actual <= hi else
                             f"OUTSIDE the predicted 80 % interval ({'above' if actual > hi else 'below'})")}
    return check


def bound_effects(rig: Rig) -> tuple[list[str], list[str]]:
    """Effects ``gap`` confirms because ``rig fit`` left a parameter at a search bound.

    A parameter fitted at its bound (:func:`aeropend_ident.greybox.rig_fit.bound_flags`) may have
    absorbed an unmodelled effect's signature (an amplifier input offset standing in for a sensor
    offset): the catalog effects that set that parameter, and those confusable with them, are
    fitted and ranked whether or not the screening shortlists them.

    Returns
    -------
    notes : list of str
        One line per flagged parameter, naming the effects confirmed for it.
    effects : list of str
        The effects to confirm (``diagnose_effects(..., also_confirm=)``).
    """
    from aeropend_ident.gap.effects import catalog
    from aeropend_ident.greybox.rig_fit import bound_flags

    flags = bound_flags(rig.sources)
    effects = {e.name: e for e in catalog(rig.family)}
    notes, out = [], []
    for key in flags:
        own = [n for n, e in effects.items() if any(p.rig_field == key for p in e.parameters)]
        near = [c for n in own for c in effects[n].confusable_with if c in effects]
        names = list(dict.fromkeys([*own, *near]))
        out += names
        notes.append(f"rig fit left {key} at a search bound (the bound, not the data, may have set it): "
                     + (f"confirming {', '.join(names)}, which it may have absorbed" if names else
                        "no catalog effect sets it"))
    return notes, list(dict.fromkeys(out))


def _to_confirm(rig: Rig, where: WhereReport, skip: Sequence[str], say: Callable[[str], None]
                ) -> tuple[list[str], list[str]]:
    """(bound notes, effects the diagnosis confirms whether or not screened): the timing effects when
    the where-analysis sees a clear lead/lag (alignment lag), and :func:`bound_effects`."""
    from aeropend_ident.gap.effects import timing_effects

    timing = any(timing_lag_seen(r.alignment) for r in where.recordings)
    notes, at_bound = bound_effects(rig)
    for line in notes:
        say(line)
    confirm = [*(timing_effects(rig.family) if timing else ()), *at_bound]
    return notes, [n for n in dict.fromkeys(confirm) if n not in skip]


def _validation_set(fit: list[Recording], held_out: list[Recording], validation: Sequence[Recording] | None,
                    fraction: float, split_rule: str, say: Callable[[str], None]
                    ) -> tuple[list[Recording], list[Recording], str]:
    """(fit core, validation, split rule) of :func:`run_gap`: explicit validation recordings, else
    :func:`carve_validation` (its rule appended and said), else (fraction 0) the held-out ones."""
    if validation is not None:
        if not validation:
            raise GapInputError("validation recordings given but empty")
        return fit, list(validation), split_rule
    if fraction > 0.0:
        core, val, carved = carve_validation(fit, fraction)
        say(carved)
        return core, val, f"{split_rule}; {carved}" if split_rule else carved
    return fit, held_out, split_rule


@single_blas
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
    skip: Sequence[str] = (),
    workers: int | None = 1,
    scheduler: str | None = None,
    tables: Sequence[Any] = (),
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
        θ_model − θ_recorded [rad] (see :func:`aeropend_ident.greybox.parameters.rig_theta_offset`).
    split_rule : str
        How the held-out set was chosen (provenance).
    max_effects : int
        Most effects added to the corrected rig (1, 2 or 3: each one after the first by the
        forward-selection step of :func:`aeropend_ident.gap.which.diagnosis.diagnose_effects`).
    horizon : float
        Short-horizon prediction length [s] of the where-analysis.
    seed : int
        Seed of the effect ranking's resampling.
    validation_fraction : float
        Share of the fit data the diagnosis uses to choose and rank the effects
        (:func:`carve_validation`); the held-out recordings are then never seen before the final
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
        Predict the held-out NRMSE from the fit data and the held-out duty before the held-out
        replay.
    oracle : bool
        Fit the best catalog set on each held-out recording (attainable shrink; the chosen set is
        refitted there in any case; the command line does this unless --no-oracle).
    drift_sigma : mapping, optional
        σ of the session-to-session log change per drift-prone parameter (default: the measured
        one with ``sessions``, else :data:`aeropend_ident.gap.drift.DRIFT_PRIOR`).
    skip : sequence of str
        Catalog effects left out of the diagnosis (``diagnose_effects(..., skip=)``).
    workers, scheduler : int or None, str or None
        Where the session analysis' diagnoses run (:func:`aeropend_ident.parallel.run_cases`): this
        process (``workers`` = 1), a local Dask cluster (None: one worker per core) or ``scheduler``.
    tables : sequence of StaticTable
        Balance / thrust tables (as ``rig fit`` takes them): checked against the nominal and the
        corrected rig (:func:`static_table_check`); the diagnosis itself works on the recordings.

    Returns
    -------
    GapResult
        The optional sections (session analysis, prediction, attainable shrink) that could not
        be computed are None, with the reason in ``not_computed``: they never cost the result.

    Raises
    ------
    aeropend_ident.gap.effects.GapError, aeropend_ident.gap.where.GapInputError
        Unusable recordings (no θ, NaNs, too short, constant input) or rig (before any result).
    """
    from aeropend_ident.gap.which.diagnosis import diagnose_effects

    say = progress or (lambda _msg: None)
    fit, held_out = list(fit), list(held_out)
    if not fit or not held_out:
        raise GapInputError(f"need fit and held-out recordings (got {len(fit)} fit, {len(held_out)} held)")
    say(f"where: nominal {rig.name} on {len(fit)} fit recording(s)")
    where = locate_gap(rig, fit, horizon=horizon, theta_offset=theta_offset)
    fit_core, validation, split_rule = _validation_set(fit, held_out, validation, validation_fraction,
                                                       split_rule, say)
    say(f"which: screening and fitting the effect catalog ({len(fit_core)} fit / {len(validation)} "
        "validation recording(s))")
    # the diagnosis works in the model's angle frame (θ shifted by the rig's recording-frame offset)
    bound_notes, confirm = _to_confirm(rig, where, skip, say)
    diag = diagnose_effects(
        rig, [_shift(r, theta_offset) for r in fit_core], [_shift(r, theta_offset) for r in validation],
        max_effects=max_effects, seed=seed, progress=progress, also_confirm=confirm, skip=skip)
    optional = _Optional(say)
    fit_m, held_m = ([_shift(r, theta_offset) for r in recs] for recs in (fit, held_out))
    sess, prediction = _sessions_and_prediction(
        rig, diag, validation, held_out, theta_offset=theta_offset, sessions=sessions,
        session_labels=session_labels, max_effects=max_effects, seed=seed, progress=progress,
        predict=predict, drift_sigma=drift_sigma, optional=optional, engine=(workers, scheduler))
    say("after: replaying the held-out recordings; a plain refit of the nominal parameters to compare")
    overlays, test, w_nom, w_cor = _replay_held_out(rig, diag, diag.corrected_rig, held_out, theta_offset,
                                                    horizon)
    check = _prediction_check(prediction, test)
    refit, attain = _refit_and_attainable(
        rig, diag, fit_m, held_m, float(test[-1]["nrmse"]), optional, max_effects=max_effects, seed=seed,
        oracle=oracle, progress=progress)
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
        refit=refit,
        not_computed=optional.not_computed,
        bound_notes=bound_notes,
        tables=(optional.run("static tables", lambda: static_table_check(
            rig, diag.corrected_rig, diag.measurement, tables, theta_offset)) or []) if tables else [],
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
