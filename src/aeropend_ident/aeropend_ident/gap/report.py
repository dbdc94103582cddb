"""Sim-to-real gap, part 4: report a :class:`~aeropend_ident.gap.result.GapResult` (JSON, HTML, terminal).

:func:`write_report` writes ``report.json`` (everything, machine-readable), ``report.html``
(one self-contained page: the PNGs of :mod:`aeropend_ident.gap.figures` embedded as base64),
``corrected_rig.yaml`` (loadable by :func:`aeropend_sim.params.load_rig`) and the figures as PNG
files; :func:`terminal_summary` is the one-screen text summary. The run itself is
:func:`aeropend_ident.gap.run.run_gap`.

No rclpy import; matplotlib (through :mod:`aeropend_ident.gap.figures`) with the Agg backend.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from aeropend_ident.gap.figures import (
    figures,
)
from aeropend_ident.gap.result import (
    GapResult,
    _label,
    corrected_rig_dict,
)
from aeropend_ident.gap.run import run_gap
from aeropend_ident.gap.where import EQUATIONS
from aeropend_ident.gap.which.evidence import CANDIDATE_PRESENCE, NAMED_COMPLETENESS, NAMED_PRESENCE
from aeropend_ident.gap.which.ranking import SWAP_GAIN
from aeropend_ident.greybox.replay import start_text
from aeropend_ident.io.jsonutil import jsonable

# --------------------------------------------------------------------------- text
#: A value below this magnitude (SI units) is a round-off of 0 (a parameter fitted onto its bound of
#: 0 reads 1.854e-27, a difference of equal numbers 1.1102e-17): printed as 0.
ZERO_BELOW = 1e-15


def _fmt(v: Any, spec: str = ".4g") -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        if math.isfinite(v) and abs(v) < ZERO_BELOW:
            return "0"
        return format(v, spec) if math.isfinite(v) else "–"
    return str(v)


def table_line(row: dict[str, Any]) -> str:
    """One static table's check in words (``GapResult.tables`` row)."""
    unit, scale = ("mrad", 1e3) if row["unit"] == "rad" else ("mN", 1e3)

    def fig(v: float | None) -> str:
        return "no steady state" if v is None else f"{v * scale:.3g} {unit}"

    std = f"; the table's own standard error {fig(row['std'])}" if row.get("std") else ""
    return (f"STATIC TABLE {row['source']} ({row['kind']}, {row['rows']} rows, not used by the diagnosis): "
            f"RMS steady-state error nominal {fig(row['nominal'])} -> corrected {fig(row['corrected'])}{std}")


def terminal_summary(result: GapResult) -> str:
    """One-screen summary: verdict, located subsystem, ranked effects, before/after."""
    h = result.headline()
    lines = [
        f"gap: nominal rig {result.rig.name}; {h['n_fit_recordings']} fit / "
        f"{h['n_heldout_recordings']} held-out recording(s) ({result.split_rule})",
        f"  significant gap: {'yes' if h['significant_gap'] else 'no'} ({h['significant_gap_why']})",
    ]
    lines += _where_lines(result)
    lines += _which_lines(result)
    lines += _sessions_lines(result)
    lines += _prediction_lines(result.prediction)
    lines += _held_out_lines(result, h)
    lines += _attainable_lines(result)
    if result.refit:
        lines.append(f"  {'WORSE THAN A REFIT' if result.refit['worse_than_refit'] else 'REFIT'}: "
                     f"{result.refit['verdict']}")
    for row in result.tables:
        lines.append("  " + table_line(row))
    lines += [f"  BOUND: {n}" for n in result.bound_notes]
    for section, why in result.not_computed.items():
        lines.append(f"  NOT COMPUTED: {section}: {why}")
    return "\n".join(lines)


def _where_lines(result: GapResult) -> list[str]:
    """The WHERE section of :func:`terminal_summary`: the nominal rig's equations on the fit recordings."""
    lines = ["  WHERE (nominal on fit recordings):"]
    for row in result.where.located:
        mark = "!" if row["flagged"] else " "
        lines.append(
            f"   {mark} {row['equation']:9s} ({row['subsystem']:10s}) residual "
            + (f"{row['relative']:7.1%} of driving term" if math.isfinite(row["relative"])
               else "(no driving term in these recordings)")
            + f"; top terms: {row['top_group']}"
        )
    for nc in result.where.not_checked:
        lines.append(f"     {nc['equation']:9s} not checked: {nc['reason']}")
    r0 = result.where.recordings[0]
    lines.append(
        f"    free-run NRMSE {r0.free_run['nrmse']:.4f}, {result.where.recordings[0].horizon:g} s-ahead "
        f"NRMSE {r0.short_horizon['nrmse']:.4f}; Ljung-Box p {r0.whiteness['p_value']:.2g}; "
        f"alignment lag {r0.alignment['lag_s']:.3f} s"
    )
    return lines


