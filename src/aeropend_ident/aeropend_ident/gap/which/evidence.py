"""Which, the evidence numbers: split test, presence, status words, unresolved timing effects.

Part of the effect diagnosis of :mod:`aeropend_ident.gap.which` (step 5 of its pipeline); no rclpy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy.stats import false_discovery_control
from scipy.stats import t as student_t

from aeropend_ident.gap.effects import (
    get_effect,
)
from aeropend_ident.gap.which.screening import MIN_BIC_GAIN

#: Least share of the validation gap above noise an effect must remove to be significant.
MIN_EXPLAINED = 0.25


#: A chosen effect is "named" with presence at least this (its false-discovery-rate adjusted
#: p-value ≤ 0.1, and winning its rivals' resamples) and a chosen set that explains at least
#: NAMED_COMPLETENESS of the gap ("mostly explained"); a chosen effect short of either is a
#: "candidate", as is an unchosen effect with presence ≥ CANDIDATE_PRESENCE (as likely present as not).
NAMED_PRESENCE = 0.9


NAMED_COMPLETENESS = 0.5


CANDIDATE_PRESENCE = 0.5


def split_test(base: np.ndarray, new: np.ndarray, noise: float, min_share: float) -> float:
    """One-sided p-value that a model removes a relevant share of the validation gap: the
    sample-split test of presence.

    ``base`` and ``new`` are the validation SSE per segment (:func:`segment_sse`, 1 s segments) of
    the model without and with the effect, whose parameters were fitted on the fit part only. Per
    segment, l_j = log(base_j / new_j) is the factor by which the effect shrinks that second's
    error (scale-free: a second with a large gap and one with a small gap weigh as evidence by how
    much of their own error goes, not by their size); the segments are weighted by the share of
    their error above the noise, w_j = max(base_j − noise, 0)/base_j (a second at the noise floor
    holds no evidence either way, one whose error is all gap counts fully). H0: the weighted mean
    of l is at most −log(1 − ``min_share``), i.e. the effect removes less than the share of the
    gap the decision asks for (:data:`MIN_EXPLAINED`; under "absent", a
    model fitted on other data removes nothing on average: l ≤ 0). A t test whose sample size is
    the weights' effective number (Σw)²/Σw² reduced for the correlation of neighbouring seconds
    (a free-run error persists): n_eff·(1 − ρ₁)/(1 + ρ₁), ρ₁ the lag-1 autocorrelation of l
    clipped to [0, 0.9] (Wilks, *Statistical methods in the atmospheric sciences*, §5.2.4).

    Parameters
    ----------
    base, new : numpy.ndarray
        Shape (n,), validation SSE per segment without / with the effect (same segments).
    noise : float
        Noise part of one segment's SSE (same normalisation).
    min_share : float
        Share of the gap the effect must remove, in [0, 1).

    Returns
    -------
    float
        p in [0, 1]; 1.0 when no segment carries a gap above noise.
    """
    base = np.asarray(base, dtype=float)
    tiny = 1e-300
    lr = np.log(np.maximum(base, tiny) / np.maximum(np.asarray(new, dtype=float), tiny))
    w = np.maximum(base - noise, 0.0) / np.maximum(base, tiny)
    if w.sum() <= 0.0:
        return 1.0
    w = w / w.sum()
    mean = float(np.sum(w * lr))
    h0 = -math.log(1.0 - min_share)
    var = float(np.sum(w * (lr - mean) ** 2))
    n_w = 1.0 / float(np.sum(w**2))
    keep = w > 0.0
    rho = float(np.corrcoef(lr[:-1], lr[1:])[0, 1]) if keep.sum() > 3 and np.ptp(lr) > 0 else 0.0
    rho = float(np.clip(rho if np.isfinite(rho) else 0.0, 0.0, 0.9))
    n_eff = max(n_w * (1.0 - rho) / (1.0 + rho), 2.0)
    if var <= 1e-24:
        return 0.0 if mean > h0 else 1.0
    se = math.sqrt(var * n_w / max(n_w - 1.0, 1.0) / n_eff)
    return float(student_t.sf((mean - h0) / se, df=n_eff - 1.0))


#: A fitted time (a dead time, a lag or a response time constant: a parameter in s) shorter than this
#: share of the recordings' sample period is not resolved by them (:func:`unresolved_times`).
RESOLVED_SHARE = 0.5


def unresolved_times(effect: str, values: Mapping[str, float], dt: float) -> str:
    """Why a fitted timing effect is not resolved by recordings sampled every ``dt``, '' when it is.

    A dead time or a first-order lag shorter than half the sample period settles between two
    samples: the angle cannot show it, and what such a fit improves is *when the logger stamps* a
    channel. A drive output (the armature voltage v_a) logged as the previous period's value, after
    the command of that period, is matched by the smallest lag or an input delay → 0 that moves the
    model's drive output by one sample. That is a logging convention, not the plant's physics
    (found on closed-loop logs whose v_a is stamped one period late: an actuator lag at its range's
    lower bound, 1 ms at 4.1 ms per sample, and an input delay of 2e-9 s at 20.5 ms, each named at
    presence ≥ 0.9 on plants without them; docs/findings/gap.md).

    Parameters
    ----------
    effect : str
        Catalog name.
    values : mapping
        Its fitted parameter values (physical units).
    dt : float
        The recordings' (longest) sample period [s].

    Returns
    -------
    str
        The reason (every time parameter of the effect below :data:`RESOLVED_SHARE` × dt), or ''
        (the effect has no time parameter, or one at least that long).
    """
    times = [p for p in get_effect(effect).parameters if p.unit == "s"]
    if not times or any(float(values.get(p.name, math.inf)) >= RESOLVED_SHARE * dt for p in times):
        return ""
    fitted = ", ".join(f"{p.name} {1e3 * float(values[p.name]):.2g} ms" for p in times)
    return (f"{effect} fitted shorter than half the {1e3 * dt:.3g} ms sample period ({fitted}): not resolved "
            "at this rate; what it fits is when the logger stamps a channel (e.g. v_a read as the previous "
            "period's drive output), not the plant")


def _mark_unresolved(ranking: list[dict[str, Any]], cands: Any, dt: float) -> None:
    """Mark, in place, the ranked single-effect fits not resolved at the sample period ``dt``
    (:func:`unresolved_times`, entry field ``unresolved``)."""
    for r in ranking:
        fr = cands.fits.get(r["effect"])
        why = unresolved_times(r["effect"], fr.values[r["effect"]], dt) if fr is not None else ""
        if why:
            r["unresolved"] = why


def _unresolved_reason(ranking: Sequence[Mapping[str, Any]], chosen: Sequence[str]) -> str:
    """'; why' for each unchosen timing fit that passed the bar but is not resolved at this rate."""
    out = ""
    for r in ranking:
        passed = (r.get("bic_delta") is not None and r["bic_delta"] <= -MIN_BIC_GAIN
                  and (r.get("above_noise_explained") or 0.0) >= MIN_EXPLAINED)
        if r.get("unresolved") and r["effect"] not in chosen and passed:
            out += f"; {r['unresolved']}"
    return out


def status_of(presence: float | None, chosen: bool, completeness: float | None,
              not_separated: bool = False) -> str:
    """The word the report uses for an effect, from its presence and the chosen set's completeness.

    Parameters
    ----------
    presence : float or None
        Evidence the effect is present (0..1, :func:`_evidence`).
    chosen : bool
        In the corrected rig.
    completeness : float or None
        How completely the chosen set explains the validation gap (0..1, :func:`_completeness`).
    not_separated : bool
        The data do not separate it from a chosen effect (``ambiguous_with`` of one).

    Returns
    -------
    str
        ``"named"`` (chosen, presence ≥ :data:`NAMED_PRESENCE`, completeness ≥
        :data:`NAMED_COMPLETENESS`), ``"candidate"`` (chosen but short of either, or presence ≥
        :data:`CANDIDATE_PRESENCE`), ``"not separated"`` or ``"not significant"``.
    """
    p = presence or 0.0
    if chosen:
        return "named" if p >= NAMED_PRESENCE and (completeness or 0.0) >= NAMED_COMPLETENESS else "candidate"
    if not_separated:
        return "not separated"
    return "candidate" if p >= CANDIDATE_PRESENCE else "not significant"


def misspecification_factor(completeness: float | None) -> float:
    """The bound a residual far above the noise puts on any catalog effect's presence.

    The sample-split test compares two models of one family; it tells "this effect" from "no
    effect" only when the family holds the plant. When the best model (the chosen set for a chosen
    effect, the effect alone otherwise) still leaves a residual far above the noise (completeness
    0, :func:`_completeness`), the data show something the catalog does not hold, and an effect that
    passes the test is as likely a stand-in for it as present itself: its presence is at most ½.
    Linear between: 0.5 + 0.5·completeness (1 for a model that leaves the noise level).

    Parameters
    ----------
    completeness : float or None
        0..1; None (not computed) counts as 1.
    """
    c = 1.0 if completeness is None else float(np.clip(completeness, 0.0, 1.0))
    return 0.5 + 0.5 * c


def _evidence(ranking: list[dict[str, Any]], chosen: Sequence[str], shares: Mapping[str, float],
              pvals: Mapping[str, float], explained: Mapping[str, Any], *, in_sample: bool) -> None:
    """Presence, q-value and status of every ranked effect (module doc, step 5), in place; the
    chosen effects first (in the order chosen), the others by presence.

    The p-values of every test made (each single candidate against the nominal, each added effect
    against the set before it: ``pvals`` overrides an entry's own) are adjusted together by
    Benjamini-Hochberg (:func:`scipy.stats.false_discovery_control`); presence = (1 − q) × the
    effect's bootstrap share (``shares`` for a chosen effect, else its ``bootstrap_first``) ×
    :func:`misspecification_factor` of the completeness (the chosen set's for a chosen effect,
    its own otherwise). A chosen effect with k alternatives the validation figures do not separate
    from it (``ambiguity`` entries without a bootstrap share: :func:`_not_separated`, alone or in the
    joint fit) shares its bootstrap share equally with them, each 1/(k + 1) of it: the bootstrap
    gives every resample to the one a hair ahead, and the data give no reason to prefer it.
    ``in_sample``: the validation part was the fit part (see :func:`_setup`), said on each entry.
    """
    shares = dict(shares)
    first = {r["effect"]: r.get("bootstrap_first") or 0.0 for r in ranking}
    for r in ranking:
        tied = [a for a, v in (r.get("ambiguity") or {}).items() if v.get("bootstrap_first") is None]
        own = shares.get(r["effect"], r.get("bootstrap_first"))
        if r["effect"] in chosen and tied and own is not None:
            shares[r["effect"]] = own / (len(tied) + 1)
            for a in tied:
                if a not in chosen:
                    shares[a] = max(shares.get(a, first.get(a, 0.0)), own / (len(tied) + 1))
    tested = [r for r in ranking if not r.get("detected")]
    ps = [pvals.get(r["effect"], r.get("p_value")) for r in tested]
    have = [i for i, p in enumerate(ps) if p is not None]
    qs = false_discovery_control([ps[i] for i in have], method="bh") if have else []
    q_of = {tested[i]["effect"]: float(q) for i, q in zip(have, qs, strict=True)}
    ambiguous = {a for r in ranking if r["effect"] in chosen for a in r.get("ambiguous_with", [])}
    for r in tested:
        name = r["effect"]
        if name in pvals:
            r["p_value"] = pvals[name]
        q = q_of.get(name)
        share = shares.get(name, r.get("bootstrap_first"))
        comp = (explained.get("completeness") if name in chosen
                else (r.get("explained") or {}).get("completeness"))
        r["q_value"] = q
        r["presence"] = (None if q is None or share is None
                         else float((1.0 - q) * share * misspecification_factor(comp)))
        if r.get("unresolved") and name not in chosen:  # not the plant's: no evidence of a present effect
            r["presence"] = 0.0 if r["presence"] is not None else None
        r["status"] = status_of(r["presence"], name in chosen, explained.get("completeness"),
                                name in ambiguous)
        if in_sample:
            r["presence_in_sample"] = True
    rank = {n: i for i, n in enumerate(chosen)}
    ranking.sort(key=lambda r: (rank.get(r["effect"], len(rank)), not r.get("detected"),
                                -(r.get("presence") or 0.0)))

