"""Figures of the gap report (matplotlib, Agg backend, PNG bytes), apart from the computation.

:func:`figures` draws all of them for :func:`aeropend_ident.gap.report.write_report`: the
held-out overlay, equation residuals, regions, residual tests and the effect ranking.
"""

from __future__ import annotations

import io
import math
import textwrap
from typing import Any

import numpy as np

from aeropend_ident.gap.result import (
    GapResult,
    _label,
)
from aeropend_ident.gap.where_report import WhereReport
from aeropend_ident.io.overlay_axes import clip_to_recorded, fit_title
from aeropend_ident.io.overlay_axes import short_number as num
from aeropend_sim.output_folder import is_fault

#: Most held-out recordings drawn in the overlay figure.
MAX_OVERLAYS = 3


# --------------------------------------------------------------------------- figures
def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    _plt().close(fig)
    return buf.getvalue()


def fig_overlay(result: GapResult) -> bytes:
    """Held-out recordings: measured θ, nominal and corrected free run; duty below."""
    plt = _plt()
    ovs = result.overlays[:MAX_OVERLAYS]
    fig, axes = plt.subplots(
        2 * len(ovs),
        1,
        figsize=(11, 3.6 * len(ovs)),
        squeeze=False,
        height_ratios=[3, 1] * len(ovs),
        constrained_layout=True,
    )
    for j, o in enumerate(ovs):
        ax, axu = axes[2 * j, 0], axes[2 * j + 1, 0]
        ax.plot(o["t"], o["theta"], color="black", lw=1.2, label="recorded (held out)")
        ax.plot(o["t"], o["nominal"], color="tab:orange", lw=1.0, ls="--", label="nominal simulator")
        ax.plot(o["t"], o["corrected"], color="tab:blue", lw=1.0, label="corrected simulator")
        clip_to_recorded(ax, o["t"], o["theta"], {"nominal simulator": o["nominal"],
                                                  "corrected simulator": o["corrected"]})
        m = o["metrics"]

        def figure(label: str, m: dict = m) -> str:
            return "diverges" if m[label].get("diverges") else f"NRMSE {num(m[label]['nrmse'], 4)}"

        fit_title(ax, f"{_label(o['source'])}: nominal {figure('nominal')} -> "
                      f"corrected {figure('corrected')}")
        ax.set_ylabel("θ [rad]")
        ax.legend(loc="best", fontsize=8)
        ax.grid(alpha=0.3)
        axu.step(o["t"], o["duty"], where="post", color="tab:green", lw=1.0)
        axu.set_ylabel("duty τ [1]")
        axu.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time t [s] (from the held-out part's start)")
    return _png(fig)


def fig_equations(where: WhereReport) -> bytes:
    """Relative equation residual per state equation (bars) and the residual time series."""
    plt = _plt()
    rec = where.recordings[0]
    checked = [e for e in rec.equations if e.checked]
    fig, axes = plt.subplots(
        1 + len(checked), 1, figsize=(11, 2.4 * (1 + len(checked))), squeeze=False, constrained_layout=True
    )
    ax = axes[0, 0]
    names = [f"{r['equation']}\n({r['subsystem']})" for r in where.located]
    vals = [r["relative"] if math.isfinite(r["relative"]) else 0.0 for r in where.located]
    colors = ["tab:red" if r["flagged"] else "tab:gray" for r in where.located]
    ax.bar(names, vals, color=colors)
    for k, r in enumerate(where.located):
        size = f"{vals[k]:.1%}" if math.isfinite(r["relative"]) else "no driving term"
        ax.text(k, vals[k], f" {size}\n top: {r['top_group']}", ha="center", va="bottom", fontsize=8)
    miss = ", ".join(nc["equation"] for nc in where.not_checked)
    fit_title(ax, "equation residual / driving term (red = flagged)"
              + (f"; not checked: {miss}" if miss else ""))
    ax.set_ylabel("relative residual [1]")
    ax.set_ylim(0, max([*vals, 0.01]) * 1.5)
    for j, e in enumerate(checked, start=1):
        a = axes[j, 0]
        a.plot(rec.t, e.residual, lw=0.7, color="tab:red" if e.flagged else "tab:gray")
        a.axhline(0, color="black", lw=0.5)
        a.set_ylabel(f"{e.equation}\n[{e.unit}]")
        fit_title(a, f"{e.equation} equation residual on {_label(rec.source)} (RMS {num(e.rms)} {e.unit}, "
                     f"method floor {num(e.method_floor)}, noise floor {num(e.noise_floor)})", fontsize=8)
        a.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time t [s]")
    return _png(fig)


def fig_regions(where: WhereReport) -> bytes:
    """Free-run residual per θ, duty and |θ̇| bin, transient vs steady, and per frequency band."""
    plt = _plt()
    rec = where.recordings[0]
    reg = rec.regions
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), constrained_layout=True)
    for ax, key, label in (
        (axes[0, 0], "theta_bins", "θ [rad]"),
        (axes[0, 1], "duty_bins", "duty τ [1]"),
        (axes[0, 2], "rate_bins", "|θ̇| [rad/s]"),
    ):
        bins = reg[key]
        centres = [0.5 * (b["lower"] + b["upper"]) for b in bins]
        width = [(b["upper"] - b["lower"]) * 0.9 or 0.01 for b in bins]
        rms = [b["rms_residual"] or 0.0 for b in bins]
        mean = [b["mean_residual"] or 0.0 for b in bins]
        ax.bar(centres, rms, width=width, color="tab:orange", alpha=0.6, label="RMS")
        ax.bar(centres, mean, width=[w * 0.5 for w in width], color="tab:blue", label="mean")
        ax.set_xlabel(label)
        ax.set_ylabel("residual θ_sim − θ_meas [rad]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    mo = reg["motion"]
    ax = axes[1, 0]
    ax.bar(
        ["transient", "steady"],
        [mo["transient"]["rms_residual"] or 0.0, mo["steady"]["rms_residual"] or 0.0],
        color="tab:orange",
    )
    ax.set_ylabel("RMS residual [rad]")
    ax.set_title(f"|θ̇| threshold {num(reg['rate_threshold'])} rad/s", fontsize=9)
    ax = axes[1, 1]
    bands = [b for b in rec.bands if "residual_power_fraction" in b]
    ax.bar(
        [f"{b['band']}\n{b['f_lo_hz']:.2g}-{b['f_hi_hz']:.2g} Hz" for b in bands],
        [b["residual_power_fraction"] for b in bands],
        color="tab:purple",
    )
    ax.set_ylabel("share of residual power")
    ax.tick_params(axis="x", labelsize=7)
    ax = axes[1, 2]
    holds = rec.holds
    if holds:
        ax.plot([h["duty"] for h in holds], [h["theta_meas_ss"] for h in holds], "ko", label="recorded")
        ax.plot(
            [h["duty"] for h in holds],
            [h["theta_sim_ss"] for h in holds],
            "x",
            color="tab:orange",
            label="nominal",
        )
        ax.set_xlabel("duty τ [1]")
        ax.set_ylabel("steady θ [rad]")
        ax.legend(fontsize=8)
        ax.set_title("steady state per constant-duty hold", fontsize=9)
    else:
        ax.text(0.5, 0.5, "no constant-duty hold >= 1 s", ha="center", va="center")
    ax.grid(alpha=0.3)
    fig.suptitle(f"free-run residual by operating region: {_label(rec.source)}", fontsize=10)
    return _png(fig)


def fig_tests(where: WhereReport) -> bytes:
    """Residual autocorrelation (Ljung-Box) and input-residual cross-correlation with bounds."""
    plt = _plt()
    rec = where.recordings[0]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 3.4), constrained_layout=True)
    acf = rec.whiteness["acf"]
    n = rec.t.size
    a1.bar(np.arange(1, len(acf) + 1), acf, color="tab:blue")
    b = 2.58 / math.sqrt(n)
    a1.axhline(b, color="red", ls=":")
    a1.axhline(-b, color="red", ls=":")
    fit_title(a1, f"residual autocorrelation: Ljung-Box Q = {num(rec.whiteness['q'])}, "
                  f"p = {num(rec.whiteness['p_value'])}")
    a1.set_xlabel("lag [samples]")
    xc = rec.input_xcorr
    if xc["lags"]:
        a2.plot(np.array(xc["lags"]) * rec.dt, xc["rho"], color="tab:green")
        a2.axhline(xc["bound"], color="red", ls=":")
        a2.axhline(-xc["bound"], color="red", ls=":")
        a2.axvline(xc["peak_lag_s"], color="black", lw=0.8)
    fit_title(a2, f"input-residual cross-correlation (prewhitened): peak {num(xc['max_abs'])} at "
                  f"{num(xc['peak_lag_s'])} s, p = {num(xc['p_value'])}")
    a2.set_xlabel("lag [s] (> 0: residual follows input)")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    return _png(fig)