def _which_lines(result: GapResult) -> list[str]:
    """The WHICH section: ranked effects, the chosen ones and how much they explain."""
    d = result.diagnosis
    lines: list[str] = []
    lines.append("  WHICH (ranked effects; 'validation' = the part of the fit data that chooses them):")
    for r in list(d.ranking)[:5]:
        lines.append(
            f"    {r['effect']:22s} {r.get('subsystem', ''):12s} score {_fmt(r.get('score'), '.3g'):>8s} "
            f"validation explained {_fmt(r.get('validation_explained'), '.2f'):>5s} "
            f"presence {_fmt(r.get('presence'), '.2f')} {r.get('status', '')}"
        )
        if r.get("ambiguous_with"):
            lines.append(f"      not separated by these data from: {', '.join(r['ambiguous_with'])}")
    for ni in list(d.not_identifiable)[:4]:
        lines.append(f"    (not identifiable: {ni['effect']}: {ni['reason'][:70]})")
    lines.append(f"  chosen: {', '.join(d.chosen) or 'none'}")
    det = _detected_text(d)
    if det:
        lines.append(f"  detected from the recorded values (not fitted): {det}")
    side = getattr(d, "plant_side", None)
    if side:
        lines.append(f"  corrected_rig.yaml holds {side['by']} instead of {side['replaces']} (not separated "
                     "by these data; sensor frame kept nominal: check the angle sensor's calibration)")
    if getattr(d, "explained", None):
        lines.append(f"  explained: completeness {d.explained['completeness']:.2f}, "
                     f"{d.explained['verdict']} (named = chosen, presence ≥ {NAMED_PRESENCE:g}, "
                     f"completeness ≥ {NAMED_COMPLETENESS:g})")
    if result.agreement:
        lines.append(f"  WHERE vs WHICH: {result.agreement['explanation']}")
    return lines


def _sessions_lines(result: GapResult) -> list[str]:
    """The VALIDATION and SESSIONS sections."""
    d = result.diagnosis
    lines: list[str] = []
    lines.append("  VALIDATION (carved from the fit data; chooses the effects):")
    for row in d.validation:
        lines.append(f"    {('+'.join(row['effects']) or 'nominal'):40s} NRMSE {row['nrmse']:.4f}")
    if result.sessions:
        lines.append("  SESSIONS (leave one session out: effects chosen on the others, θ NRMSE on it):")
        for row in result.sessions["leave_one_out"]:
            lines.append(f"    {row['left_out'][:30]:30s} {'+'.join(row['chosen_on_others']) or 'none':32s} "
                         f"{row['nrmse_nominal']:.4f} -> {row['nrmse_corrected']:.4f} ({row['shrink']:.1%})")
        lines += _drift_lines(result.sessions["drift"])
    return lines


def _prediction_lines(prediction: dict[str, Any] | None) -> list[str]:
    """The PREDICTED line (none without a prediction)."""
    lines: list[str] = []
    pr = prediction
    if pr and pr.get("useful") is False:
        lines.append(f"  PREDICTED held-out θ NRMSE of the corrected rig: {pr['why_not_useful']}")
    elif pr:
        # one line, the screen is full: the NRMSE change of each drift-prone parameter alone at -σ / +σ
        sens = pr.get("sensitivity") or {}
        alone = ("; alone at -σ/+σ: " + ", ".join(f"{k} {a:.4f}/{b:.4f}" for k, (a, b) in sens.items())
                 if sens else "")
        lines.append(
            f"  PREDICTED held-out θ NRMSE of the corrected rig (fit data and held-out duty): "
            f"{pr['predicted']:.4f}, 80 % interval [{pr['interval'][0]:.4f}, {pr['interval'][1]:.4f}] "
            f"(within session {pr['within_session']:.4f}, session drift {pr['drift_part']:.4f} from the "
            f"{pr['drift_source']}{alone})" + (f"; {pr['why_wide']}" if pr.get("why_wide") else ""))
    return lines


