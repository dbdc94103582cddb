"""Sim-to-real gap, part 3: the diagnosis as a pipeline of stages (where, which, after).

:func:`run_gap` is the pipeline behind the ``gap`` command. It reads as its stages, each a function
of one :class:`GapRun` (the immutable context :func:`prepare` builds once per run: the nominal rig
and its plant model, the recordings in both angle frames, the fit / validation / held-out split,
the options) and of the earlier stages' results:

0. **prepare** — :func:`prepare`: the rig's plant is built once (a rig it cannot model is refused
   before any stage), the recordings are split and moved into the model's angle frame once;
1. **where** — :func:`locate`: :func:`aeropend_ident.gap.where.locate_gap` of the nominal rig on the
   *fit* recordings (equation errors per subsystem, regions, bands, residual tests);
2. **which** — :func:`choose`: :func:`aeropend_ident.gap.which.diagnosis.diagnose_effects` screens,
   fits and ranks the catalog's unmodelled effects (:mod:`aeropend_ident.gap.effects`). It fits on
   the *fit core* and ranks / chooses on a *validation* part, both carved out of the fit
   recordings (:func:`aeropend_ident.io.split.carve_validation`: train / validation / test),
   because the ranking itself selects on the data it is given;
3. **sessions and prediction** — :func:`predict_held_out`: the leave-one-session-out diagnosis and drift
   table (with sessions), and the held-out NRMSE predicted before the held-out replay;
4. **after** — :func:`replay_held_out`: the corrected rig is replayed on the **held-out**
   recordings, which no stage before has seen (overlay and before/after NRMSE,
   :func:`aeropend_ident.gap.which.metrics.gap_metrics`), and
   :func:`~aeropend_ident.gap.where.locate_gap` is run again there, for the nominal and the
   corrected rig (does the residual become white, does the flagged equation clear?);
   :func:`attainable_shrink`: a plain refit of the nominal parameters and the best catalog fit on
   each held-out recording; :func:`check_tables`: the static tables against both rigs.

The result (:class:`aeropend_ident.gap.result.GapResult`, with its JSON form and the corrected rig
file) is written by :mod:`aeropend_ident.gap.report` and drawn by :mod:`aeropend_ident.gap.figures`.

No rclpy import, no matplotlib.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from aeropend_ident.errors import GapInputError, IdentError
from aeropend_ident.gap.residual_tests import timing_lag_seen
from aeropend_ident.gap.result import GapResult, where_which_agreement
from aeropend_ident.gap.where import locate_gap
from aeropend_ident.gap.where_report import WhereReport
from aeropend_ident.greybox.batch import single_blas
from aeropend_ident.greybox.fit import error_metrics
from aeropend_ident.io.split import (
    VALIDATION_FRACTION,
    carve_validation,
)
from aeropend_sim.model import PlantModel, plant_model
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording


# --------------------------------------------------------------------------- helpers of the stages
def to_model_frame(rec: Recording, offset: float) -> Recording:
    """The recording with θ moved into the model frame (θ_model = θ_recorded + offset)."""
    if offset == 0.0:
        return rec
    ch = {**rec.channels, "theta": rec.channels["theta"] + offset}
    return Recording(
        t=rec.t, duty=rec.duty, channels=ch, source=rec.source, stamp0_ns=rec.stamp0_ns, meta=dict(rec.meta),
        duty_before=rec.duty_before)


def _overlay(rig: Rig, diag: Any, rec: Recording, prep: Any, offset: float) -> dict[str, Any]:
    """Held-out replay of the nominal and the corrected rig (the one free run of every command,
    :func:`aeropend_ident.greybox.replay.free_run`, as in the held-out table), θ in the recording's frame.
    ``prep`` is the recording in the model frame, prepared for the replay
    (:func:`aeropend_ident.gap.which.data.prepare`)."""
    from aeropend_ident.gap.effects import MeasurementMap
    from aeropend_ident.gap.which.metrics import one_free_run

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

    A parameter fitted at its bound (:func:`aeropend_ident.greybox.rig_fit_result.bound_flags`) may have
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
    from aeropend_ident.greybox.rig_fit_result import bound_flags

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


# --------------------------------------------------------------------------- the context
@dataclass(frozen=True)
class GapOptions:
    """The knobs of one run: :func:`run_gap`'s keyword arguments of the same names."""

    max_effects: int = 2
    horizon: float = 0.2
    seed: int = 0
    predict: bool = True
    oracle: bool = False
    drift_sigma: Mapping[str, float] | None = None
    skip: tuple[str, ...] = ()
    workers: int | None = 1
    scheduler: str | None = None


