"""Which, stage 5 — ranking and decision: first effect, forward selection, confusable swaps, refinement.

Part of the effect diagnosis of :mod:`aeropend_ident.gap.which` (step 4 of its pipeline); no rclpy.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from aeropend_ident.errors import GapError
from aeropend_ident.gap.effects import (
    get_effect,
)
from aeropend_ident.gap.which.candidates import _Candidates
from aeropend_ident.gap.which.context import _each, _holds_in_sample, _in_catalog, _param_table, _Setup
from aeropend_ident.gap.which.evidence import MIN_EXPLAINED, split_test, unresolved_times
from aeropend_ident.gap.which.fitting import MAX_NFEV, EffectFit, _n_fitted, fit_effects
from aeropend_ident.gap.which.metrics import segment_sse
from aeropend_ident.gap.which.screening import MIN_BIC_GAIN, N_BOOTSTRAP, Screening, _bic, screen

#: Least further share of the remaining validation gap above noise a second effect must remove.
MIN_EXPLAINED_SECOND = 0.3


#: Screened groups and ranked single effects tried (each) as the next effect of forward selection.
FORWARD_CANDIDATES = 3


#: Least share of the validation gap above noise left by the chosen set that a confusable
#: alternative must remove to replace a chosen effect (:func:`_swap_confusables`).
SWAP_GAIN = 0.1


#: Bootstrap share of the validation resamples in which a runner-up is first for it to be
#: reported as not separated from the first-ranked effect (``ambiguous_with``).
AMBIGUOUS_FIRST = 0.2


def _bootstrap_first(st: _Setup, cands: _Candidates, order: Sequence[str],
                     seed: int) -> tuple[dict[str, float], dict[str, float]]:
    """Bootstrap over validation segments: how often each effect is first, and significant."""
    rng = np.random.default_rng(seed)
    first = dict.fromkeys(order, 0)
    signif = dict.fromkeys(order, 0)
    nseg = st.seg0.size
    for _ in range(N_BOOTSTRAP):
        pick = rng.integers(0, nseg, nseg)
        base = float(st.seg0[pick].sum())
        sse = {n: float(cands.segs[n][pick].sum()) for n in order}
        ex = {n: st.above_noise_share(sse[n], base) for n in order}
        if order:
            win = max(ex, key=ex.get)
            for simple in get_effect(win).nests:  # parsimony, as in _ranking
                if simple in sse and st.above_noise_share(sse[win], sse[simple]) < MIN_EXPLAINED_SECOND:
                    win = simple
            first[win] += 1
        for n in order:
            signif[n] += ex[n] >= MIN_EXPLAINED
    return ({n: v / N_BOOTSTRAP for n, v in first.items()}, {n: v / N_BOOTSTRAP for n, v in signif.items()})


def _ranking(st: _Setup, cands: _Candidates, scr: Screening, seed: int) -> list[dict[str, Any]]:
    """Candidates best first by validation explained, with their bootstrap frequencies, split-test
    p-value and ambiguity."""
    order = sorted(cands.stats, key=lambda n: -cands.stats[n]["validation_explained"])
    # parsimony: an effect that nests a simpler one (the thrust law with α = 2 is a thrust-coefficient
    # error) ranks above it only when it removes at least MIN_EXPLAINED_SECOND of the validation gap
    # above noise that the simpler one leaves, the criterion any further parameter must meet
    for name in list(order):
        for simple in get_effect(name).nests:
            if simple in order and order.index(simple) > order.index(name):
                s_rich, s_simple = float(cands.segs[name].sum()), float(cands.segs[simple].sum())
                if st.above_noise_share(s_rich, s_simple) < MIN_EXPLAINED_SECOND:
                    order.remove(simple)
                    order.insert(order.index(name), simple)
    first, signif = _bootstrap_first(st, cands, order, seed)
    ranking: list[dict[str, Any]] = []
    for name in order:
        e = get_effect(name)
        c = cands.stats[name]
        ranking.append({
            "effect": name, "subsystem": e.subsystem, "score": c["validation_explained"],
            "validation_explained": c["validation_explained"],
            "above_noise_explained": c["above_noise_explained"], "bic_delta": c["bic_delta"],
            "bootstrap_first": first[name], "bootstrap_significant": signif[name],
            # the sample-split test of the single effect against the nominal (presence: _evidence)
            "p_value": split_test(st.seg0, cands.segs[name], st.noise_sse / st.seg0.size, MIN_EXPLAINED),
            "explained": {k: cands.completeness[name][k] for k in ("completeness", "worst_channel",
                                                                  "residual_over_noise", "verdict")},
            "parameters": _param_table(cands.fits[name], name),
            "rig_values": get_effect(name).rig_values(st.rig, cands.fits[name].values[name]),
            "screening": ({"explained_strong": scr.explained_strong[name],
                           "explained_weak": scr.explained_weak[name], "inclusion": scr.inclusion[name],
                           "equation_error_estimate": scr.estimates.get(name)}
                          if name in scr.explained_strong else {"not_screened": True}),
            "confusable_with": _in_catalog(e.confusable_with, st),
            "ambiguous_with": [],
        })
    if ranking:
        top = ranking[0]
        # effects these data do not separate from the first: they win a share of the bootstrap
        # resamples of the validation segments
        amb = [r for r in ranking[1:] if r["bootstrap_first"] >= AMBIGUOUS_FIRST]
        top["ambiguous_with"] = [r["effect"] for r in amb]
        if amb:
            top["ambiguity"] = {r["effect"]: {"validation_explained": r["validation_explained"],
                                              "bootstrap_first": r["bootstrap_first"]} for r in amb}
    return ranking


class _Added(NamedTuple):
    """The effect one forward-selection step adds (:func:`_add_effect`)."""

    gain: float  # share of the validation SSE left by the chosen set that it removes
    effect: str
    fit: EffectFit  # chosen + effect, fitted jointly
    bic_delta: float
    screening: Screening  # of the residual the chosen set left
    sse: float  # validation SSE of chosen + effect (segment_sse summed)
    segs: np.ndarray  # validation SSE per segment of chosen + effect
    share: float  # bootstrap frequency of the gain passing the threshold
    p_value: float  # sample-split test of chosen + effect against chosen (split_test)


def excluded_with(chosen: Sequence[str]) -> set[str]:
    """The chosen effects and every effect that sets the same rig parameter as one of them
    (``exclusive_with``): what may not join them in a fit."""
    out = set(chosen)
    for n in chosen:
        out |= set(get_effect(n).exclusive_with)
    return out


def _joint(st: _Setup, cur: EffectFit, chosen: Sequence[str], o: str,
           alone: EffectFit | None = None,
           o_start: Mapping[str, float] | None = None,
           say: Callable[[str], None] | None = None) -> tuple[EffectFit, np.ndarray] | None:
    """``chosen`` + ``o`` fitted jointly from the chosen values and ``o``'s fit on the corrected
    model (fitted here unless given, from ``o_start`` where given); its validation SSE per segment.
    None when a fit fails. Progress goes to ``say`` (default ``st.say``)."""
    (say or st.say)(f"joint fit of {' + '.join(chosen)} + {o}")
    try:
        alone = alone or fit_effects(cur.rig, [o], st.pf, st.ctx, start={o: dict(o_start or {})})
        start = {**{n: cur.values[n] for n in chosen}, o: alone.values[o]}
        fr2 = fit_effects(st.rig, [*chosen, o], st.pf, st.ctx, start=start, scan=False, max_nfev=MAX_NFEV)
    except GapError:
        return None
    return fr2, segment_sse(fr2.rig, fr2.meas, st.pv)


def _add_effect(st: _Setup, cur: EffectFit, cur_segs: np.ndarray, chosen: Sequence[str],
                ranking: Sequence[Mapping[str, Any]], screened: Sequence[str], forced: Sequence[str],
                seed: int) -> _Added | None:
    """One forward-selection step of :func:`diagnose_effects`: the next effect, or None.

    The residual left by the ``chosen`` effects (fitted in ``cur``) is screened (discrepancy SINDy
    on the corrected model); its :data:`FORWARD_CANDIDATES` best groups, the next
    :data:`FORWARD_CANDIDATES` ranked single effects that remove more than 10 % of the validation
    residual alone, and the ``forced`` (timing) effects are each fitted jointly with the chosen
    ones, starting from the chosen values and the candidate's fit on the corrected model. When none
    of them passes, every other identifiable effect is fitted alone on the corrected model and the
    :data:`FORWARD_CANDIDATES` best are fitted jointly too (a sign-function friction, say, is
    blurred in the derivative-based screening). A candidate counts when it removes at least
    :data:`MIN_EXPLAINED_SECOND` of the validation gap above noise the chosen set leaves, with a BIC
    gain of :data:`MIN_BIC_GAIN` on the fit data; the largest removal wins. Effects that set the
    same rig parameter as a chosen one (``exclusive_with``) are not tried.
    """
    cur_sse = float(cur_segs.sum())
    skip = excluded_with(chosen)
    rest = [n for n in screened if n not in skip]
    st.say(f"screening the residual left by {' + '.join(chosen)}")
    scr2 = screen(cur.rig, st.pf, rest, st.channels, st.ctx, seed=seed, meas=cur.meas, estimate=False)
    ranked = [r for r in ranking if r["effect"] not in skip and r["validation_explained"] is not None]
    ranked = ranked[:FORWARD_CANDIDATES]
    others: list[str] = []
    for o in (*scr2.shortlist(FORWARD_CANDIDATES),
              *(r["effect"] for r in ranked if r["validation_explained"] > 0.1)):
        if o not in others and o not in skip:
            others.append(o)
    # timing effects requested by the caller are also tried: a lead or lag often shows only once
    # the dominant (e.g. damping) error is removed
    cands = others + [f for f in forced if f not in others and f not in skip]
    k1 = sum(_n_fitted(n, st.ctx) for n in chosen)
    rng = np.random.default_rng(seed)
    best2 = None

    def consider(o: str, res: tuple[EffectFit, np.ndarray] | None) -> None:
        nonlocal best2
        if res is None:
            return
        fr2, segs2 = res
        sse2 = float(segs2.sum())
        gain = st.above_noise_share(sse2, cur_sse)
        k2 = k1 + _n_fitted(o, st.ctx)
        bic_gain = (_bic(fr2.sse * st.n_eff / st.n_fit, st.n_eff, k2)
                    - _bic(cur.sse * st.n_eff / st.n_fit, st.n_eff, k1))
        st.say(f"  {o}: removes {100 * gain:.1f} % of the remaining validation gap above noise, "
               f"BIC change {bic_gain:.1f}")
        passes = gain >= MIN_EXPLAINED_SECOND and bic_gain <= -MIN_BIC_GAIN
        why = unresolved_times(o, fr2.values[o], max(p.dt for p in st.pf))
        if passes and why:
            st.say(f"  {why}")
            passes = False
        p_value = (split_test(cur_segs, segs2, st.noise_sse / cur_segs.size, MIN_EXPLAINED_SECOND)
                   if passes else 1.0)
        if passes and not _holds_in_sample(st, p_value):
            st.say(f"  {o}: in-sample, its gain does not hold second by second (split-test p {p_value:.2f})")
            passes = False
        if passes and (best2 is None or gain > best2.gain):
            hits = 0
            for _ in range(N_BOOTSTRAP):
                pick = rng.integers(0, segs2.size, segs2.size)
                hits += st.above_noise_share(float(segs2[pick].sum()),
                                             float(cur_segs[pick].sum())) >= MIN_EXPLAINED_SECOND
            best2 = _Added(gain, o, fr2, bic_gain, scr2, sse2, segs2, hits / N_BOOTSTRAP, p_value)

    # the joint fits are independent (run at once, _each); their figures are taken in order
    for o, res in _each(st, cands, lambda o, say: _joint(st, cur, chosen, o, say=say)):
        consider(o, res)
    if best2 is None:
        more = [n for n in st.model_effects if n not in skip and n not in cands]
        st.say(f"no proposed effect passes; fitting the rest of the catalog on the corrected model: {more}")

        def alone_fit(o: str, _say: Callable[[str], None]) -> tuple[float, EffectFit] | None:
            try:
                fr = fit_effects(cur.rig, [o], st.pf, st.ctx)
            except GapError:
                return None
            return float(segment_sse(fr.rig, fr.meas, st.pv).sum()), fr

        alone = {o: r for o, r in _each(st, more, alone_fit) if r is not None}
        best = sorted(alone, key=lambda n: alone[n][0])[:FORWARD_CANDIDATES]
        for o, res in _each(st, best, lambda o, say: _joint(st, cur, chosen, o, alone[o][1], say=say)):
            consider(o, res)
    return best2


_Swapped = tuple[EffectFit, np.ndarray, list[str], dict[str, dict[str, float]],
                 dict[tuple[str, str], EffectFit]]


def _swap_confusables(st: _Setup, cur: EffectFit, cur_segs: np.ndarray, chosen: list[str]) -> _Swapped:
    """Replacement pass after forward selection: each chosen effect is replaced, in turn, by each
    of its physics-confusable or nested alternatives, fitted jointly with the other chosen ones.

    With two causes at once, the best single effect is often a stand-in (a back-EMF error for an
    armature-resistance error) that the joint fit with the true partner then keeps. An
    alternative replaces it when it removes at least :data:`SWAP_GAIN` of the validation gap above
    noise that the current set leaves; a simpler nested effect (K_q for the thrust law) replaces
    its richer one unless the richer one removes :data:`MIN_EXPLAINED_SECOND` of what it leaves.
    An alternative that neither set beats by :data:`SWAP_GAIN` is returned as not separated from
    the chosen effect (``{chosen effect: {alternative: its validation explained, jointly fitted}}``),
    and its joint fit as ``{(chosen effect, alternative): fit}``.
    """
    amb: dict[str, dict[str, float]] = {}
    alt_fits: dict[tuple[str, str], EffectFit] = {}
    for i in range(len(chosen)):
        name = chosen[i]
        others = [n for n in chosen if n != name]
        blocked = excluded_with(others) | set(chosen)
        alts = [a for a in dict.fromkeys((*get_effect(name).nests, *get_effect(name).confusable_with))
                if a in st.model_effects and a not in blocked]
        for alt in alts:
            st.say(f"replacement: {name} -> {alt}")
            base = EffectFit(effects=tuple(others), values={n: cur.values[n] for n in others}, std={},
                             rig=cur.rig, meas=cur.meas, sse=cur.sse, n=cur.n, nfev=0)
            res = _joint(st, base, others, alt)
            if res is None:
                continue
            fr2, segs2 = res
            if unresolved_times(alt, fr2.values[alt], max(p.dt for p in st.pf)):
                continue  # not resolved at this rate: neither a replacement nor an alternative
            s_cur, s_alt = float(cur_segs.sum()), float(segs2.sum())
            if alt in get_effect(name).nests:  # simpler alternative: the richer one must earn it
                better = st.above_noise_share(s_cur, s_alt) < MIN_EXPLAINED_SECOND
            elif name in get_effect(alt).nests:  # richer alternative: the same criterion
                better = st.above_noise_share(s_alt, s_cur) >= MIN_EXPLAINED_SECOND
            else:
                better = st.above_noise_share(s_alt, s_cur) >= SWAP_GAIN
            if not better and st.above_noise_share(s_cur, s_alt) < SWAP_GAIN:
                # neither is better: these data do not separate the two (for a confusable one, the
                # rule of :func:`_not_separated`)
                amb.setdefault(name, {})[alt] = 1.0 - s_alt / max(st.sse_val0, 1e-300)
                alt_fits[(name, alt)] = fr2
            if better:
                st.say(f"  {alt} replaces {name}")
                amb.pop(name, None)
                alt_fits = {k: v for k, v in alt_fits.items() if k[0] != name}
                chosen = [alt if n == name else n for n in chosen]
                order = list(chosen)
                cur = EffectFit(effects=tuple(order), values={n: fr2.values[n] for n in order}, std=fr2.std,
                                rig=fr2.rig, meas=fr2.meas, sse=fr2.sse, n=fr2.n, nfev=fr2.nfev)
                cur_segs = segs2
                break
    return cur, cur_segs, chosen, amb, alt_fits


def _not_separated(st: _Setup, sse_a: float, sse_b: float) -> bool:
    """Whether two models with validation SSE ``sse_a`` and ``sse_b`` are not separated by these
    data: neither removes :data:`SWAP_GAIN` of the validation gap above noise that the other
    leaves (the replacement pass' rule for a confusable alternative, :func:`_swap_confusables`)."""
    return st.above_noise_share(sse_a, sse_b) < SWAP_GAIN and st.above_noise_share(sse_b, sse_a) < SWAP_GAIN


def plant_side_alternative(chosen: Sequence[str], ambiguous: Mapping[str, Mapping[str, float]]
                           ) -> tuple[str, str] | None:
    """The plant-side effect to write instead of a chosen sensor-frame effect the data do not
    separate from it, as ``(sensor effect, plant-side effect)``; ``None`` when there is none.

    A sensor gain and a thrust-coefficient (or gravity, inertia) error shape the recorded angle
    alike at small angles (only sin θ tells them apart), so one recording often cannot separate
    them. For the rig file a controller is designed on they are not alike: a wrong sensor frame
    makes the loop hold every set point at the wrong physical angle (by the fitted gain), while a
    plant-side stand-in for a true sensor error holds the angle the nominal rig file would. The
    plant-side alternative is therefore the one written (:attr:`EffectDiagnosis.plant_side`); the
    diagnosis still names what fitted best.

    Parameters
    ----------
    chosen : sequence of str
        Effects chosen, in order.
    ambiguous : mapping
        ``{chosen effect: {alternative: validation explained}}`` (the replacement pass' record of
        alternatives the data do not separate).

    Returns
    -------
    tuple of str or None
        The first chosen ``kind == "measurement"`` effect with a ``kind == "model"`` alternative,
        and of those alternatives the one explaining most of the validation error.
    """
    for name in chosen:
        if get_effect(name).kind != "measurement":
            continue
        alts = {a: v for a, v in ambiguous.get(name, {}).items() if get_effect(a).kind == "model"}
        if alts:
            return name, max(alts, key=lambda a: alts[a])
    return None


#: A refinement's own parameter this close to a bound of its search range (a factor for log
#: parameters, a share of the range otherwise) does not describe the refinement.
AT_BOUND_FACTOR = 1.25


AT_BOUND_SHARE = 0.02


def _added_at_bound(st: _Setup, name: str, ref: str, values: Mapping[str, float]) -> list[str]:
    """The parameters ``ref`` adds to ``name`` whose fitted values sit at a bound of their search
    range: a Stribeck velocity at its floor (3× the sign's regularisation width) only sharpens the
    model's smooth sign, an excess static friction at 0 is no stiction; the refinement is then not
    what the data show."""
    out = []
    shared = set(get_effect(name).parameter_names)
    for p in get_effect(ref).parameters:
        if p.name in shared:
            continue
        r, v = p.bind(st.ctx), values[p.name]
        if r.log:
            near = v <= r.lower * AT_BOUND_FACTOR or v >= r.upper / AT_BOUND_FACTOR
        else:
            span = r.upper - r.lower
            near = v <= r.lower + AT_BOUND_SHARE * span or v >= r.upper - AT_BOUND_SHARE * span
        if near:
            out.append(p.name)
    return out


def _refine(st: _Setup, cur: EffectFit, cur_segs: np.ndarray, chosen: list[str]
            ) -> tuple[EffectFit, np.ndarray, list[str], dict[str, dict[str, float]]]:
    """Refinement pass: each chosen effect that an operating-point refinement refines (Coulomb →
    Stribeck friction, ``Effect.refines``) is replaced by it, fitted jointly with the other chosen
    effects from the values they share, when the refinement earns its extra parameters twice:
    it removes :data:`MIN_EXPLAINED_SECOND` of the validation gap above noise that the chosen set
    leaves, and lowers the fit data's BIC by :data:`MIN_BIC_GAIN`; and its own parameters are not
    at a bound of their range (:func:`_added_at_bound`). Returns the (new) fit, its
    validation SSE per segment, the chosen names and, per tried refinement, its figures."""
    tried: dict[str, dict[str, float]] = {}
    for name in list(chosen):
        for ref in st.refinements:
            if name not in get_effect(ref).refines:
                continue
            others = [n for n in chosen if n != name]
            if ref in excluded_with(others):
                continue
            st.say(f"refinement: {name} -> {ref}")
            shared = {k: v for k, v in cur.values[name].items() if k in get_effect(ref).parameter_names}
            base = EffectFit(effects=tuple(others), values={n: cur.values[n] for n in others}, std={},
                             rig=cur.rig, meas=cur.meas, sse=cur.sse, n=cur.n, nfev=0)
            res = _joint(st, base, others, ref, o_start=shared)
            if res is None:
                continue
            fr2, segs2 = res
            k1 = sum(_n_fitted(n, st.ctx) for n in chosen)
            k2 = k1 - _n_fitted(name, st.ctx) + _n_fitted(ref, st.ctx)
            bic = (_bic(fr2.sse * st.n_eff / st.n_fit, st.n_eff, k2)
                   - _bic(cur.sse * st.n_eff / st.n_fit, st.n_eff, k1))
            gain = st.above_noise_share(float(segs2.sum()), float(cur_segs.sum()))
            at_bound = _added_at_bound(st, name, ref, fr2.values[ref])
            kept = gain >= MIN_EXPLAINED_SECOND and bic <= -MIN_BIC_GAIN and not at_bound
            tried[ref] = {"replaces": name, "above_noise_explained_of_rest": gain, "bic_delta": bic,
                          "at_bound": at_bound, "kept": kept}
            st.say(f"  {ref} removes {100 * gain:.1f} % of what {name} leaves above noise, BIC change "
                   f"{bic:.1f}{', ' + ', '.join(at_bound) + ' at a bound' if at_bound else ''}: "
                   f"{'kept' if kept else 'not kept'}")
            if kept:
                chosen = [ref if n == name else n for n in chosen]
                cur = EffectFit(effects=tuple(chosen), values={n: fr2.values[n] for n in chosen}, std=fr2.std,
                                rig=fr2.rig, meas=fr2.meas, sse=fr2.sse, n=fr2.n, nfev=fr2.nfev)
                cur_segs = segs2
                break
    return cur, cur_segs, chosen, tried

