"""Which, the one context of a diagnosis run (:class:`_Setup`): prepared data, nominal errors, noise parts.

Built once per run by :func:`_setup` and read by every later stage of
:mod:`aeropend_ident.gap.which`; also the threads the independent fits of one step run in
(:func:`_each`). No rclpy.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from aeropend_ident.gap.effects import (
    EffectContext,
    MeasurementMap,
    catalog,
    check_recordings,
    get_effect,
    identifiable,
    nominal_model_check,
)
from aeropend_ident.gap.which.data import (
    INITIAL_STATE_WINDOW,
    Prepared,
    _changes,
    _noise_var,
    prepare,
    replay,
    residuals,
)
from aeropend_ident.gap.which.fitting import BIC_DECIMATION, EffectFit
from aeropend_ident.gap.which.metrics import gap_metrics, validation_errors
from aeropend_ident.greybox.batch import one_replay_thread, replay_threads
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording

#: Largest split-test p-value (:func:`split_test`) with which an effect is chosen when the effects are
#: ranked on the fit part itself (the in-sample fallback of :func:`_setup`): there the test is
#: in-sample and optimistic, and p ≤ 0.5 asks only that the effect remove the required share of the
#: gap second by second on a weighted average, not through a few seconds that carry the total (an
#: inertia scale fitted to a closed-loop log's first seconds on an effect-free lab plant: 26 % of the
#: total, p 0.98; docs/findings/gap.md).
IN_SAMPLE_MAX_P = 0.5


#: Nominal θ error below this many noise standard deviations counts as noise floor (the floors
#: reported per channel).
NOISE_FLOOR_FACTOR = 3.0


#: A gap is above the noise floor when some channel's nominal validation error exceeds its noise
#: part by this factor (squared errors: RMS 1.12× the noise; the noise estimates of
#: :func:`_noise_var` are good to about 5 % on white noise), plus the chance margin of a held
#: rounding error (:data:`ROUNDING_CHANCE_Z`).
ABOVE_NOISE = 1.25


#: Standard deviations of the rounding part of the noise added to the above-noise threshold
#: (:func:`_rounding_chance`). With white noise far below a lattice step (a 10-bit encoder holding
#: a set point), the rounding error e = Q(θ) − θ is one draw of U(−q/2, q/2) per hold, not one per
#: sample: its mean square q²/12 is then an average over a few holds, with a relative standard
#: deviation 0.894/√(holds). An effect-free closed loop at 50 Hz read 1.43× its noise part
#: (effective holds 17, one standard deviation 0.22 of it) and had a voltage drop of −0.0016 V
#: fitted to its holds' rounding errors (docs/findings/gap.md).
ROUNDING_CHANCE_Z = 2.0


#: sqrt(Var(u²))/E(u²) for u uniform on (−q/2, q/2): E(u²) = q²/12, Var(u²) = q⁴(1/80 − 1/144).
_ROUNDING_SQUARE_REL_SD = 12.0 * math.sqrt(1.0 / 80.0 - 1.0 / 144.0)


#: Recording time [s] per independent residual sample in the confirmation BIC: the
#: :data:`BIC_DECIMATION` samples at 490 Hz. A free-run error stays correlated over a time set by
#: the rod's dynamics, not by the logger, so a 40 s log carries the same evidence at 50 Hz as at
#: 490 Hz (counting 1 in 20 samples at 50 Hz asked a slow logger for 10× the evidence per second).
#: Tried once before the resampling of jittered logs put each command on its own sample, it named
#: a motor time constant on an effect-free jittered 100 Hz log; with that fixed, it no longer does
#: (docs/findings/gap.md, "The BIC's effective sample count").
BIC_RESIDUAL_TIME = BIC_DECIMATION / 490.0


def bic_samples(preps: Sequence[Prepared]) -> int:
    """Independent residual samples the confirmation BIC counts in ``preps`` (all channels).

    Each recording contributes its residual samples (channels × samples) divided by the number of
    its samples in :data:`BIC_RESIDUAL_TIME` (at least 1: a log slower than that counts every
    sample); at least 10 in all.

    Parameters
    ----------
    preps : sequence of Prepared
        The recordings the BIC is computed on.

    Returns
    -------
    int
        The effective sample count n_eff of ``n_eff·ln(SSE/n_eff) + k·ln(n_eff)``.
    """
    return max(sum(len(p.y) * p.n // max(round(BIC_RESIDUAL_TIME / p.dt), 1) for p in preps), 10)


def _param_table(fitres: EffectFit, name: str) -> dict[str, dict[str, Any]]:
    """``{parameter: {value, std, unit}}`` of one effect's fit; a held parameter the fit kept at
    the rig's value (no standard error) also says ``"held": True``."""
    e = get_effect(name)
    out = {}
    for p in e.parameters:
        std = fitres.std.get(name, {}).get(p.name)
        out[p.name] = {"value": fitres.values[name][p.name], "std": std, "unit": p.unit}
        if p.held and std is None:
            out[p.name]["held"] = True
    return out


