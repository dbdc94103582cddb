"""Figures of the gap report (matplotlib, Agg backend, PNG bytes), apart from the computation.

:func:`figures` draws all of them for :func:`aeropend_ident.gap.report.write_report`: the
held-out overlay, equation residuals, regions, residual tests and the effect ranking.
"""

from __future__ import annotations

import io
import math
from typing import Any

import numpy as np

from aeropend_ident.gap.run import (
    GapResult,
    _label,
)
from aeropend_ident.gap.where import WhereReport

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
    fig.savefig(buf, format="png", dpi=100)
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
        m = o["metrics"]
        ax.set_title(
            f"{_label(o['source'])}: NRMSE nominal {m['nominal']['nrmse']:.4f} -> corrected "
            f"{m['corrected']['nrmse']:.4f}",
            fontsize=9,
        )
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
    vals = [r["relative"] for r in where.located]
    colors = ["tab:red" if r["flagged"] else "tab:gray" for r in where.located]
    ax.bar(names, vals, color=colors)
    for k, r in enumerate(where.located):
        ax.text(k, vals[k], f" {vals[k]:.1%}\n top: {r['top_group']}", ha="center", va="bottom", fontsize=8)
    miss = ", ".join(nc["equation"] for nc in where.not_checked)
    ax.set_title(
        "equation residual / driving term (red = flagged)" + (f"; not checked: {miss}" if miss else ""),
        fontsize=9,
    )
    ax.set_ylabel("relative residual [1]")
    ax.set_ylim(0, max([*vals, 0.01]) * 1.5)
    for j, e in enumerate(checked, start=1):
        a = axes[j, 0]
        a.plot(rec.t, e.residual, lw=0.7, color="tab:red" if e.flagged else "tab:gray")
        a.axhline(0, color="black", lw=0.5)
        a.set_ylabel(f"{e.equation}\n[{e.unit}]")
        a.set_title(
            f"{e.equation} equation residual on {_label(rec.source)} (RMS {e.rms:.3g} {e.unit}, "
            f"method floor {e.method_floor:.3g}, noise floor {e.noise_floor:.3g})",
            fontsize=8,
        )
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
    ax.set_title(f"|θ̇| threshold {reg['rate_threshold']} rad/s", fontsize=9)
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
    a1.set_title(
        f"residual autocorrelation: Ljung-Box Q = {rec.whiteness['q']:.3g}, "
        f"p = {rec.whiteness['p_value']:.3g}",
        fontsize=9,
    )
    a1.set_xlabel("lag [samples]")
    xc = rec.input_xcorr
    if xc["lags"]:
        a2.plot(np.array(xc["lags"]) * rec.dt, xc["rho"], color="tab:green")
        a2.axhline(xc["bound"], color="red", ls=":")
        a2.axhline(-xc["bound"], color="red", ls=":")
        a2.axvline(xc["peak_lag_s"], color="black", lw=0.8)
    a2.set_title(
        f"input-residual cross-correlation (prewhitened): peak {xc['max_abs']:.3f} at "
        f"{xc['peak_lag_s']} s, p = {xc['p_value']:.3g}",
        fontsize=9,
    )
    a2.set_xlabel("lag [s] (> 0: residual follows input)")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    return _png(fig)


def fig_effects(result: GapResult) -> bytes:
    """Ranked effects (score and validation explained) and the before/after NRMSE per effect set."""
    plt = _plt()
    d = result.diagnosis
    rank = list(d.ranking)[:8]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 3.8), constrained_layout=True)
    if rank:
        names = [r["effect"] for r in rank][::-1]
        expl = [float(r.get("validation_explained") or 0.0) for r in rank][::-1]
        conf = [float(r.get("confidence") or 0.0) for r in rank][::-1]
        y = np.arange(len(names))
        a1.barh(y, expl, color="tab:blue", label="validation explained")
        a1.scatter(conf, y, color="black", marker="D", label="confidence", zorder=3)
        a1.set_yticks(y, names, fontsize=8)
        a1.set_xlabel("fraction [1]")
        a1.legend(fontsize=8)
    a1.set_title("ranked effects (best on top)", fontsize=9)
    rows = [("validation", r) for r in d.validation] + [("HELD OUT", r) for r in result.test]
    if rows:
        labels = [
            f"{part}\n" + ("nominal" if not r["effects"] else "+" + "+".join(r["effects"]))
            for part, r in rows
        ]
        colors = [("tab:orange" if not r["effects"] else "tab:blue") for _, r in rows]
        alpha = [0.45 if part == "validation" else 1.0 for part, _ in rows]
        bars = a2.bar(labels, [r["nrmse"] for _, r in rows], color=colors)
        for b, al in zip(bars, alpha, strict=True):
            b.set_alpha(al)
        a2.set_ylabel("NRMSE [1]")
        a2.tick_params(axis="x", labelsize=7)
    a2.set_title("NRMSE as effects are added: validation (chooses) and held out (never seen)", fontsize=9)
    for a in (a1, a2):
        a.grid(alpha=0.3)
    return _png(fig)


def figures(result: GapResult) -> dict[str, bytes]:
    """All report figures as PNG bytes, keyed by file stem."""
    return {
        "overlay": fig_overlay(result),
        "equations": fig_equations(result.where),
        "regions": fig_regions(result.where),
        "tests": fig_tests(result.where),
        "effects": fig_effects(result),
    }