def _held_out_lines(result: GapResult, h: dict[str, Any]) -> list[str]:
    """The HELD OUT section: per channel, the θ before/after (or why there is none), the prediction
    check."""
    lines: list[str] = []
    # the one free run's start (greybox.replay, its rule in report.json), stated with the held-out figures
    starts = [f"{_label(r['recording'] or 'held-out')[:40]}: {start_text(r['initial_state'])}"
              for r in h.get("heldout_free_run", {}).get("nominal", [])]
    lines.append("  HELD OUT (never seen by the diagnosis), NRMSE per recorded channel"
                 + (f"; free-run start {'; '.join(starts)}:" if starts else ":"))
    for row in result.test:
        per = "  ".join(f"{c} {v:.4f}" for c, v in row.get("channel_nrmse", {}).items())
        lines.append(f"    {('+'.join(row['effects']) or 'nominal'):40s} {per}")
    if h["heldout_divergence"]:  # no shrink between runs that left the recorded range
        lines.append("  held-out θ: no NRMSE or shrink figure: the "
                     + " and the ".join(h["heldout_divergence"]) + " model diverges")
        lines += [f"    {label}: {why}" for label, whys in h["heldout_divergence"].items() for why in whys]
    else:
        lines.append(
            f"  held-out NRMSE θ {h['heldout_nrmse_nominal']:.4f} -> {h['heldout_nrmse_corrected']:.4f} "
            f"(shrink {h['heldout_shrink']:.1%}{noise_floor_text(h)})"
            + "".join(f"; {c} {v:.1%}" for c, v in h["heldout_channel_shrink"].items() if c != "theta")
        )
    chk = result.prediction_check
    if chk:  # on the held-out line: the screen is full
        lines[-1] += f"; prediction check: actual {chk['actual']:.4f} {chk['verdict']}"
    return lines


def _attainable_lines(result: GapResult) -> list[str]:
    """The ATTAINABLE section, per held-out recording."""
    lines: list[str] = []
    for a in result.attainable or []:
        sp = a["split"]
        if a.get("diverges"):  # no NRMSE, no split of a gap between runs that left the recorded range
            lines.append(f"  ATTAINABLE on {_label(a['source'] or 'held-out')[:40]}: no figure: the "
                         + "; the ".join(f"{k} run {why}" for k, why in a["diverges"].items())
                         + f" (best constant-parameter fit there {a['oracle']:.4f})")
            continue
        lines.append(
            f"  ATTAINABLE on {_label(a['source'] or 'held-out')[:40]}: nominal {a['nominal']:.4f}, "
            f"corrected {a['corrected']:.4f}, best constant-parameter fit there {a['oracle']:.4f}, "
            f"noise floor {a['noise_floor']:.4f}")
        lines.append(
            f"    held-out gap: removed {sp['removed']:.0%}, removable but not removed (session drift or "
            f"off parameters) {sp['removable_not_removed']:.0%}, not removable by the catalog "
            f"{sp['not_removable']:.0%}")
        if a.get("drift"):
            lines += _drift_lines(a["drift"])
    return lines


def _detected_text(diag: Any) -> str:
    """The diagnosis' detected (not fitted) effects in one phrase, '' without any."""
    from aeropend_ident.gap.effects import get_effect

    parts = []
    for name, vals in (getattr(diag, "detected", None) or {}).items():
        units = {p.name: p.unit for p in get_effect(name).parameters}
        parts.append(f"{name} (" + ", ".join(f"{k} = {v:.4g} {units.get(k, '')}".rstrip()
                                              for k, v in vals.items()) + ")")
    return "; ".join(parts)