#: Characters per line of a bar label in the effects figure (longer effect sets wrap at a "+").
LABEL_WIDTH = 34


def _set_label(part: str, row: dict[str, Any]) -> str:
    """Bar label of an effect set: ``"held out: nominal"`` or the set (with the pass that made it, a
    replacement or refinement), wrapped at its ``+`` signs."""
    effects = list(row["effects"])
    step = "".join(f" ({k})" for k in ("replacement", "refinement") if row.get(k))
    text = f"{part}: " + ("nominal" if not effects else " +".join(["", *effects]).strip()) + step
    return textwrap.fill(text, LABEL_WIDTH, break_long_words=False, break_on_hyphens=False)


def fig_effects(result: GapResult) -> bytes:
    """Ranked effects (validation explained, presence) and the NRMSE per effect set, as horizontal
    bars whose labels sit on the y axis (one row each: no label overlaps another, however many sets
    and however long their names); the figure grows with the number of rows."""
    plt = _plt()
    d = result.diagnosis
    rank = list(d.ranking)[:8]
    rows = [("validation", r) for r in d.validation] + [("held out", r) for r in result.test]
    labels = [_set_label(part, r) for part, r in rows]
    n_lines = max(len(rank), sum(lab.count("\n") + 1 for lab in labels), 3)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 1.2 + 0.32 * n_lines), constrained_layout=True)
    if rank:
        tag = {**{n: " (chosen)" for n in d.chosen}, **{n: " (detected)" for n in getattr(d, "detected", {})}}
        names = [r["effect"] + tag.get(r["effect"], "") for r in rank][::-1]
        expl = [float(r.get("validation_explained") or 0.0) for r in rank][::-1]
        conf = [float(r.get("presence") or 0.0) for r in rank][::-1]
        y = np.arange(len(names))
        a1.barh(y, expl, color="tab:blue", label="validation explained")
        a1.scatter(conf, y, color="black", marker="D", label="presence", zorder=3)
        a1.set_yticks(y, names, fontsize=8)
        a1.set_xlabel("fraction [1]")
        a1.legend(fontsize=8, loc="lower right")
    fit_title(a1, "ranked effects (best on top)")
    if rows:
        y = np.arange(len(rows))[::-1]
        colors = [("tab:orange" if not r["effects"] else "tab:blue") for _, r in rows]
        bars = a2.barh(y, [r["nrmse"] for _, r in rows], color=colors)
        for b, (part, _) in zip(bars, rows, strict=True):
            b.set_alpha(0.45 if part == "validation" else 1.0)
        a2.set_yticks(y, labels, fontsize=8)
        a2.set_xlabel("NRMSE [1]")
    fit_title(a2, "NRMSE as effects are added: validation (chooses, pale) and held out (never seen)")
    for a in (a1, a2):
        a.grid(alpha=0.3, axis="x")
    return _png(fig)


def figures(result: GapResult, not_drawn: dict[str, str] | None = None) -> dict[str, bytes]:
    """All report figures as PNG bytes, keyed by file stem.

    Parameters
    ----------
    result : GapResult
    not_drawn : dict, optional
        Given: a figure that fails is left out and its reason stored here under its key (the
        report is written without it); else the failure propagates.
    """
    draw = {
        "overlay": lambda: fig_overlay(result),
        "equations": lambda: fig_equations(result.where),
        "regions": lambda: fig_regions(result.where),
        "tests": lambda: fig_tests(result.where),
        "effects": lambda: fig_effects(result),
    }
    out: dict[str, bytes] = {}
    for key, make in draw.items():
        if not_drawn is None:
            out[key] = make()
            continue
        try:
            out[key] = make()
        except Exception as exc:  # a figure never costs the report (a full disk does)
            if is_fault(exc):
                raise
            not_drawn[key] = f"{type(exc).__name__}: {exc}"
            _plt().close("all")
    return out
