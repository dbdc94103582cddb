"""Which, stage 4 — confirmation: each shortlisted effect fitted alone and scored (``_Candidates``).

Part of the effect diagnosis of :mod:`aeropend_ident.gap.which` (steps 3 and 5 of its pipeline); no rclpy.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeropend_ident.gap.effects import (
    EffectContext,
    get_effect,
)
from aeropend_ident.gap.which.context import _each, _Setup
from aeropend_ident.gap.which.fitting import EffectFit, _n_fitted, fit_effects
from aeropend_ident.gap.which.metrics import validation_errors
from aeropend_ident.gap.which.screening import Screening, _bic

#: Validation error over its noise part (per channel, squared) up to which an effect (set) counts
#: as a complete explanation, and from which it counts as none; the completeness is scaled
#: log-linearly between. Ratio − 1 is the unexplained variance over the noise variance: complete
#: while the systematic error is below 30 % of the noise variance, no explanation once it is as
#: large as the noise itself. A model with the right structure and fitted parameters leaves
#: 1 + O(k/N) plus the few-% error of the noise estimate: measured 1.00–1.2 on the independent
#: benchmark's correctly named cases, 1.8 to thousands where the cause lies outside the catalog
#: (bench/results/gap_independent.md).
RESIDUAL_NOISE_OK = 1.3


RESIDUAL_NOISE_MAX = 2.0


@dataclass
class _Candidates:
    """Single-effect fits on the nominal rig and their validation figures."""

    fits: dict[str, EffectFit] = field(default_factory=dict)
    segs: dict[str, np.ndarray] = field(default_factory=dict)
    stats: dict[str, dict[str, float]] = field(default_factory=dict)
    completeness: dict[str, dict[str, Any]] = field(default_factory=dict)

    def confirm(self, st: _Setup, names: Sequence[str], scr: Screening) -> None:
        """Fit each effect alone (multi-start, from its equation-error estimate too) and score it
        on the validation recordings.

        The fits are independent and run at once (:func:`_each`); the figures are those of
        fitting one after the other. A held setting freed by one fit
        (:func:`_free_settings_if_validated`) concerns that effect's parameters only, so it is
        merged into ``st.ctx`` after the fit: one after the other, each fit reads the context the
        ones before it left; at once, the context of the step's start (the same for its own
        parameters)."""
        todo = [n for n in dict.fromkeys(names) if n not in self.fits]
        def work(name: str, say: Callable[[str], None]) -> tuple[EffectFit, np.ndarray, dict, frozenset[str]]:
            return _confirm_one(st, st.ctx, name, scr.estimates.get(name), say)

        for name, result in _each(st, todo, work):
            self._take(st, name, result)

    def _take(self, st: _Setup, name: str,
              result: tuple[EffectFit, np.ndarray, dict, frozenset[str]]) -> None:
        """Record one single-effect fit (:func:`_confirm_one`) and its validation figures."""
        fr, sg, per_channel, freed = result
        if freed:
            st.ctx = dataclasses.replace(st.ctx, free_settings=st.ctx.free_settings | freed)
        self.fits[name] = fr
        self.segs[name] = sg
        self.completeness[name] = _completeness(st, per_channel)
        k = _n_fitted(name, st.ctx)
        self.stats[name] = {
            "validation_explained": 1.0 - float(sg.sum()) / max(st.sse_val0, 1e-300),
            "above_noise_explained": st.above_noise_share(float(sg.sum())),
            "bic_delta": (_bic(fr.sse * st.n_eff / st.n_fit, st.n_eff, k)
                          - _bic(st.sse_fit0 * st.n_eff / st.n_fit, st.n_eff, 0)),
        }

    def best_above_noise(self) -> float:
        """Largest share of the validation gap above noise that one candidate removes."""
        return max((c["above_noise_explained"] for c in self.stats.values()), default=0.0)


def _confirm_one(st: _Setup, ctx: EffectContext, name: str, est: Mapping[str, float] | None,
                 say: Callable[[str], None]) -> tuple[EffectFit, np.ndarray, dict, frozenset[str]]:
    """The single-effect fit of ``name`` on the fit recordings (starting from its equation-error
    estimate ``est`` too), its validation SSE per segment and per channel, and the effects whose
    held settings it freed (:func:`_free_settings_if_validated`; empty when none). Reads ``st``
    and ``ctx`` only: the fits of several effects may run at once."""
    say(f"grey-box fit of {name}")
    fr = fit_effects(st.rig, [name], st.pf, ctx, starts=[{name: est}] if est else ())
    sg, per_channel = validation_errors(fr.rig, fr.meas, st.pv)
    if any(p.held for p in get_effect(name).parameters) and name not in ctx.free_settings:
        return _free_settings_if_validated(st, ctx, name, est, (fr, sg, per_channel), say)
    return fr, sg, per_channel, frozenset()


def _free_settings_if_validated(st: _Setup, ctx: EffectContext, name: str, est: Mapping[str, float] | None,
                                held: tuple[EffectFit, np.ndarray, dict], say: Callable[[str], None]
                                ) -> tuple[EffectFit, np.ndarray, dict, frozenset[str]]:
    """The single-effect fit of ``name`` with its held parameters (the dry friction's onset
    width v_ε) fitted too, kept when it predicts the validation recordings better than the fit
    with the rig's settings (``held``: fit, validation SSE per segment, per channel); the diagnosis
    then fits them wherever the effect enters (the returned names join ``st.ctx.free_settings``:
    ``name`` and its refinements, a Stribeck law of the dry friction; empty when the rig's
    settings stay). A sample-split choice
    between two nested models: on a rod that creeps slower than the rig file's regularisation
    allows, the free width wins by far; where the fit data alone favour a width the validation
    data do not bear out (a real rig with more than dry friction), the rig's width stays."""
    freed = frozenset({name} | {r for r in st.refinements if name in get_effect(r).refines})
    fr = fit_effects(st.rig, [name], st.pf, dataclasses.replace(ctx, free_settings=ctx.free_settings | freed),
                     starts=[{name: est}] if est else ())
    sg, per_channel = validation_errors(fr.rig, fr.meas, st.pv)
    what = ", ".join(p.name for p in get_effect(name).parameters if p.held)
    if float(sg.sum()) < float(held[1].sum()):
        say(f"  {name}: {what} fitted (validation SSE {st.noise_ratio(float(sg.sum()))} against "
            f"{st.noise_ratio(float(held[1].sum()))} at the rig's value)")
        return fr, sg, per_channel, freed
    say(f"  {name}: {what} kept at the rig's value (fitted, the validation SSE is "
        f"{st.noise_ratio(float(sg.sum()))}, not below {st.noise_ratio(float(held[1].sum()))})")
    return (*held, frozenset())