def _drift_html(result: GapResult) -> str:
    """HTML of the prediction, its check, the attainable shrink and the drift tables."""
    parts = []
    pr, chk = result.prediction, result.prediction_check
    if pr and pr.get("useful") is False:
        parts.append("<h3>Predicted vs actual held-out θ NRMSE of the corrected rig</h3>"
                     f"<p>{html.escape(pr['why_not_useful'])}.</p>")
    elif pr:
        rows = [["predicted (fit data, held-out duty)", _fmt(pr["predicted"]),
                 f"[{_fmt(pr['interval'][0])}, {_fmt(pr['interval'][1])}]", _fmt(pr["within_session"]),
                 f"{_fmt(pr['drift_part'])} ({pr['drift_source']})",
                 _fmt(chk["actual"]) if chk else "–", chk["verdict"] if chk else "–"]]
        parts.append("<h3>Predicted vs actual held-out θ NRMSE of the corrected rig</h3>" + _table(
            rows, ["", "predicted", "80 % interval", "within session", "session drift", "actual", "check"])
            + (f"<p>{html.escape(pr['why_wide'])}.</p>" if pr.get("why_wide") else ""))
    if result.attainable:
        rows = [[_label(a["source"] or "held-out"), _fmt(a["nominal"]), _fmt(a["corrected"]),
                 _fmt(a["oracle"]), _fmt(a["noise_floor"]),
                 *([f"{a['split'][k]:.0%}" for k in ("removed", "removable_not_removed", "not_removable")]
                   if a["split"] else ["diverges: no split"] * 3)]
                for a in result.attainable]
        parts.append("<h3>Attainable shrink: the held-out gap split</h3>" + _table(
            rows, ["recording", "nominal", "corrected", "best constant-parameter fit there", "noise floor",
                   "removed", "removable, not removed", "not removable"]))
    tables = [a["drift"] for a in result.attainable or [] if a.get("drift")]
    if result.sessions:
        tables.insert(0, result.sessions["drift"])
    for t in tables:
        rows = [[f"{r['effect']}.{r['parameter']}{_derived_note(r)}", " / ".join(
            f"{_fmt(float(v))} ± {_fmt(sd, '.2g')}" for v, sd in zip(r["values"], r["std"], strict=True)),
            r["unit"],
            _change(r), _fmt(r["z"], ".1f"), "yes" if r["drifts"] else ""] for r in t["rows"]]
        parts.append(f"<h3>Parameter drift: {' vs '.join(_label(x) for x in t['sessions'])}</h3>" + _table(
            rows, ["parameter", "values ± std", "unit", "change", "z", "drifts"]))
    return "\n".join(parts)


def _headline_html(h: dict[str, Any], d: Any) -> str:
    """The report's first line: held-out NRMSE before → after and the shrink, or the divergence."""
    with_ = html.escape(", ".join(d.chosen) or "no effect")
    if h["heldout_divergence"]:
        whys = "; ".join(f"{k}: {w}" for k, ws in h["heldout_divergence"].items() for w in ws)
        return (f"Held-out θ: <b>no NRMSE or shrink figure</b> (corrected with {with_}): the "
                f"{' and the '.join(h['heldout_divergence'])} model diverges ({html.escape(whys)}).")
    return (f"Held-out NRMSE <b>{h['heldout_nrmse_nominal']:.4f}</b> (nominal) &rarr; "
            f"<b>{h['heldout_nrmse_corrected']:.4f}</b> (corrected with {with_}): "
            f"shrink <b>{h['heldout_shrink']:.1%}</b>{html.escape(noise_floor_text(h))}.")


def noise_floor_text(h: dict) -> str:
    """``"; noise floor 0.0958 (…)"``: the held-out NRMSE a perfect model would have (the recorded θ
    noise over the held-out ranges), said when the nominal NRMSE is within twice it; '' otherwise."""
    floor, before = h.get("heldout_noise_floor_nrmse"), h.get("heldout_nrmse_nominal")
    if floor is None or before is None or not before <= 2.0 * floor:
        return ""
    return (f"; noise floor {floor:.4f}: the held-out error is the sensor's noise over the held-out "
            "ranges, not a model error")


def _detected_html(diag: Any) -> str:
    """Paragraph on the detected (not fitted) effects, '' without any."""
    det = _detected_text(diag)
    if not det:
        return ""
    return (f"<p>Detected from the recorded values (a property of the data, not fitted; in "
            f"<code>corrected_rig.yaml</code> and in the noise floor): {html.escape(det)}.</p>\n")


def _not_computed_html(result: GapResult) -> str:
    """The static tables' check, and the optional sections that could not be computed with the reason
    ('' if neither)."""
    tables = "".join(f"<p>{html.escape(line)}</p>\n" for line in
                     [*map(table_line, result.tables), *result.bound_notes])
    if not result.not_computed:
        return tables
    items = "".join(f"<li><b>{html.escape(k)}</b>: {html.escape(v)}</li>"
                    for k, v in result.not_computed.items())
    return f"{tables}<p>Not computed (the rest of the report stands):</p><ul>{items}</ul>\n"


def _change(row: dict[str, Any]) -> str:
    """A drift-table change: relative where the reference is a size, else absolute in the unit."""
    c = row.get("change")
    if c is not None and math.isfinite(c):
        return f"{c:+.1%}"
    return f"{row['abs_change']:+.4g} {row['unit']}"


def _refit_html(result: GapResult) -> str:
    """The comparison with a plain refit of the nominal parameters ('' when not computed)."""
    r = result.refit
    if not r:
        return ""
    tag = "<b>Worse than a refit:</b> " if r["worse_than_refit"] else ""
    pars = "; ".join(f"{e}.{k} = {_fmt(v)}" for e, d in r["values"].items() for k, v in d.items())
    return (f"<p>{tag}{html.escape(r['verdict'])} (held-out θ NRMSE: corrected "
            f"{_fmt(r['corrected_nrmse'], '.4f')}, refit {_fmt(r['refit_nrmse'], '.4f')}; "
            f"refitted {html.escape(pars)}).</p>")


