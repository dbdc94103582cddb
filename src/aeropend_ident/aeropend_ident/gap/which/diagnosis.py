"""Which, the whole diagnosis (:func:`diagnose_effects`): the stages in order, and its result.

The pipeline is described in :mod:`aeropend_ident.gap.which`; no rclpy.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeropend_ident.errors import GapError
from aeropend_ident.gap.effects import (
    MeasurementMap,
    detect_quantum,
    get_effect,
)
from aeropend_ident.gap.which.candidates import _Candidates, _completeness, unreachable_channels
from aeropend_ident.gap.which.context import (
    ABOVE_NOISE,
    IN_SAMPLE_MAX_P,
    _above_noise,
    _holds_in_sample,
    _in_catalog,
    _param_table,
    _Setup,
    _setup,
)
from aeropend_ident.gap.which.data import replay
from aeropend_ident.gap.which.evidence import MIN_EXPLAINED, _evidence, _mark_unresolved, _unresolved_reason
from aeropend_ident.gap.which.fitting import EffectFit
from aeropend_ident.gap.which.metrics import channel_sse, gap_metrics
from aeropend_ident.gap.which.ranking import (
    _add_effect,
    _Added,
    _not_separated,
    _ranking,
    _refine,
    _swap_confusables,
    plant_side_alternative,
)
from aeropend_ident.gap.which.screening import MIN_BIC_GAIN, SHORTLIST, Screening, screen
from aeropend_ident.io.jsonutil import jsonable
from aeropend_sim.params import Rig, rig_to_dict
from aeropend_sim.recording import Recording

#: Further screened effects confirmed when the best shortlisted effect leaves more than
#: EXTEND_BELOW_GAP of the validation gap above noise.
EXTEND_SHORTLIST = 3


EXTEND_BELOW_GAP = 0.2


@dataclass
class EffectDiagnosis:
    """Outcome of :func:`diagnose_effects` (see the module docstring).

    "Validation" is the part of the fit data the diagnosis chooses and ranks on; the held-out
    recordings of :func:`aeropend_ident.gap.run.run_gap` are never seen here.

    Attributes
    ----------
    significant : bool
        False => "no significant gap".
    ranking : list of dict
        Best first: ``effect``, ``subsystem``, ``score``, ``validation_explained`` (share of the
        nominal validation SSE the effect removes), ``bic_delta``, ``p_value`` (its sample-split
        test), ``q_value`` (false-discovery-rate adjusted), ``presence`` (0..1, the evidence the
        effect is present: :func:`_evidence`), ``status`` ("named", "candidate", "not separated",
        "not significant", "detected": :func:`status_of`), ``parameters``
        ``{name: {value, std, unit}}`` (physical units), ``rig_values``, ``screening`` (strong/weak
        explained, inclusion, equation-error estimate), ``confusable_with`` (physics),
        ``ambiguous_with`` (effects these data do not separate from it, with the evidence in
        ``ambiguity``).
    not_identifiable : list of dict
        ``{"effect", "reason"}`` for effects the recorded channels cannot reveal.
    chosen : list of str
        Fitted effects added to the corrected rig (0 to ``max_effects``), in the order chosen.
        Never a directly detected effect (see ``detected``).
    corrected_rig : Rig
        Nominal rig + chosen effects, fitted, + the detected effects.
    validation : list of dict
        Validation gap per cumulative effect set (:func:`gap_metrics`), first row nominal
        (``effects`` = []).
    measurement : MeasurementMap
        θ transform of chosen sensor effects (offset/scale), identity otherwise.
    screening : dict
        Discrepancy-SINDy screening details.
    reason : str
        Why the gap is (not) significant.
    channels : list of str
        Channels used.
    explained : dict
        How completely the chosen set explains the validation gap: ``share_above_noise``
        (1 − (SSE_chosen − SSE_noise)/(SSE_nominal − SSE_noise)), ``residual_over_noise``
        (SSE_chosen/SSE_noise), ``completeness`` (0..1) and a ``verdict``.
    elapsed : float
        Wall time [s].
    detected : dict
        Effects read from the recordings themselves, not fitted (catalog kind ``"direct"``):
        ``{"quantisation": {"theta_quantum": q}}`` [rad] when the recorded angle lies on a lattice
        the nominal rig does not model. They describe the measurement (the corrected rig's sensor,
        the noise floor q/√12); they are never refitted (:func:`fit_effects` refuses them). Their
        ranking entry says ``"detected": True``.
    plant_side : dict or None
        When a chosen sensor-frame effect is not separated by these data from a plant-side one
        (:func:`plant_side_alternative`): ``replaces``, ``by``, ``validation_explained``,
        ``parameters`` (the alternative's fitted values) and the jointly fitted ``rig`` and
        ``measurement`` with the alternative in its place. The corrected rig *file*
        (:func:`aeropend_ident.gap.result.corrected_rig_dict`) is written from these.
    """

    significant: bool
    ranking: list[dict]
    not_identifiable: list[dict]
    chosen: list[str]
    corrected_rig: Rig
    validation: list[dict]
    measurement: MeasurementMap = field(default_factory=MeasurementMap)
    screening: dict = field(default_factory=dict)
    reason: str = ""
    channels: list[str] = field(default_factory=list)
    explained: dict = field(default_factory=dict)
    elapsed: float = 0.0
    plant_side: dict | None = None
    detected: dict[str, dict[str, float]] = field(default_factory=dict)
    free_settings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        """JSON-able summary; the corrected rig as its YAML dict (with ``recording_frame`` if a
        sensor offset was found; a sensor scale is reported in ``measurement``)."""
        rig = rig_to_dict(self.corrected_rig)
        if self.measurement.theta_offset != 0.0:
            rig["recording_frame"] = {"theta_offset": {
                "value": self.measurement.theta_offset, "unit": "rad",
                "source": "gap diagnosis: fitted sensor offset"}}
        return jsonable({
            "significant": self.significant,
            "reason": self.reason,
            "ranking": self.ranking,
            "not_identifiable": self.not_identifiable,
            "chosen": self.chosen,
            "detected": self.detected,
            "explained": self.explained,
            "corrected_rig": rig,
            "measurement": dataclasses.asdict(self.measurement),
            "validation": self.validation,
            "screening": self.screening,
            "channels": self.channels,
            "free_settings": self.free_settings,
            "elapsed_s": self.elapsed,
            "plant_side": ({k: v for k, v in self.plant_side.items() if k not in ("rig", "measurement")}
                           if self.plant_side else None),
        })


def _quantisation_entry(st: _Setup, q_hat: float) -> dict[str, Any]:
    """Ranking entry of a detected angle quantum q (not fitted): its score is the share of the nominal
    validation mean square error that the rounding noise q²/12 accounts for."""
    ms0 = float(np.mean([np.mean((replay(st.rig, MeasurementMap(), p)["theta"] - p.y["theta"]) ** 2)
                         for p in st.pv]))
    share = min(1.0, (q_hat**2 / 12.0) / max(ms0, 1e-300))
    return {
        "effect": "quantisation", "subsystem": get_effect("quantisation").subsystem, "score": share,
        "validation_explained": share, "bic_delta": None, "presence": 1.0, "status": "detected",
        "detected": True,
        "parameters": {"theta_quantum": {"value": q_hat, "std": 0.0, "unit": "rad"}},
        "rig_values": {"sensors.theta_quantum": q_hat},
        "screening": {"detected": "lattice of recorded angles"},
        "confusable_with": [], "ambiguous_with": [],
    }


def _unmodelled_quantum(rig: Rig, st: _Setup) -> float:
    """The angle quantum q [rad] every fit and validation recording shows
    (:func:`aeropend_ident.gap.effects.detect_quantum`, median over them) when the nominal rig does
    not model it (no quantisation, or an LSB under 2/3 of q); else 0."""
    quanta = [detect_quantum(p.y["theta"]) for p in (*st.pf, *st.pv)]
    q_hat = float(np.median(quanta)) if all(q > 0 for q in quanta) else 0.0
    q_nominal = rig.sensors.theta_quantum if rig.effects.quantisation else 0.0
    return q_hat if q_hat > 0.0 and q_hat > 1.5 * q_nominal else 0.0


def _add_quantum(st: _Setup, q_hat: float, ranking: list[dict[str, Any]], corrected: Rig, sig_first: bool,
                 reason: str) -> tuple[Rig, str]:
    """A detected angle quantum into the diagnosis: its ranking entry (first when no dynamic effect is
    significant or it accounts for more of the validation error), the corrected rig's sensor LSB and
    the reason; returns (corrected rig, reason)."""
    entry = _quantisation_entry(st, q_hat)
    # the first entry may be a chosen effect a replacement pass brought in, never fitted alone (no
    # figure of its own): compare with the best single effect's
    first_ex = max((r["validation_explained"] for r in ranking if r.get("validation_explained") is not None),
                   default=0.0)
    ranking.insert(0 if (not sig_first or entry["validation_explained"] >= first_ex) else 1, entry)
    corrected = get_effect("quantisation").apply(corrected, {"theta_quantum": q_hat})
    note = (f"angle quantised with LSB {q_hat:.4g} rad (detected from the recorded values, not "
            "fitted), not modelled by the nominal rig")
    return corrected, (f"{reason}; {note}" if sig_first else
                       f"{note}; no dynamic effect is significant ({reason})")


def _screen_and_confirm(rig: Rig, st: _Setup, also_confirm: Sequence[str], seed: int,
                        say: Callable[[str], None]) -> tuple[Screening, _Candidates, list[str], list[str]]:
    """Screening and grey-box confirmation of :func:`diagnose_effects`: (screening, candidates,
    screened effects, effects confirmed without screening)."""
    # screening; effects marked screened=False (the motor time constant: its θ̈ column, through the
    # simulated thrust, is nearly collinear with the damping term and crowds it out of the group
    # selection) are not screened but always confirmed by a grey-box fit
    screened = [n for n in st.model_effects if get_effect(n).screened]
    unscreened = [n for n in st.model_effects if not get_effect(n).screened]
    say(f"screening {len(screened)} effects by discrepancy SINDy (strong + weak, group sparse)")
    scr = screen(rig, st.pf, screened, st.channels, st.ctx, seed=seed)
    short = scr.shortlist(SHORTLIST)
    say(f"shortlist: {short}")
    cands = _Candidates()
    forced = list(dict.fromkeys(n for n in (*unscreened, *also_confirm) if n in st.model_effects))
    if forced:
        say(f"also confirming {[f for f in forced if f not in short]} (not screened, or requested: "
            "timing lead/lag seen by the where-analysis)")
    cands.confirm(st, [*short, *forced], scr)  # one step: the fits run at once (_each)
    if 1.0 - cands.best_above_noise() > EXTEND_BELOW_GAP:
        # the best candidate leaves much of the gap above noise: confirm the next screened effects
        extra = [n for n in scr.shortlist(SHORTLIST + EXTEND_SHORTLIST) if n not in cands.fits]
        say(f"best candidate leaves {100 * (1 - cands.best_above_noise()):.0f} % of the gap above noise; "
            f"also confirming {extra}")
        cands.confirm(st, extra, scr)
    if cands.best_above_noise() < MIN_EXPLAINED and _above_noise(st.sse0_c, st.noise_c, st.chance_c):
        # a gap, but nothing the screening proposed explains it (small gaps at low SNR blur the
        # derivative-based screening): confirm every remaining identifiable effect
        rest = [n for n in st.model_effects if n not in cands.fits]
        say(f"no shortlisted effect explains the gap; confirming the rest of the catalog {rest}")
        cands.confirm(st, rest, scr)
    return scr, cands, screened, forced


def _no_effect_reason(st: _Setup, best: dict[str, Any] | None, above_floor: bool) -> str:
    """Why :func:`diagnose_effects` names no dynamic effect."""
    if best is None:
        reason = "no identifiable candidate effect"
    elif not above_floor:
        noise = {c: max(st.noise_c[c], 1e-300) for c in st.noise_c}
        worst = max(st.sse0_c, key=lambda c: st.sse0_c[c] / (ABOVE_NOISE * noise[c] + st.chance_c[c]))
        bound = math.sqrt(ABOVE_NOISE + st.chance_c[worst] / noise[worst])
        reason = (f"nominal validation error is at the noise floor: every channel's error is within "
                  f"{math.sqrt(ABOVE_NOISE):.2f}× its noise RMS, more by the chance of a few held rounding "
                  f"errors (closest: {worst}, {math.sqrt(st.sse0_c[worst] / noise[worst]):.2f}× "
                  f"against {bound:.2f}×)")
    elif (best["above_noise_explained"] >= MIN_EXPLAINED and best["bic_delta"] <= -MIN_BIC_GAIN
          and not _holds_in_sample(st, best["p_value"])):
        reason = (f"best candidate {best['effect']} removes {100 * best['above_noise_explained']:.1f} % of "
                  "the fit part's gap above noise in all but not second by second: in-sample split-test p "
                  f"{best['p_value']:.2f}, needs {IN_SAMPLE_MAX_P:g} or less, and the validation part, which "
                  "shows no gap, cannot support it")
    elif best["above_noise_explained"] >= MIN_EXPLAINED:
        reason = (f"best candidate {best['effect']} removes {100 * best['above_noise_explained']:.1f} % of "
                  "the validation gap above noise, but its BIC on the fit data changes by "
                  f"{best['bic_delta']:+.1f} (needs -{MIN_BIC_GAIN:g} or less)")
    else:
        reason = (f"best candidate {best['effect']} removes only {100 * best['above_noise_explained']:.1f} % "
                  f"of the validation gap above noise (needs {100 * MIN_EXPLAINED:.0f} % and a BIC gain of "
                  f"{MIN_BIC_GAIN:g}; BIC change {best['bic_delta']:.1f})")
    return reason


@dataclass
class _Selection:
    """The effects :func:`_select` chose and what they leave (the fields of :class:`EffectDiagnosis`
    of the same meaning; ``shares`` / ``pvals``: each chosen effect's bootstrap share of presence
    and split-test p-value)."""

    chosen: list[str]
    corrected: Rig
    measurement: MeasurementMap
    table: list[dict[str, Any]]
    shares: dict[str, float]
    pvals: dict[str, float]
    plant_side: dict[str, Any] | None
    explained: dict[str, Any]
    reason: str


def _select(st: _Setup, scr: Any, cands: _Candidates, ranking: list[dict[str, Any]], best: dict[str, Any],
            screened: Any, forced: Any, *, max_effects: int, seed: int, say: Callable[[str], None]
            ) -> _Selection:
    """The first-ranked effect, then forward selection while the chosen set leaves some channel
    above its noise, the swaps of confusable effects and the refinements (:func:`diagnose_effects`,
    when the first effect is significant); ``ranking`` is completed in place."""
    chosen: list[str] = []
    table = [{"effects": [], **st.base_metrics}]
    shares: dict[str, float] = {}  # chosen effect -> bootstrap share of its presence
    pvals: dict[str, float] = {}  # chosen effect -> its split-test p-value
    name = best["effect"]
    chosen.append(name)
    cur, cur_segs = cands.fits[name], cands.segs[name]
    corrected, meas = cur.rig, cur.meas
    table.append({"effects": list(chosen), **gap_metrics(corrected, meas, st.pv)})
    say(f"{name} leaves a validation SSE of {st.noise_ratio(float(cur_segs.sum()))}")
    shares[name], pvals[name] = best["bootstrap_first"], best["p_value"]
    # forward selection: while the chosen set leaves some channel's residual above its noise
    # (completeness < 1), screen its residual and confirm the best candidates by a joint fit with
    # the effects already chosen
    floor = unreachable_channels(st, cands)
    while (len(chosen) < max_effects
           and _completeness(st, channel_sse(corrected, meas, st.pv), floor)["completeness"] < 1.0):
        added = _add_effect(st, cur, cur_segs, chosen, ranking, screened, forced, seed + 2 * len(chosen))
        if added is None:
            break
        o = added.effect
        chosen.append(o)
        cur, cur_segs = added.fit, added.segs
        corrected, meas = cur.rig, cur.meas
        shares[o], pvals[o] = added.share, added.p_value
        _record_added(ranking, st, added, chosen)
        table.append({"effects": list(chosen), **gap_metrics(corrected, meas, st.pv)})
    amb, alt_fits = _unseparated_single(st, best, cands, ranking) if len(chosen) == 1 else ({}, {})
    if len(chosen) >= 2:
        before = list(chosen)
        cur, cur_segs, chosen, amb, alt_fits = _swap_confusables(st, cur, cur_segs, chosen)
        for r in ranking:
            alts = amb.get(r["effect"], {})
            if alts:
                r["ambiguous_with"] = list(dict.fromkeys([*r.get("ambiguous_with", []), *alts]))
                r.setdefault("ambiguity", {}).update(
                    {a: {"validation_explained": v, "bootstrap_first": None, "joint_fit": True}
                     for a, v in alts.items()})
        if chosen != before:
            corrected, meas = _take_over(st, cur, before, chosen, (shares, pvals), ranking, scr, table,
                                         "replacement")
    if st.refinements:
        before = list(chosen)
        cur, cur_segs, chosen, tried = _refine(st, cur, cur_segs, chosen)
        if chosen != before:
            corrected, meas = _take_over(st, cur, before, chosen, (shares, pvals), ranking, scr, table,
                                         "refinement")
        for r in ranking:  # the figures of each tried refinement, on the refined and the refining entry
            refs = {k: v for k, v in tried.items() if r["effect"] in (k, v["replaces"])}
            if refs:
                r["refinements"] = refs
    plant_side = _plant_side_entry(chosen, amb, alt_fits)
    explained = _completeness(st, channel_sse(corrected, meas, st.pv), unreachable_channels(st, cands))
    reason = (f"{name} removes {100 * best['above_noise_explained']:.1f} % of the validation gap above "
              f"noise (BIC change {best['bic_delta']:.1f}); {explained['verdict']}")
    return _Selection(chosen, corrected, meas, table, shares, pvals, plant_side, explained, reason)


def diagnose_effects(rig: Rig, fit: Sequence[Recording], validation: Sequence[Recording], *,
                     max_effects: int = 2, seed: int = 0,
                     progress: Callable[[str], None] | None = None,
                     also_confirm: Sequence[str] = (), skip: Sequence[str] = ()) -> EffectDiagnosis:
    """Find which catalog effect(s) explain the gap between a rig file and recordings.

    Parameters
    ----------
    rig : Rig
        Nominal rig (the simulator as the lab has it).
    fit : sequence of Recording
        Recordings used for screening and fitting (θ and duty needed; i_a, v_a, ω₁ used when
        every recording has them).
    validation : sequence of Recording
        Recordings on which the effects are ranked and chosen (another stretch or experiment;
        never the held-out recordings of the final before/after).
    max_effects : int
        Most effects added to the corrected rig (1, 2 or 3; each one after the first by the same
        forward-selection step, :func:`_add_effect`).
    seed : int
        Seed of the bootstraps and weak-form test functions.
    progress : callable, optional
        Called with short status messages.
    also_confirm : sequence of str
        Catalog effects confirmed by a grey-box fit in addition to the screening shortlist, e.g.
        the timing effects (:func:`aeropend_ident.gap.effects.timing_effects`) when the
        where-analysis finds the simulated response leading or lagging the recorded one. Effects the
        channels cannot reveal, or that are not candidates for the rig's family, are skipped.
    skip : sequence of str
        Catalog effects left out of the diagnosis (hypotheses the lab rules out, or a benchmark
        measuring what one candidate changes).

    Returns
    -------
    EffectDiagnosis

    Raises
    ------
    GapError
        Recordings lacking θ or the duty cycle, with NaNs, too short, non-uniform or unexcited;
        an unusable nominal rig; ``max_effects`` outside 1..3; an unknown effect in
        ``also_confirm`` or ``skip``.
    """
    t0 = time.perf_counter()
    for name in (*also_confirm, *skip):
        get_effect(name)
    say = progress or (lambda _m: None)
    if max_effects not in (1, 2, 3):
        raise GapError(f"max_effects = {max_effects!r}; expected 1, 2 or 3")
    if not isinstance(rig, Rig):
        raise GapError(f"rig is a {type(rig).__name__}; expected aeropend_sim.params.Rig (load_rig)")
    st = _setup(rig, fit, validation, say, skip)
    q_hat = _unmodelled_quantum(rig, st)
    scr, cands, screened, forced = _screen_and_confirm(rig, st, also_confirm, seed, say)
    ranking = _ranking(st, cands, scr, seed + 1)
    _mark_unresolved(ranking, cands, max(p.dt for p in st.pf))
    best = next((r for r in ranking if not r.get("unresolved")), None)
    # a gap above the noise floor: some channel's nominal validation error exceeds its noise part
    above_floor = _above_noise(st.sse0_c, st.noise_c, st.chance_c)
    sig_first = bool(best and above_floor and best["above_noise_explained"] >= MIN_EXPLAINED
                     and best["bic_delta"] <= -MIN_BIC_GAIN and _holds_in_sample(st, best["p_value"]))
    chosen: list[str] = []
    plant_side: dict[str, Any] | None = None
    corrected, meas = rig, MeasurementMap()
    table = [{"effects": [], **st.base_metrics}]
    reason, explained = "", {}
    shares: dict[str, float] = {}  # chosen effect -> bootstrap share of its presence
    pvals: dict[str, float] = {}  # chosen effect -> its split-test p-value
    if sig_first:
        sel = _select(st, scr, cands, ranking, best, screened, forced, max_effects=max_effects, seed=seed,
                      say=say)
        chosen, corrected, meas, table = sel.chosen, sel.corrected, sel.measurement, sel.table
        shares, pvals, plant_side = sel.shares, sel.pvals, sel.plant_side
        explained, reason = sel.explained, sel.reason
    else:
        reason = _no_effect_reason(st, best, above_floor)
    detected: dict[str, dict[str, float]] = {}
    if q_hat > 0.0:
        # a property of the recordings, not an effect to fit: it describes the corrected rig's
        # sensor (and, through _noise_var, the noise floor), and never enters ``chosen``, whose
        # effects later steps refit (attainable shrink, drift tables)
        detected["quantisation"] = {"theta_quantum": q_hat}
        corrected, reason = _add_quantum(st, q_hat, ranking, corrected, sig_first, reason)
        sig_first = True
    _evidence(ranking, chosen, shares, pvals, explained, in_sample=st.pv is st.pf)
    if st.note:
        reason += f"; {st.note}"
    reason += _unresolved_reason(ranking, chosen)
    if st.not_ident and sig_first:
        reason += ("; not identifiable from the recorded channels (their θ signature may be what the "
                   f"ranked effect stands in for): {', '.join(x['effect'] for x in st.not_ident)}")
    return EffectDiagnosis(
        significant=sig_first, ranking=ranking, not_identifiable=st.not_ident, chosen=chosen,
        corrected_rig=corrected, validation=table, measurement=meas, screening=scr.as_dict(),
        reason=reason if sig_first or reason else "no significant gap", channels=sorted(st.channels),
        explained=explained, elapsed=time.perf_counter() - t0, plant_side=plant_side, detected=detected,
        free_settings=sorted(st.ctx.free_settings),
    )


def _unseparated_single(st: _Setup, best: dict[str, Any], cands: _Candidates,
                        ranking: Sequence[Mapping[str, Any]]
                        ) -> tuple[dict[str, dict[str, float]], dict[tuple[str, str], EffectFit]]:
    """Alternatives the single-effect fits do not separate from the first-ranked effect, and their
    fits, in the form :func:`_swap_confusables` returns them; ``best``'s ``ambiguous_with`` and
    ``ambiguity`` are completed in place.

    Two kinds: a runner-up first in a share of the bootstrap resamples (:data:`AMBIGUOUS_FIRST`,
    :func:`_ranking`), and a physics-confusable alternative (``confusable_with``, fitted alone,
    resolved at this rate: not marked ``unresolved`` in ``ranking``, :func:`_mark_unresolved`)
    that the figures do not separate by the rule of the replacement pass (:func:`_not_separated`).
    The second catches a rival that loses every resample by a margin too small to matter (an
    armature-resistance error and a back-EMF error each explain 97.4 % of a motor's gap, one
    consistently 0.04 % more). A nested alternative (the thrust law for K_q) is left to the
    parsimony rule of :func:`_ranking`: at its nesting value it is the same model.
    """
    name = best["effect"]
    amb = {name: {a: v["validation_explained"] for a, v in (best.get("ambiguity") or {}).items()}}
    e = get_effect(name)
    s_best = float(cands.segs[name].sum())
    unresolved = {r["effect"] for r in ranking if r.get("unresolved")}
    for alt in _in_catalog(e.confusable_with, st):
        if (alt in amb[name] or alt not in cands.segs or alt in e.nests or name in get_effect(alt).nests
                or alt in unresolved):
            continue
        if _not_separated(st, s_best, float(cands.segs[alt].sum())):
            amb[name][alt] = cands.stats[alt]["validation_explained"]
            best["ambiguous_with"] = [*best.get("ambiguous_with", []), alt]
            best.setdefault("ambiguity", {})[alt] = {"validation_explained": amb[name][alt],
                                                     "bootstrap_first": None, "within_swap_gain": True}
    return amb, {(name, a): cands.fits[a] for a in amb[name] if a in cands.fits}


def _plant_side_entry(chosen: Sequence[str], amb: Mapping[str, Mapping[str, float]],
                      alt_fits: Mapping[tuple[str, str], EffectFit]) -> dict[str, Any] | None:
    """:attr:`EffectDiagnosis.plant_side` from the record of unseparated alternatives, if its fit
    belongs to the final chosen set (a later replacement or refinement makes it stale)."""
    pair = plant_side_alternative(chosen, amb)
    fit = alt_fits.get(pair) if pair else None
    if pair is None or fit is None or set(fit.effects) != (set(chosen) - {pair[0]}) | {pair[1]}:
        return None
    return {"replaces": pair[0], "by": pair[1], "validation_explained": float(amb[pair[0]][pair[1]]),
            "parameters": dict(fit.values[pair[1]]), "rig": fit.rig, "measurement": fit.meas}


def _take_over(st: _Setup, cur: EffectFit, before: Sequence[str], chosen: Sequence[str],
               evidence: tuple[dict[str, float], dict[str, float]], ranking: list[dict[str, Any]],
               scr: Screening, table: list[dict[str, Any]], step: str) -> tuple[Rig, MeasurementMap]:
    """A chosen set changed by a replacement or refinement pass (``step``): each new effect takes
    over its predecessor's evidence (bootstrap share and split-test p-value; the replacement beat
    it on the validation part), the ranking gets the joint values, the validation table a row
    ``{step: True}``; returns the corrected rig and measurement map."""
    for old_name, new_name in zip(before, chosen, strict=True):
        if old_name != new_name:
            for d in evidence:
                d[new_name] = d.pop(old_name)
    _record_chosen(ranking, st, cur, chosen, scr)
    table.append({"effects": list(chosen), step: True, **gap_metrics(cur.rig, cur.meas, st.pv)})
    return cur.rig, cur.meas


def _record_chosen(ranking: list[dict[str, Any]], st: _Setup, fit: EffectFit, chosen: Sequence[str],
                   scr: Screening) -> None:
    """Update the ranking for a (new) chosen set fitted jointly in ``fit``: an entry for a chosen
    effect that was not ranked yet (screening figures from ``scr``), the joint values of the chosen
    effects, and the chosen set first, in its order."""
    for name in chosen:
        if name not in [r["effect"] for r in ranking]:
            e = get_effect(name)
            ranking.append({
                "effect": name, "subsystem": e.subsystem, "score": None, "validation_explained": None,
                "bic_delta": None, "p_value": None, "parameters": {}, "rig_values": {},
                "screening": ({"explained_strong": scr.explained_strong[name],
                               "explained_weak": scr.explained_weak[name], "inclusion": scr.inclusion[name]}
                              if name in scr.explained_strong else {"not_screened": True}),
                "confusable_with": _in_catalog(e.confusable_with, st), "ambiguous_with": [],
            })
    for r in ranking:
        if r["effect"] in chosen:
            r["parameters"] = _param_table(fit, r["effect"])
            r["rig_values"] = get_effect(r["effect"]).rig_values(st.rig, fit.values[r["effect"]])
    ranking.sort(key=lambda r: list(chosen).index(r["effect"]) if r["effect"] in chosen else len(chosen))


def _record_added(ranking: list[dict[str, Any]], st: _Setup, added: _Added, chosen: Sequence[str]) -> None:
    """Update the ranking after a forward-selection step (:func:`_record_chosen`) and note the added
    effect's gain."""
    _record_chosen(ranking, st, added.fit, chosen, added.screening)
    for r in ranking:
        if r["effect"] == added.effect:
            r["added_explained"] = added.gain
            r["added_bic_delta"] = added.bic_delta