#: A channel's nominal validation excess over its noise part (ratio − 1) that no single candidate
#: reduces by at least this share is a floor the catalog cannot reach (:func:`unreachable_channels`).
REACH_SHARE = 0.1


def unreachable_channels(st: _Setup, cands: _Candidates) -> frozenset[str]:
    """Recorded channels other than θ whose validation residual stands above its noise and which no
    candidate effect changed (each one's ratio stayed within :data:`REACH_SHARE` of the nominal
    excess): a residual the catalog cannot reach, e.g. a v_a mismatch of 0.5 % of its range that every
    correction leaves as it was. :func:`_completeness` reports such a channel without letting it zero
    the completeness of a correction that removed the gap where the catalog can act."""
    out = set()
    for c, s0 in st.sse0_c.items():
        n_c = max(st.noise_c[c], 1e-300)
        r0 = s0 / n_c
        if c == "theta" or r0 <= RESIDUAL_NOISE_OK:
            continue
        best = min((v["per_channel"][c]["residual_over_noise"] for v in cands.completeness.values()
                    if c in v.get("per_channel", {})), default=r0)
        if best >= r0 - REACH_SHARE * (r0 - 1.0):
            out.add(c)
    return frozenset(out)


def _completeness(st: _Setup, sse: Mapping[str, float], unreachable: frozenset[str] = frozenset()
                  ) -> dict[str, Any]:
    """How completely a corrected model explains the validation gap, judged channel by channel.

    ``sse`` is the corrected model's validation error per channel (:func:`validation_errors`).
    Each channel's error is compared with its noise part (:func:`_noise_var`): a model that
    captures the plant leaves only noise (ratio near 1). ``completeness`` is 1 while every channel's
    ratio is at most :data:`RESIDUAL_NOISE_OK` (RMS within 2× the noise), 0 from
    :data:`RESIDUAL_NOISE_MAX` on (RMS 5×), log-linear between; the worst channel counts. Pooling the
    channels would let the noise of well-modelled channels hide a residual left in another. A channel
    in ``unreachable`` (:func:`unreachable_channels`) is reported (``per_channel[c]["unreachable"]``,
    the verdict) but does not count.
    """
    per: dict[str, dict[str, float]] = {}
    comp = 1.0
    for c, s_c in sse.items():
        n_c = max(st.noise_c[c], 1e-300)
        s0 = st.sse0_c[c]
        ratio = s_c / n_c
        share = (s0 - s_c) / (s0 - n_c) if s0 > n_c else math.nan
        c_c = float(np.clip(math.log(RESIDUAL_NOISE_MAX / max(ratio, 1e-300))
                            / math.log(RESIDUAL_NOISE_MAX / RESIDUAL_NOISE_OK), 0.0, 1.0))
        per[c] = {"residual_over_noise": ratio, "nominal_over_noise": s0 / n_c, "share_above_noise": share,
                  "completeness": c_c, "unreachable": c in unreachable}
        if c not in unreachable:
            comp = min(comp, c_c)
    counted = [k for k in per if k not in unreachable] or list(per)
    worst = max(counted, key=lambda k: per[k]["residual_over_noise"])
    w = per[worst]
    times = f"{math.sqrt(w['residual_over_noise']):.1f}× its noise RMS"
    if comp >= 1.0:
        verdict = "explained: the corrected model leaves the noise level"
    elif comp >= 0.5:
        verdict = f"mostly explained ({worst} residual {times})"
    else:
        verdict = (f"partly explained: the {worst} residual stays {times}, which no chosen effect accounts "
                   "for (an effect outside the catalog, several at once, or a time-varying rig)")
    floors = [k for k in per if k in unreachable]
    if floors:
        verdict += "; not counted: " + ", ".join(
            f"the {k} residual ({math.sqrt(per[k]['residual_over_noise']):.1f}× its noise RMS), which no "
            "candidate effect changes" for k in floors)
    return {"completeness": comp, "worst_channel": worst, "residual_over_noise": w["residual_over_noise"],
            "share_above_noise": w["share_above_noise"], "per_channel": per, "verdict": verdict}