def _derived_note(row: dict[str, Any]) -> str:
    """What a drift row derived from a power law compares
    (:func:`aeropend_ident.gap.sessions.power_law_levels`)."""
    if not row.get("derived_from"):
        return ""
    return f" (the {row['derived_from']}'s level at ω_ref {row['reference_speed']:.0f} rad/s)"


def _drift_lines(table: dict[str, Any], top: int = 4) -> list[str]:
    """Terminal lines of a drift table (most significant rows)."""
    out = [f"    drift table ({' vs '.join(_label(x)[:24] for x in table['sessions'])}):"]
    for r in table["rows"][:top]:
        vals = " / ".join(f"{v:.4g}" for v in r["values"])
        note = (f" {r.get('combination', 'ratio')}: the single parameters are confounded "
                f"(r {r.get('signed_correlation', r['correlation']):+.2f})"
                if r.get("kind") == "combination" else
                f" not flagged alone: confounded with {', '.join(r['confounded_with'])}"
                if r.get("flag_suppressed") else "") + _derived_note(r)
        out.append(f"      {'!' if r['drifts'] else ' '} {r['effect']}.{r['parameter']:14s} {vals} "
                   f"{r['unit']} change {_change(r)} (z {r['z']:.1f}){note}")
    return out


def _step_text(sm: dict[str, Any]) -> str:
    """'simulated (recorded)' step metrics of the diagnosis' first step, or the flat entries."""
    sim, rec = sm.get("simulated"), sm.get("recorded")
    if isinstance(sim, dict) and isinstance(rec, dict):
        parts = [f"{k.replace('_', ' ')} {_fmt(sim.get(k), '.3g')} ({_fmt(rec.get(k), '.3g')})" for k in sim]
        t0 = sm.get("t_start")
        return (
            (f"step at {t0:.3g} s: " if isinstance(t0, (int, float)) else "")
            + ", ".join(parts)
            + " — simulated (recorded)"
        )
    return ", ".join(f"{k} {_fmt(v, '.3g')}" for k, v in sm.items() if not isinstance(v, dict))