@dataclass(frozen=True)
class GapRun:
    """One run's context: built once by :func:`prepare`, read by every stage, never changed.

    Attributes
    ----------
    rig : Rig
        Nominal rig.
    model : PlantModel
        Its plant, built once (:func:`aeropend_sim.model.plant_model`, whose cache hands this
        same object to every replay of ``rig`` in the stages).
    rig_ref : str
        Rig name or path (provenance).
    theta_offset : float
        θ_model − θ_recorded [rad].
    fit, held_out : list[Recording]
        The recordings as given (recording frame).
    fit_core, validation : list[Recording]
        What the diagnosis fits on and chooses on (recording frame); ``validation`` *is*
        ``held_out`` when the held-out recordings are the validation set (fraction 0).
    split_rule : str
        How the held-out and the validation recordings were chosen.
    fit_m, held_out_m, fit_core_m, validation_m : list[Recording]
        The same recordings in the model's angle frame (:func:`to_model_frame`), made once.
    sessions_m : list of list of Recording, optional
        The fit recordings grouped by session, model frame.
    session_labels : sequence of str, optional
    tables : tuple
        Static tables (``rig fit``'s balance / thrust tables).
    options : GapOptions
    progress : callable, optional
        Receives one-line progress messages (passed on to the stages' own steps).
    optional : _Optional
        Collects the optional sections that could not be computed (the one part that grows).
    """

    rig: Rig
    model: PlantModel
    rig_ref: str
    theta_offset: float
    fit: list[Recording]
    held_out: list[Recording]
    fit_core: list[Recording]
    validation: list[Recording]
    split_rule: str
    fit_m: list[Recording]
    held_out_m: list[Recording]
    fit_core_m: list[Recording]
    validation_m: list[Recording]
    sessions_m: list[list[Recording]] | None
    session_labels: Sequence[str] | None
    tables: tuple[Any, ...]
    options: GapOptions
    progress: Callable[[str], None] | None
    optional: _Optional

    def say(self, message: str) -> None:
        """One progress line (nothing without a ``progress`` callback)."""
        if self.progress is not None:
            self.progress(message)


class HeldOutReplay(NamedTuple):
    """What :func:`replay_held_out` found: overlays, before/after metrics and where-analyses."""

    overlays: list[dict[str, Any]]
    test: list[dict[str, Any]]
    where_nominal: WhereReport
    where_corrected: WhereReport


# --------------------------------------------------------------------------- the stages
def prepare(rig: Rig, fit: Sequence[Recording], held_out: Sequence[Recording], *, rig_ref: str = "",
            theta_offset: float = 0.0, split_rule: str = "",
            validation_fraction: float = VALIDATION_FRACTION, validation: Sequence[Recording] | None = None,
            sessions: Sequence[Sequence[Recording]] | None = None,
            session_labels: Sequence[str] | None = None,
            tables: Sequence[Any] = (), options: GapOptions | None = None,
            progress: Callable[[str], None] | None = None) -> GapRun:
    """Stage 0: the run's context (:class:`GapRun`; parameters as :func:`run_gap`'s).

    Raises
    ------
    aeropend_ident.errors.GapInputError
        No fit or no held-out recording, or explicit validation recordings that are empty.
    aeropend_sim.params.RigFileError, aeropend_sim.model.ModelError
        A rig that cannot be modelled.
    """
    say = progress or (lambda _msg: None)
    fit, held_out = list(fit), list(held_out)
    if not fit or not held_out:
        raise GapInputError(f"need fit and held-out recordings (got {len(fit)} fit, {len(held_out)} held)")
    model = plant_model(rig)
    fit_core, val, split_rule = _validation_set(fit, held_out, validation, validation_fraction, split_rule,
                                                say)

    def frame(recs: Sequence[Recording]) -> list[Recording]:
        return [to_model_frame(r, theta_offset) for r in recs]

    return GapRun(
        rig=rig, model=model, rig_ref=rig_ref or rig.name, theta_offset=theta_offset, fit=fit,
        held_out=held_out, fit_core=fit_core, validation=val, split_rule=split_rule, fit_m=frame(fit),
        held_out_m=frame(held_out), fit_core_m=frame(fit_core), validation_m=frame(val),
        sessions_m=None if sessions is None else [frame(g) for g in sessions],
        session_labels=session_labels, tables=tuple(tables), options=options or GapOptions(),
        progress=progress, optional=_Optional(say))