@dataclass
class _Setup:
    """Validated inputs and nominal figures shared by the steps of :func:`diagnose_effects`."""

    rig: Rig
    pf: list[Prepared]
    pv: list[Prepared]
    ctx: EffectContext
    channels: frozenset[str]
    model_effects: list[str]
    refinements: list[str]
    not_ident: list[dict]
    sse_fit0: float
    n_fit: int
    n_eff: int
    seg0: np.ndarray
    base_metrics: dict[str, Any]
    floors: dict[str, float]
    noise_sse: float
    noise_c: dict[str, float]
    chance_c: dict[str, float]
    sse0_c: dict[str, float]
    note: str
    say: Callable[[str], None]

    @property
    def sse_val0(self) -> float:
        return float(self.seg0.sum())

    def above_noise_share(self, sse: float, base: float | None = None) -> float:
        """Share of the validation gap above the noise part (of ``base``, default nominal) removed
        by a model with validation SSE ``sse``: (base − sse) / (base − noise part), 0 when ``base``
        is at or below the noise part.

        The gap is taken as at least the smallest one that counts as a gap (:func:`_above_noise`:
        :data:`ABOVE_NOISE` times the noise part plus the rounding chance margin, less the noise
        part): a ``base`` just above the noise part would otherwise turn a change of noise size
        into any share (an effect-free case's ranking read 146.8 and −56.9).
        """
        b = self.sse_val0 if base is None else base
        if not b > self.noise_sse:
            return 0.0
        least = (ABOVE_NOISE - 1.0) * self.noise_sse + sum(self.chance_c.values())
        return (b - sse) / max(b - self.noise_sse, least)

    def noise_ratio(self, sse: float) -> str:
        """``sse`` as a multiple of the validation noise part, for progress lines."""
        return f"{sse / self.noise_sse:.3g} × its noise part"


def _setup(rig: Rig, fit: Sequence[Recording], validation: Sequence[Recording],
           say: Callable[[str], None], skip: Sequence[str] = ()) -> _Setup:
    nominal_model_check(rig)
    ch_fit = check_recordings(fit, "fit recordings", need_changing_input=True)
    ch_val = check_recordings(validation, "validation recordings")
    channels = ch_fit & ch_val
    pf, pv = prepare(fit, channels), prepare(validation, channels)
    ctx = EffectContext.from_prepared(rig, pf)
    model_effects, refinements, not_ident = [], [], []
    for e in catalog(rig.family):
        if e.name in skip:
            continue
        why = identifiable(e, channels)
        if why is not None:
            not_ident.append({"effect": e.name, "subsystem": e.subsystem, "reason": why})
        elif e.refines:
            refinements.append(e.name)
        elif e.kind != "direct":
            model_effects.append(e.name)
    say(f"nominal replay on {len(pf)} fit / {len(pv)} validation recordings, channels {sorted(channels)}")
    nominal = MeasurementMap()
    sse_fit0 = float(np.sum(residuals(rig, nominal, pf) ** 2))
    n_fit = sum(len(p.y) * p.n for p in pf)
    note = ""
    seg0, sse0_c = validation_errors(rig, nominal, pv)
    noise_c, chance_c = noise_parts(pv), _rounding_chance(pv)
    if not _above_noise(sse0_c, noise_c, chance_c):
        fit_c = _errors_after_start(rig, nominal, pf)
        fit_noise, fit_chance = noise_parts(pf), _rounding_chance(pf)
        if _above_noise(fit_c, fit_noise, fit_chance):
            # the validation part does not reach the operating region of the gap (e.g. an end stop
            # touched only in the fit part), judged after each fit recording's start: rank on the
            # fit data instead, and say so
            worst = max(fit_c, key=lambda c: fit_c[c] / fit_noise[c])
            note = (f"the validation part shows no gap above noise while the fit part does ({worst} "
                    f"{math.sqrt(fit_c[worst] / fit_noise[worst]):.1f}× its noise RMS): the effects were "
                    "ranked and chosen on the fit part (in-sample); only the held-out check is independent")
            say(note)
            pv, noise_c, chance_c = pf, fit_noise, fit_chance
            seg0, sse0_c = validation_errors(rig, nominal, pf)
    # noise floor of every compared channel (relative to its range), and the noise part of the
    # validation SSE (normalised like segment_sse): what no effect can remove
    floors = {c: NOISE_FLOOR_FACTOR * float(np.mean([math.sqrt(_noise_var(p.y[c])) / p.scale[c] for p in pv]))
              for c in pv[0].y}
    noise_sse = noise_part(noise_c, seg0)
    return _Setup(rig=rig, pf=pf, pv=pv, ctx=ctx, channels=channels, model_effects=model_effects,
                  refinements=refinements, not_ident=not_ident, sse_fit0=sse_fit0, n_fit=n_fit,
                  n_eff=bic_samples(pf),
                  seg0=seg0, base_metrics=gap_metrics(rig, nominal, pv), floors=floors, noise_sse=noise_sse,
                  noise_c=noise_c, chance_c=chance_c, sse0_c=sse0_c, note=note, say=say)


