"""Identify a sparse model from recordings: ``identify BAG_OR_CSV [...] --rig RIG --out DIR``.

Plain command (no ROS needed; also ``ros2 run aeropend_ident identify``): one or more contract
bags or CSV logs (``FILE.csv:PRESET`` per file, else ``--preset`` of
:data:`aeropend_ident.io.csv_import.PRESETS`, else picked by file name) + rig file + method in,
results folder out:

* ``model.yaml``: equations in readable form, coefficients (with spread for ``ensemble``),
  derived physical parameters with units, held-out scores, provenance;
* ``summary.json``: the same headline figures, the selection sweep and what was *not*
  identified and why;
* ``coefficients.png`` (heat-map, rows = equations, columns = library terms),
  ``derivatives.png`` (held-out predicted vs estimated derivatives), ``free_run.png``; the first
  two (and the training-tail free run of the third) are drawn in a forked child process while
  this one runs the held-out free runs (in-process where ``fork`` is unavailable).

What is identified follows from the recorded channels:

* θ, i_a and ω₁ recorded (full state): θ̈ (with the default physics-structured library in the
  second-order weak form from θ alone, :mod:`aeropend_ident.sindy.second_order`; with the other
  libraries θ̇ is estimated when not recorded), di_a/dt when i_a,
  ω₁ and v_a are, dω₁/dt when i_a and ω₁ are; v_a from the duty cycle with the rig's map
  (thesis Eq. 4.3) when not recorded; λ by BIC over a sweep scored on the last quarter of the
  training part, then refitted on the whole training part (the λ-independent regression is built
  once per data set, :func:`aeropend_ident.sindy.core.regression_problem`).
* θ and τ only (partial state, most real logs): the pendulum equation with estimated θ̇ and a
  static or first-order thrust map of the rig's drive quantity (v_a of the voltage families, the
  rotor-speed set-point of an ESC; :func:`aeropend_ident.sindy.partial.search_thrust_map`: lag time
  constant and dead time chosen by the free-run error on the training part, over the range the
  recordings can show, :func:`aeropend_ident.io.recording_input.timing_range`: up to 1 s of dead
  time and more when the holds are long; an optimum at the end of that range is a warning); a
  command with one level (a step test, a free decay) fits the pendulum about that level without
  thrust terms; the current and rotor equations are refused (named in ``summary.json``). With the
  per-equation (structured) library, an equation whose library the data leaves rank deficient
  (e.g. di_a/dt under a constant v_a) is refused with that reason and the others are still
  identified.

Split: each recording in time order, first ``--train-fraction`` (default 75 %) to fit, the rest
held out; free-run NRMSE of θ on every held-out part (a free run that diverges,
:func:`aeropend_ident.io.overlay_axes.diverges`, is reported as such instead). Several recordings:
the training parts are stacked (strong form: ``--method sindy`` or ``ensemble``), each held-out part
is scored alone.

Timing: every recording goes through the one resampling of the tools
(:func:`aeropend_ident.io.resampling.uniform_recording`, onto the first recording's grid);
jitter, dropped rows and gaps are reported in the summary, never refused. Closed-loop logs are
accepted as they are (the commanded duty is the input; see docs/identification.md on what closed
loop means for the estimators). A recording whose constant duty cycle cannot explain θ (a closed
loop's reference without its command) is refused with the ``csv_import`` message
(:func:`aeropend_ident.io.csvspec.constant_input.excitation_problem`).

Errors (unreadable input, a bag without the needed topics, NaNs, too short or unexcited data,
i.e. a rank-deficient library) are printed with the message of the failing step; exit status 2.
Progress goes to stderr (``--quiet`` to silence it).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.errors import IdentificationError
from aeropend_ident.io.csvspec.constant_input import excitation_problem
from aeropend_ident.io.overlay_axes import diverges, hold_span
from aeropend_ident.io.recording_input import TimingRange, ignored_channels, load_recording, timing_range
from aeropend_ident.io.resampling import resampling_notes, uniform_recording
from aeropend_ident.sindy.choices import METHODS, OUTPUT_FILES
from aeropend_ident.sindy.core import WEAK_IV, regression_problem, weak_iv_options
from aeropend_ident.sindy.libraries import (
    CandidateLibrary,
    physics_library,
    physics_structured_library,
    structured_library,
    thesis_library,
)
from aeropend_ident.sindy.model import (
    TARGET_INFO,
    FreeRun,
    IdentData,
    NoEquationError,
    SindyModel,
    free_run,
    save_model,
)
from aeropend_ident.sindy.output_error import refine_output_error
from aeropend_ident.sindy.partial import (
    angle_only_data,
    concat_data,
    search_thrust_map,
    theta_scores,
)
from aeropend_ident.sindy.preprocess import add_derivatives, differentiate
from aeropend_ident.sindy.second_order import combine_models, fit_pendulum
from aeropend_ident.sindy.sweep import select_threshold, sweep_threshold
from aeropend_sim.model import plant_model
from aeropend_sim.output_folder import is_fault
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording

LAMBDAS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5)
#: Fixed λ of weak-iv (its refinement passes make a sweep costly; the benchmark's value).
WEAK_IV_THRESHOLD = WEAK_IV["threshold"]
#: Fewest samples per recording (derivative windows, split, library fit).
MIN_SAMPLES = 50
#: Share of each training part used as the validation tail for λ selection (full-state path).
VALIDATION_FRACTION = 0.25
#: Smallest non-zero lag T [s] of the thrust-map search, and the ratio between successive ones
#: (the grid runs to the data-derived TimingRange.lag_max).
FIRST_ORDER_T_MIN = 0.02
FIRST_ORDER_T_RATIO = 2.2
#: Whole-sample delays always tried, then about this many more, geometrically spaced up to the
#: data-derived TimingRange.delay_max.
FIRST_ORDER_DELAYS = (0, 1, 2, 3)
DELAY_STEPS = 10

Progress = Callable[[str], None]


def _quiet(_msg: str) -> None:
    return None


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
        m = plant_model(rig)
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


def refused_targets(channels: Sequence[str]) -> dict[str, str]:
    """Equations a recording with these channels cannot support, with the reason."""
    have = set(channels)
    out = {}
    if "i_a" not in have:
        out["i_a"] = "armature-current equation di_a/dt: the armature current i_a was not recorded"
    elif "omega_rotor" not in have:
        out["i_a"] = "armature-current equation di_a/dt: needs the rotor speed ω₁ (back-EMF), not recorded"
    if "omega_rotor" not in have:
        out["omega_rotor"] = "rotor-speed equation dω₁/dt: the rotor speed ω₁ was not recorded"
    elif "i_a" not in have:
        out["omega_rotor"] = "rotor-speed equation dω₁/dt: needs the armature current i_a, not recorded"
    return out


def _library(
    name: str, data: IdentData, targets: list[str]
) -> CandidateLibrary | dict[str, CandidateLibrary]:
    variables = [v for v in ("theta", "theta_dot", "i_a", "omega_rotor", "v_a") if v in data.variables]
    if name == "physics-structured":
        psl = physics_structured_library(variables)
        missing = [tg for tg in targets if tg not in psl]
        if missing:
            raise IdentificationError(f"physics-structured library has no equation for {missing} with "
                                      f"variables {variables}")
        return {tg: psl[tg] for tg in targets}
    if name in ("thesis", "full"):
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


def _check_excitation(recs: Sequence[Recording], train_fraction: float) -> None:
    """Refuse recordings whose training parts cannot be identified from (the rule of every fit)."""
    found = []
    for r in recs:
        k = max(round(train_fraction * len(r)), 3)
        ref = "channel theta_ref" if "theta_ref" in r.extra else None
        why = excitation_problem(r.t[:k], r.duty[:k], r.channels["theta"][:k], ref)
        if why is not None and why[0] == "driven":
            raise IdentificationError(f"{r.source}: {why[1]}")
        found.append(why)
    if all(f is not None for f in found):
        raise IdentificationError(f"{recs[0].source}: training part: {found[0][1]}")


def _check_theta(rec: Recording) -> None:
    if len(rec) < MIN_SAMPLES:
        raise IdentificationError(f"{rec.source}: {len(rec)} samples ({rec.t[-1] - rec.t[0]:.3g} s); need at "
                                  f"least {MIN_SAMPLES} to estimate derivatives, split and fit")
    if "theta" not in rec.channels:
        raise IdentificationError(f"{rec.source}: no angle θ recorded (channels {sorted(rec.channels)}); "
                                  "nothing to identify")
    for k, y in [("theta", rec.channels["theta"]), ("duty", rec.duty)]:
        bad = ~np.isfinite(y)
        if bad.any():
            t_bad = rec.t[int(np.flatnonzero(bad)[0])]
            raise IdentificationError(f"{rec.source}: {k} has {int(bad.sum())} NaN/inf value(s), first at "
                                      f"t = {t_bad:.4g} s; cut or repair the log")


#: Training time shown before the held-out part in ``free_run.png`` [s] (the free run over it is
#: recomputed for the plot, so it is kept short).
PLOT_TRAIN_TAIL_S = 10.0


def _model_plot_paths(out: Path, model: SindyModel, held: IdentData) -> list[Path]:
    """Files :func:`_model_plots` draws: ``coefficients.png`` and, with held-out derivatives,
    ``derivatives.png``."""
    files = [out / "coefficients.png"]
    if any(tg in held.derivatives for tg in model.targets):
        files.append(out / "derivatives.png")
    return files


def _model_plots(out: Path, model: SindyModel, held: IdentData) -> list[Path]:
    """Draw :func:`_model_plot_paths` (they need only the model and the held-out derivatives)."""
    from aeropend_ident.sindy.plots import plot_coefficients, plot_derivatives

    coef_path, *deriv_path = _model_plot_paths(out, model, held)
    return [plot_coefficients(model, coef_path), *(plot_derivatives(model, held, p) for p in deriv_path)]


def _train_tail(train: IdentData) -> IdentData:
    """The last :data:`PLOT_TRAIN_TAIL_S` of training shown before the held-out part in ``free_run.png``."""
    dt = float(np.median(np.diff(train.t))) if len(train) > 1 else 1.0
    return train.slice(max(0, len(train) - int(PLOT_TRAIN_TAIL_S / dt)), len(train))


def _plot_child_work(out: Path, model: SindyModel, held: IdentData, tail: IdentData, conn: Any) -> None:
    """In the plotting child: the free run over the training tail (sent back first), then the model plots.

    Ctrl-C at a terminal reaches the child too: it ignores it (the command stops it and says so).
    """
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    conn.send(free_run(model, tail, substeps=1))
    conn.close()
    _model_plots(out, model, held)


@dataclass
class _PlotChild:
    """A forked plotting process and the receiving end of its pipe (the training-tail free run)."""

    proc: Any
    conn: Any

    def join(self) -> None:
        self.proc.join()
        self.conn.close()


def _start_plot_child(out: Path, model: SindyModel, held: IdentData, train: IdentData) -> _PlotChild | None:
    """Fork a child that runs the training-tail free run for ``free_run.png`` and draws :func:`_model_plots`
    while this process runs the held-out free run(s) and draws ``free_run.png``.

    The two halves take about equally long, so on a machine with a spare core they overlap.
    Returns None where ``fork`` is not available or there is one CPU only (:func:`_plots` then
    does everything here, as it does when the child fails).
    """
    import multiprocessing
    import warnings

    if (os.cpu_count() or 1) < 2 or "fork" not in multiprocessing.get_all_start_methods():
        return None
    import aeropend_ident.sindy.plots  # noqa: F401  matplotlib imported once, before the fork, for both
    ctx = multiprocessing.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)
    # fork, not spawn: the model holds the library's lambdas, which do not pickle. OpenBLAS's worker
    # threads are fork-safe (pthread_atfork), which Python >= 3.12's generic multi-threaded-fork
    # DeprecationWarning cannot know.
    proc = ctx.Process(target=_plot_child_work, args=(out, model, held, _train_tail(train), send),
                       name="identify-plots", daemon=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        proc.start()
    send.close()  # this process's copy: a child that dies early then gives EOF, not a hang
    return _PlotChild(proc, recv)


def _plots(out: Path, model: SindyModel, held: IdentData, train: IdentData, held_run: FreeRun,
           say: Progress, child: _PlotChild | None = None) -> list[str]:
    from aeropend_ident.sindy.plots import plot_free_run, source_label

    train = _train_tail(train)
    tr = None
    if child is not None:
        try:
            tr = child.conn.recv()
        except (EOFError, OSError):  # the child failed before sending: run it here
            tr = None
    if tr is None:
        tr = free_run(model, train, substeps=1)
    ho = held_run
    states = [s for s in ho.states if s in held.variables and s in ("theta", "i_a", "omega_rotor")]
    # the recording's own time, as derivatives.png; two free runs: the training tail's and the held-out one
    t = np.concatenate([train.t, held.t])
    meas = {s: np.concatenate([train.variables[s], held.variables[s]]) for s in states}
    sim = {s: np.concatenate([tr.states[s], ho.states[s]]) for s in states}
    last = plot_free_run(t, meas, sim, out / "free_run.png", t_split=float(held.t[0]), states=states,
                         title=f"free run of the identified model on {source_label(held.source)}: last "
                               f"{PLOT_TRAIN_TAIL_S:g} s of training, then held out (each run from its "
                               "first measured state)")
    if child is not None:
        child.join()
    if child is None or child.proc.exitcode != 0:  # no child, or it failed: draw here (raises the real error)
        first = _model_plots(out, model, held)
    else:
        first = _model_plot_paths(out, model, held)
    files = [*first, last]
    say(f"plots: {', '.join(p.name for p in files)}")
    return [p.name for p in files]


def _held_out_runs(model: SindyModel, recs: Sequence[Recording], parts: Sequence[tuple[IdentData, IdentData]],
                   say: Progress) -> tuple[list[dict[str, Any]], list[FreeRun]]:
    """Free run of the model on each held-out part: θ scores per recording and the runs."""
    say("free runs on the held-out part(s)")
    scores, held_runs = [], []
    for r, (tr, ho) in zip(recs, parts, strict=True):
        fr = free_run(model, ho, substeps=1)
        held_runs.append(fr)
        sc = theta_scores(ho.variables["theta"], fr.states["theta"])
        del sc["max_abs_rad"]  # not part of identify's report
        sc.update({"recording": r.source, "heldout_samples": len(ho), "free_run_nrmse_std": fr.nrmse})
        # a held-out hold (it barely moves) is measured in the recording's range, as baseline does
        whole = np.concatenate([tr.variables["theta"], ho.variables["theta"]])
        span = hold_span(ho.variables["theta"], float(np.nanmax(whole) - np.nanmin(whole)))
        if span is not None:
            sc.update({"nrmse_range": sc["rms_rad"] / span,
                       "normalised_by": "the recording's range (a hold)"})
        why = diverges(fr.states["theta"], ho.variables["theta"], ho.t - ho.t[0], span=span)
        if why is not None:  # the one divergence rule: no NRMSE for a run that left the recorded range
            sc.update({"diverges": f"free run {why}", "nrmse_range": None, "nrmse_std": None})
        scores.append(sc)
        say(f"  {r.source}: held-out free run of θ: "
            + (sc["diverges"] if why else f"NRMSE(range) {sc['nrmse_range']:.4g}"))
    return scores, held_runs


def _pendulum_alone(train: IdentData, library: Any, extra: dict[str, Any], say: Progress) -> Any:
    """The pendulum equation θ̈ from θ alone (second-order weak form,
    :func:`~aeropend_ident.sindy.second_order.fit_pendulum`), its selection details in ``extra``."""
    say("pendulum equation θ̈ from θ alone (second-order weak form; λ by BIC, pruning by the "
        "validation free run)")
    pendulum = fit_pendulum(train, library)
    say(f"  {pendulum.model.equations()[0]} (λ = {pendulum.threshold:g})")
    extra["pendulum"] = {
        "form": "second-order weak form (θ̈ and θ̇ integrated onto the test functions)",
        "threshold_selection": "BIC on the weak residual of the last 25 % of the training part",
        "threshold": pendulum.threshold, "H_xt_s": pendulum.H_xt, "K": pendulum.K,
        "sweep": pendulum.sweep, "pruning": pendulum.pruning,
    }
    return pendulum


def _identify_full_state(
    recs: Sequence[Recording], paths: Sequence[str | Path], rig: Rig | None, method: str, library: str,
    train_fraction: float, threshold: float | None, output_error: bool, refused: dict[str, str],
    extra: dict[str, Any], say: Progress,
) -> tuple[SindyModel, list[tuple[IdentData, IdentData]], dict[str, float], list[str]]:
    """The full-state path of :func:`identify` (θ, i_a, ω₁ recorded): every supported equation.

    Adds the equations the data refuse to ``refused`` and the selection details to ``extra``;
    returns the model, the (train, held-out) parts, the held-out MSE and the targets.
    """
    datas = []
    for r in recs:
        d = data_from_recording(r, rig)
        datas.append(add_derivatives(d, targets=supported_targets(d), method="savgol"))
    targets = supported_targets(datas[0])
    parts = [d.split(train_fraction) for d in datas]
    train = concat_data([p[0] for p in parts])
    test = concat_data([p[1] for p in parts])
    lib = _library(library, train, targets)
    pendulum = None
    if library == "physics-structured" and "theta_dot" in targets:
        pendulum = _pendulum_alone(train, lib["theta_dot"], extra, say)
        targets = [tg for tg in targets if tg != "theta_dot"]
        lib = {tg: lib[tg] for tg in targets}
    kw: dict[str, Any] = {"method": method, "exclude_input_steps": 3}
    if method == "weak":
        kw.update(K=300, H_xt=min(0.05, 0.2 * (train.t[-1] - train.t[0])))
    elif method == "weak-iv":
        kw.update(weak_iv_options(train.t[-1] - train.t[0]))
    # the λ-independent regression on the whole training part(s), built once: it refuses the
    # equations the data cannot support (per-equation library) and serves the final refit
    train_kw = dict(kw)
    try:
        problem = regression_problem(train, lib, targets, drop_unidentifiable=isinstance(lib, dict),
                                     **train_kw)
        dropped = problem.dropped
    except NoEquationError as exc:
        problem, dropped = None, exc.dropped
    for tg, why in dropped.items():
        refused[tg] = f"{TARGET_INFO[tg][1]}: {why}"
        say(f"not identified: {refused[tg]}")
    if problem is None:
        raise IdentificationError(f"no equation can be identified from {paths}: {refused}")
    targets, lib = list(problem.targets), problem.library
    # λ by BIC on a validation tail of each training part (the held-out parts are only scored),
    # then the model is refitted with that λ on the whole training parts
    if threshold is None:
        fits = [p[0].split(1.0 - VALIDATION_FRACTION) for p in parts]
        fit_part, val_part = concat_data([f[0] for f in fits]), concat_data([f[1] for f in fits])
        if method == "weak":
            kw["H_xt"] = min(kw["H_xt"], 0.2 * (fit_part.t[-1] - fit_part.t[0]))
        say(f"sweeping λ over {list(LAMBDAS)} ({method}, {library} library, targets {targets})")
        pts, _models = sweep_threshold(fit_part, val_part, lib, LAMBDAS, targets=targets, **kw)
        best = select_threshold(pts, "bic")
        lam = best.threshold
        say(f"λ = {lam:g} (BIC on the validation tail); refitting on the training part(s)")
        if kw != train_kw:  # a shorter subdomain half-width for a short record: rebuild
            problem = regression_problem(train, lib, targets, **kw)
        extra["threshold_selection"] = (f"BIC on the last {VALIDATION_FRACTION:.0%} of each training "
                                        "part (held-out parts not used)")
        extra["sweep"] = [{"threshold": p.threshold, "n_terms": p.n_terms, "bic": p.bic} for p in pts]
    else:
        lam = float(threshold)
        say(f"fitting at the fixed λ = {lam:g} ({method}, {library} library, targets {targets})")
        extra["threshold_selection"] = "fixed"
    model = problem.solve(lam)
    oe = [tg for tg in ("i_a", "omega_rotor") if tg in model.targets]
    if output_error and oe:
        say(f"output-error refinement of {oe} (simulation error, multiple shooting)")
        model = refine_output_error(model, train, targets=oe)
    elif output_error:
        say("output-error refinement skipped: neither di_a/dt nor dω₁/dt is identified")
    if pendulum is not None:
        extra["electrical_threshold"] = lam
        model = combine_models([pendulum.model, model], method=f"weak2+{model.method}")
        targets = list(model.targets)
    test_mse = model.test_mse(test, exclude_input_steps=kw["exclude_input_steps"])
    return model, parts, test_mse, targets


def thrust_map_grids(timing: TimingRange, dt: float) -> tuple[tuple[float, ...], tuple[int, ...]]:
    """The (T [s], delay [samples]) search of the first-order thrust map over the range the data show.

    T: 0 (static), then from :data:`FIRST_ORDER_T_MIN` by factors of about
    :data:`FIRST_ORDER_T_RATIO` up to ``timing.lag_max``; delays: :data:`FIRST_ORDER_DELAYS`, then
    about :data:`DELAY_STEPS` whole-sample values geometrically spaced up to ``timing.delay_max``.
    """
    n_t = max(2, math.ceil(math.log(max(timing.lag_max, 2 * FIRST_ORDER_T_MIN) / FIRST_ORDER_T_MIN)
                         / math.log(FIRST_ORDER_T_RATIO)) + 1)
    grid_t = (0.0, *np.geomspace(FIRST_ORDER_T_MIN, max(timing.lag_max, FIRST_ORDER_T_MIN), n_t).tolist())
    n_max = math.floor(timing.delay_max / dt + 1e-9)
    first = FIRST_ORDER_DELAYS[-1] + 1
    more = np.rint(np.geomspace(first, n_max, DELAY_STEPS)) if n_max >= first else np.array([])
    grid_d = sorted({d for d in FIRST_ORDER_DELAYS if d <= n_max} | {int(v) for v in more})
    return tuple(sorted(set(grid_t))), tuple(grid_d)


def _bound_warnings(sel: Any, grid_t: Sequence[float], grid_d: Sequence[int], dt: float,
                    timing: TimingRange) -> list[str]:
    """Warnings for a thrust-map optimum at the upper end of its search range."""
    out = []
    if len(grid_d) > 1 and sel.delay == max(grid_d):
        out.append(f"the thrust-map dead time {sel.delay * dt:.3g} s ({sel.delay} samples) sits at the upper "
                   f"end of its search range 0-{max(grid_d) * dt:.3g} s ({timing.rule()}): the data may hide "
                   "a longer dead time; record longer holds, or a step from rest, to show it")
    if len(grid_t) > 1 and sel.time_constant == max(grid_t):
        out.append(f"the thrust-map lag T = {sel.time_constant:.3g} s sits at the upper end of its search "
                   f"range 0-{max(grid_t):.3g} s ({timing.rule()}): the data may hide a slower response")
    return out


def _drive(rig: Rig | None) -> tuple[Any, str, str]:
    """(τ -> drive quantity map or None, its symbol, its description) of the partial-state path."""
    if rig is None:
        return None, "v_a", "duty cycle τ [1]"
    model = plant_model(rig)
    if model.assembly.drive_name == "v_a":
        return model.drive, "v_a", "v_a [V] from the rig's duty map"
    return model.drive, "ω_sp", "the ESC's rotor-speed set-point ω_sp [rad/s] from the rig's throttle map"


def _identify_partial_state(
    recs: Sequence[Recording], paths: Sequence[str | Path], rig: Rig | None, method: str, thrust_map: str,
    train_fraction: float, threshold: float | None, output_error: bool, extra: dict[str, Any], say: Progress,
) -> tuple[SindyModel, list[tuple[IdentData, IdentData]], dict[str, float], list[str]]:
    """The partial-state path of :func:`identify` (θ and τ only): pendulum equation + thrust map.

    Adds the thrust map, notes and warnings to ``extra``; returns the model, the (train, held-out)
    parts, the held-out MSE and the targets.
    """
    vmap, symbol, described = _drive(rig)
    datas = [angle_only_data(r.t - r.t[0], r.channels["theta"], r.duty, vmap, source=r.source)
             for r in recs]
    dt = recs[0].dt
    timing = timing_range([r.slice(0, max(round(train_fraction * len(r)), 2)) for r in recs])
    grid_t, grid_d = thrust_map_grids(timing, dt) if thrust_map == "first_order" else ((0.0,), (0,))
    if method == "weak-iv" or output_error:
        raise IdentificationError("weak-iv and --output-error need the full state (θ, i_a, ω₁); "
                                  f"{paths} record only θ and the duty cycle: use weak or sindy")
    kw = {"K": 300, "H_xt": min(0.5, 0.1 * (datas[0].t[-1] - datas[0].t[0]))} if method == "weak" else {}
    if threshold is not None:
        kw["threshold"] = float(threshold)
    say(f"partial state (θ, τ): pendulum equation with a {thrust_map} thrust map of {described}, T up to "
        f"{max(grid_t):.3g} s and dead time up to {max(grid_d) * dt:.3g} s ({timing.rule()}), {method}")
    sel = search_thrust_map(datas, train_fraction, grid_t, grid_d, method=method, progress=say, symbol=symbol,
                            **kw)
    model, parts = sel.model, sel.parts
    test = concat_data([p[1] for p in parts])
    test_mse = model.test_mse(test)
    targets = ["theta_dot"]
    extra["thrust_map"] = {"kind": thrust_map, "time_constant_s": sel.time_constant,
                           "delay_samples": sel.delay, "delay_s": sel.delay * dt,
                           "training_free_run_nrmse": sel.train_nrmse, "input": described,
                           "search": {**timing.as_dict(), "time_constants_s": list(grid_t),
                                      "delays_samples": list(grid_d)},
                           "grid": sel.grid}
    extra["notes"] = sel.notes
    extra.setdefault("warnings", []).extend(_bound_warnings(sel, grid_t, grid_d, dt, timing))
    for n in sel.notes:
        say(f"note: {n}")
    return model, parts, test_mse, targets


def _read_recordings(paths: Sequence[Path], preset: Any, namespace: Any, say: Callable[[str], None]
                     ) -> list[Recording]:
    """The recordings, each checked for θ and put on one uniform grid (the first one's period: the
    one resampling of the tools), their resampling said."""
    recs: list[Recording] = []
    for p in paths:
        say(f"reading {p}")
        rec = load_recording(p, preset, namespace)
        _check_theta(rec)
        rec = uniform_recording(rec, dt=recs[0].dt if recs else None)
        say(f"  {len(rec)} samples at {1.0 / rec.dt:.4g} Hz, channels {sorted(rec.channels)}")
        for note in resampling_notes([rec]):
            say(f"  {note}")
        recs.append(rec)
    return recs


def _method_and_threshold(method: str | None, threshold: float | None, full: bool, n_recordings: int
                          ) -> tuple[str, float | None]:
    """The regression method (default: the weak form for one full-state recording, else the strong
    form) and the STLSQ threshold λ (weak-iv's own by default), checked.

    Raises
    ------
    IdentificationError
        An unknown method, a λ that is not finite and ≥ 0, or the weak form over several recordings.
    """
    if method is None:
        method = "weak" if (full and n_recordings == 1) else "sindy"
    if method not in METHODS:
        raise IdentificationError(f"method = {method!r}; expected one of {list(METHODS)}")
    if threshold is None and method == "weak-iv":
        threshold = WEAK_IV_THRESHOLD
    if threshold is not None and not (math.isfinite(threshold) and threshold >= 0.0):
        raise IdentificationError(f"threshold = {threshold!r}; expected a finite λ >= 0")
    if n_recordings > 1 and method in ("weak", "weak-iv"):
        raise IdentificationError("several recordings are stacked for a strong-form regression; use "
                                  "--method sindy or ensemble (the weak form would integrate across joins)")
    return method, threshold


def identify(
    bag: Path | Sequence[Path], out: Path, rig: Rig | None, method: str | None = None,
    library: str = "physics-structured", namespace: str = "", preset: str | None = None,
    train_fraction: float = 0.75, thrust_map: str = "first_order", plots: bool = True,
    progress: Progress | None = None, threshold: float | None = None, output_error: bool = False,
) -> dict[str, Any]:
    """Run the whole pipeline; returns the summary written to ``out/summary.json``.

    Parameters
    ----------
    bag : Path or sequence of Path
        Contract bag(s) and/or CSV log(s).
    rig : Rig, optional
        Duty -> v_a map (thesis Eq. 4.3), gear ratio and L/J for K_q.
    method : {"weak", "weak-iv", "sindy", "ensemble"}, optional
        Default: ``"weak"`` for one full-state recording, ``"sindy"`` otherwise. ``"weak-iv"``
        (full state, one recording): the weak form with the hold-exact input quadrature refined
        twice (intra-sample curvature + instrumental variables, ridge 1;
        :data:`aeropend_ident.sindy.core.WEAK_IV`), at
        the fixed λ = :data:`WEAK_IV_THRESHOLD` unless ``threshold`` is given (the estimator of
        the issue-4 benchmark).
    thrust_map : {"first_order", "static"}
        Partial-state path: lag grid :data:`FIRST_ORDER_T` × :data:`FIRST_ORDER_DELAYS`, or T = 0.
    threshold : float, optional
        Fixed STLSQ threshold λ (no sweep); default: λ by BIC over :data:`LAMBDAS` (weak-iv:
        :data:`WEAK_IV_THRESHOLD`).
    library : str
        One of :data:`~aeropend_ident.sindy.choices.LIBRARIES` (full-state path).
        ``"physics-structured"``: θ̈ from the angle alone in the second-order weak form
        (:func:`aeropend_ident.sindy.second_order.fit_pendulum`: λ by BIC, terms pruned by the
        validation free run), di_a/dt and dω₁/dt from their physical
        terms with ``method``.
    output_error : bool
        Full-state path: re-estimate the selected terms of di_a/dt and dω₁/dt by output-error
        minimisation (:func:`aeropend_ident.sindy.output_error.refine_output_error`), with standard
        errors in ``model.yaml``.

    Raises
    ------
    IdentificationError, BagError, CsvImportError, RecordingError, RecordingInputError
        With the message of the failing step.
    """
    say = progress or _quiet
    t0 = time.perf_counter()
    paths = [Path(bag)] if isinstance(bag, (str, Path)) else [Path(b) for b in bag]
    if not paths:
        raise IdentificationError("no input recording given")
    if thrust_map not in ("first_order", "static"):
        raise IdentificationError(f"thrust_map = {thrust_map!r}; expected 'first_order' or 'static'")
    recs = _read_recordings(paths, preset, namespace, say)
    _check_excitation(recs, train_fraction)
    full = all({"i_a", "omega_rotor"} <= set(r.channels) for r in recs)
    method, threshold = _method_and_threshold(method, threshold, full, len(recs))
    refused = {} if full else refused_targets(sorted(set.intersection(*(set(r.channels) for r in recs))))
    for why in refused.values():
        say(f"not identified: {why}")
    out.mkdir(parents=True, exist_ok=True)
    extra: dict[str, Any] = {}
    if full:
        model, parts, test_mse, targets = _identify_full_state(
            recs, paths, rig, method, library, train_fraction, threshold, output_error, refused, extra, say)
    else:
        model, parts, test_mse, targets = _identify_partial_state(
            recs, paths, rig, method, thrust_map, train_fraction, threshold, output_error, extra, say)
    child = _start_plot_child(out, model, parts[0][1], parts[0][0]) if plots else None
    try:
        scores, held_runs = _held_out_runs(model, recs, parts, say)
        gear = rig.motor.gear_ratio if rig is not None else None
        l_j = rig.pendulum.L_over_J if rig is not None else None
        prov = {"inputs": [str(p) for p in paths], "rig": rig.name if rig else None, "library": library,
                "samples": [len(r) for r in recs], "train_fraction": train_fraction}
        if "thrust_map" in extra:
            prov["thrust_map"] = {k: v for k, v in extra["thrust_map"].items() if k != "grid"}
        model_file, summary_file = OUTPUT_FILES
        save_model(out / model_file, model, gear_ratio=gear, L_over_J=l_j, test_mse=test_mse,
                   free_run_nrmse=scores[0]["free_run_nrmse_std"], provenance=prov)
        files = list(OUTPUT_FILES)
        not_computed: dict[str, str] = {}
        if plots:
            try:
                files += _plots(out, model, parts[0][1], parts[0][0], held_runs[0], say, child)
            except Exception as exc:  # the figures never cost the identified model (a full disk does)
                if is_fault(exc):
                    raise
                not_computed["plots"] = f"{type(exc).__name__}: {exc}"
                say(f"plots: not drawn: {not_computed['plots']}")
    finally:
        if child is not None:  # also on an error: never leave the plotting child behind
            child.join()
    summary = {
        "inputs": [str(p) for p in paths], "bag": str(paths[0]), "samples": sum(len(r) for r in recs),
        "targets": targets, "not_identified": refused, "method": model.method, "library": library,
        "threshold": model.threshold, "equations": model.equations(),
        "derived_parameters": {k: {"value": v, "unit": u} for k, (v, u) in
                               model.derived_parameters(gear, l_j).items()},
        "test_mse": test_mse, "heldout": scores, "free_run_nrmse": scores[0]["free_run_nrmse_std"],
        **extra, "files": files, "not_computed": not_computed,
        "ignored_channels": ignored_channels(recs, "θ, the duty cycle and the contract channels"),
        "resampling": resampling_notes(recs), "warnings": extra.pop("warnings", []),
        "wall_time_s": round(time.perf_counter() - t0, 3),
    }
    if "thrust_map" in extra:
        tm = extra["thrust_map"]
        summary["derived_parameters"]["thrust_time_constant"] = {"value": tm["time_constant_s"], "unit": "s"}
        summary["derived_parameters"]["thrust_delay"] = {"value": tm["delay_s"], "unit": "s"}
    text = json.dumps(summary, indent=1, ensure_ascii=False, default=float) + "\n"
    (out / summary_file).write_text(text, encoding="utf-8")
    return summary
