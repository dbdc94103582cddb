"""Model-discrimination design: the command sequence whose outputs tell the candidates apart.

Divergence of a candidate pair: each logged channel's squared difference of their predicted
outputs divided by its measured noise variance,

    D_ij(u) = Σ_c Σ_k (y_i,c[k] − y_j,c[k])² / σ_c²,

twice the expected log-likelihood ratio of the pair under Gaussian noise (a Kullback-Leibler
divergence, Box & Hill's discrimination idea in its simplest form), on the channels the rig logs,
at its logging rate. Criterion (maximised): the mean over pairs of log10(1 + D_ij). The issue's
first suggestion, the smallest D_ij, is reported too but not optimised: two candidates that
predict alike under every command (a nested set whose extra effect is nearly absent) pin it at
zero and leave the search without a gradient; the mean of logs still rewards separating every
pair and gives diminishing returns on pairs already far apart.

Each candidate's output is its free run from rest (rod hanging, motor at duty 0) on the
compiled replays the gap fits use (:class:`aeropend_ident.greybox.batch.RigReplays`: no new
integrator), its angle through its measurement map (sensor gain and offset).

The angle range is a penalty: a sequence under which any candidate leaves
[theta_min, theta_max] scores below every sequence that stays inside. The command range and slew
hold by construction (:mod:`aeropend_ident.design.sequence`).

Optimiser: CMA-ES (the ``cma`` package, seeded, bounded to the unit cube) over the APRBS
parametrisation, started from the seeded APRBS of the same shape; the best point seen is
returned, so the design never scores below that APRBS. Each generation's sequences are scored in
one thread per core (:func:`thread_batch`; the candidates' compiled replays release the GIL): the
same values in the same order as in one thread, so the same design on any number of cores (lab
case 76 at 200 Hz: 54 s of search in one thread, 26 s in two on this 2-core machine).

Predicted value (:func:`rank_first_probability`): each candidate is the truth in turn; its output
plus Gaussian noise of the measured σ (the angle then rounded to the logger's quantum) is ranked
against every candidate's noise-free prediction by the sum of squared normalised residuals; the
share of draws in which the truth ranks first. It does not refit the candidates on the new
recording (the diagnosis does), so it is an upper bound when a refit can bend a wrong candidate
toward the data.

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import copy
import functools
import itertools
import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from aeropend_ident.design.candidates import (
    Candidate,
    fit_candidates,
    held_setting_effects,
    nested_sets,
)
from aeropend_ident.design.sequence import (
    ANGLE_PENALTY,
    BUDGET_S,
    DISCRIMINATION_WORK,
    AprbsShape,
    Limits,
    angle_penalty,
    aprbs_vector,
    check_mode,
    default_evaluations,
    recorded_margin,
    search,
    sequence,
)
from aeropend_ident.gap.which.metrics import SEGMENT
from aeropend_ident.gap.which.ranking import MIN_EXPLAINED_SECOND
from aeropend_ident.greybox.batch import RigReplays, one_replay_thread, single_blas
from aeropend_ident.greybox.fit import motor_equilibrium

#: The best candidate's error RMS over the noise σ on a recording above which no candidate explains
#: it as sized (:func:`verdict` names none; a candidate that explains it leaves the noise, about 1).
#: A χ² of 9 per sample is not a noise draw: every candidate is mis-sized or mis-specified, and
#: which of them the split test refutes then reflects their misfits, not which effects are there
#: (lab case 80: the truth set, sized on the earlier data, refuted by a wrong one at 10 times the
#: noise; case 76 named a wrong set at 17.6).
UNEXPLAINED_RMS = 3.0


class Predictor:
    """Noise-free logged outputs of the candidates under any command sequence of one length.

    Parameters
    ----------
    candidates : sequence of Candidate
    channels : sequence of str
        Logged channels (``theta`` and any of ``i_a``, ``v_a``, ``omega_rotor``).
    dt : float
        Logging period [s].
    n : int
        Samples per sequence.
    """

    def __init__(self, candidates: Sequence[Candidate], channels: Sequence[str], dt: float, n: int) -> None:
        self.candidates = list(candidates)
        self.channels = tuple(channels)
        self.rigs = [c.rig.with_effects(sensor_noise=False, quantisation=False) for c in self.candidates]
        self.replays = RigReplays(np.zeros(n), dt, tau_before=0.0)
        self.x0 = np.array([[0.0, 0.0, *motor_equilibrium(r, 0.0)] for r in self.rigs])
        self.calls = 0

    def twin(self) -> Predictor:
        """A predictor of the same candidates with replays of its own (one per thread: a
        predictor's replays hold the sequence being replayed)."""
        twin = copy.copy(self)  # the candidates, rigs and initial states are only read
        twin.replays = RigReplays(np.zeros_like(self.replays.duty), self.replays.dt, tau_before=0.0)
        twin.calls = 0
        return twin

    def __call__(self, duty: np.ndarray) -> dict[str, np.ndarray]:
        """Channel -> (B, N) predicted outputs (NaN rows where a replay failed)."""
        self.replays.duty = np.ascontiguousarray(duty, dtype=float)
        sim, _ok = self.replays.run(self.rigs, self.x0, self.channels)
        self.calls += 1
        if "theta" in sim:
            sim["theta"] = np.stack([c.meas.to_recorded(sim["theta"][b])
                                     for b, c in enumerate(self.candidates)])
        return sim


def pair_divergences(outputs: Mapping[str, np.ndarray], sigma: Mapping[str, float]) -> np.ndarray:
    """Divergence of every candidate pair (module doc): (B, B) symmetric, zero diagonal, ∞ where a
    prediction failed."""
    b = next(iter(outputs.values())).shape[0]
    d = np.zeros((b, b))
    for i, j in itertools.combinations(range(b), 2):
        s = 0.0
        for c, y in outputs.items():
            s += float(np.sum((y[i] - y[j]) ** 2)) / sigma[c] ** 2
        d[i, j] = d[j, i] = s if math.isfinite(s) else math.inf
    return d


def mean_log_divergence(outputs: Mapping[str, np.ndarray], sigma: Mapping[str, float]) -> float:
    """Mean over candidate pairs of log10(1 + D_ij) (module doc); −:data:`ANGLE_PENALTY` when a
    prediction failed (non-finite)."""
    d = pair_divergences(outputs, sigma)
    iu = np.triu_indices(d.shape[0], 1)
    vals = d[iu]
    return float(np.mean(np.log10(1.0 + vals))) if np.all(np.isfinite(vals)) else -ANGLE_PENALTY


def criterion(outputs: Mapping[str, np.ndarray], sigma: Mapping[str, float], limits: Limits) -> float:
    """:func:`mean_log_divergence`; when a candidate's predicted angle, widened by what the recorded
    angle may stray from it (:func:`~aeropend_ident.design.sequence.recorded_margin`), leaves the
    angle range or a replay fails, :func:`~aeropend_ident.design.sequence.angle_penalty` instead
    (module doc)."""
    outside = angle_penalty(outputs["theta"], limits, recorded_margin(limits, sigma.get("theta", 0.0)))
    if outside < 0.0:
        return outside
    return mean_log_divergence(outputs, sigma)


@dataclass
class Discrimination:
    """A discrimination design.

    Attributes
    ----------
    duty : ndarray, shape (N,)
        Designed commands on the logging grid.
    baseline : ndarray, shape (N,)
        The seeded APRBS of the same shape (the search's start).
    value, baseline_value : float
        :func:`criterion` of each.
    min_divergence, baseline_min_divergence : float
        Smallest pairwise divergence of each (expected log-likelihood ratio units).
    evaluations : int
        Sequences simulated.
    elapsed_s : float
        Wall time of the search [s].
    z : ndarray, shape (2M,)
        The design vector.
    stopped_by : str
        What ended the search (:func:`~aeropend_ident.design.sequence.search`): ``"evaluations"``
        or ``"converged"`` (reproducible from the seed) or ``"budget"`` (wall time).
    """

    duty: np.ndarray
    baseline: np.ndarray
    value: float
    baseline_value: float
    min_divergence: float
    baseline_min_divergence: float
    evaluations: int
    elapsed_s: float
    z: np.ndarray
    stopped_by: str = "evaluations"


def smallest_divergence(outputs: Mapping[str, np.ndarray], sigma: Mapping[str, float]) -> float:
    """The smallest :func:`pair_divergences` of the candidates (∞ with fewer than two)."""
    d = pair_divergences(outputs, sigma)
    iu = np.triu_indices(d.shape[0], 1)
    return float(np.min(d[iu])) if iu[0].size else math.inf


@single_blas
def design_discrimination(candidates: Sequence[Candidate], sigma: Mapping[str, float], limits: Limits,
                          shape: AprbsShape | None = None, *, seed: int = 0, budget_s: float = BUDGET_S,
                          max_evaluations: int | None = None, mode: str = "open_loop") -> Discrimination:
    """Search the APRBS parametrisation for the sequence that best separates ``candidates``.

    Parameters
    ----------
    candidates : sequence of Candidate
        At least two.
    sigma : mapping
        Noise σ per logged channel [its unit]; its keys are the channels compared.
    limits : Limits
        Command range, slew, angle range, logging period.
    shape : AprbsShape
        Length and parametrisation.
    seed : int
        Seed of the starting APRBS and of CMA-ES (the design is reproducible).
    budget_s : float
        Wall-time safety net of the search [s] (:func:`~aeropend_ident.design.sequence.search`).
    max_evaluations : int, optional
        Most sequences simulated (default
        :func:`~aeropend_ident.design.sequence.default_evaluations` of the candidates: the design
        is then reproducible from its seed).
    mode : str
        ``"open_loop"`` (a command sequence) only; set points for the lab's controller are
        :func:`aeropend_ident.design.reference.design_reference`'s.

    Returns
    -------
    Discrimination

    Raises
    ------
    ValueError
        With fewer than two candidates; :class:`~aeropend_ident.design.sequence.DesignError` for a
        mode other than ``open_loop``.
    """
    check_mode(mode, where="an open-loop discrimination design (design_reference is the closed-loop one)")
    if len(candidates) < 2:
        raise ValueError("a discrimination design needs at least two candidates")
    shape = shape or AprbsShape()
    t0 = time.perf_counter()
    n = shape.samples(limits.dt)
    pred = Predictor(candidates, tuple(sigma), limits.dt, n)

    def value_with(p: Predictor, z: np.ndarray) -> tuple[float, None]:
        return criterion(p(sequence(z, shape, limits)), sigma, limits), None

    z0 = aprbs_vector(shape, seed)
    if max_evaluations is None:
        max_evaluations = default_evaluations(len(candidates), n, len(sigma), work=DISCRIMINATION_WORK)
    popsize = 8 + shape.size // 6
    preds = [pred, *(pred.twin() for _ in range(design_threads(popsize) - 1))]
    with thread_batch(value_with, preds) as batch:
        best_z, best_v, _, v0, _, stopped = search(functools.partial(value_with, pred), z0, seed=seed,
                                                   budget_s=budget_s, max_evaluations=max_evaluations,
                                                   popsize=popsize, started=t0, tolfun=1e-4, batch=batch)
    duty, base = sequence(best_z, shape, limits), sequence(z0, shape, limits)
    return Discrimination(duty=duty, baseline=base, value=best_v, baseline_value=v0,
                          min_divergence=smallest_divergence(pred(duty), sigma),
                          baseline_min_divergence=smallest_divergence(pred(base), sigma),
                          evaluations=sum(p.calls for p in preds), elapsed_s=time.perf_counter() - t0,
                          z=best_z, stopped_by=stopped)


def design_threads(popsize: int) -> int:
    """Threads that score an open-loop search's generation: as many as the closed-loop design's
    worker processes (:func:`aeropend_control.design_gains.design_workers`, ``AEROPEND_DESIGN_WORKERS``
    when set, else one per core), at most one per sequence of the generation."""
    from aeropend_control.design_gains import design_workers

    return max(1, min(design_workers(popsize), popsize))


@contextmanager
def thread_batch(score: Callable[[Any, np.ndarray], tuple[float, Any]], states: Sequence[Any]
                 ) -> Iterator[Callable[[list[np.ndarray]], list[tuple[float, Any]]] | None]:
    """A ``batch`` for :func:`~aeropend_ident.design.sequence.search` that scores a generation in
    one thread per state: thread i scores the i-th contiguous share of the sequences as
    ``score(states[i], z)``, its replays on that thread alone
    (:func:`~aeropend_ident.greybox.batch.one_replay_thread`). The compiled replay releases the GIL,
    so the shares run at once on the cores; each value is the one a single thread computes, in the
    same order, so the search and its design are the same with any number of threads. None (score
    in the caller) with one state."""
    if len(states) < 2:
        yield None
        return

    def share(state: Any, zs: list[np.ndarray]) -> list[tuple[float, Any]]:
        with one_replay_thread():
            return [score(state, z) for z in zs]

    with ThreadPoolExecutor(len(states), thread_name_prefix="aeropend-design") as pool:
        def batch(zs: list[np.ndarray]) -> list[tuple[float, Any]]:
            bounds = np.linspace(0, len(zs), len(states) + 1).round().astype(int)
            jobs = [pool.submit(share, st, zs[a:b])
                    for st, (a, b) in zip(states, itertools.pairwise(bounds), strict=True)]
            return [v for job in jobs for v in job.result()]

        yield batch


@single_blas
def rank_first_probability(candidates: Sequence[Candidate], duty: np.ndarray, sigma: Mapping[str, float],
                           limits: Limits, *, draws: int = 200, seed: int = 0) -> dict[str, Any]:
    """Monte-Carlo probability that each candidate, when it is the truth, ranks first (module doc).

    Parameters
    ----------
    candidates : sequence of Candidate
    duty : ndarray, shape (N,)
        The sequence on the logging grid.
    sigma : mapping
        Noise σ per logged channel.
    limits : Limits
        Its ``quantum`` rounds the simulated angle.
    draws : int
        Noise draws per candidate.
    seed : int

    Returns
    -------
    dict
        ``per_candidate`` {name: probability}, ``mean`` over candidates, ``draws``.
    """
    out = Predictor(candidates, tuple(sigma), limits.dt, np.asarray(duty).size)(duty)
    return rank_draws([c.name for c in candidates], lambda _t: out, sigma, limits.quantum, draws=draws,
                      seed=seed)


def rank_draws(names: Sequence[str], outputs_of: Callable[[int], Mapping[str, np.ndarray]],
               sigma: Mapping[str, float], quantum: float, *, draws: int, seed: int) -> dict[str, Any]:
    """The Monte-Carlo ranking of :func:`rank_first_probability`, the truth ``t``'s outputs and
    every candidate's prediction given by ``outputs_of(t)`` (channel -> (B, N); row ``t`` is the
    truth's noise-free output).

    Returns
    -------
    dict
        ``per_candidate`` {name: probability}, ``mean`` over candidates, ``draws``.
    """
    rng = np.random.default_rng(seed)
    probs: dict[str, float] = {}
    for t, name in enumerate(names):
        out = outputs_of(t)
        if not all(np.all(np.isfinite(y[t])) for y in out.values()):
            probs[name] = math.nan
            continue
        wins = 0
        for _ in range(draws):
            sse = np.zeros(len(names))
            for c, y in out.items():
                obs = y[t] + rng.normal(0.0, sigma[c], y.shape[1])
                if c == "theta" and quantum > 0.0:
                    obs = np.round(obs / quantum) * quantum
                sse += np.nansum((y - obs) ** 2, axis=1) / sigma[c] ** 2 + np.where(
                    np.all(np.isfinite(y), axis=1), 0.0, np.inf)
            wins += int(np.argmin(sse) == t)
        probs[name] = wins / draws
    finite = [p for p in probs.values() if math.isfinite(p)]
    return {"per_candidate": probs, "mean": float(np.mean(finite)) if finite else math.nan, "draws": draws}


#: Most candidates a refit keeps for the verdict (:func:`refit_evidence`; its nested special cases
#: beside them): every set one swap from the best within the fit-error factor fits in.
REFIT_CANDIDATES = 16

#: Most rounds of swap neighbours a refit climbs through while no set it fitted explains the designed
#: recording (:func:`refit_evidence`): from the first best, then twice more from the sets the
#: recording cannot tell from the best (a truth two swaps from every candidate is reached).
REFIT_ROUNDS = 3

#: Most sets a refit's later round climbs from (the best first; :func:`refit_evidence`).
REFIT_FRONTIER = 8

#: Family-wise false-refutation rate of :func:`verdict` (Bonferroni over the rivals of the best).
VERDICT_ALPHA = 0.05


@single_blas
def evidence(candidates: Sequence[Candidate], duty: np.ndarray, recorded: Mapping[str, np.ndarray],
             sigma: Mapping[str, float], dt: float, *, alpha: float = VERDICT_ALPHA,
             refuted_before: int = 0) -> dict[str, Any]:
    """Each candidate's free run from rest on a recorded sequence against the recording, and what
    the recording names (:func:`verdict`).

    The candidates keep the parameters fitted on the earlier recordings (no refit): the designed
    recording is data none of them saw, so a candidate it refutes is refuted out of sample.

    Parameters
    ----------
    candidates : sequence of Candidate
    duty : ndarray, shape (N,)
        The recorded commands (the designed sequence as played).
    recorded : mapping
        Channel -> (N,) recorded values; the channels of ``sigma`` are compared.
    sigma : mapping
        Noise σ per channel.
    dt : float
        Sample period [s].
    alpha : float
        Family-wise level of the refutations (:func:`verdict`).
    refuted_before : int
        Rivals refuted before this verdict by data that include this recording (:func:`verdict`).

    Returns
    -------
    dict
        ``chi2`` {name: Σ residual²/σ²}, ``first`` (the candidate with the least), ``order`` (best
        first), ``samples``, ``best_rms_over_noise`` (the first one's error RMS over the noise σ:
        about 1 when it explains the recording; far above, the recording shows a gap no candidate
        explains, and a refit on it, ``gap``, is the next step), and :func:`verdict`'s ``named``,
        ``survivors``, ``refuted_p``.
    """
    n = min(np.asarray(duty).size, *(np.asarray(recorded[c]).size for c in sigma))
    pred = Predictor(candidates, tuple(sigma), dt, n)
    out = pred(np.asarray(duty, dtype=float)[:n])
    e2 = np.zeros((len(candidates), n))
    for c in sigma:
        e2 += (out[c] - np.asarray(recorded[c], dtype=float)[:n]) ** 2 / sigma[c] ** 2
    e2 = np.where(np.isfinite(e2), e2, np.inf)
    chi2 = {cand.name: float(np.sum(e2[b])) for b, cand in enumerate(candidates)}
    order = sorted(chi2, key=chi2.get)
    w = min(max(round(SEGMENT / dt), 1), n)  # 1 s segments (one when the recording is shorter)
    k = n // w
    segs = np.add.reduceat(e2[:, : k * w], np.arange(0, k * w, w), axis=1)
    segs[:, -1] += e2[:, k * w:].sum(axis=1)
    res = {"chi2": chi2, "first": order[0] if order else None, "order": order, "samples": int(n),
           "best_rms_over_noise": math.sqrt(chi2[order[0]] / (n * len(sigma))) if order else math.nan}
    res.update(verdict(candidates, segs, noise=float(w * len(sigma)), alpha=alpha,
                       misfit=res["best_rms_over_noise"], refuted_before=refuted_before))
    return res


@single_blas
def refit_evidence(rig: Any, earlier: Sequence[Any], designed: Any, sets: Sequence[Sequence[str]],
                   sigma: Mapping[str, float], *, alpha: float = VERDICT_ALPHA) -> dict[str, Any]:
    """What a designed recording names once the candidates are refitted on it: the step after a
    recording that no candidate explains as sized on the earlier recordings (:func:`evidence`'s
    ``unexplained``).

    Every candidate set, the sets one swap away from the best refit and the nested special cases
    of each (:func:`~aeropend_ident.design.candidates.fit_candidates` with ``neighbours``) are fitted
    on the earlier recordings and the designed one together (while none of the sets fitted
    explains the designed recording, the sets one swap from each set the recording cannot tell
    from the best too, at most :data:`REFIT_FRONTIER` of them a round and :data:`REFIT_ROUNDS`
    rounds: a truth two swaps from every candidate is reached; lab case 95), the held settings of
    their effects fitted too (the dry friction's onset width v_ε: a designed recording's holds show how slowly
    the rod creeps, and at the rig file's width a Stribeck curve stood in for a plain Coulomb
    friction on lab cases 73 and 76). A set whose fit error on all of them exceeds
    :data:`~aeropend_ident.design.candidates.KEEP_SSE_FACTOR` × the best is refuted by data that
    include the designed recording; the others (at most :data:`REFIT_CANDIDATES`, with the nested
    special cases of each) go to :func:`verdict` on the designed recording's 1 s segments, which
    refutes the rivals of the best and names the fewest effects among those it cannot refute. The
    refutations are in sample (each set saw the recording), so a richer set fits at least as well as
    the set it extends; what keeps an effect the recording does not demand out is the same rule as
    without refit: of the sets not refuted the fewest effects, a nested special case before its
    richer effect, which refutes it only by removing a share of its error (:func:`verdict`).

    Parameters
    ----------
    rig : Rig
        The nominal rig the diagnosis was made against.
    earlier : sequence of Recording
        The earlier recordings (recording frame), as given to the design.
    designed : Recording
        The designed recording (recording frame, uniform grid).
    sets : sequence of sequences of str
        The design's candidate effect sets.
    sigma : mapping
        Noise σ per channel (the design's).
    alpha : float
        Family-wise level of the refutations.

    Returns
    -------
    dict
        :func:`evidence` of the refitted candidates on the designed recording, with ``refit``
        True, ``refit_rows`` (one row per set fitted: its fit error, or why it could not be
        fitted) and ``refit_free_settings`` (the effects whose held settings were fitted).

    Raises
    ------
    GapError
        When the nominal rig cannot be replayed on the recordings, or no set could be fitted.
    """
    free = held_setting_effects(rig.family)

    def climb_from(fitted: Sequence[Candidate]) -> list[tuple[str, ...]]:
        """While no set fitted so far explains the designed recording: the sets it cannot tell
        from the best (its verdict's survivors, best first), to climb on from."""
        ev = evidence(fitted, designed.duty, designed.channels, sigma, designed.dt, alpha=alpha)
        if ev["best_rms_over_noise"] <= UNEXPLAINED_RMS:
            return []
        effects = {c.name: c.effects for c in fitted}
        return [effects[n] for n in ev["survivors"]][:REFIT_FRONTIER]

    cands, rows = fit_candidates(rig, [*earlier, designed], sets, neighbours=True,
                                 max_candidates=REFIT_CANDIDATES, free_settings=free,
                                 climb=climb_from, max_rounds=REFIT_ROUNDS)
    res = evidence(cands, designed.duty, designed.channels, sigma, designed.dt, alpha=alpha,
                   refuted_before=sum(bool(r.get("refuted")) for r in rows))
    res.update({"refit": True, "refit_rows": rows, "refit_free_settings": sorted(free)})
    return res


def verdict(candidates: Sequence[Candidate], segments: np.ndarray, noise: float,
            alpha: float = VERDICT_ALPHA, misfit: float | None = None, refuted_before: int = 0
            ) -> dict[str, Any]:
    """What one recording names among candidates fitted without it.

    The candidate with the least error is the best; each other candidate is refuted when the
    best removes its error second by second (the gap diagnosis' sample-split test,
    :func:`aeropend_ident.gap.which.evidence.split_test`, asked for any share: H0 "the best does
    not do better on average") at p < ``alpha`` / (candidates − 1). Of the best and the rivals
    it does not refute, the one with the fewest effects is named (an effect the recording does
    not demand is not named), and of two such sets that differ by an effect and the effect that
    nests it (a thrust law and its thrust coefficient,
    :func:`~aeropend_ident.design.candidates.nested_sets`) the special case: the richer one must
    earn its parameter by refuting it, and it refutes its special case only by removing at least
    :data:`~aeropend_ident.gap.which.ranking.MIN_EXPLAINED_SECOND` of the special case's error
    second by second (the split test asked for that share: H0 "it removes less"; a second at the
    noise floor weighs nothing), the share a richer effect must remove in the gap diagnosis'
    ranking. When two of that size survive otherwise, nothing is named and both are reported as
    not separated. A recording that refutes no rival separated nothing: it names the nominal rig
    (no effect) when that is a candidate, else nothing. A recording that no candidate explains (the
    best one's error RMS over :data:`UNEXPLAINED_RMS` times the noise) names nothing either: the
    refutations then rank misfits, and a refit on the recording is the next step.

    Parameters
    ----------
    candidates : sequence of Candidate
    segments : ndarray, shape (B, S)
        Normalised squared error (Σ residual²/σ² over channels) per candidate and 1 s segment.
    noise : float
        The noise part of one segment's error (its samples × channels).
    alpha : float
        Family-wise level.
    misfit : float, optional
        The best candidate's error RMS over the noise σ (:func:`evidence`); above
        :data:`UNEXPLAINED_RMS` nothing is named.
    refuted_before : int
        Rivals refuted before this verdict by data that include this recording (a refit's sets
        whose fit error on the earlier recordings and this one together exceeds
        :data:`~aeropend_ident.design.candidates.KEEP_SSE_FACTOR` × the best,
        :func:`refit_evidence`): the recording has then separated something even when it refutes
        none of the candidates left.

    Returns
    -------
    dict
        ``named`` (the named candidate's name, or None), ``named_effects`` (its effects, or None),
        ``survivors`` (names not refuted, best first), ``refuted_p`` {rival: p; for the best's
        special cases the p of the share :data:`~aeropend_ident.gap.which.ranking.MIN_EXPLAINED_SECOND`},
        ``alpha``, ``unexplained`` (the misfit is above :data:`UNEXPLAINED_RMS`), ``gave_way`` {survivor: the
        surviving special case it gave way to (its richer effect did not refute it)}.
    """
    from aeropend_ident.gap.which.evidence import split_test

    segments = np.asarray(segments, dtype=float)
    tot = segments.sum(axis=1)
    best = int(np.argmin(tot))
    if not np.isfinite(tot[best]):  # no candidate could be replayed on the recording: it names nothing
        return {"named": None, "named_effects": None, "survivors": [], "refuted_p": {}, "alpha": alpha,
                "unexplained": True, "gave_way": {}}
    level = alpha / max(len(candidates) - 1, 1)
    pvals: dict[str, float] = {}
    alive = [best]
    # the best set's special cases (its richer effect replaced by the effect it nests): the best must
    # remove MIN_EXPLAINED_SECOND of their error to refute them, the share a richer effect must
    # remove in the gap diagnosis' ranking. Share 0 would let a consistent hair refute them: after
    # a refit both sets saw the recording, and a thrust law whose exponent fits the noise led its
    # thrust coefficient by 3 parts in a million of its error at p < 1e-16 (lab case 95 in closed loop)
    special = set(nested_sets(candidates[best].effects))
    for b, cand in enumerate(candidates):
        if b == best:
            continue
        share = MIN_EXPLAINED_SECOND if tuple(cand.effects) in special else 0.0
        p = 0.0 if not np.isfinite(tot[b]) else split_test(segments[b], segments[best], noise, share)
        pvals[cand.name] = float(p)
        if p >= level:
            alive.append(b)
    alive.sort(key=lambda b: tot[b])
    fewest = min(len(candidates[b].effects) for b in alive)
    small = [b for b in alive if len(candidates[b].effects) == fewest]
    # a richer effect the recording does not demand is not named either: a survivor whose set is
    # another survivor's with one effect replaced by an effect that nests it (a thrust law for the
    # thrust coefficient it contains) gives way to it, as in the gap diagnosis' ranking
    sets = {tuple(candidates[b].effects): candidates[b].name for b in small}
    gave_way = {candidates[b].name: sets[s] for b in small for s in nested_sets(candidates[b].effects)
                if s in sets}
    small = [b for b in small if candidates[b].name not in gave_way]
    # a recording that refutes none of the rivals separated nothing: it may still say that it
    # demands no effect (the nominal rig among the survivors), but the fewest effects among all the
    # candidates would be effects named without it (lab case 80 named such a set, wrongly)
    refuted_any = len(alive) < len(candidates) or refuted_before > 0
    unexplained = misfit is not None and not misfit <= UNEXPLAINED_RMS
    named = (candidates[small[0]] if len(small) == 1 and (refuted_any or fewest == 0) and not unexplained
             else None)
    return {"named": named.name if named else None,
            "named_effects": list(named.effects) if named else None,
            "survivors": [candidates[b].name for b in alive], "refuted_p": pvals, "alpha": alpha,
            "unexplained": unexplained, "gave_way": gave_way}