def _table(rows: list[list[Any]], head: list[str]) -> str:
    th = "".join(f"<th>{html.escape(str(c))}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_fmt(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def _html_rows(result: GapResult) -> dict[str, Any]:
    """The rows of the HTML report's tables (and the verdict list, channels, explained share)."""
    return {**_where_rows(result), **_which_rows(result), **_held_out_rows(result)}


def _where_rows(result: GapResult) -> dict[str, Any]:
    """The where-analysis' verdict list, equation rows and per-recording rows."""
    w = result.where
    verdict = "".join(f"<li>{html.escape(v)}</li>" for v in w.verdict())
    eq_rows = [
        [
            r["equation"],
            r["subsystem"],
            f"{r['relative']:.2%}" if math.isfinite(r["relative"]) else "no driving term",
            "yes" if r["flagged"] else "no",
            r["top_group"],
            r["top_group_subsystem"],
        ]
        for r in w.located
    ]
    eq_rows += [[nc["equation"], "", "not checked", "", nc["reason"], ""] for nc in w.not_checked]
    rec_rows = [
        [
            _label(r.source),
            r.free_run["nrmse"],
            r.short_horizon["nrmse"],
            r.whiteness["p_value"],
            r.input_xcorr["p_value"],
            r.input_xcorr["peak_lag_s"],
            r.alignment["lag_s"],
            "yes" if r.significant else "no",
        ]
        for r in w.recordings
    ]
    return {"verdict": verdict, "eq_rows": eq_rows, "rec_rows": rec_rows}


def _which_rows(result: GapResult) -> dict[str, Any]:
    """The ranked effects, the not identifiable ones, the pairs not separated, the explained share."""
    d = result.diagnosis
    rank_rows = [
        [
            k + 1,
            r["effect"],
            r.get("subsystem"),
            r.get("score"),
            r.get("validation_explained"),
            r.get("bic_delta"),
            r.get("presence"),
            r.get("q_value"),
            r.get("status"),
            "; ".join(
                f"{n} = {_fmt(p.get('value'))} {p.get('unit', '')} (the rig's, not fitted)" if p.get("held")
                else f"{n} = {_fmt(p.get('value'))} ± {_fmt(p.get('std'), '.2g')} {p.get('unit', '')}"
                for n, p in (r.get("parameters") or {}).items()
            ),
        ]
        for k, r in enumerate(d.ranking)
    ]
    ni_rows = [[n["effect"], n["reason"]] for n in d.not_identifiable]
    amb_rows = [[r["effect"], ", ".join(r["ambiguous_with"]),
                 "; ".join(f"{k}: validation explained {_fmt(v.get('validation_explained'), '.3f')}, "
                           + (f"first in {v['bootstrap_first']:.0%} of resamples" if v.get("bootstrap_first")
                              is not None else "as good in the joint fit with the other chosen effects"
                              if v.get("joint_fit") else "fitted alone, neither removes "
                              f"{SWAP_GAIN:.0%} of the gap above noise the other leaves")
                           for k, v in r.get("ambiguity", {}).items())]
                for r in d.ranking if r.get("ambiguous_with")]
    explained = getattr(d, "explained", {}) or {}
    return {"rank_rows": rank_rows, "ni_rows": ni_rows, "amb_rows": amb_rows, "explained": explained}


def _held_out_rows(result: GapResult) -> dict[str, Any]:
    """Before / after rows: held-out and validation figures, overlays, channels, residual tests."""
    d = result.diagnosis
    shrink_rows = []
    for part, row in [("held out", r) for r in result.test] + [("validation", r) for r in d.validation]:
        sm = row.get("step_metrics") or {}
        shrink_rows.append(
            [
                part,
                "+".join(row["effects"]) or "nominal",
                row.get("nrmse"),
                row.get("max_error"),
                row.get("steady_state_error"),
                _step_text(sm),
            ]
        )
    after_rows = [
        [
            _label(o["source"]),
            o["metrics"]["nominal"]["nrmse"],
            o["metrics"]["corrected"]["nrmse"],
            o["metrics"]["nominal"]["max_abs_error"],
            o["metrics"]["corrected"]["max_abs_error"],
        ]
        for o in result.overlays
    ]
    chans = list(result.test[0].get("channel_nrmse", {}))
    channel_rows = [["+".join(row["effects"]) or "nominal", *[row["channel_nrmse"].get(c) for c in chans]]
                    for row in result.test]
    wc = result.where_heldout_corrected
    wn = result.where_heldout_nominal
    white_rows = [
        [
            _label(a.source),
            a.whiteness["p_value"],
            b.whiteness["p_value"],
            "yes" if a.significant else "no",
            "yes" if b.significant else "no",
        ]
        for a, b in zip(wn.recordings, wc.recordings, strict=True)
    ]
    return {"shrink_rows": shrink_rows, "after_rows": after_rows, "chans": chans,
            "channel_rows": channel_rows, "white_rows": white_rows}


#: What presence, completeness and the status words mean (the HTML report, section 4).
_PRESENCE_HTML = f"""
<p>Presence is the evidence that an effect is in the plant: its fit (on the fit part) tested on the
validation part against the model without it (one-sided t test that it shrinks each second's error,
weighted by the share of that second's error above noise, by more than the share the decision asks
for), the p-values of every candidate tried adjusted for the false-discovery rate (q,
Benjamini-Hochberg), times how often it wins its rivals' bootstrap resamples, times 0.5 + 0.5 ×
completeness (a residual far above the noise shows something outside the catalog, for which a
passing effect may stand in: presence at most ½). A chosen effect is <b>named</b> with presence ≥
{NAMED_PRESENCE:g} and a completeness of the chosen set ≥ {NAMED_COMPLETENESS:g}, else a
<b>candidate</b>; an unchosen one is a candidate with presence ≥ {CANDIDATE_PRESENCE:g}.</p>"""


def html_page(result: GapResult, figs: dict[str, bytes]) -> str:
    """The self-contained HTML report (figures embedded as base64 PNG): the headline, then one
    section per step (before / after on held-out recordings, where, which) and the definitions."""
    h = result.headline()
    d = result.diagnosis
    img = _figure_tag(result, figs)
    t = _html_rows(result)
    css = (
        "body{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em;color:#222}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;padding:3px 7px;"
        "font-size:13px}th{background:#eee}img{max-width:100%}.big{font-size:1.2em}"
        ".small{font-size:0.75em;color:#555}"
    )
    return (f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>aeropend gap report: {html.escape(result.rig.name)}</title>
<style>{css}</style></head><body>
<h1>Sim-to-real gap report: {html.escape(result.rig.name)}</h1>
<p class="big">{_headline_html(h, d)} Significant gap: {"yes" if h["significant_gap"] else "no"}
<span class="small">({html.escape(h["significant_gap_why"])})</span>;
located in: <b>{html.escape(str(h["where_subsystem"]))}</b>.</p>
{_detected_html(d)}{_not_computed_html(result)}
<p>Rig {html.escape(result.rig_ref)}; {len(result.fit)} fit recording(s), {len(result.held_out)} held-out
recording(s) ({html.escape(result.split_rule)}). The held-out recordings were used neither to locate the gap
nor to choose or fit the effects: the diagnosis fitted on {len(result.fit_core)} part(s) of the fit recordings
and chose the effects on {len(result.validation)} validation part(s) carved from them.</p>
"""
            + _before_after_html(result, t, img) + _where_html(result, t, img) + _which_html(result, t, img)
            + _DEFINITIONS_HTML)


def _figure_tag(result: GapResult, figs: dict[str, bytes]) -> Callable[[str, str], str]:
    """``img(key, alt)``: the figure embedded as base64 PNG, or why it was not drawn."""

    def img(key: str, alt: str) -> str:
        if key not in figs:
            why = result.not_computed.get(f"figure {key}", "not drawn")
            return f"<p><i>figure {html.escape(key)} not drawn: {html.escape(why)}</i></p>"
        return f'<img alt="{alt}" src="data:image/png;base64,{base64.b64encode(figs[key]).decode()}">'

    return img


def _before_after_html(result: GapResult, t: dict[str, Any], img: Callable[[str, str], str]) -> str:
    """Section 1 of :func:`html_page`: the held-out recordings before / after, per channel, residual tests."""
    after_rows, shrink_rows, chans = t["after_rows"], t["shrink_rows"], t["chans"]
    channel_rows, white_rows = t["channel_rows"], t["white_rows"]
    return f"""<h2>1. Before / after on held-out recordings</h2>
{img("overlay", "overlay")}
{
        _table(
            after_rows,
            [
                "recording",
                "NRMSE nominal",
                "NRMSE corrected",
                "max |e| nominal [rad]",
                "max |e| corrected [rad]",
            ],
        )
    }
{
        _table(
            shrink_rows,
            [
                "data",
                "effects added",
                "NRMSE (mean over recordings)",
                "max error [rad]",
                "steady-state error [rad]",
                "step metrics",
            ],
        )
    }
{_refit_html(result)}
<h3>Held-out NRMSE per recorded channel</h3>
{_table(channel_rows, ["effects added", *[f"NRMSE {c}" for c in chans]])}
<h3>Residual tests on held-out data, nominal vs corrected</h3>
{
        _table(
            white_rows,
            ["recording", "Ljung-Box p nominal", "Ljung-Box p corrected", "gap nominal", "gap corrected"],
        )
    }
{_drift_html(result)}
"""


def _where_html(result: GapResult, t: dict[str, Any], img: Callable[[str, str], str]) -> str:
    """Sections 2 and 3 of :func:`html_page`: the residual per state equation, by region and band."""
    verdict, eq_rows, rec_rows, w = t["verdict"], t["eq_rows"], t["rec_rows"], result.where
    return f"""<h2>2. Where: residual per state equation (fit recordings)</h2>
<ul>{verdict}</ul>
<p>Each state equation is evaluated on the measured signals; its residual is shown relative to the equation's
driving term (v<sub>a</sub> for the armature, K<sub>t</sub>i<sub>a</sub> for the rotor, (L/J)f for the
pendulum). The "top terms" column is the term group whose regressors explain most of the residual (R²).
Equations whose channels were not recorded cannot be checked.</p>
{_table(eq_rows, ["equation", "subsystem", "residual / driving term", "flagged", "top terms", "points to"])}
{img("equations", "equation residuals")}
{
        _table(
            rec_rows,
            [
                "recording",
                "free-run NRMSE",
                f"{w.recordings[0].horizon:g} s-ahead NRMSE",
                "Ljung-Box p",
                "input xcorr p",
                "xcorr peak lag [s]",
                "alignment lag [s]",
                "significant",
            ],
        )
    }
<h2>3. Where: residual by operating region, frequency band, residual tests</h2>
{img("regions", "regions")}
{img("tests", "residual tests")}
"""


def _which_html(result: GapResult, t: dict[str, Any], img: Callable[[str, str], str]) -> str:
    """Section 4 of :func:`html_page`: the ranked effects, completeness, what the data do not separate."""
    rank_rows, ni_rows, amb_rows, explained = t["rank_rows"], t["ni_rows"], t["amb_rows"], t["explained"]
    return f"""<h2>4. Which: ranked unmodelled effects</h2>
{img("effects", "effects")}
{
        _table(
            rank_rows,
            [
                "rank",
                "effect",
                "subsystem",
                "score",
                "validation explained",
                "ΔBIC",
                "presence",
                "q (FDR)",
                "status",
                "parameters",
            ],
        )
    }
{_PRESENCE_HTML}
<p>Completeness {_fmt(explained.get("completeness"), ".2f")}: how completely the chosen effects explain
the gap: {html.escape(explained.get("verdict", "–"))}
(worst channel {html.escape(str(explained.get("worst_channel", "–")))}: share of its above-noise
validation gap removed {_fmt(explained.get("share_above_noise"), ".3f")},
validation residual / its noise part: {_fmt(explained.get("residual_over_noise"), ".3g")}).</p>
<p>Where vs which: {html.escape(result.agreement.get("explanation", "–"))}.</p>
<h3>Effects these data do not separate</h3>
{_table(amb_rows, ["effect", "not separated from", "evidence"])}
<h3>Not identifiable from these recordings</h3>
{_table(ni_rows, ["effect", "reason"])}
"""


#: Section 5 of :func:`html_page`: the definitions.
_DEFINITIONS_HTML = """<h2>5. Definitions</h2>
<ul>
<li>NRMSE = RMS(θ<sub>sim</sub> − θ<sub>meas</sub>) / (max θ<sub>meas</sub> − min θ<sub>meas</sub>),
free run from the recording's first samples, driven by the recorded duty cycle only.</li>
<li>Significant gap: the free-run residual fails the Ljung-Box whiteness test (p &lt; 0.01), its RMS exceeds
3&times; the measurement noise and the NRMSE exceeds 0.01.</li>
<li>Validation: the part of the fit recordings on which the diagnosis chooses and ranks the effects
("validation explained" = share of the nominal validation error an effect removes). Held out: the
recordings only replayed here, at the end.</li>
<li>Confidence: how often the effect comes first (or, for an added effect, passes its threshold) when the
validation segments are resampled, times the completeness of the chosen set (1 when it leaves the noise
level, 0 when more than a quarter of the gap above noise remains) (0..1).</li>
<li>Corrected rig: <code>corrected_rig.yaml</code> next to this page (load with
<code>aeropend_sim.params.load_rig</code>); the full numbers are in <code>report.json</code>.</li>
</ul>
</body></html>
"""


#: What :func:`write_report` writes at the top of a report folder, by key (the ``gap`` command's
#: ``--overwrite`` replaces only a folder that holds one of them).
REPORT_FILES = {"report": "report.json", "html": "report.html", "corrected_rig": "corrected_rig.yaml",
                "figures": "figures"}


def write_report(result: GapResult, outdir: str | Path) -> dict[str, Path]:
    """Write ``report.json``, ``report.html``, ``corrected_rig.yaml`` and ``figures/*.png``
    (:data:`REPORT_FILES`; files of the same names are replaced, others are left alone: the ``gap``
    command claims an empty folder first).

    A figure that cannot be drawn is left out, with its reason in ``result.not_computed``
    (``"figure <name>"``), which the JSON, the HTML page and :func:`terminal_summary` show.

    Returns
    -------
    dict
        Paths keyed ``report``, ``html``, ``corrected_rig`` and ``fig_<name>``.
    """
    out = Path(outdir)
    (out / REPORT_FILES["figures"]).mkdir(parents=True, exist_ok=True)
    not_drawn: dict[str, str] = {}
    figs = figures(result, not_drawn=not_drawn)
    result.not_computed.update({f"figure {k}": why for k, why in not_drawn.items()})
    paths: dict[str, Path] = {}
    for k, png in figs.items():
        p = out / REPORT_FILES["figures"] / f"{k}.png"
        p.write_bytes(png)
        paths[f"fig_{k}"] = p
    paths["report"] = out / REPORT_FILES["report"]
    paths["report"].write_text(json.dumps(result.as_dict(), indent=2, allow_nan=False), encoding="utf-8")
    paths["html"] = out / REPORT_FILES["html"]
    paths["html"].write_text(html_page(result, figs), encoding="utf-8")
    paths["corrected_rig"] = out / REPORT_FILES["corrected_rig"]
    paths["corrected_rig"].write_text(
        yaml.safe_dump(jsonable(corrected_rig_dict(result)), sort_keys=False, allow_unicode=True),
        encoding="utf-8",
    )
    return paths


__all__ = [
    "EQUATIONS",
    "REPORT_FILES",
    "GapResult",
    "corrected_rig_dict",
    "figures",
    "html_page",
    "run_gap",
    "terminal_summary",
    "write_report",
]