def locate(run: GapRun) -> WhereReport:
    """Stage 1, where: the nominal rig's equation errors on the fit recordings."""
    run.say(f"where: nominal {run.rig.name} on {len(run.fit)} fit recording(s)")
    return locate_gap(run.rig, run.fit, horizon=run.options.horizon, theta_offset=run.theta_offset)


def choose(run: GapRun, where: WhereReport) -> tuple[list[str], Any]:
    """Stage 2, which: the effect diagnosis on the fit core, chosen on the validation recordings.

    Returns
    -------
    bound_notes : list of str
        :func:`bound_effects`' notes.
    diagnosis : EffectDiagnosis
        :func:`aeropend_ident.gap.which.diagnosis.diagnose_effects` (model frame).
    """
    from aeropend_ident.gap.which.diagnosis import diagnose_effects

    opt = run.options
    run.say(f"which: screening and fitting the effect catalog ({len(run.fit_core)} fit / "
            f"{len(run.validation)} validation recording(s))")
    bound_notes, confirm = _to_confirm(run.rig, where, opt.skip, run.say)
    diag = diagnose_effects(run.rig, run.fit_core_m, run.validation_m, max_effects=opt.max_effects,
                            seed=opt.seed, progress=run.progress, also_confirm=confirm, skip=opt.skip)
    return bound_notes, diag


def predict_held_out(run: GapRun, diag: Any) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """Stage 3: the session analysis (with sessions, its cases run where ``workers`` /
    ``scheduler`` say) and the held-out prediction, made before any held-out replay (each optional:
    a failure is recorded in ``run.optional``)."""
    from aeropend_ident.gap.drift import predict_heldout
    from aeropend_ident.gap.sessions import session_analysis

    opt = run.options
    drift_sigma = opt.drift_sigma
    sess = None
    if run.sessions_m is not None:
        run.say(f"sessions: {len(run.sessions_m)} sessions, leave-one-session-out and drift table")
        sess = run.optional.run("sessions", lambda: session_analysis(
            run.rig, run.sessions_m, diag.chosen, labels=run.session_labels,
            channels=diag.channels or ("theta",), max_effects=opt.max_effects, seed=opt.seed,
            progress=run.progress, workers=opt.workers, scheduler=opt.scheduler))
        if drift_sigma is None and sess is not None and sess["drift_sigma"]:
            drift_sigma = sess["drift_sigma"]
    prediction = None
    if opt.predict:
        run.say("predict: held-out NRMSE of the corrected rig from the fit data and the held-out duty")
        prediction = run.optional.run("prediction", lambda: predict_heldout(
            run.rig, diag, run.validation_m, targets=run.held_out_m, drift_sigma=drift_sigma, seed=opt.seed))
        if prediction is not None:
            if sess is not None and drift_sigma is sess["drift_sigma"]:
                prediction["drift_source"] = "sessions"
            prediction["saw_heldout"] = run.validation is run.held_out
    return sess, prediction


