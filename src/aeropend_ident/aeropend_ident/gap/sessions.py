"""The gap between sessions: what a refit on held-out data attains, and which parameters drifted.

:func:`attainable` fits each held-out recording itself (an oracle: the chosen effects, and the best
catalog set) and splits its gap into what the chosen effects can attain and what drifted since the
fit session; the drift set (the chosen effects plus the drift-prone parameters, :func:`drift_set`),
the table of per-session estimates and their changes (:func:`drift_table`, :func:`drift_rows`),
parameters confounded in a session reported as their ratio (:func:`combination_rows`), the
power-law levels of a slow trend (:func:`power_law_levels`) and one session's analysis
(:func:`session_analysis`) serve ``gap --held-out``, ``gap --sessions`` and ``gap-batch``. The
held-out prediction itself is :mod:`aeropend_ident.gap.drift`. No rclpy import: this module runs
without ROS.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from types import SimpleNamespace
from typing import Any

import numpy as np

from aeropend_ident.errors import GapError, GapInputError
from aeropend_ident.gap.drift import (
    DRIFT_PARAMETERS,
    _chosen_values,
    _fit_set,
    _preps,
    drift_parameters,
    noise_floor,
    theta_nrmse,
    theta_run,
)
from aeropend_ident.gap.effects import (
    MeasurementMap,
    get_effect,
)
from aeropend_ident.gap.which.data import Prepared
from aeropend_ident.gap.which.diagnosis import EffectDiagnosis, diagnose_effects
from aeropend_ident.gap.which.ranking import excluded_with
from aeropend_sim.components import registry
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording

#: A parameter drifts when |change| > DRIFT_Z combined standard errors ...
DRIFT_Z = 3.0


#: ... and more than this relative change.
DRIFT_MIN = 0.03


#: |correlation| of two parameters' log estimates from which the drift table reports their ratio
#: instead of each (:func:`combination_rows`): at 0.9 the ratio's standard error is under a third of
#: the single ones' (√(2(1 − r)) for equal errors).
CONFOUNDED_CORR = 0.9


#: A change is relative only when the reference value exceeds this share of the largest value
#: (a dead zone, drop or delay absent in one session has no relative change; its absolute is given).
RELATIVE_FLOOR = 1e-3


def _oracle(rig: Rig, effects: Sequence[str], prep: Prepared, start: Mapping[str, Mapping[str, float]],
            free_settings: Sequence[str] = ()) -> tuple[float, dict[str, Any]]:
    fr = _fit_set(rig, effects, [prep], start=start, scan=len(effects) == 1, free_settings=free_settings)
    params = {e: {k: {"value": fr.values[e][k], "std": fr.std.get(e, {}).get(k)} for k in fr.values[e]}
              for e in fr.values}
    return theta_nrmse(fr.rig, fr.meas, prep), params


def attainable(nominal: Rig, diag: EffectDiagnosis, held_out: Sequence[Recording], *, max_effects: int = 2,
               seed: int = 0, best_set: bool = True, fit: Sequence[Recording] = (),
               progress: Callable[[str], None] | None = None, fitted: Any = None) -> list[dict[str, Any]]:
    """Oracle fits on each held-out recording and the split of its gap (module docstring).

    Parameters
    ----------
    nominal : Rig
    diag : EffectDiagnosis
        The diagnosis made on the fit data.
    held_out : sequence of Recording
        Held-out recordings in the model frame (as the diagnosis saw its recordings).
    max_effects : int
        Largest set of the best-catalog oracle.
    seed : int
    best_set : bool
        Also run the best-catalog oracle (a diagnosis on the held-out recording alone).
    fit : sequence of Recording
        The fit recordings (model frame): with them, the chosen set plus the drift-prone
        parameters is fitted there too and each held-out recording gets a drift table (fit
        session vs that recording, :func:`drift_rows`).
    progress : callable, optional
    fitted : EffectFit, optional
        An effect set already fitted on ``fit`` (the plain refit of :func:`refit_comparison`): used
        as the fit-session drift fit when it is the same set, not fitted again.

    Returns
    -------
    list of dict
        Per recording: ``source``, θ NRMSEs ``nominal``, ``corrected``, ``oracle_same`` (the chosen
        set refitted there), ``oracle_drift`` (the chosen set plus the drift-prone parameters,
        :func:`drift_set`), ``oracle_best`` (and ``oracle_best_effects``), ``oracle`` (the
        smallest), ``noise_floor``; ``split`` shares of N² − n²: ``removed``,
        ``removable_not_removed``, ``not_removable``; ``parameters``: the correction's and the
        oracle's values with standard errors side by side.
    """
    from aeropend_ident.io.split import validation_split

    say = progress or (lambda _m: None)
    vals, std = _chosen_values(diag)
    dset = drift_set(diag.chosen, diag.channels or ("theta",), nominal.family)
    fit_a = None
    if fit and fitted is not None and tuple(fitted.effects) == tuple(dset):
        fit_a = fitted
    elif fit:
        say(f"attainable: fitting {', '.join(dset)} on the fit recordings")
        fit_a = _fit_set(nominal, dset, _preps(fit, diag.channels or ("theta",)), start=vals,
                         free_settings=diag.free_settings)
    out = []
    for rec in held_out:
        prep = _preps([rec], diag.channels or ("theta",))[0]
        (n_nom, why_nom), (n_cor, why_cor) = (theta_run(nominal, MeasurementMap(), prep),
                                              theta_run(diag.corrected_rig, diag.measurement, prep))
        floor = noise_floor(prep)
        row: dict[str, Any] = {"source": rec.source, "nominal": n_nom, "corrected": n_cor,
                               "noise_floor": floor}
        o_same, p_same = (n_cor, {}) if not diag.chosen else _oracle(nominal, diag.chosen, prep, vals,
                                                                                diag.free_settings)
        row["oracle_same"] = min(o_same, n_cor) if diag.chosen else n_nom
        row["parameters"] = {e: {k: {"correction": vals[e][k], "correction_std": std[e].get(k),
                                     "oracle": p_same[e][k]["value"], "oracle_std": p_same[e][k]["std"]}
                                 for k in vals[e]} for e in vals}
        # the chosen set plus the drift-prone parameters: what a session change of the rig needs
        try:
            fit_b = _fit_set(nominal, dset, [prep], start=vals, free_settings=diag.free_settings)
            o_drift = theta_nrmse(fit_b.rig, fit_b.meas, prep)
            if fit_a is not None:
                row["drift"] = {"sessions": ["fit", rec.source or "held-out"], "effects": dset,
                                "rows": drift_rows([fit_a, fit_b], dset)}
                row["drift"]["drifting"] = [f"{r['effect']}.{r['parameter']}" for r in row["drift"]["rows"]
                                            if r["drifts"]]
        except GapError as exc:
            o_drift = math.inf
            row["oracle_drift_error"] = str(exc)
        row["oracle_drift"], row["oracle_drift_effects"] = o_drift, dset
        o_best, best_eff = row["oracle_same"], list(diag.chosen)
        if best_set:
            say(f"attainable: best catalog set on {rec.source or 'a held-out recording'}")
            try:
                core, val = validation_split([rec])
                d2 = diagnose_effects(nominal, core, val, max_effects=max_effects, seed=seed)
                if d2.chosen:
                    v2, _ = _chosen_values(d2)
                    ob, _ = _oracle(nominal, d2.chosen, prep, v2, d2.free_settings)
                    if ob < o_best:
                        o_best, best_eff = ob, list(d2.chosen)
            except (GapError, GapInputError) as exc:  # e.g. a free decay: no changing command to choose on
                row["oracle_best_error"] = str(exc)
        row["oracle_best"], row["oracle_best_effects"] = o_best, best_eff
        o = min(row["oracle_same"], o_drift, o_best, n_cor, n_nom)
        row["oracle"] = o
        gone = {label: why for label, why in (("nominal", why_nom), ("corrected", why_cor)) if why}
        total = n_nom**2 - floor**2
        if gone:  # an NRMSE of a run that left the recorded range measures how far it went: no split
            row["diverges"] = gone
            row["split"] = None
            for key in ("nominal", "corrected") if len(gone) == 2 else tuple(gone):
                row[key] = None
        elif total > 0.0:
            row["split"] = {
                "removed": (n_nom**2 - n_cor**2) / total,
                "removable_not_removed": max(n_cor**2 - o**2, 0.0) / total,
                "not_removable": max(o**2 - floor**2, 0.0) / total,
            }
        else:
            row["split"] = {"removed": 0.0, "removable_not_removed": 0.0, "not_removable": 0.0}
        out.append(row)
    return out


#: Chosen effects the drift-prone parameters express exactly (the rod inertia scales mgd/J, c/J
#: and L/J together: gravity, viscous friction and thrust coefficient together are the same
#: change), left out of :func:`drift_set` so that its joint fit stays identifiable.
SPANNED_BY_DRIFT = ("inertia",)


def drift_set(chosen: Sequence[str], channels: Sequence[str] = ("theta",),
              family: str = registry.DEFAULT_FAMILY) -> list[str]:
    """The chosen effects plus the drift-prone parameters identifiable from ``channels``
    (:func:`drift_parameters`) they do not already set (an effect the drift-prone parameters span,
    :data:`SPANNED_BY_DRIFT`, is replaced by them)."""
    kept = [n for n in chosen if n not in SPANNED_BY_DRIFT]
    excluded = excluded_with(kept)
    return [*kept, *(e for e in drift_parameters(channels, family) if e not in excluded)]


def _session_labels(sessions: Sequence[Sequence[Recording]], labels: Sequence[str] | None,
                    what: str) -> list[str]:
    """Names of two or more sessions (default "session k"); GapError for fewer than two."""
    if len(sessions) < 2:
        raise GapError(f"{what}: {len(sessions)} session(s) given; need at least 2")
    return list(labels or [f"session {k + 1}" for k in range(len(sessions))])


def drift_table(nominal: Rig, sessions: Sequence[Sequence[Recording]], effects: Sequence[str], *,
                labels: Sequence[str] | None = None, channels: Sequence[str] = ("theta",),
                progress: Callable[[str], None] | None = None, free_settings: Sequence[str] = ()
                ) -> dict[str, Any]:
    """Fit ``effects`` on each session separately; which parameter changes between sessions.

    Parameters
    ----------
    nominal : Rig
    sessions : sequence of sequences of Recording
        Two or more sessions (model frame), each one or more recordings.
    effects : sequence of str
        Effects fitted jointly on every session (e.g. :func:`drift_set` of the chosen ones).
    labels : sequence of str, optional
        Session names.
    channels : sequence of str
        Channels compared.
    progress : callable, optional
    free_settings : sequence of str
        Effects whose held parameters are fitted too (a diagnosis' ``free_settings``, e.g.
        the dry friction's onset width); others hold them at the rig's values (no row).

    Returns
    -------
    dict
        ``sessions`` (labels), ``effects``, ``rows``: one per parameter, sorted by significance:
        ``effect``, ``parameter``, ``unit``, ``values`` and ``std`` per session, ``change``
        (largest relative change from the first session), ``z`` (largest |change| over combined
        standard errors), ``drifts`` (bool); ``drifting`` (names of the drifting parameters).

    Raises
    ------
    GapError
        Fewer than two sessions, or a fit failing on a session.
    """
    labels = _session_labels(sessions, labels, "drift table")
    say = progress or (lambda _m: None)
    fits = []
    for lab, recs in zip(labels, sessions, strict=True):
        say(f"drift: fitting {', '.join(effects)} on {lab}")
        fits.append(_fit_set(nominal, effects, _preps(recs, channels), free_settings=free_settings))
    return _drift_table(labels, effects, fits)


def _drift_table(labels: Sequence[str], effects: Sequence[str], fits: Sequence[Any]) -> dict[str, Any]:
    """The :func:`drift_table` dictionary of the per-session fits."""
    rows = drift_rows(fits, effects)
    return {"sessions": list(labels), "effects": list(effects), "rows": rows,
            "drifting": [f"{r['effect']}.{r['parameter']}" for r in rows if r["drifts"]]}


def drift_rows(fits: Sequence[Any], effects: Sequence[str]) -> list[dict[str, Any]]:
    """Rows of a drift table from the same effect set fitted on several sessions (first = reference).

    Each row: ``effect``, ``parameter``, ``unit``, ``values``, ``std``, ``abs_change`` (largest
    change from the first session, in the unit), ``change`` (the same relative to the first
    session's value; NaN when that value is ~0, :data:`RELATIVE_FLOOR`), ``z`` (the change over the
    combined standard errors), ``drifts`` (z > :data:`DRIFT_Z` and, where relative, |change| >
    :data:`DRIFT_MIN`), ``kind`` ("parameter"), plus the ratio rows of confounded parameters
    (:func:`combination_rows`, ``kind`` "combination"); drifting rows first, each group by
    significance, a ratio ranked among the single parameters (:func:`_in_table_order`).
    """
    fits, effects, derived = power_law_levels(fits, effects)
    rows = []
    for eff in effects:
        for par in get_effect(eff).parameters:
            if par.held and all(par.name not in f.std.get(eff, {}) for f in fits):
                continue  # a held parameter at the rig's value: not fitted, nothing to compare
            if any(par.name not in f.values.get(eff, {}) for f in fits):
                continue  # a power law's level, compared as its nested effect's (power_law_levels)
            v = np.array([f.values[eff][par.name] for f in fits])
            s = np.array([f.std.get(eff, {}).get(par.name, math.nan) for f in fits])
            # a relative change only where the reference is a size (not an absent effect at ~0)
            relative = abs(v[0]) > RELATIVE_FLOOR * float(np.max(np.abs(v)))
            comb = np.sqrt(s**2 + s[0] ** 2)
            with np.errstate(divide="ignore", invalid="ignore"):
                z = np.where(comb > 0.0, np.abs(v - v[0]) / comb, math.inf)
            k = int(np.argmax(np.abs(v[1:] - v[0]))) + 1
            change = float((v[k] - v[0]) / abs(v[0])) if relative else math.nan
            zk = float(z[k]) if np.isfinite(z[k]) else math.inf
            rows.append({"effect": eff, "parameter": par.name, "kind": "parameter", "unit": par.unit,
                         "values": v.tolist(),
                         "std": s.tolist(), "change": change, "abs_change": float(v[k] - v[0]), "z": zk,
                         "drifts": bool(zk > DRIFT_Z and (not relative or abs(change) > DRIFT_MIN))})
            rows[-1].update(derived.get((eff, par.name), {}))
    rows += combination_rows(fits, rows)
    return _in_table_order(rows)


def _in_table_order(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Drift rows in table order: flagged rows first, then by significance (largest z first), a
    ratio ranked among the single parameters (a ratio pinned at z 16 is surer evidence of a change
    than a single parameter at z 4). A flagged single parameter takes the z of a flagged ratio it
    is part of when that is larger, and comes right before it: it says which of the two moved."""
    ratio_z: dict[tuple[str, str], float] = {}
    for r in rows:
        if r["kind"] == "combination" and r["drifts"]:
            for member in zip(combination_members(r["effect"]), combination_members(r["parameter"]),
                              strict=True):
                ratio_z[member] = max(ratio_z.get(member, 0.0), r["z"])

    def rank(r: dict[str, Any]) -> float:
        if r["kind"] == "parameter" and r["drifts"]:
            return max(r["z"], ratio_z.get((r["effect"], r["parameter"]), 0.0))
        return r["z"]

    return sorted(rows, key=lambda r: (not r["drifts"], -rank(r), r["kind"] == "combination", -r["z"]))


def power_law_levels(fits: Sequence[Any], effects: Sequence[str]
                     ) -> tuple[list[Any], list[str], dict[tuple[str, str], dict[str, Any]]]:
    """Per-session fits with each power law's level (:attr:`aeropend_sim.components.base.Diagnosis.power_law`)
    taken at one reference speed, as the effect it nests: what a drift table compares.

    The thrust law f = K_q·|ω|^α has K_q in N·(s/rad)^α: a fit that moves α by δ moves log K_q by
    about −δ·ln ω to keep the thrust where the rotor runs, so K_q alone is pinned to ±100 % where
    the thrust at the operating speed is pinned to a few %, and two sessions' K_q are in two
    units when their α differ. The level compared is K = K_q·ω_ref^(α − α₀) (α₀ = 2: the thrust
    coefficient, f(ω_ref)/ω_ref²), ω_ref the first session's reference rotor speed
    (:attr:`aeropend_ident.gap.which.fitting.EffectFit.omega_ref`): its ratio between two sessions is the
    ratio of their thrusts at ω_ref. Its log is log K_q + (α − α₀)·ln ω_ref, a linear change of
    the fit's coordinates, so its covariance with every other coordinate follows exactly (T·C·Tᵀ)
    and it takes part in the ratio rows (:func:`combination_rows`). The exponent keeps its row.

    Parameters
    ----------
    fits : sequence
        The same effect set fitted on each session (:class:`aeropend_ident.gap.which.fitting.EffectFit`:
        ``values``, ``std``, ``cov``, ``labels``, ``log``, ``spans``, ``omega_ref``).
    effects : sequence of str
        The effect set.

    Returns
    -------
    (list, list of str, dict)
        The fits (views with the level as the nested effect's parameter; the inputs themselves
        where no power law is fitted or a fit lacks its covariance or reference speed), the effect
        set with each nested effect after its law, and per derived ``(effect, parameter)`` the
        fields its row gets (``derived_from``: the law, ``reference_speed``: ω_ref [rad/s]).
    """
    laws = [(law, *get_effect(law).power_law, get_effect(law).nests[0])
            for law in effects if get_effect(law).power_law]
    w0 = getattr(fits[0], "omega_ref", None) if fits else None
    if (not laws or w0 is None or w0 <= 0.0 or any(getattr(f, "cov", None) is None for f in fits)
            or any((law, p) not in f.labels for f in fits for law, level, expo, _, _ in laws
                   for p in (level, expo))):
        return list(fits), list(effects), {}
    out_effects = list(effects)
    for law, _, _, _, nested in laws:
        if nested not in out_effects:
            out_effects.insert(out_effects.index(law) + 1, nested)
    derived = {(nested, level): {"derived_from": law, "reference_speed": w0}
               for law, level, _, _, nested in laws}
    views = []
    for f in fits:
        values = {k: dict(v) for k, v in f.values.items()}
        std = {k: dict(v) for k, v in f.std.items()}
        labels, cov = list(f.labels), np.array(f.cov, dtype=float)
        for law, level, expo, expo0, nested in laws:
            i, j = labels.index((law, level)), labels.index((law, expo))
            t = np.eye(len(labels))
            # d log K / dz_α = ln ω_ref · dα/dz_α (the range's span for a linear coordinate)
            t[i, j] = math.log(w0) * (values[law][expo] if f.log[j] else f.spans[j])
            cov = t @ cov @ t.T
            k = values[law].pop(level) * w0 ** (values[law][expo] - expo0)
            std[law].pop(level, None)
            values[nested] = {level: k}
            std[nested] = {level: k * math.sqrt(max(cov[i, i], 0.0))}
            labels[i] = (nested, level)
        changed = {"values": values, "std": std, "cov": cov, "labels": tuple(labels)}
        views.append(dataclasses.replace(f, **changed) if dataclasses.is_dataclass(f)
                     else SimpleNamespace(**{**vars(f), **changed}))
    return views, out_effects, derived


def _log_coords(fit: Any) -> dict[tuple[str, str], int]:
    """Index of each log-scaled coordinate of a fit's covariance."""
    return {lab: i for i, (lab, lg) in enumerate(zip(fit.labels, fit.log, strict=True)) if lg}


#: How a combination row joins its two members' names: a ratio a/b, a product a·b.
COMBINE = {"ratio": "/", "product": "·"}


def combination_members(name: str) -> list[str]:
    """The members of a combination row's ``effect`` or ``parameter`` ("A/B" or "A·B"), or
    ``[name]`` for a single parameter's row."""
    for sep in COMBINE.values():
        if sep in name:
            return name.split(sep)
    return [name]


def combination_rows(fits: Sequence[Any], rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Drift rows of the combinations the data identify where the single parameters are confounded.

    Two strictly positive parameters whose estimates correlate by at least
    :data:`CONFOUNDED_CORR` (in |r| of their logs, in any session's covariance,
    :attr:`aeropend_ident.gap.which.fitting.EffectFit.cov`) are not separately identifiable from these
    recordings; what the data pin is the direction across the correlation. Positively correlated
    (r > 0, both move together) it is their ratio: with the angle alone in closed loop, the thrust
    coefficient K_q (through L/J) and the gravity term mgd/J, whose ratio is the duty needed per
    unit of sin θ. Negatively correlated (r < 0, one up as the other goes down) it is their
    product: the ratio is then the least determined combination (its variance va + vb + 2|cov| is
    larger than either's). The sign is that of the session with the largest |r|. The combination
    is a row of its own (``kind`` "combination", ``combination`` "ratio" or "product", ``effect``
    "A/B" or "A·B", ``parameter`` "p_a/p_b" or "p_a·p_b"): values, standard error from
    var(log a) + var(log b) ∓ 2 cov, change and z as for a parameter. The single rows of a
    confounded pair are kept with ``confounded_with``; while their combination does not change
    they are not flagged (``drifts`` False, ``flag_suppressed``): both moved along the direction
    the data do not pin, which the fit cannot tell from a rig change, and that raises no alarm.
    When the combination changes, it is flagged, and so are the single rows whose own change is
    significant (the most significant row comes first).
    """
    out = []
    if any(getattr(f, "cov", None) is None for f in fits) or not fits:
        return out
    idx = [_log_coords(f) for f in fits]
    common = [lab for lab in idx[0] if all(lab in ix for ix in idx[1:])]
    by_label = {(r["effect"], r["parameter"]): r for r in rows}
    for a, b in itertools.combinations(common, 2):
        corr = []
        for f, ix in zip(fits, idx, strict=True):
            c = f.cov
            va, vb = c[ix[a], ix[a]], c[ix[b], ix[b]]
            corr.append(c[ix[a], ix[b]] / math.sqrt(va * vb) if va > 0 and vb > 0 else 0.0)
        strongest = max(corr, key=abs)
        if abs(strongest) < CONFOUNDED_CORR:
            continue
        sign = 1.0 if strongest > 0 else -1.0  # ratio: log a − log b; product: log a + log b
        kind = "ratio" if sign > 0 else "product"
        lr = np.array([math.log(f.values[a[0]][a[1]]) - sign * math.log(f.values[b[0]][b[1]]) for f in fits])
        var = np.array([f.cov[ix[a], ix[a]] + f.cov[ix[b], ix[b]] - 2.0 * sign * f.cov[ix[a], ix[b]]
                        for f, ix in zip(fits, idx, strict=True)])
        sd = np.sqrt(np.clip(var, 0.0, None))
        k = int(np.argmax(np.abs(lr[1:] - lr[0]))) + 1
        comb = math.sqrt(sd[k] ** 2 + sd[0] ** 2)
        z = abs(lr[k] - lr[0]) / comb if comb > 0 else math.inf
        change = math.expm1(lr[k] - lr[0])
        value = np.exp(lr)
        sep = COMBINE[kind]
        out.append({"effect": f"{a[0]}{sep}{b[0]}", "parameter": f"{a[1]}{sep}{b[1]}", "unit": "1",
                    "kind": "combination", "combination": kind, "values": value.tolist(),
                    "std": (value * sd).tolist(), "change": change, "abs_change": float(value[k] - value[0]),
                    "z": z, "correlation": abs(strongest), "signed_correlation": strongest,
                    "drifts": bool(z > DRIFT_Z and abs(change) > DRIFT_MIN)})
        for lab, other in ((a, b), (b, a)):
            r = by_label.get(lab)
            if r is not None:
                r.setdefault("confounded_with", []).append(f"{other[0]}.{other[1]}")
                if r["drifts"] and not out[-1]["drifts"]:  # moved along the unidentified direction
                    r["drifts"], r["flag_suppressed"] = False, True
    return out


def session_sigma(table: Mapping[str, Any]) -> dict[str, float]:
    """σ of the log change per drift-prone parameter measured across sessions (for
    :func:`predict_heldout`): the RMS deviation of log(value) from its session mean, times
    √(1 + 1/k) for a new session (k sessions)."""
    out = {}
    k = len(table["sessions"])
    for r in table["rows"]:
        if r["effect"] in DRIFT_PARAMETERS and r["parameter"] == DRIFT_PARAMETERS[r["effect"]][1]:
            v = np.asarray(r["values"], dtype=float)
            if np.all(v > 0.0):
                lv = np.log(v)
                out[r["effect"]] = float(np.sqrt(np.sum((lv - lv.mean()) ** 2) / max(k - 1, 1))
                                         * math.sqrt(1.0 + 1.0 / k))
    return out


def session_task(task: tuple) -> Any:
    """One independent step of :func:`session_analysis` (run by :func:`aeropend_ident.parallel.run_cases`):
    ``("diagnose", nominal, core, validation, max_effects, seed)`` -> EffectDiagnosis, or
    ``("fit", nominal, effects, recordings, channels)`` -> the effect set's fit on one session."""
    if task[0] == "diagnose":
        _, nominal, core, val, max_effects, seed = task
        return diagnose_effects(nominal, core, val, max_effects=max_effects, seed=seed)
    _, nominal, effects, recs, channels = task
    return _fit_set(nominal, effects, _preps(recs, channels))


def session_analysis(nominal: Rig, sessions: Sequence[Sequence[Recording]], chosen: Sequence[str], *,
                     labels: Sequence[str] | None = None, channels: Sequence[str] = ("theta",),
                     max_effects: int = 2, seed: int = 0,
                     progress: Callable[[str], None] | None = None, workers: int | None = 1,
                     scheduler: str | None = None, quiet: bool = True) -> dict[str, Any]:
    """Leave-one-session-out diagnosis, the effects named per session, and the drift table.

    The per-session diagnoses, the leave-one-out diagnoses (three or more sessions) and the
    per-session fits of the drift table are independent: they run as one batch of cases through
    :func:`aeropend_ident.parallel.run_cases` (in this process with ``workers`` = 1 and no
    ``scheduler``; on a local Dask cluster of ``workers`` processes, or on the cluster at
    ``scheduler``, otherwise).

    Parameters
    ----------
    nominal : Rig
    sessions : sequence of sequences of Recording
        Two or more sessions (model frame).
    chosen : sequence of str
        Effects the diagnosis on all sessions chose (the drift table fits them plus the
        drift-prone parameters, :func:`drift_set`).
    labels, channels, max_effects, seed, progress
        As in :func:`drift_table` / :func:`aeropend_ident.gap.which.diagnosis.diagnose_effects`.
    workers, scheduler, quiet
        Where the cases run (above; None workers: one per core) and whether to hide the progress bar.

    Returns
    -------
    dict
        ``per_session``: effects named by a diagnosis on each session alone; ``leave_one_out``:
        per session, the effects chosen on the other sessions and the θ NRMSE of the nominal and
        of that correction on the left-out session (``shrink``); ``drift``: :func:`drift_table`;
        ``drift_sigma``: :func:`session_sigma` of it.

    Raises
    ------
    GapError
        Fewer than two sessions; unusable recordings.
    """
    from aeropend_ident.io.split import validation_split
    from aeropend_ident.parallel import run_cases

    labels = _session_labels(sessions, labels, "leave-one-session-out")
    say = progress or (lambda _m: None)
    effects = drift_set(chosen, channels, nominal.family)
    tasks: list[tuple] = [("diagnose", nominal, *validation_split(list(recs)), max_effects, seed)
                          for recs in sessions]
    if len(sessions) > 2:
        for k in range(len(sessions)):
            others = [r for j, s in enumerate(sessions) if j != k for r in s]
            tasks.append(("diagnose", nominal, *validation_split(others), max_effects, seed))
    tasks += [("fit", nominal, effects, list(recs), tuple(channels)) for recs in sessions]
    say(f"sessions: {len(tasks)} independent diagnoses and fits ({len(sessions)} sessions)")
    done = dict(run_cases(session_task, tasks, workers=workers, scheduler=scheduler, desc="sessions",
                          quiet=quiet))
    results = [done[i] for i in range(len(tasks))]
    k_s = len(sessions)
    diags = results[:k_s]
    per = [{"session": lab, "chosen": list(d.chosen), "significant": bool(d.significant)}
           for lab, d in zip(labels, diags, strict=True)]
    loo = []
    for k, (lab, recs) in enumerate(zip(labels, sessions, strict=True)):
        d = diags[1 - k] if k_s == 2 else results[k_s + k]
        preps = _preps(recs, channels)
        n0 = float(np.mean([theta_nrmse(nominal, MeasurementMap(), p) for p in preps]))
        n1 = float(np.mean([theta_nrmse(d.corrected_rig, d.measurement, p) for p in preps]))
        loo.append({"left_out": lab, "chosen_on_others": list(d.chosen), "nrmse_nominal": n0,
                    "nrmse_corrected": n1, "shrink": 1.0 - n1 / n0 if n0 > 0 else math.nan})
    table = _drift_table(labels, effects, results[-k_s:])
    return {"sessions": labels, "per_session": per, "leave_one_out": loo, "drift": table,
            "drift_sigma": session_sigma(table)}

