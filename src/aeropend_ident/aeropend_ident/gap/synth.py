"""Blind benchmark of the gap diagnosis: a generator of "real" recordings and a scorer.

The generator (:func:`make_case`) builds a hidden "real" plant from a nominal rig by adding one
or two catalog effects (:mod:`aeropend_ident.gap.effects`) at random magnitudes
(:func:`truth_ranges`, declared with each effect in ``aeropend_sim.components``), simulates it
with :func:`aeropend_sim.simulation.simulate` under random excitation and sensor noise, and returns
fit and held-out recordings made with **different excitations and seeds** (fit: amplitude-modulated
PRBS; held-out: Latin-hypercube steps). The truth stays in the :class:`SynthCase`; the diagnosis
sees only the nominal rig and the recordings. :func:`score_case` compares afterwards (top-1 /
top-3, confusable pairs, magnitude error, held-out shrink) and :func:`summarise` aggregates per
effect.

Sensor offset and scale are applied as the measurement transform of
:class:`aeropend_ident.gap.effects.MeasurementMap` (the plant model has no such effect), before
the noise and quantisation of :func:`aeropend_sim.simulation.measure`.

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeropend_ident.errors import GapError
from aeropend_ident.gap.effects import EFFECTS, EffectContext, MeasurementMap, apply_effects, get_effect
from aeropend_ident.greybox.fit import motor_equilibrium
from aeropend_sim.components import registry
from aeropend_sim.components.xp import MATH
from aeropend_sim.excitation import aprbs, lhs_steps
from aeropend_sim.model import PlantModel
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import measure, simulate


def truth_ranges(name: str) -> dict[str, tuple[tuple[float, float], ...]]:
    """Truth magnitude ranges of one catalog effect: parameter -> (low, high) intervals (one is
    drawn, then a value uniformly inside it), read from the registry where the effect is declared.

    The effect's own absolute ranges (:attr:`aeropend_sim.components.base.Diagnosis.truth`) when it
    declares any; otherwise the factor intervals of its rig parameters
    (:attr:`aeropend_sim.components.base.Param.relative_truth`: the physical value is factor ×
    nominal, see :func:`relative_key`). Sized so each effect changes the free-run angle clearly
    above 50 dB sensor noise.

    Raises
    ------
    GapError
        For an unknown effect.
    """
    get_effect(name)
    d = next(x for x in registry.diagnoses() if x.name == name)
    if d.truth:
        return {k: tuple(v) for k, v in d.truth.items()}
    return {p: registry.param(key).relative_truth for p in d.params if (key := relative_key(name, p))}


def relative_key(name: str, parameter: str) -> str | None:
    """The rig parameter ``"section.name"`` whose value a relative truth of ``parameter`` of effect
    ``name`` multiplies, or None when the effect draws absolute values."""
    d = next(x for x in registry.diagnoses() if x.name == name)
    if d.truth:
        return None
    target = next((s.target for s in d.search if s.name == parameter), "")
    if target in registry.params() and registry.param(target).relative_truth:
        return target
    return None


#: Operating angle [rad] at which the thrust-law truth keeps the nominal thrust (only the shape of
#: the law changes there).
THRUST_REFERENCE_ANGLE = 0.5
#: All recorded channels of a fully instrumented synthetic rig.
FULL_CHANNELS = ("theta", "i_a", "v_a", "omega_rotor")
#: Duty cycle range of the excitations (θ from about 0 to 1.1 rad on the thesis rig).
DUTY_RANGE = (0.1, 0.72)
#: Rest at zero duty before each excitation [s] (the replay starts from rest).
REST = 0.5


@dataclass
class SynthCase:
    """One benchmark case.

    Attributes
    ----------
    case_id : str
    truth : dict
        ``{effect: {parameter: value}}`` ({} for a plant with no added effect).
    channels : tuple of str
        Recorded channels.
    fit, held_out : list of Recording
    snr_db : float
        Sensor SNR of every channel [dB].
    seed : int
    """

    case_id: str
    truth: dict[str, dict[str, float]]
    channels: tuple[str, ...]
    fit: list[Recording]
    held_out: list[Recording]
    snr_db: float
    seed: int
    meta: dict[str, Any] = field(default_factory=dict)


def thrust_reference_speed(rig: Rig) -> float:
    """Propeller speed ω₂ [rad/s] holding the rod at :data:`THRUST_REFERENCE_ANGLE` with α = 2 (the
    rig's steady state, :meth:`aeropend_sim.components.assembly.Assembly.steady_state`)."""
    a = PlantModel(rig.with_effects(thrust_exponent=False)).assembly
    x, _ = a.steady_state(THRUST_REFERENCE_ANGLE)
    return float(a.propeller(MATH, x[3])[0])


def draw_truth(name: str, rng: np.random.Generator, nominal: Rig) -> dict[str, float]:
    """Random physical truth of one effect from :func:`truth_ranges` for a nominal rig.

    Relative ranges (:func:`relative_key`) are scaled by the nominal value; a thrust-law truth gets
    the coefficient that keeps the nominal thrust at :data:`THRUST_REFERENCE_ANGLE`.

    Raises
    ------
    GapError
        For an unknown effect, or a relative truth of a parameter the rig does not model.
    """
    out = {}
    for p, intervals in truth_ranges(name).items():
        lo, hi = intervals[int(rng.integers(len(intervals)))]
        v = float(rng.uniform(lo, hi))
        if (key := relative_key(name, p)) is not None:
            if nominal.value(key) == 0.0:
                raise GapError(f"effect {name!r}: its truth is a factor of {key}, which rig {nominal.name!r} "
                               "does not model (0)")
            v *= nominal.value(key)
        out[p] = v
    if name == "thrust_law":
        out["K_q"] = nominal.thrust.K_q * thrust_reference_speed(nominal) ** (2.0 - out["exponent"])
    return out


def real_plant(nominal: Rig, truth: Mapping[str, Mapping[str, float]],
               snr_db: float) -> tuple[Rig, MeasurementMap]:
    """The hidden plant: nominal + truth effects, sensor noise at ``snr_db`` (quantisation if drawn)."""
    rig, meas = apply_effects(nominal, truth)
    rig = rig.with_params("sensors", snr_db=float(snr_db)).with_effects(sensor_noise=True)
    if "quantisation" not in truth:
        rig = rig.with_effects(quantisation=False)
    return rig, meas


def record(real: Rig, meas: MeasurementMap, duty: np.ndarray, seed: int, channels: Sequence[str],
           source: str) -> Recording:
    """Simulate the hidden plant from rest and return what its acquisition records.

    Parameters
    ----------
    real : Rig
        Hidden plant (noise/quantisation switches honoured).
    meas : MeasurementMap
        Angle-sensor transform applied to the true θ before noise and quantisation.
    duty : ndarray, shape (N,)
    seed : int
        Noise seed.
    channels : sequence of str
        Channels kept (θ always).
    """
    if "theta" not in channels:
        raise GapError(f"channels {list(channels)} lack 'theta'; every synthetic recording has the angle")
    i0, w0, tf0 = motor_equilibrium(real.with_effects(sensor_noise=False), float(duty[0]))
    traj = simulate(real, duty, x0=np.array([0.0, 0.0, i0, w0, tf0]), seed=seed, tau_before=float(duty[0]))
    true = dict(traj.true)
    true["theta"] = meas.to_recorded(true["theta"])
    y = measure(real, true, np.random.default_rng(seed + 7919))
    return Recording(t=traj.t, duty=traj.duty, channels={c: y[c] for c in channels}, source=source,
                     meta={"synthetic": True})


def _with_rest(duty: np.ndarray, dt: float) -> np.ndarray:
    return np.concatenate([np.zeros(round(REST / dt)), duty])


def fit_excitation(seed: int, duration: float, dt: float) -> np.ndarray:
    """Fit excitation: APRBS over :data:`DUTY_RANGE`, holds 0.3-2.5 s, after a rest."""
    s = aprbs(duration, lo=DUTY_RANGE[0], hi=DUTY_RANGE[1], min_hold=0.3, max_hold=2.5, seed=seed, dt=dt)
    return _with_rest(s.duty, dt)


def held_out_excitation(seed: int, n_steps: int, dt: float) -> np.ndarray:
    """Held-out excitation: Latin-hypercube steps over :data:`DUTY_RANGE`, holds 1-3 s, after a rest."""
    s = lhs_steps(n_steps, tau_min=DUTY_RANGE[0], tau_max=DUTY_RANGE[1], hold_min=1.0, hold_max=3.0,
                  seed=seed, dt=dt)
    return _with_rest(s.duty, dt)


def make_case(nominal: Rig, effects: Sequence[str], seed: int, *, channels: Sequence[str] = FULL_CHANNELS,
              snr_db: float | None = None, fit_duration: float = 24.0, held_out_steps: int = 8,
              truth: Mapping[str, Mapping[str, float]] | None = None) -> SynthCase:
    """One blind case: hidden plant, fit recording (APRBS) and held-out recording (LHS steps).

    Parameters
    ----------
    nominal : Rig
        The rig file the diagnosis will be given.
    effects : sequence of str
        Catalog effects added to the hidden plant (0, 1 or 2).
    seed : int
        Seeds the magnitudes, the excitations and the noise (fit and held-out use different ones).
    channels : sequence of str
        Recorded channels (θ always; ``("theta",)`` for an angle-only rig).
    snr_db : float, optional
        Sensor SNR [dB]; default drawn in [45, 60].
    fit_duration : float
        Fit excitation length [s] (plus the rest).
    held_out_steps : int
        Number of held-out LHS steps.
    truth : mapping, optional
        Fixed magnitudes instead of random ones.

    Raises
    ------
    GapError
        On an unknown effect.
    """
    rng = np.random.default_rng(seed)
    tr = {e: dict(truth[e]) if truth and e in truth else draw_truth(e, rng, nominal) for e in effects}
    snr = float(rng.uniform(45.0, 60.0)) if snr_db is None else float(snr_db)
    real, meas = real_plant(nominal, tr, snr)
    dt = nominal.sample_period
    fit = [record(real, meas, fit_excitation(seed + 11, fit_duration, dt), seed + 101, channels,
                  f"synth-{seed}-fit")]
    ho = [record(real, meas, held_out_excitation(seed + 5003, held_out_steps, dt), seed + 202, channels,
                 f"synth-{seed}-held-out")]
    name = "+".join(effects) or "none"
    ctx = EffectContext.from_data(nominal, fit[0].channels["theta"], fit[0].duty)
    off = {e: {k: r.off for k, r in get_effect(e).ranges(ctx).items()} for e in tr}
    return SynthCase(case_id=f"{name}@{seed}", truth=tr, channels=tuple(channels), fit=fit, held_out=ho,
                     snr_db=snr, seed=seed, meta={"off": off})


def _confusable(names: Sequence[str]) -> set[str]:
    out = set(names)
    for n in names:
        out |= set(EFFECTS[n].confusable_with)
    return out


def score_case(case: SynthCase, diagnosis: Any) -> dict[str, Any]:
    """Compare a diagnosis (an ``EffectDiagnosis`` or its ``as_dict()``) with the hidden truth.

    Returns
    -------
    dict
        ``truth``, ``ranked`` (effect names, best first), ``top1`` (first ranked effect is a true
        one; for a plant without effect: "no significant gap" was reported), ``top1_confusable``
        (first is true or confusable with a true one), ``top3`` (every true effect among the first
        three), ``magnitude_error`` (per true effect found: the largest over its parameters of
        |fitted − true|/|true − off|, ``off`` the nominal rig's value),
        ``nrmse_before``/``nrmse_after``/``shrink`` (held-out, 1 − after/before, on the NRMSE over
        all compared channels), ``theta_nrmse_before``/``theta_nrmse_after``/``theta_shrink`` (θ
        only), ``identifiable``
        (every true effect identifiable from the channels), ``reported_not_identifiable``.
    """
    d = diagnosis if isinstance(diagnosis, dict) else diagnosis.as_dict()
    ranked = [r["effect"] for r in d["ranking"]] if d["significant"] else []
    truth = list(case.truth)
    not_id = {x["effect"] for x in d["not_identifiable"]}
    ident = [t for t in truth if t not in not_id]
    out: dict[str, Any] = {"case": case.case_id, "truth": case.truth, "channels": list(case.channels),
                           "snr_db": case.snr_db, "significant": bool(d["significant"]), "ranked": ranked[:5],
                           "chosen": d["chosen"]}
    if not truth:
        out.update(top1=not d["significant"], top3=not d["significant"], top1_confusable=not d["significant"])
    elif not ident:
        out.update(top1=None, top3=None, top1_confusable=None)
    else:
        out["top1"] = bool(ranked) and ranked[0] in ident
        out["top1_confusable"] = bool(ranked) and ranked[0] in _confusable(ident)
        out["top3"] = all(t in ranked[:3] for t in ident)
    out["identifiable"] = len(ident) == len(truth)
    out["reported_not_identifiable"] = sorted(set(truth) & not_id)
    mag: dict[str, float | None] = {}
    offs = case.meta.get("off", {})
    for t in ident:
        row = next((r for r in d["ranking"] if r["effect"] == t), None)
        errs = []
        for pname, true_v in case.truth[t].items():
            if row is None or pname not in row["parameters"]:
                continue
            off = offs.get(t, {}).get(pname, 0.0)
            size = abs(true_v - off) if off else abs(true_v)
            if size > 0:
                errs.append(abs(row["parameters"][pname]["value"] - true_v) / size)
        mag[t] = max(errs) if errs else None
    out["magnitude_error"] = mag
    shrink = d.get("validation", d.get("shrink"))
    for key, tag in (("nrmse", "theta_"), ("nrmse_channels", "")):
        before = shrink[0].get(key, shrink[0]["nrmse"])
        after = shrink[-1].get(key, shrink[-1]["nrmse"])
        out[f"{tag}nrmse_before"], out[f"{tag}nrmse_after"] = before, after
        out[f"{tag}shrink"] = (1.0 - after / before) if before and len(shrink) > 1 else 0.0
    out["elapsed_s"] = d.get("elapsed_s")
    return out


def summarise(scores: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Aggregate scored cases: overall and per-effect top-1/top-3, magnitude error, shrink.

    Cases whose truth is not identifiable from the recorded channels count separately
    (``not_identifiable_reported``: fraction that said so).
    """
    def frac(vals: list[bool]) -> float | None:
        return float(np.mean(vals)) if vals else None

    scored = [s for s in scores if s["top1"] is not None]
    with_effect = [s for s in scored if s["truth"]]
    shrinks = [s["shrink"] for s in with_effect if s["significant"]]
    shrink_all = [s["shrink"] for s in with_effect]
    shrink_theta = [s.get("theta_shrink", s["shrink"]) for s in with_effect]
    per: dict[str, dict[str, Any]] = {}
    for s in scored:
        keys = list(s["truth"]) or ["none"]
        for k in keys:
            per.setdefault(k, {"top1": [], "top3": [], "top1_confusable": [], "mag": [], "shrink": [],
                               "theta_shrink": []})
            per[k]["top1"].append(bool(s["top1"]))
            per[k]["top3"].append(bool(s["top3"]))
            per[k]["top1_confusable"].append(bool(s["top1_confusable"]))
            m = s["magnitude_error"].get(k) if k != "none" else None
            if m is not None:
                per[k]["mag"].append(m)
            if k != "none":
                per[k]["shrink"].append(s["shrink"])
                per[k]["theta_shrink"].append(s.get("theta_shrink", s["shrink"]))
    per_out = {
        k: {"cases": len(v["top1"]), "top1": frac(v["top1"]), "top3": frac(v["top3"]),
            "top1_confusable": frac(v["top1_confusable"]),
            "median_magnitude_error": float(np.median(v["mag"])) if v["mag"] else None,
            "median_shrink": float(np.median(v["shrink"])) if v["shrink"] else None,
            "median_theta_shrink": float(np.median(v["theta_shrink"])) if v["theta_shrink"] else None}
        for k, v in per.items()
    }
    ni = [s for s in scores if s["top1"] is None]
    return {
        "cases": len(scores),
        "scored_cases": len(scored),
        "top1": frac([bool(s["top1"]) for s in scored]),
        "top3": frac([bool(s["top3"]) for s in scored]),
        "top1_confusable": frac([bool(s["top1_confusable"]) for s in scored]),
        "median_shrink": float(np.median(shrink_all)) if shrink_all else None,
        "median_shrink_significant": float(np.median(shrinks)) if shrinks else None,
        "median_theta_shrink": float(np.median(shrink_theta)) if shrink_theta else None,
        "median_magnitude_error": (float(np.median(m)) if (m := [v for s in scored for v in
                                   s["magnitude_error"].values() if v is not None]) else None),
        "not_identifiable_cases": len(ni),
        "not_identifiable_reported": frac([bool(s["reported_not_identifiable"]) for s in ni]),
        "per_effect": per_out,
    }


def confusion(scores: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, int]]:
    """Single-effect cases: true effect -> {first-ranked effect (or "none"): count}."""
    out: dict[str, dict[str, int]] = {}
    for s in scores:
        if len(s["truth"]) > 1 or s["top1"] is None:
            continue
        t = next(iter(s["truth"]), "none")
        got = s["ranked"][0] if s["ranked"] else "none"
        out.setdefault(t, {})
        out[t][got] = out[t].get(got, 0) + 1
    return out
