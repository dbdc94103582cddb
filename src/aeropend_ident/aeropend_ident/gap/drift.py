"""Held-out error prediction of a gap correction, and the drift priors it draws from.

A constant-parameter correction found on one session removes the missing physics it names, but
not the rig changing between sessions (battery, propeller, load, bearings, sensor mount). This
module and :mod:`aeropend_ident.gap.sessions` tell them apart, for
:func:`aeropend_ident.gap.run.run_gap`:

**Prediction** (:func:`predict_heldout`, computed from the fit data and the held-out recordings'
duty and start only, before any held-out error is computed): a Monte-Carlo predictive
distribution of the corrected rig's held-out θ NRMSE e. Each of :data:`N_DRAWS` draws takes

* e_in: the corrected rig's error within the session, i.e. on the validation part the effects
  were chosen on, as a two-stage block bootstrap of its RMS error in rad: the validation
  recordings' :data:`BLOCK_S` s blocks drawn with replacement (the uncertainty of that estimate),
  then per held-out recording as many blocks as it holds drawn from them (its own sampling; a
  held-out NRMSE is an RMS over a whole recording, not one block's): the within-session
  variation;
* a session-to-session log change of each drift-prone parameter (:data:`DRIFT_PARAMETERS`:
  thrust coefficient K_q, gravity term mgd/J, viscous friction c/J, and the supply voltage V_s
  when v_a is recorded) from :func:`draw_log_changes`: per session an unknown share
  π ~ Uniform(0, 1) of the parameters changes, each by N(0, 2σ_p²) (σ_p: :data:`DRIFT_PRIOR`, the
  standard deviation of the log change, kept), or, when the fit data hold several sessions, a
  normal change with their measured σ_p;

re-simulates the drawn rig on each held-out recording's duty and records
e² = (e_in² + mean squared change of the replay) / s², s the expected range of the recorded angle
on that recording: the corrected rig's replay plus the measurement noise (:func:`recorded_range`;
the NRMSE is over the held-out recording's recorded range, and a drift moves θ by what the duty
asks of the rod, not by the validation part's range). The median of the draws is the
prediction; the shortest interval in log e holding 80 % of them and 80 % of the draws in which
nothing moved (:func:`shortest_interval`) is the 80 % interval: the atom "nothing moved" at the
distribution's lower end is a possible outcome, inside, not a tail beyond it. The
chosen effects' parameters are the fitted ones in every draw: their error is already in e_in,
which is measured with them (docs/findings/gap.md, "The noise on a lattice, a product in the
drift table").

**Attainable shrink** (:func:`aeropend_ident.gap.sessions.attainable`, after the held-out
replay): the chosen effect set,
the chosen set plus the drift-prone parameters, and separately the best catalog set up to
``max_effects`` (a diagnosis run on that recording alone), fitted directly on each held-out
recording: the best a constant-parameter correction could
do there (an oracle, in-sample on purpose). With N, C, O the nominal, corrected and oracle θ
NRMSEs and n the θ noise floor (σ_θ / range), the nominal gap N² − n² splits into

* removed by the correction: N² − C²;
* removable but not removed: C² − O² (the correction's parameters are off for this session:
  drift, or an effect the fit data did not show);
* not removable by the catalog: O² − n² (missing physics).

**Session drift** (:func:`aeropend_ident.gap.sessions.drift_table`): the chosen effects plus
the drift-prone parameters fitted
on each session separately, with standard errors; a parameter drifts when its change between
sessions exceeds :data:`DRIFT_Z` combined standard errors and :data:`DRIFT_MIN` relative.

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from aeropend_ident.errors import GapError
from aeropend_ident.gap.effects import (
    EffectContext,
    MeasurementMap,
    get_effect,
    identifiable,
    measurement_noise,
)
from aeropend_ident.gap.which.data import INITIAL_STATE_WINDOW, Prepared, prepare, replay, replay_many
from aeropend_ident.gap.which.diagnosis import EffectDiagnosis
from aeropend_ident.gap.which.fitting import COVARIANCE_BLOCK_S, fit_effects
from aeropend_sim.components import registry
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording

#: Drift-prone parameters: effect -> (rig section, field), every hypothesis of the registry that
#: declares a session-to-session drift (:attr:`aeropend_sim.components.base.Diagnosis.drift_sigma`),
#: in catalog order. A drift-only entry (the supply voltage, :func:`aeropend_ident.gap.effects.drift_only`)
#: needs the armature voltage v_a recorded: with the angle alone a supply change is a thrust-gain
#: change (thrust ∝ v_a²), which K_q's prior covers.
DRIFT_PARAMETERS: dict[str, tuple[str, str]] = {
    d.name: tuple(d.search[0].target.split(".", 1)) for d in registry.diagnoses() if d.drift_sigma > 0.0
}


#: Prior standard deviation of the session-to-session log change of each drift-prone parameter
#: (0.15 ≈ ±15 %), declared with the hypothesis (its physical size and reason there, and in
#: docs/gap.md, "Drift prior"); its shape is :func:`draw_log_changes`'. The real rigs in
#: ``../shared/data/real`` show such changes between sessions (AeroShield's thrust per duty up to
#: 35 % apart at 29–33 PWM counts, Etchepareborda's rod hanging 0.1–0.2 rad higher). Used only
#: when the fit data hold one session.
DRIFT_PRIOR: dict[str, float] = {d.name: d.drift_sigma for d in registry.diagnoses() if d.drift_sigma > 0.0}


#: Monte-Carlo draws of the prediction (one replay of each validation recording per draw).
N_DRAWS = 300


#: Block length of the within-session error [s]: the block sandwich's
#: (:data:`aeropend_ident.gap.which.fitting.COVARIANCE_BLOCK_S`), longer than a replay's error stays
#: correlated by the rod's own dynamics; a 10 s validation part holds five. With 5 s blocks it held
#: two, too few to estimate a spread from: the unchanged rig's actual fell just under the
#: within-session atom (docs/findings/gap.md, "The atom inside the interval").
BLOCK_S = COVARIANCE_BLOCK_S


#: Probability of the predicted interval (80 %): the shortest interval in log NRMSE holding this
#: share of the draws (:func:`shortest_interval`).
LEVEL = 0.80


#: Noise draws of :func:`recorded_range` (the expected range of a recorded angle).
RANGE_DRAWS = 16


#: An interval whose upper end exceeds this many times its lower end says why (``why_wide``).
WIDE_RATIO = 10.0


def _preps(recs: Sequence[Recording], channels: Sequence[str]) -> list[Prepared]:
    return prepare(list(recs), frozenset(channels) | {"theta"})


def _start_only(prep: Prepared) -> Prepared:
    """A target recording as the prediction may read it: the whole duty, the measured channels
    over the first :data:`aeropend_ident.gap.which.data.INITIAL_STATE_WINDOW` only (where a replay's
    start is estimated, its noise level included); the rest of the angle, its error, stays unread."""
    k = min(prep.n, max(round(INITIAL_STATE_WINDOW / prep.dt), 1))
    return Prepared(rec=prep.rec, dt=prep.dt, duty=prep.duty, y={c: v[:k] for c, v in prep.y.items()},
                    scale=prep.scale)


def _fit_set(nominal: Rig, effects: Sequence[str], preps: Sequence[Prepared],
             start: Mapping[str, Mapping[str, float]] | None = None, scan: bool = False,
             free_settings: Sequence[str] = ()) -> Any:
    """The effect set fitted on prepared recordings, search ranges from those recordings; the
    held parameters of ``free_settings`` (a diagnosis' ``free_settings``) fitted too."""
    ctx = EffectContext.from_prepared(nominal, preps)
    ctx = dataclasses.replace(ctx, free_settings=frozenset(free_settings))
    return fit_effects(nominal, list(effects), list(preps), ctx, start=start, scan=scan)


def theta_nrmse(rig: Rig, meas: MeasurementMap, prep: Prepared) -> float:
    """Free-run θ NRMSE (RMS error / θ range) of a rig on one prepared recording."""
    return theta_run(rig, meas, prep)[0]


def theta_run(rig: Rig, meas: MeasurementMap, prep: Prepared) -> tuple[float, str | None]:
    """One free run of a rig on one prepared recording: its θ NRMSE (RMS error / θ range) and whether
    it diverges (the one rule of every tool, :func:`aeropend_ident.io.overlay_axes.diverges`: the
    reason, or None)."""
    from aeropend_ident.io.overlay_axes import diverges

    sim = replay(rig, meas, prep)["theta"]
    nrmse = float(np.sqrt(np.mean((sim - prep.y["theta"]) ** 2)) / prep.scale["theta"])
    return nrmse, diverges(sim, prep.y["theta"])


def noise_floor(prep: Prepared) -> float:
    """θ noise floor n = σ̂_θ / range, σ̂_θ from :func:`aeropend_ident.gap.effects.measurement_noise`
    (the white-noise estimate, at least the rounding noise q/√12 of a detected angle quantum q)."""
    return measurement_noise(prep.y["theta"]) / prep.scale["theta"]


def drift_parameters(channels: Sequence[str], family: str = registry.DEFAULT_FAMILY) -> list[str]:
    """The drift-prone parameters (:data:`DRIFT_PARAMETERS`) of a rig of ``family`` identifiable
    from these channels."""
    have = frozenset(channels) | {"theta"}
    return [e for e in DRIFT_PARAMETERS
            if family in get_effect(e).families and identifiable(get_effect(e), have) is None]


def _perturbed_or_none(rig: Rig, factors: Mapping[str, float]) -> Rig | None:
    """:func:`_perturbed`, None when a factor takes a value outside its limits (a failed draw)."""
    try:
        return _perturbed(rig, factors)
    except GapError:
        return None


def _perturbed(rig: Rig, factors: Mapping[str, float]) -> Rig:
    new = rig
    for eff, f in factors.items():
        section, name = DRIFT_PARAMETERS[eff]
        v = float(getattr(getattr(new, section), name))
        if v != 0.0 and f != 1.0:  # through the effect: the Eq. 4.3 map scales with the supply too
            new = get_effect(eff).apply(new, {name: v * f})
    return new


def _chosen_values(diag: EffectDiagnosis) -> tuple[dict[str, dict[str, float]], dict[str, dict[str, float]]]:
    """(values, standard errors) of the chosen effects' parameters from the diagnosis' ranking."""
    vals: dict[str, dict[str, float]] = {}
    std: dict[str, dict[str, float]] = {}
    by_name = {r["effect"]: r for r in diag.ranking}
    for name in diag.chosen:
        params = by_name.get(name, {}).get("parameters", {})
        vals[name] = {k: float(v["value"]) for k, v in params.items()}
        # a standard error the data do not give (None, or infinite: not determined) draws no spread
        std[name] = {k: (float(v["std"]) if v.get("std") is not None and math.isfinite(v["std"]) else 0.0)
                     for k, v in params.items()}
    return vals, std


def _ms_changes(rigs: Sequence[Rig | None], meas: MeasurementMap, preps: Sequence[Prepared],
                base: Sequence[np.ndarray], scales: Sequence[float], *,
                base_rig: Rig | None = None) -> list[list[float] | None]:
    """Per rig and recording: the mean squared θ change of its replay from the base replay, over
    that recording's scale²; None for a rig that is None or whose replay fails on any recording.
    One batched replay per recording (:func:`aeropend_ident.gap.which.data.replay_many`) of each distinct
    rig object: a rig given twice is replayed once, and ``base_rig`` (the rig of the base replays,
    replayed the same way) not at all: its change is 0.0 exactly, as its replay is the base replay
    bit for bit (a draw in which no drift-prone parameter changes returns that very rig,
    :func:`_perturbed`)."""
    out: list[list[float] | None] = [[] if r is not None else None for r in rigs]
    first: dict[int, int] = {}  # id of a rig object -> the first row holding it
    for b, r in enumerate(rigs):
        if r is not None and r is not base_rig:
            first.setdefault(id(r), b)
    live = list(first.values())
    for p, sim, s in zip(preps, base, scales, strict=True):
        rows = replay_many([(rigs[b], meas) for b in live], p, ("theta",)) if live else []
        for b, row in zip(live, rows, strict=True):
            if row is None or out[b] is None:
                out[b] = None
                continue
            out[b].append(float(np.mean((row["theta"] - sim) ** 2)) / s**2)
    for b, r in enumerate(rigs):
        if r is None:
            continue
        if r is base_rig:
            out[b] = [0.0] * len(preps)
        elif first[id(r)] != b:
            src = out[first[id(r)]]
            out[b] = None if src is None else list(src)
    return out


def _nrmse_of(e_in: float | Sequence[float], ms: Sequence[float], scales: Sequence[float]) -> float:
    """The held-out θ NRMSE of one draw: per target recording √(e_in²/s² + ms), e_in the
    within-session RMS error [rad] (one, or one per target), s the recording's θ scale [rad] and ms
    its replay's mean squared change over s²; the mean over the recordings (as the held-out NRMSE
    is)."""
    e = [float(e_in)] * len(ms) if np.ndim(e_in) == 0 else [float(x) for x in e_in]
    return float(np.mean([math.sqrt(x**2 / s**2 + m) for x, m, s in zip(e, ms, scales, strict=True)]))


def draw_log_changes(sigma: Mapping[str, float], params: Sequence[str], rng: np.random.Generator, *,
                     occurrence: bool = True) -> dict[str, float]:
    """One draw of the session-to-session log change of each drift-prone parameter.

    Parameters
    ----------
    sigma : mapping
        Standard deviation σ_p of the log change of parameter p between two sessions.
    params : sequence of str
        The drift-prone parameters drawn (:func:`drift_parameters`).
    rng : numpy.random.Generator
    occurrence : bool
        True (the prior): whether a parameter changes at all is an event of probability π, shared by
        the rig's parameters and unknown, π ~ Uniform(0, 1) drawn per session (a rig left alone
        changes nothing, one taken apart or moved changes several things at once); a parameter
        that changes moves by N(0, 2σ_p²), so that the log change keeps the standard deviation σ_p
        (E[π] = 1/2) and only its shape changes: mass at zero and heavier tails. The number of
        changing parameters is uniform on 0..len(params). False (σ measured across sessions, which
        already holds the sessions in which nothing changed): N(0, σ_p²) for every parameter.

    Returns
    -------
    dict
        Log change per parameter (0.0 for one that does not change).
    """
    pi, widen = (float(rng.uniform()), math.sqrt(2.0)) if occurrence else (1.0, 1.0)
    out = {}
    for eff in params:
        changes = bool(rng.uniform() < pi)
        x = float(widen * sigma.get(eff, 0.0) * rng.standard_normal())
        out[eff] = x if changes else 0.0
    return out


def within_session_draw(block_errors: Sequence[np.ndarray], rng: np.random.Generator,
                        target_blocks: Sequence[int] | None = None) -> float | list[float]:
    """One block-bootstrap draw of the within-session θ NRMSE of a whole recording.

    A held-out NRMSE is the RMS error over a whole recording, so its within-session part is an RMS
    over that recording's blocks, not the error of one block: per validation recording, as many
    blocks as it holds are drawn with replacement from its own block errors and their mean
    square taken; the mean over the recordings (the statistic :func:`_ms_change` averages the same
    way) gives e_in² (non-overlapping block bootstrap, Carlstein 1986).

    With ``target_blocks`` the draw is a prediction of each target recording's own error: the
    validation blocks resampled as above (the uncertainty of the estimate), then per target as many
    blocks as it holds drawn from that resample (the target's own sampling), so that the spread
    is that of e_in² plus that of the target's mean square, σ²(1/k + 1/m) for k validation and m
    target blocks (a two-stage predictive bootstrap).

    Parameters
    ----------
    block_errors : sequence of numpy.ndarray
        Per validation recording, the θ RMS error of each of its blocks (shape (k_j,), k_j ≥ 1;
        in rad, or normalised: the draw has their unit).
    rng : numpy.random.Generator
    target_blocks : sequence of int, optional
        Per target recording, its number of blocks (≥ 1).

    Returns
    -------
    float or list of float
        e_in, in the blocks' unit; with ``target_blocks`` one per target.
    """
    resampled = [rng.choice(b, size=b.size, replace=True) for b in block_errors]
    if target_blocks is None:
        return math.sqrt(float(np.mean([np.mean(np.square(r)) for r in resampled])))
    pool = np.concatenate(resampled)
    return [math.sqrt(float(np.mean(np.square(rng.choice(pool, size=max(1, int(m)), replace=True)))))
            for m in target_blocks]


def shortest_interval(samples: Sequence[float], level: float = LEVEL,
                      atom: Sequence[float] | None = None) -> tuple[float, float]:
    """The shortest interval in log scale holding ``level`` of the draws (a highest-density interval
    of log e), and ``level`` of the ``atom`` draws when they are given.

    The predictive distribution of a held-out error has an atom at "nothing moved" (the
    within-session error, drawn whenever no drift-prone parameter changes) at its lower end and a
    long tail of session changes above it. An equal-tailed interval (10 % / 90 % quantiles) would
    cut its lower 10 % out of that atom and leave "nothing moved" a tail beyond the interval. A
    shortest interval over the draws alone keeps the atom only while it holds more than
    1 − ``level`` of them: with four drift-prone parameters the prior gives it 1/5, and a long
    upper tail then wins the comparison (lab benchmark case 56: the atom at 0.0014, the interval
    [0.0092, 0.48], the unchanged rig's actual 0.0014). A point mass is where the density is
    highest, so a highest-density region holds it first: with ``atom`` the interval must hold
    ``level`` of the atom's own draws too (its spread is the within-session error's), and is the
    shortest such. Log scale, because an error is a size: 0.001 to 0.002 is as far as 0.1 to 0.2.

    Parameters
    ----------
    samples : sequence of float
        Draws (> 0), shape (n,), n ≥ 1.
    level : float
        Share of the draws the interval holds, in (0, 1].
    atom : sequence of float, optional
        The draws of the atom (a subset of ``samples``, shape (m,)); none or empty: no constraint.

    Returns
    -------
    (float, float)
        Lower and upper end (draws themselves).
    """
    raw = np.sort(np.maximum(np.asarray(samples, dtype=float), 1e-300))
    x = np.log(raw)  # the ends returned are draws themselves, not exp(log(draw))
    k = max(1, math.ceil(level * x.size))
    a = np.log(np.sort(np.maximum(np.asarray(atom if atom is not None else [], dtype=float), 1e-300)))
    if a.size == 0:
        i = int(np.argmin(x[k - 1:] - x[: x.size - k + 1]))
        return float(raw[i]), float(raw[i + k - 1])
    ka = max(1, math.ceil(level * a.size))
    starts = np.arange(x.size - k + 1)
    below = np.searchsorted(a, x[starts], side="left")  # atom draws left out below each start
    ok = below + ka <= a.size
    starts, below = starts[ok], below[ok]
    # the end: k draws from the start, and far enough to hold ka of the atom's draws
    need = np.searchsorted(x, a[below + ka - 1], side="left")
    ends = np.maximum(starts + k - 1, need)
    i = int(np.argmin(x[ends] - x[starts]))
    return float(raw[starts[i]]), float(raw[ends[i]])


def recorded_range(replay: np.ndarray, sigma: float, rng: np.random.Generator,
                   draws: int = RANGE_DRAWS) -> float:
    """Expected θ range of a recording whose noise-free angle is ``replay``: the mean peak-to-peak of
    ``replay`` plus white measurement noise of standard deviation ``sigma``.

    A held-out NRMSE divides by the range of the *recorded* angle, whose noise widens it at both
    ends (by about 3.7σ each side where the angle dwells at its extremes for thousands of samples).
    A prediction that divided by the noise-free replay's range would sit above every actual by as
    much: 3.7 % on a 30 s, 490 Hz step test at 40 dB (σ 0.5 % of the range).

    Parameters
    ----------
    replay : numpy.ndarray
        Noise-free θ of the corrected rig on the target, shape (n,) [rad].
    sigma : float
        θ measurement noise σ̂ [rad] (:func:`aeropend_ident.gap.effects.measurement_noise`, at
        least the rounding noise of a detected quantum).
    rng : numpy.random.Generator
    draws : int
        Noise draws averaged.

    Returns
    -------
    float
        The expected range [rad], at least 1e-6.
    """
    x = np.asarray(replay, dtype=float)
    if sigma <= 0.0 or x.size < 2:
        return max(float(np.ptp(x)), 1e-6)
    noisy = x[None, :] + sigma * rng.standard_normal((draws, x.size))
    return max(float(np.mean(np.ptp(noisy, axis=1))), 1e-6)


def _why_wide(lo: float, hi: float, within: float, sensitivity: Mapping[str, Sequence[float]],
              sigma: Mapping[str, float]) -> str:
    """Why a predicted interval spans more than :data:`WIDE_RATIO` (its upper end over its lower end),
    '' when it does not: the lower end is the rig unchanged (the within-session error), the upper
    end a session change of the drift-prone parameter the replay is most sensitive to."""
    if lo <= 0.0 or hi <= WIDE_RATIO * lo:
        return ""
    size = {k: float(np.nanmax(v)) for k, v in sensitivity.items() if np.any(np.isfinite(v))}
    worst = max(size, key=size.get, default=None)
    tail = ""
    if worst is not None:
        tail = (f" ({worst} alone at ±{100 * sigma.get(worst, 0.0):.0f} %, its prior σ, moves the replay by "
                f"{size[worst]:.3g})")
    return (f"the interval spans {hi / lo:.0f}×: its lower end is the rig unchanged (within-session error "
            f"{within:.3g}), its upper end a session change of the drift-prone parameters{tail}; the "
            "held-out error tells which happened, the drift table what moved")


def predict_heldout(nominal: Rig, diag: EffectDiagnosis, validation: Sequence[Recording], *,
                    targets: Sequence[Recording] | None = None,
                    drift_sigma: Mapping[str, float] | None = None, draws: int = N_DRAWS,
                    seed: int = 0) -> dict[str, Any]:
    """Predicted held-out θ NRMSE of the corrected rig, from the fit data and the held-out duty
    (module docstring).

    A Monte-Carlo predictive distribution: each draw takes per target a within-session error e_in
    [rad] (a two-stage block bootstrap of the corrected rig's RMS error on the validation
    recordings, as many blocks as the target holds, :func:`within_session_draw`) and a
    log change of every drift-prone parameter from the drift prior (:func:`draw_log_changes`;
    :data:`DRIFT_PRIOR` is its standard deviation), replays the drawn rig on each target recording's
    duty and records, per target, e = √(e_in²/s² + mean squared change of the replay / s²), s the
    expected range of the recorded angle there (the corrected rig's replay plus the validation
    recordings' θ noise, :func:`recorded_range`, as the actual NRMSE divides by the recorded
    range); the mean over the targets is the draw's NRMSE. The median of the draws is the
    prediction, the shortest interval in log NRMSE that holds 80 % of them and 80 % of those in
    which no drift-prone parameter changed (the atom "nothing moved", :func:`shortest_interval`)
    its 80 % interval.

    The chosen effects keep their fitted values in every draw. Their fit error is in e_in already
    (the validation error is measured with them), and a draw of each from its marginal standard
    error ignores their correlation: three effects that stand in together for a cause outside the
    catalog, each with a wide standard error, moved the draws' median to 0.37 where the unchanged
    rig's error was 0.0021 (lab benchmark case 102; docs/findings/gap.md).

    Why the target's duty and not the validation's: the held-out NRMSE is over the held-out
    recording's own range, and what a drift does to θ depends on where the recording takes the rod,
    not on its range (a K_q change moves the hanging angle at each duty by a fixed amount). A
    validation part that holds a set point spans a tenth of the held-out range, and its NRMSEs,
    noise included, would be ten times a held-out one. From a target only its duty and its start
    are read: its channels over the first :data:`aeropend_ident.gap.which.data.INITIAL_STATE_WINDOW`
    (1 s), where every free-run replay's start is estimated (:func:`_start_only`), never its error.

    Parameters
    ----------
    nominal : Rig
        The nominal rig (its family sets the drift-prone parameters).
    diag : EffectDiagnosis
        The diagnosis (corrected rig, measurement map, chosen effects with standard errors).
    validation : sequence of Recording
        The diagnosis' validation recordings (model frame): the within-session error.
    targets : sequence of Recording, optional
        The recordings whose θ NRMSE is predicted (model frame; the held-out ones); default
        ``validation``.
    drift_sigma : mapping, optional
        Standard deviation of the log change per drift-prone parameter; default
        :data:`DRIFT_PRIOR`.
    draws : int
        Monte-Carlo draws (one replay per target recording each).
    seed : int
        Random seed.

    Returns
    -------
    dict
        ``predicted`` (median), ``interval`` [lo, hi] (80 %), ``level`` 0.8, ``within_session``
        (RMS of the validation blocks' errors over the targets' θ scale) and ``blocks`` (each
        block's RMS error [rad]), ``target_scale`` (per target, the expected recorded θ range
        [rad], :func:`recorded_range`), ``why_wide`` (why an interval spans more than
        :data:`WIDE_RATIO`, else ''),
        ``drift_part`` (median RMS change of the drawn replays: the drift),
        ``drift_sigma`` used, ``drift_prior`` ("occurrence" or "normal", :func:`draw_log_changes`)
        and its ``drift_source`` ("prior" / "sessions"), ``sensitivity`` (per drift-prone parameter:
        the θ NRMSE change of the corrected rig's replay for that parameter alone changed by −σ and
        +σ), ``noise_floor`` (θ noise σ̂ of the validation recordings over the targets' scale),
        ``draws`` (those whose replays succeeded).

    Raises
    ------
    GapError
        If a replay fails for the corrected rig, or for every draw.
    """
    sigma = dict(DRIFT_PRIOR if drift_sigma is None else drift_sigma)
    channels = diag.channels or ("theta",)
    preps = _preps(validation, channels)
    tpreps = preps if targets is None else [_start_only(p) for p in _preps(targets, channels)]
    rng = np.random.default_rng(seed)

    def corrected(ps: Sequence[Prepared]) -> list[np.ndarray]:
        out = []
        for p in ps:  # on the draws' sub-steps, so that a draw that changes nothing changes nothing
            row = replay_many([(diag.corrected_rig, diag.measurement)], p, ("theta",))[0]
            if row is None:
                raise GapError("prediction: the replay of the corrected rig failed on "
                               f"{p.rec.source or 'a recording'}")
            out.append(row["theta"])
        return out

    per_rec: list[np.ndarray] = []  # the within-session error [rad], per validation recording's blocks
    val_sims = corrected(preps)
    for p, sim in zip(preps, val_sims, strict=True):
        e = sim - p.y["theta"]
        k = max(1, round(e.size * p.dt / BLOCK_S))
        per_rec.append(np.array([np.sqrt(np.mean(b**2)) for b in np.array_split(e, k) if b.size]))
    base = val_sims if targets is None else corrected(tpreps)  # the default targets: replayed once
    sigma_theta = float(np.mean([measurement_noise(p.y["theta"]) for p in preps]))
    noise_rng = np.random.default_rng([seed, 1])  # its own stream: the draws below stay as they were
    scales = [recorded_range(b, sigma_theta, noise_rng) for b in base]
    blocks = [float(b) for rec in per_rec for b in rec]
    params = drift_parameters(channels, nominal.family)
    one_at_a_time = [_perturbed_or_none(diag.corrected_rig, {eff: math.exp(sign * sigma.get(eff, 0.0))})
                     for eff in params for sign in (-1.0, 1.0)]
    ms_one = _ms_changes(one_at_a_time, diag.measurement, tpreps, base, scales)
    sensitivity = {eff: [math.sqrt(float(np.mean(m))) if m is not None else math.nan
                         for m in ms_one[2 * i: 2 * i + 2]] for i, eff in enumerate(params)}
    target_blocks = [max(1, round(p.duty.size * p.dt / BLOCK_S)) for p in tpreps]  # the targets' own lengths
    drawn: list[Rig | None] = []
    e_ins: list[Any] = []
    still: list[bool] = []  # the draws in which no drift-prone parameter changes: the atom
    for _ in range(draws):  # the random draws first, in the order of one draw after the other
        logs = draw_log_changes(sigma, params, rng, occurrence=drift_sigma is None)
        still.append(all(x == 0.0 for x in logs.values()))
        e_ins.append(within_session_draw(per_rec, rng, target_blocks=target_blocks))
        drawn.append(_perturbed_or_none(diag.corrected_rig, {eff: math.exp(x) for eff, x in logs.items()}))
    samples, changes, atom = [], [], []
    ms_drawn = _ms_changes(drawn, diag.measurement, tpreps, base, scales, base_rig=diag.corrected_rig)
    for e_in, ms, none_moved in zip(e_ins, ms_drawn, still, strict=True):
        if ms is None:
            continue
        changes.append(math.sqrt(float(np.mean(ms))))
        samples.append(_nrmse_of(e_in, ms, scales))
        if none_moved:
            atom.append(samples[-1])
    if not samples:
        raise GapError("prediction: every replay of the corrected rig failed")
    lo, hi = shortest_interval(samples, LEVEL, atom=atom)
    within_rad = float(np.sqrt(np.mean(np.square(blocks))))
    within = float(np.mean([within_rad / s for s in scales]))
    return {
        "why_wide": _why_wide(float(lo), float(hi), within, sensitivity, sigma),
        "predicted": float(np.median(samples)),
        "interval": [float(lo), float(hi)],
        "level": LEVEL,
        "within_session": within,
        "blocks": blocks,
        "target_scale": scales,
        "drift_part": float(np.median(changes)),
        "drift_sigma": sigma,
        "drift_prior": "occurrence" if drift_sigma is None else "normal",
        "drift_source": "prior" if drift_sigma is None else "sessions",
        "sensitivity": sensitivity,
        "noise_floor": float(np.mean([sigma_theta / s for s in scales])),
        "draws": len(samples),
    }


def refit_comparison(nominal: Rig, diag: EffectDiagnosis, fit: Sequence[Recording],
                     held_out: Sequence[Recording], corrected_nrmse: float) -> tuple[dict[str, Any], Any]:
    """The corrected rig against a plain refit of the nominal parameters, on the held-out recordings.

    A diagnosis adds physics; a lab's first alternative is to refit the rig's own numbers, as
    ``baseline`` does by default (the rod's gravity term mgd/J, its viscous friction c/J and the
    thrust scale, here the thrust coefficient K_q, plus the supply voltage V_s when v_a is
    recorded: the drift-prone parameters, :func:`drift_parameters`). They are fitted on every fit
    recording (output error, :func:`aeropend_ident.gap.which.fitting.fit_effects`) and replayed on the
    held-out ones with the same metric as the corrected rig. When the corrected rig predicts the
    held-out recordings worse than that refit, the report says so and shows both.

    Parameters
    ----------
    nominal : Rig
    diag : EffectDiagnosis
    fit, held_out : sequence of Recording
        All fit recordings and the held-out ones, model frame.
    corrected_nrmse : float
        Held-out θ NRMSE of the corrected rig (mean over the held-out recordings).

    Returns
    -------
    dict
        ``parameters`` refitted, ``values`` and ``std`` (physical units), ``refit_nrmse`` (held-out
        θ NRMSE, mean over recordings; NaN when its replay diverges), ``corrected_nrmse``,
        ``worse_than_refit`` (bool) and a one-line ``verdict``.
    EffectFit
        The refit itself (:func:`attainable` reuses it as its fit-session drift fit when nothing is
        chosen).

    Raises
    ------
    GapError
        If the refit fails.
    """
    from aeropend_ident.gap.which.metrics import gap_metrics

    channels = diag.channels or ("theta",)
    params = drift_parameters(channels, nominal.family)
    fr = _fit_set(nominal, params, _preps(fit, channels))
    m = gap_metrics(fr.rig, fr.meas, _preps(held_out, channels))
    refit = math.nan if m.get("diverges") else float(m["nrmse"])
    worse = bool(math.isfinite(refit) and corrected_nrmse > refit)
    names = ", ".join(f"{e}" for e in params)
    if not math.isfinite(refit):
        verdict = f"the refit of the nominal parameters ({names}) diverges on the held-out data"
    elif worse:
        verdict = (f"the corrected rig predicts the held-out data WORSE than a plain refit of the nominal "
                   f"parameters ({names}): θ NRMSE {corrected_nrmse:.4f} vs {refit:.4f}; the named effects "
                   "do not carry over to these recordings better than the rig's own numbers refitted")
    else:
        verdict = (f"the corrected rig predicts the held-out data better than a plain refit of the nominal "
                   f"parameters ({names}): θ NRMSE {corrected_nrmse:.4f} vs {refit:.4f}")
    return {"parameters": params, "values": fr.values, "std": fr.std, "refit_nrmse": refit,
            "corrected_nrmse": float(corrected_nrmse), "worse_than_refit": worse, "verdict": verdict}, fr

