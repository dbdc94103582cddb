"""Grey-box baseline: fit a rig's nominal model on recordings, test it on data the fit never saw.

Pipeline (:func:`baseline`, :func:`run_baseline`):

1. **Held-out design.** One or more recordings: each is split in time order (default 70 % fit /
   30 % held out, :meth:`aeropend_sim.recording.Recording.split`); or, with ``held_out``, the
   recordings are fitted whole and the held-out recordings are replayed (split by recordings: fit
   on some recordings, validate on another). A held-out part may be a constant hold (the end of a
   step test); identifiability is decided on what is fitted
   (:func:`aeropend_ident.greybox.uniform.check_excited`: the fitted data must excite the rig — a
   changing command, or a free decay or step from rest under a constant one).
2. **Grid.** Every recording goes through the one resampling of the tools
   (:func:`aeropend_ident.io.resampling.uniform_recording`) onto the grid of the first fit
   recording; what was done (jitter, dropped rows, gaps) is reported.
3. **Fit** the selected parameters on the fit data by output error
   (:func:`aeropend_ident.greybox.fit.fit_greybox`, default parameter set for θ-only data), every
   fit recording from its own initial state. A fitted dead time or actuator lag is searched over
   the range the recordings can show (:func:`aeropend_ident.io.recording_input.timing_range`, at
   least 1 s of dead time when they are long enough), from the best start of a coarse scan.
4. **Replay** each held-out part's recorded duty cycle through the fitted model in free run,
   the one replay of every command (:func:`aeropend_ident.greybox.replay.free_run`: θ₀, θ̇₀ from a
   quadratic fit over the part's first 0.1 s, motor at the steady state of its first duty; its
   divergence rule and NRMSE), and the same for the **nominal** (unfitted) rig; a held-out part that
   continues its fit part starts its replay early enough that a dead time sees the commands
   before the split.
5. **Metrics** on fit and held-out data, for the nominal and the fitted model:
   NRMSE = RMS(θ_sim − θ_meas) / (max θ_meas − min θ_meas) over that part (over the whole
   recordings when the part barely moves: a hold, :data:`HOLD_RANGE_SHARE`), RMS error [rad] and
   max |error| [rad]. A model that diverges (:func:`aeropend_ident.io.overlay_axes.diverges`:
   non-finite, or beyond the recorded range by more than a recorded span and a quarter turn) is reported as
   divergence, not as an NRMSE.
6. **Warnings**: a fitted model that predicts the held-out data worse than the nominal, with the
   parameters that are implausible (:func:`implausible`: relative standard error > 100 %, at a
   bound, outside the physical range the registry declares), a divergence, a parameter at a
   search bound derived from the data; on the terminal, in ``report.json`` and on the overlay.
7. **Residual per operating region** (residual = θ_sim − θ_meas): equal-width bins of the
   measured θ and of the duty cycle (count, mean, RMS), and transient vs steady state
   (|θ̇_meas| above/below a threshold, θ̇ from a Savitzky-Golay derivative of the measured θ).
8. **Report** (:func:`write_report`): ``report.json`` (parameters with units and standard
   errors, metrics, regions, warnings, provenance) and ``overlay.png`` (recorded vs nominal vs
   fitted θ with the fit/held-out boundaries, duty cycle below), plus ``fitted_rig.yaml`` (the
   fitted rig in the rig-file format, loadable by :func:`aeropend_sim.params.load_rig`).

No rclpy import; matplotlib is used with the Agg backend only when writing the plot.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from aeropend_ident.errors import IdentificationError
from aeropend_ident.greybox.baseline_result import TIMING_PARAMS, BaselineResult, _name
from aeropend_ident.greybox.fit import error_metrics, fit_greybox, free_run_theta
from aeropend_ident.greybox.fit_result import GreyBoxResult, ParameterEstimate
from aeropend_ident.greybox.parameters import (
    THETA_OFFSET,
    apply_parameters,
    default_parameters,
    rig_theta_offset,
)
from aeropend_ident.greybox.replay import FreeRun, free_run
from aeropend_ident.greybox.uniform import UniformData, check_excited, concat_uniform, uniform_data
from aeropend_ident.io.jsonutil import jsonable
from aeropend_ident.io.overlay_axes import HOLD_RANGE_SHARE, diverges, short_number
from aeropend_ident.io.recording_input import TimingRange, timing_range
from aeropend_sim.components import registry
from aeropend_sim.output_folder import is_fault
from aeropend_sim.params import Rig, RigFileError, load_rig, rig_to_dict
from aeropend_sim.recording import Recording, RecordingError

#: Default |θ̇| threshold [rad/s] separating transient from steady-state samples.
STEADY_RATE = 0.05
#: Default number of equal-width bins for the θ and duty operating regions.
N_BINS = 5
#: Default multiple-shooting horizon [s] that initialises the free-run fit.
INIT_HORIZON = 2.0
#: A part whose θ range is below this share of the range over all recordings is a hold: its NRMSE is
#: normalised by the recordings' range (its own range is its noise).
#: Relative standard error above which a fitted parameter is implausible.
MAX_RELATIVE_ERROR = 1.0
#: Values a coarse scan tries for a fitted dead time or lag before the fit starts.
TIMING_SCAN = 9


# --------------------------------------------------------------------------- regions
def residual_bins(values: np.ndarray, residual: np.ndarray, n_bins: int, unit: str) -> list[dict[str, Any]]:
    """Residual statistics in ``n_bins`` equal-width bins of an operating variable.

    Parameters
    ----------
    values : ndarray, shape (N,)
        Operating variable per sample (angle, duty cycle, |θ̇|, ...).
    residual : ndarray, shape (N,)
        Residual per sample.
    n_bins : int
        Number of bins over [min(values), max(values)] (one bin when the values are constant).
    unit : str
        Unit of ``values`` (copied into each bin).

    Returns
    -------
    list of dict
        Per bin: ``lower``, ``upper``, ``unit``, ``count``, ``mean_residual`` and ``rms_residual``
        (None for an empty bin).
    """
    lo, hi = float(np.min(values)), float(np.max(values))
    if hi == lo:
        edges = np.array([lo, hi])
    else:
        edges = np.linspace(lo, hi, n_bins + 1)
    idx = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, edges.size - 2)
    out = []
    for b in range(edges.size - 1):
        r = residual[idx == b]
        out.append({
            "lower": float(edges[b]), "upper": float(edges[b + 1]), "unit": unit, "count": int(r.size),
            "mean_residual": float(np.mean(r)) if r.size else None,
            "rms_residual": float(np.sqrt(np.mean(r**2))) if r.size else None,
        })
    return out


def measured_rate(theta: np.ndarray, dt: float, window: float = 0.2) -> np.ndarray:
    """θ̇ [rad/s] of a measured angle by a Savitzky-Golay derivative (quadratic, ≈ ``window`` s).

    Parameters
    ----------
    theta : ndarray, shape (N,)
        Angle [rad] on a uniform grid.
    dt : float
        Grid period [s].
    window : float
        Window length [s] (at least 5 samples, odd, at most N).
    """
    n = theta.size
    w = max(5, round(window / dt) | 1)
    if w > n:
        w = n if n % 2 else n - 1
    if w < 3:
        return np.gradient(theta, dt) if n > 1 else np.zeros(n)
    from scipy.signal import savgol_filter  # here: importing scipy.signal costs ~1 s (`baseline --help`)

    return savgol_filter(theta, w, min(2, w - 1), deriv=1, delta=dt, mode="interp")


def residual_regions(theta: np.ndarray, duty: np.ndarray, residual: np.ndarray, dt: float,
                     n_bins: int = N_BINS, rate_threshold: float = STEADY_RATE) -> dict[str, Any]:
    """Residual statistics per operating region.

    Parameters
    ----------
    theta : ndarray, shape (N,)
        Measured angle [rad].
    duty : ndarray, shape (N,)
        Duty cycle [1].
    residual : ndarray, shape (N,)
        θ_sim − θ_meas [rad].
    dt : float
        Sample period [s].
    n_bins : int
        Equal-width bins over the measured θ range and over the duty range.
    rate_threshold : float
        |θ̇_meas| [rad/s] below which a sample counts as steady state.

    Returns
    -------
    dict
        ``theta_bins``, ``duty_bins`` (lists of {lower, upper, unit, count, mean_residual,
        rms_residual}), ``motion`` ({"transient": {...}, "steady": {...}}), ``rate_threshold``.
    """
    rate = measured_rate(theta, dt)
    steady = np.abs(rate) < rate_threshold
    motion = {}
    for label, mask in (("transient", ~steady), ("steady", steady)):
        r = residual[mask]
        motion[label] = {"count": int(r.size),
                         "mean_residual": float(np.mean(r)) if r.size else None,
                         "rms_residual": float(np.sqrt(np.mean(r**2))) if r.size else None}
    return {
        "theta_bins": residual_bins(theta, residual, n_bins, "rad"),
        "duty_bins": residual_bins(duty, residual, n_bins, "1"),
        "motion": motion,
        "rate_threshold": rate_threshold,
        "rate_threshold_unit": "rad/s",
    }


# --------------------------------------------------------------------------- implausible parameters
def implausible(p: ParameterEstimate, timing: TimingRange | None = None) -> list[str]:
    """Why a fitted value is implausible (empty list: nothing to say).

    The rules: a relative standard error above :data:`MAX_RELATIVE_ERROR` (or none: the data do not
    determine it), a value at a bound of its search range (the bound decided it, not the data), a
    value outside the physical range the registry declares for the parameter (its sign, its strict
    upper limit, its declared fit bounds: :class:`aeropend_sim.components.base.Param`).

    Parameters
    ----------
    p : ParameterEstimate
    timing : TimingRange, optional
        The data-derived search range of a timing parameter (named in the reason).
    """
    out = []
    if p.at_bound:
        lower = abs(p.value - p.lower) <= abs(p.value - p.upper)
        side, bound = ("lower", p.lower) if lower else ("upper", p.upper)
        where = (f" (search range derived from the data: {timing.rule()})"
                 if timing is not None and p.name in TIMING_PARAMS and side == "upper" else "")
        out.append(f"at its {side} bound {short_number(bound)} {p.unit}{where}")
    elif math.isinf(p.std_error) or math.isnan(p.std_error):
        out.append("not determined by these data (no finite standard error)")
    elif p.relative_std_error > MAX_RELATIVE_ERROR:
        out.append(f"relative standard error {p.relative_std_error:.0%} > {MAX_RELATIVE_ERROR:.0%}")
    if p.name != THETA_OFFSET:
        par = registry.param(p.name)
        why = par.violation(p.value)
        declared = par.fit
        if why is None and declared is not None and (
                (declared.lower is not None and p.value < declared.lower)
                or (declared.upper is not None and p.value > declared.upper)):
            why = (f"outside its physical range [{short_number(declared.lower)}, "
                   f"{short_number(declared.upper)}] {p.unit} ({par.doc})")
        if why is not None:
            out.append(why)
    return out


# --------------------------------------------------------------------------- pipeline
def _resolve_rig(rig: Rig | str | Path) -> tuple[Rig, str, float]:
    if isinstance(rig, Rig):
        return rig, rig.name, 0.0
    try:
        loaded = load_rig(rig)
    except RigFileError as exc:
        raise IdentificationError(str(exc)) from exc
    return loaded, str(rig), rig_theta_offset(rig)


def _on_grid(rec: Recording, dt: float, decimate: int, min_samples: int) -> tuple[UniformData, Recording]:
    """θ and the duty cycle of ``rec`` on the grid of step ``dt`` (the one resampling), and the resampled
    θ-only recording (its ``meta["resampling"]`` says what was done)."""
    from aeropend_ident.io.resampling import uniform_recording

    if "theta" not in rec.channels:
        uniform_data(rec)  # raises the grey-box fit's message (no θ)
    slim = Recording(t=rec.t, duty=rec.duty, channels={"theta": rec.channels["theta"]}, source=rec.source,
                     meta=dict(rec.meta))
    try:
        grid = uniform_recording(slim, dt=dt)
    except ValueError as exc:
        raise IdentificationError(str(exc)) from exc
    data = uniform_data(grid, dt=dt, decimate=decimate, min_samples=min_samples)
    return dataclasses.replace(data, resampled=data.resampled or grid is not slim), grid


def _design(recordings: Sequence[Recording], held_out: Sequence[Recording], train_fraction: float,
            decimate: int) -> tuple[list[UniformData], list[UniformData], list[Recording], float | None]:
    """Fit and held-out data (one per recording part) on the first recording's grid, the resampled
    parts (for the report) and the split time of a single recording split in time order."""
    if not (isinstance(train_fraction, (int, float)) and 0.0 < train_fraction < 1.0):
        raise IdentificationError(f"train_fraction = {train_fraction!r}; expected a number in (0, 1)")
    dt = recordings[0].dt
    fit_parts, held_parts, t_split = list(recordings), list(held_out), None
    if not held_out:
        fit_parts, held_parts = [], []
        for r in recordings:
            try:
                a, b = r.split(train_fraction)
            except RecordingError as exc:
                raise IdentificationError(f"cannot split {r.source or 'the recording'}: {exc}") from exc
            fit_parts.append(a)
            held_parts.append(b)
        if len(recordings) == 1:
            t_split = float(recordings[0].t[len(fit_parts[0])] - recordings[0].t[0])
    fit = [_on_grid(r, dt, decimate, 2) for r in fit_parts]
    held = [_on_grid(r, dt, decimate, 10) for r in held_parts]
    return [f[0] for f in fit], [h[0] for h in held], [x[1] for x in (*fit, *held)], t_split


def _timing_start(rig: Rig, off: float, train: UniformData, names: Sequence[str], timing: TimingRange,
                  ) -> dict[str, float]:
    """Start values of fitted timing parameters: the best of a coarse scan over their data-derived range
    (a local fit from the rig file's value would stop at the nearest local minimum of a dead time)."""
    start: dict[str, float] = {}
    current = rig
    for name in names:
        top = timing.delay_max if name == "actuator.input_delay" else timing.lag_max
        grid = (np.linspace(0.0, top, TIMING_SCAN) if name == "actuator.input_delay"
                else np.geomspace(min(1e-3, top), top, TIMING_SCAN))
        costs = []
        for v in grid:
            try:
                trial, _ = apply_parameters(current, {name: float(v)}, off)
                costs.append(float(np.sum((free_run_theta(trial, train, off) - train.theta) ** 2)))
            except IdentificationError:
                costs.append(math.inf)
        best = float(grid[int(np.argmin(costs))]) if np.isfinite(costs).any() else float(grid[0])
        start[name] = best
        current, _ = apply_parameters(current, {name: best}, off)
    return start


def _replay(rig: Rig, off: float, data: UniformData, history: UniformData | None, span: float | None,
            ) -> FreeRun:
    """The one free run (:func:`aeropend_ident.greybox.replay.free_run`) of a held-out part; with
    ``history`` (the fit part it continues) the run starts early enough that the rig's dead time
    sees the commands before the split and the rig's own effect states (a winding temperature) start
    where its replay of the fit part ends; ``span`` normalises a hold (:func:`_hold_span`)."""
    delay = rig.actuator.input_delay if rig.effects.input_delay else 0.0
    k = math.ceil(delay / data.dt) + 1 if delay > 0.0 and history is not None else 0
    if k == 0 or history is None or len(history) < k:
        return free_run(rig, data.t, data.duty, data.theta, theta_offset=off, span=span, source=data.source,
                        duty_before=None if history is None else history.duty)
    t = np.concatenate([data.t[0] - data.dt * np.arange(k, 0, -1), data.t])
    return free_run(rig, t, np.concatenate([history.duty[-k:], data.duty]),
                    np.concatenate([history.theta[-k:], data.theta]), theta_offset=off, span=span,
                    source=data.source, lead=k, duty_before=history.duty[:-k])


def _hold_span(measured: np.ndarray, span_all: float) -> float | None:
    """The span a part is scored in: the recordings' when the part is a hold, else None (its own)."""
    own = float(np.ptp(measured)) if np.size(measured) else 0.0
    return span_all if span_all > 0.0 and own < HOLD_RANGE_SHARE * span_all else None


def _run_scores(run: FreeRun, measured: np.ndarray) -> tuple[dict[str, Any], str | None]:
    """:func:`_scores`' dict of a held-out part from its one free run (the same figure as every
    command's), with the start it used."""
    m = dict(error_metrics(measured, run.theta))
    m["normalised_by"] = ("the recordings' range (this part is a hold)" if run.range != m["range"]
                          else "the part's range")
    m["nrmse"] = run.nrmse
    m["initial_state"] = run.initial.as_dict()
    if run.diverged_at is not None:
        m["diverged_at_s"] = run.diverged_at
    return m, run.divergence


def _scores(measured: np.ndarray, simulated: np.ndarray, span_all: float, t: np.ndarray | None = None,
            ) -> tuple[dict[str, Any], str | None]:
    """:func:`error_metrics` with the hold rule of the normalisation, and the divergence (None if none)."""
    m = dict(error_metrics(measured, simulated))
    own = m["range"]
    hold = span_all > 0.0 and own < HOLD_RANGE_SHARE * span_all
    span = span_all if hold else own
    m["normalised_by"] = "the recordings' range (this part is a hold)" if hold else "the part's range"
    m["nrmse"] = m["rms_error"] / span if span > 0.0 else math.inf
    why = diverges(simulated, measured, t, span=span if hold else None)
    if why is not None:
        m["nrmse"] = None
    return m, why


def baseline(
    recording: Recording | Sequence[Recording],
    rig: Rig | str | Path,
    *,
    held_out: Sequence[Recording] | None = None,
    train_fraction: float = 0.7,
    params: Sequence[str] | None = None,
    theta_offset: float | None = None,
    init_horizon: float | None = INIT_HORIZON,
    decimate: int = 1,
    n_bins: int = N_BINS,
    rate_threshold: float = STEADY_RATE,
    max_nfev: int = 400,
) -> BaselineResult:
    """Fit on the fit data, replay the held-out data, compute metrics, regions and warnings.

    Parameters
    ----------
    recording : Recording or sequence of Recording
        Needs ``theta`` [rad] and the duty cycle (a bag via :func:`aeropend_ident.io.bags.read_bag`
        or a CSV via :func:`aeropend_ident.io.csv_import.import_csv`); any timing (resampled).
    rig : Rig, str or Path
        The nominal model: a :class:`~aeropend_sim.params.Rig`, a shipped rig name or a rig-file
        path (then its ``recording_frame.theta_offset`` is used, see
        :func:`aeropend_ident.greybox.parameters.rig_theta_offset`).
    held_out : sequence of Recording, optional
        Recordings replayed as held out; the ``recording`` s are then fitted whole (split by
        recordings). Default: each recording split in time order.
    train_fraction : float
        Fraction of each recording's samples (from its start) fitted in a time-ordered split, in (0, 1).
    params : sequence of str, optional
        Fitted parameters (default :func:`aeropend_ident.greybox.parameters.default_parameters`).
    theta_offset : float, optional
        Override of the nominal angle offset [rad].
    init_horizon : float or None
        Multiple-shooting horizon [s] that initialises the free-run fit (None: free run only).
    decimate : int
        Decimation of every part (runtime; see :func:`aeropend_ident.greybox.uniform.uniform_data`).
    n_bins, rate_threshold : int, float
        Operating-region bins and the steady-state |θ̇| threshold [rad/s].
    max_nfev : int
        Most simulations per fitting stage.

    Returns
    -------
    BaselineResult

    Raises
    ------
    IdentificationError
        On an unusable recording or part (too short, not exciting the rig where it is fitted, a
        constant input that cannot explain θ, NaNs, no θ), a bad split fraction or rig, or a bad
        parameter request.
    """
    nominal, rig_ref, off = _resolve_rig(rig)
    if theta_offset is not None:
        off = float(theta_offset)
    recs = [recording] if isinstance(recording, Recording) else list(recording)
    held_recs = list(held_out or [])
    if not recs:
        raise IdentificationError("no recording given")
    fit_parts, held_parts, grids, t_split = _design(recs, held_recs, train_fraction, decimate)
    train = concat_uniform(fit_parts)
    # identifiability on what is fitted; a closed loop's reference logged without its command is named
    check_excited(train, "channel theta_ref" if any("theta_ref" in r.extra for r in recs) else None)
    names = list(default_parameters(nominal, off) if params is None else params)
    timed = [n for n in names if n in TIMING_PARAMS]
    timing, bounds, initial = None, {}, {}
    if timed:
        timing = timing_range(grids[:len(fit_parts)])
        bounds = {n: ((0.0, timing.delay_max) if n == "actuator.input_delay"
                      else (1e-4, max(timing.lag_max, 2e-4))) for n in timed}
        initial = _timing_start(nominal, off, train, timed, timing)
    fit = fit_greybox(fit_parts, nominal, names, theta_offset=off, init_horizon=init_horizon,
                      max_nfev=max_nfev, bounds=bounds or None, initial=initial or None)
    held = concat_uniform(held_parts)
    result = _evaluate(fit, nominal, off, fit_parts, held_parts, held_recs, n_bins, rate_threshold)
    return BaselineResult(
        fit=fit, nominal_rig=nominal, nominal_theta_offset=off, rig_ref=rig_ref, recordings=tuple(recs),
        held_out_recordings=tuple(held_recs), train_fraction=None if held_recs else float(train_fraction),
        train=train, heldout=held, t_split=t_split, timing=timing,
        implausible={p.name: why for p in fit.parameters if (why := implausible(p, timing))},
        **result,
    )


def _evaluate(fit: GreyBoxResult, nominal: Rig, off: float, fit_parts: Sequence[UniformData],
              held_parts: Sequence[UniformData], held_recs: Sequence[Recording], n_bins: int,
              rate_threshold: float) -> dict[str, Any]:
    """Replays, metrics, divergence, regions and warnings of :func:`baseline`."""
    span_all = float(np.ptp(np.concatenate([p.theta for p in (*fit_parts, *held_parts)])))
    theta: dict[str, dict[str, np.ndarray]] = {"train": {}, "heldout": {}}
    metrics: dict[str, dict[str, dict[str, Any]]] = {"train": {}, "heldout": {}}
    regions: dict[str, dict[str, dict[str, Any]]] = {"train": {}, "heldout": {}}
    divergence: dict[str, dict[str, str]] = {}
    per_recording: list[dict[str, Any]] = [{"recording": p.source} for p in held_parts]
    models = (("nominal", nominal, off), ("fitted", fit.rig, fit.theta_offset))
    held_runs: dict[str, FreeRun] = {}
    for model, r, o in models:
        theta["train"][model] = (fit.theta_fit if model == "fitted"
                                 else free_run_theta(r, concat_uniform(list(fit_parts)), o))
        runs = []
        for k, part in enumerate(held_parts):
            history = fit_parts[k] if not held_recs else None
            runs.append(_replay(r, o, part, history, _hold_span(part.theta, span_all)))
            per_recording[k][model], why = _run_scores(runs[-1], part.theta)
            if why:
                per_recording[k][model]["diverges"] = why
        theta["heldout"][model] = np.concatenate([run.theta for run in runs])
        if len(runs) == 1:  # one held-out part: its figure is the one free run's
            held_runs[model] = runs[0]
    for part, parts in (("train", fit_parts), ("heldout", held_parts)):
        data = concat_uniform(list(parts))
        for model, _, _ in models:
            th = theta[part][model]
            if part == "heldout" and model in held_runs:
                metrics[part][model], why = _run_scores(held_runs[model], data.theta)
            else:
                metrics[part][model], why = _scores(data.theta, th, span_all, data.t)
            if why is not None:
                divergence.setdefault(part, {})[model] = f"{model} model {why}"
            finite = np.where(np.isfinite(th), th, data.theta)
            regions[part][model] = residual_regions(data.theta, data.duty, finite - data.theta, data.dt,
                                                    n_bins, rate_threshold)
    return {"theta": theta, "metrics": metrics, "regions": regions, "per_recording": per_recording,
            "divergence": divergence, "warnings": _warnings(fit, metrics, divergence)}


#: A fit predicts the held-out data worse than the nominal when its NRMSE is higher by more than this
#: share (the issue's user read "worse … 0.003581 → 0.003581 (+0 %)").
WORSE_MARGIN = 0.01


def _warnings(fit: GreyBoxResult, metrics: dict[str, dict[str, dict[str, Any]]],
              divergence: dict[str, dict[str, str]]) -> list[str]:
    """The warnings of a baseline: a fit worse than the nominal on held-out data, divergences."""
    out = []
    held, div = metrics["heldout"], divergence.get("heldout", {})
    nominal, fitted = held["nominal"]["nrmse"], held["fitted"]["nrmse"]
    worse = ("fitted" in div and "nominal" not in div) or (
        nominal is not None and fitted is not None and fitted > nominal * (1.0 + WORSE_MARGIN))
    if worse:
        bad = [f"{p.name} = {short_number(p.value)} {p.unit} ({'; '.join(why)})"
               for p in fit.parameters if (why := implausible(p))]
        figures = ("the fitted model diverges" if "fitted" in div else
                   f"held-out NRMSE nominal {nominal:.4g} -> fitted {fitted:.4g} "
                   f"({fitted / nominal - 1.0:+.0%})")
        out.append(f"the fitted model predicts the held-out data worse than the nominal: {figures}; "
                   + (f"implausible parameters: {', '.join(bad)}" if bad else
                      "no fitted parameter is implausible: the model structure or the held-out design does "
                      "not carry over to the held-out data"))
    for part, models in divergence.items():
        for text in models.values():
            out.append(f"{text} on the {'held-out' if part == 'heldout' else 'fit'} data: no NRMSE is given "
                       "for it")
    return out


# --------------------------------------------------------------------------- report writer
def fitted_rig_dict(result: BaselineResult) -> dict[str, Any]:
    """The fitted rig in the rig-file format, each fitted number's source naming the fit."""
    data = rig_to_dict(result.fit.rig)
    data["name"] = f"{result.nominal_rig.name}_fitted"
    names = ", ".join(_name(r) for r in result.recordings)
    what = (f"{names} (whole; held out: {', '.join(_name(r) for r in result.held_out_recordings)})"
            if result.held_out_recordings else f"the first {result.train_fraction:.0%} of {names}")
    data["description"] = (f"{result.nominal_rig.description} -- grey-box fit "
                           f"(aeropend_ident.greybox.baseline) on {what}")
    moved = result.fit.theta_offset != result.nominal_theta_offset
    part = "whole" if result.held_out_recordings else "train part"
    for p in result.fit.parameters:
        if p.name == THETA_OFFSET:
            continue
        section, fname = p.name.split(".", 1)
        why = result.implausible.get(p.name)
        flag = f"; implausible: {'; '.join(why)}" if why else ""
        data[section][fname]["source"] = (f"grey-box fit on {names} ({part}), "
                                          f"std error {p.std_error:.3g} {p.unit}{flag}")
    if moved:
        for fname in ("theta_min", "theta_max"):
            data["pendulum"][fname]["source"] += " (moved with the fitted theta_offset)"
    if result.fit.theta_offset != 0.0 or result.nominal_theta_offset != 0.0:
        data["recording_frame"] = {THETA_OFFSET: {
            "value": result.fit.theta_offset, "unit": "rad",
            "source": "grey-box fit" if moved else "nominal rig file"}}
    return data


def _plot_segments(result: BaselineResult) -> list[tuple[str, str, UniformData, slice, float]]:
    """(part, label, data, slice into the part's arrays, time offset [s]) of every plotted stretch:
    a single recording split in time order on its own time axis, several recordings end to end."""
    out, t0 = [], 0.0
    for part, data in (("train", result.train), ("heldout", result.heldout)):
        for k, (a, b) in enumerate(data.bounds()):
            seg = data.parts()[k]
            if result.t_split is not None:
                t0 = 0.0 if part == "train" else result.t_split
            out.append((part, _name(seg), seg, slice(a, b), t0))
            if result.t_split is None:
                t0 += float(seg.t[-1]) + seg.dt
    return out


def plot_overlay(result: BaselineResult, path: str | Path) -> Path:
    """Write ``overlay.png``: recorded vs nominal vs fitted θ, fit/held-out boundaries, duty below.

    Angles are in the recordings' frame [rad]; time [s] from the recording's start (several
    recordings are drawn end to end, each labelled). A model that leaves the recorded range is cut
    at the plotted range with a note (:func:`aeropend_ident.io.overlay_axes.clip_to_recorded`); a
    model that diverges is named so in the title instead of an NRMSE, and the baseline's warnings
    (a fit worse than the nominal, implausible parameters) are written on the axes.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aeropend_ident.io.overlay_axes import clip_to_recorded, fit_title
    from aeropend_ident.io.overlay_axes import short_number as num

    path = Path(path)
    fig, (ax, axu) = plt.subplots(2, 1, sharex=True, figsize=(12, 6.5), height_ratios=(3, 1),
                                  constrained_layout=True)
    segments = _plot_segments(result)
    for i, (part, label, seg, sl, t0) in enumerate(segments):
        t = seg.t + t0
        ax.plot(t, seg.theta, color="black", lw=1.2, label="recorded" if i == 0 else None)
        ax.plot(t, result.theta[part]["nominal"][sl], color="tab:orange", lw=1.0, ls="--",
                label="nominal model" if i == 0 else None)
        ax.plot(t, result.theta[part]["fitted"][sl], color="tab:blue", lw=1.0,
                label="fitted model" if i == 0 else None)
        axu.step(t, seg.duty, where="post", color="tab:green", lw=1.0)
        if result.t_split is None:
            for a in (ax, axu):
                a.axvline(t0, color="tab:red" if part == "heldout" else "gray", lw=1.0, ls=":")
            ax.text(t0, 0.98, f"  {'held out' if part == 'heldout' else 'fit'}: {label}",
                    transform=ax.get_xaxis_transform(), va="top", ha="left", fontsize=8,
                    color="tab:red" if part == "heldout" else "gray")
    clip_to_recorded(ax, np.concatenate([s.t + t0 for _, _, s, _, t0 in segments]),
                     np.concatenate([s.theta for _, _, s, _, _ in segments]),
                     {f"{kind} model": np.concatenate([result.theta[p][kind][sl]
                                                       for p, _, _, sl, _ in segments])
                      for kind in ("nominal", "fitted")})
    if result.t_split is not None:
        for a in (ax, axu):
            a.axvline(result.t_split, color="tab:red", lw=1.2, ls=":")
        ax.text(0.01, 0.98, "train (fit)", transform=ax.transAxes, va="top", ha="left", color="tab:red")
        ax.text(result.t_split, 0.98, "  held out", transform=ax.get_xaxis_transform(), va="top", ha="left",
                color="tab:red")
    for a in (ax, axu):
        a.grid(alpha=0.3)

    def fig_of(part: str, model: str) -> str:
        div = result.divergence.get(part, {})
        return "diverges" if model in div else num(result.metrics[part][model]["nrmse"])

    names = ", ".join(_name(r) for r in (*result.recordings, *result.held_out_recordings))
    fit_title(ax, f"{result.nominal_rig.name} on {names}: held-out NRMSE nominal "
                  f"{fig_of('heldout', 'nominal')}, fitted {fig_of('heldout', 'fitted')} (train "
                  f"{fig_of('train', 'nominal')} / {fig_of('train', 'fitted')})", fontsize=10)
    if result.warnings:
        ax.text(0.99, 0.90, "\n".join(_wrap(f"WARNING: {w}", 110) for w in result.warnings),
                transform=ax.transAxes, va="top", ha="right", fontsize=7.5, color="tab:red",
                bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.9, "edgecolor": "tab:red"})
    ax.legend(loc="lower right")
    ax.set_ylabel("θ [rad]")
    axu.set_ylabel("duty τ [1]")
    axu.set_xlabel("time t [s]" if result.t_split is not None else "time t [s] (recordings end to end)")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def _wrap(text: str, width: int) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width, break_long_words=False))


#: The files :func:`write_report` writes into a report folder, by key (the ``baseline`` command's
#: ``--overwrite`` replaces only a folder that holds one of them).
REPORT_FILES = {"report": "report.json", "overlay": "overlay.png", "fitted_rig": "fitted_rig.yaml"}


def write_report(result: BaselineResult, outdir: str | Path) -> dict[str, Any]:
    """Write ``report.json``, ``overlay.png`` and ``fitted_rig.yaml`` (:data:`REPORT_FILES`) into
    ``outdir`` (created; files of the same names are replaced, others are left alone: the
    ``baseline`` command claims an empty folder first).

    The figure is optional: if it cannot be drawn, the report and the fitted rig are still
    written and ``report.json`` says why under ``not_computed`` (the fit is the result).

    Returns
    -------
    dict
        ``{"report": Path, "overlay": Path, "fitted_rig": Path, "not_computed": dict}``
        (no ``"overlay"`` when it could not be drawn; ``not_computed`` gives the reason).
    """
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    rig_path = out / REPORT_FILES["fitted_rig"]
    text = yaml.safe_dump(jsonable(fitted_rig_dict(result)), sort_keys=False, allow_unicode=True)
    rig_path.write_text(text, encoding="utf-8")
    paths: dict[str, Any] = {"fitted_rig": rig_path, "not_computed": {}}
    try:
        paths["overlay"] = plot_overlay(result, out / REPORT_FILES["overlay"])
    except Exception as exc:  # a figure never costs the fitted parameters (a full disk does)
        if is_fault(exc):
            raise
        paths["not_computed"]["figure overlay"] = f"{type(exc).__name__}: {exc}"
    paths["report"] = out / REPORT_FILES["report"]
    doc = {**result.report(), "not_computed": paths["not_computed"]}
    paths["report"].write_text(json.dumps(doc, indent=2, allow_nan=False), encoding="utf-8")
    return paths


def run_baseline(recording: Recording | Sequence[Recording], rig: Rig | str | Path,
                 outdir: str | Path | None = None, **kwargs: Any) -> dict[str, Any]:
    """:func:`baseline` and, if ``outdir`` is given, :func:`write_report`; returns the report dict.

    Keyword arguments are passed to :func:`baseline`. The returned dictionary is what
    ``report.json`` holds (its ``"summary"`` entry has the headline numbers).
    """
    result = baseline(recording, rig, **kwargs)
    if outdir is not None:
        write_report(result, outdir)
    return result.report()