def replay_held_out(run: GapRun, diag: Any) -> HeldOutReplay:
    """Stage 4, after: the nominal and the corrected rig replayed on the held-out recordings
    (overlays, before/after metrics) and the where-analysis of each there."""
    from aeropend_ident.gap.effects import MeasurementMap
    from aeropend_ident.gap.which.data import prepare as which_prepare
    from aeropend_ident.gap.which.metrics import gap_metrics

    run.say("after: replaying the held-out recordings; a plain refit of the nominal parameters to compare")
    rig, corrected, off, horizon = run.rig, diag.corrected_rig, run.theta_offset, run.options.horizon
    preps = which_prepare(run.held_out_m, frozenset(diag.channels or ("theta",)))
    overlays = [_overlay(rig, diag, r, p, off) for r, p in zip(run.held_out, preps, strict=True)]
    test = [{"effects": [], **gap_metrics(rig, MeasurementMap(), preps)}]
    if diag.chosen:
        test.append({"effects": list(diag.chosen), **gap_metrics(corrected, diag.measurement, preps)})
    w_nom = locate_gap(rig, run.held_out, horizon=horizon, theta_offset=off)
    # the corrected rig's where-analysis in the model frame of the diagnosis (sensor offset included)
    meas = getattr(diag, "measurement", None)
    off_c = off + (float(meas.theta_offset) if meas is not None else 0.0)
    w_cor = locate_gap(corrected, run.held_out, horizon=horizon, theta_offset=off_c)
    return HeldOutReplay(overlays, test, w_nom, w_cor)


def attainable_shrink(run: GapRun, diag: Any, test: list[dict[str, Any]]
                      ) -> tuple[dict[str, Any] | None, list[dict[str, Any]] | None]:
    """Stage 4, after: the refit comparison and the attainable shrink (model-frame recordings; each
    optional). The plain refit is the attainable shrink's fit-session drift fit when nothing is chosen
    (the same effect set on the same recordings): fitted once."""
    from aeropend_ident.gap.drift import refit_comparison
    from aeropend_ident.gap.sessions import attainable

    opt = run.options
    corrected_nrmse = float(test[-1]["nrmse"])
    out = run.optional.run("refit comparison", lambda: refit_comparison(
        run.rig, diag, run.fit_m, run.held_out_m, corrected_nrmse))
    refit, fitted = out if out is not None else (None, None)
    run.say("after: attainable shrink (correction and best catalog set fitted on each held-out recording)")
    attain = run.optional.run("attainable shrink", lambda: attainable(
        run.rig, diag, run.held_out_m, max_effects=opt.max_effects, seed=opt.seed, best_set=opt.oracle,
        fit=run.fit_m, progress=run.progress, fitted=fitted))
    return refit, attain


def check_tables(run: GapRun, diag: Any) -> list[dict[str, Any]]:
    """Stage 4, after: the static tables against the nominal and the corrected rig (optional)."""
    if not run.tables:
        return []
    return run.optional.run("static tables", lambda: static_table_check(
        run.rig, diag.corrected_rig, diag.measurement, run.tables, run.theta_offset)) or []


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
    options = GapOptions(max_effects=max_effects, horizon=horizon, seed=seed, predict=predict, oracle=oracle,
                         drift_sigma=drift_sigma, skip=tuple(skip), workers=workers, scheduler=scheduler)
    run = prepare(rig, fit, held_out, rig_ref=rig_ref, theta_offset=theta_offset, split_rule=split_rule,
                  validation_fraction=validation_fraction, validation=validation, sessions=sessions,
                  session_labels=session_labels, tables=tables, options=options, progress=progress)
    where = locate(run)
    bound_notes, diag = choose(run, where)
    sess, prediction = predict_held_out(run, diag)
    after = replay_held_out(run, diag)
    refit, attain = attainable_shrink(run, diag, after.test)
    return GapResult(
        rig=run.rig, rig_ref=run.rig_ref, theta_offset=run.theta_offset, fit=run.fit, held_out=run.held_out,
        fit_core=run.fit_core, validation=run.validation, test=after.test, split_rule=run.split_rule,
        where=where, where_heldout_nominal=after.where_nominal, where_heldout_corrected=after.where_corrected,
        diagnosis=diag, overlays=after.overlays, agreement=where_which_agreement(where, diag),
        prediction=prediction, prediction_check=_prediction_check(prediction, after.test), attainable=attain,
        sessions=sess, refit=refit, not_computed=run.optional.not_computed, bound_notes=bound_notes,
        tables=check_tables(run, diag),
    )