def _in_catalog(names: Sequence[str], st: _Setup) -> list[str]:
    """The names that are candidates for this rig (confusable effects of another family left out)."""
    have = {*st.model_effects, *st.refinements, *(r["effect"] for r in st.not_ident)}
    return [n for n in names if n in have]


def noise_parts(preps: Sequence[Prepared]) -> dict[str, float]:
    """Noise part of each channel's normalised squared error (as :func:`validation_errors`), summed
    over the recordings ``preps``: channel name -> the part no effect can remove (:func:`noise_part`
    adds them up)."""
    return {c: float(sum(_noise_var(p.y[c]) / p.scale[c] ** 2 for p in preps)) for c in preps[0].y}


def noise_part(noise_c: Mapping[str, float], seg0: np.ndarray) -> float:
    """The noise part of the validation SSE (normalised as :func:`segment_sse`): what no effect can
    remove, the sum over channels of ``noise_c`` (:func:`noise_parts`), kept above 1e-12 of the
    nominal segments' SSE ``seg0`` (n_segments,) and above 0."""
    return max(sum(noise_c.values()), 1e-12 * float(np.sum(seg0)), 1e-300)


def _errors_after_start(rig: Rig, meas: MeasurementMap, preps: Sequence[Prepared]) -> dict[str, float]:
    """Each channel's normalised squared error (as :func:`validation_errors`) without each
    recording's first :data:`INITIAL_STATE_WINDOW`: what a replay's start leaves there (a rotor
    assumed at the first duty cycle's steady speed on a log that begins as the motor starts) is no
    gap of the plant. At most half of a recording is left out."""
    out: dict[str, float] = {}
    for p in preps:
        sim = replay(rig, meas, p)
        k0 = min(round(INITIAL_STATE_WINDOW / p.dt), p.n // 2)
        for c, y in p.y.items():
            out[c] = out.get(c, 0.0) + float(np.mean(((sim[c][k0:] - y[k0:]) / p.scale[c]) ** 2))
    return out


def _rounding_chance(preps: Sequence[Prepared]) -> dict[str, float]:
    """Chance margin of each channel's noise part (normalised as :func:`noise_parts`):
    :data:`ROUNDING_CHANCE_Z` standard deviations of its rounding part.

    The rounding part of a recording's noise variance is Δ²/12 (Δ as in :func:`_noise_var`, the
    median non-zero sample-to-sample change), at most the noise variance. Its rounding errors are
    independent between runs of one recorded value, not between samples: while the value holds,
    the error does not change. A recording's runs of durations d_i give an effective number of
    independent errors (Σd_i)²/Σd_i², and the rounding part a relative standard deviation of
    :data:`_ROUNDING_SQUARE_REL_SD` over its square root. A recording whose value changes at every
    sample (white noise, an unquantised signal: no rounding error is held, and the Δ of a moving
    rod is its motion, not a step) adds no margin; a coarse lattice holding a set point, a margin
    that counts its few holds.
    """
    out: dict[str, float] = {}
    for c in preps[0].y:
        var = 0.0
        for p in preps:
            y = np.asarray(p.y[c], dtype=float)
            moved, q = _changes(y)
            if moved.all() or not moved.any():
                continue  # no value held (white noise, an unquantised signal), or nothing to count
            part = min(q * q / 12.0, _noise_var(y)) / p.scale[c] ** 2
            runs = np.diff(np.concatenate([[0], np.flatnonzero(moved) + 1, [y.size]])).astype(float)
            holds = float(runs.sum() ** 2 / np.sum(runs**2))
            var += (part * _ROUNDING_SQUARE_REL_SD) ** 2 / holds
        out[c] = ROUNDING_CHANCE_Z * math.sqrt(var)
    return out


def _above_noise(sse_c: Mapping[str, float], noise_c: Mapping[str, float],
                 chance_c: Mapping[str, float]) -> bool:
    """Some channel's error exceeds :data:`ABOVE_NOISE` times its noise part plus the chance margin
    of its rounding errors (:func:`_rounding_chance`): a gap to explain."""
    return any(sse_c[c] > ABOVE_NOISE * noise_c[c] + chance_c[c] and sse_c[c] > 1e-8 for c in sse_c)


#: An item of :func:`each_in_fit_threads`.
T = TypeVar("T")


def fit_threads() -> int:
    """Threads the independent fits of one diagnosis step run in (:func:`_each`):
    :func:`aeropend_ident.greybox.batch.replay_threads` if set (a pool or cluster worker running
    one case per core sets 1), else one per available core."""
    n = replay_threads()
    return n if n is not None else max(1, len(os.sched_getaffinity(0)))


def _each(st: _Setup, items: Sequence[str], work: Callable[[str, Callable[[str], None]], Any]
          ) -> Iterator[tuple[str, Any]]:
    """:func:`each_in_fit_threads` of one diagnosis step: progress to ``st.say``, the fit and
    validation recordings' compiled replays built first. ``work`` must not change ``st``."""
    return each_in_fit_threads(items, work, st.say, (*st.pf, *st.pv))


def each_in_fit_threads(items: Sequence[T], work: Callable[[T, Callable[[str], None]], Any],
                        say: Callable[[str], None] = lambda _line: None, preps: Sequence[Any] = ()
                        ) -> Iterator[tuple[T, Any]]:
    """``(item, work(item, say))`` for every item, in order, independent fits run in
    :func:`fit_threads` threads at once (the compiled replays release the GIL), each with its batch
    replays on its own thread.

    ``work`` reports progress through the ``say`` it is given; in threads its lines are kept and
    passed on to ``say`` in the order of ``items``, each before its result is yielded, so the
    progress reads as when the fits run one after the other (which they do with one thread). An
    exception in one item is raised when its turn comes. ``preps``
    (:class:`~aeropend_ident.gap.which.data.Prepared`) have their compiled replays built before
    the threads start, not raced for; how each of their logs began must already be decided (their
    nominal replay done: :func:`aeropend_ident.gap.which.data.residuals`), else whichever work item
    replays a log first would decide it.

    Raises
    ------
    RuntimeError
        If how one of ``preps``' logs began is not decided yet (a caller's error).
    """
    undecided = [p.rec.source or "a recording" for p in preps if not p.start_decided]
    if undecided:
        raise RuntimeError(f"how {', '.join(undecided)} began is not decided: replay the nominal rig on "
                           "it first (gap.which.data.residuals), before the fits")
    n = min(fit_threads(), len(items))
    if n <= 1:
        for item in items:
            yield item, work(item, say)
        return
    for prep in preps:
        _ = prep.replays, prep.head
    with ThreadPoolExecutor(max_workers=n, thread_name_prefix="aeropend-fit") as pool:
        jobs = []
        for item in items:
            lines: list[str] = []
            jobs.append((item, lines, pool.submit(_on_one_replay_thread, work, item, lines.append)))
        for item, lines, job in jobs:
            result = job.result()
            for line in lines:
                say(line)
            yield item, result


def _on_one_replay_thread(work: Callable[[T, Callable[[str], None]], Any], item: T,
                          say: Callable[[str], None]) -> Any:
    """``work(item, say)`` with its batch replays on the calling thread (one of
    :func:`each_in_fit_threads`')."""
    with one_replay_thread():
        return work(item, say)


def _holds_in_sample(st: _Setup, p_value: float | None) -> bool:
    """Whether an effect's split-test p-value allows its choice: always on a validation part of its
    own; when the effects are ranked on the fit part (the in-sample fallback of :func:`_setup`),
    only up to :data:`IN_SAMPLE_MAX_P`."""
    return st.pv is not st.pf or (p_value is not None and p_value <= IN_SAMPLE_MAX_P)

