"""Plots of an identified sparse model (matplotlib, Agg backend; no display needed).

* :func:`plot_coefficients`: the coefficient matrix as a heat-map, rows = equations, columns =
  library terms (as thesis Figs. 5.3/5.4), colour = sign·log₁₀|ξ| so that terms of very
  different magnitude stay visible, every non-zero value written in its cell.
* :func:`plot_derivatives`: predicted vs measured (estimated) derivatives per equation, time
  series and scatter with the identity line.
* :func:`plot_free_run`: free-run simulation over measured states, optionally with the
  training / held-out boundary.

Time axes are the recording's own time [s] (the same in every figure of one run); a free run that
diverges is cut at the plotted range with a note
(:func:`aeropend_ident.io.overlay_axes.clip_to_recorded`); titles are wrapped to their width.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from aeropend_ident.errors import IdentificationError
from aeropend_ident.io.overlay_axes import clip_to_recorded, fit_title, short_number
from aeropend_ident.sindy.model import IdentData, SindyModel, lhs

_STATE_LABEL = {"theta": "θ [rad]", "theta_dot": "θ̇ [rad/s]", "i_a": "i_a [A]", "omega_rotor": "ω₁ [rad/s]"}


def _save(fig: plt.Figure, path: str | Path) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return p


def source_label(source: str) -> str:
    """Short name of a recording source for titles: the file name of a path with its ``[a:b]``
    slices, without the derivative tag (``reports/main/run_bag+d/dt(savgol)[7425:9900]`` ->
    ``run_bag[7425:9900]``)."""
    base, sep, rest = source.partition("[")
    base = base.split("+d/dt(", 1)[0]
    return Path(base).name + sep + rest if base else source


def plot_coefficients(model: SindyModel, path: str | Path, title: str | None = None) -> Path:
    """Heat-map of the coefficient matrix Ξ (equations × library terms); writes a PNG.

    Colour is sign(ξ)·(log₁₀|ξ| − log₁₀ min|ξ| + 1) over the non-zero entries (zero = white);
    each non-zero cell shows its value (and ± spread for ensemble models).

    Returns
    -------
    Path
        The written file.
    """
    coef = np.asarray(model.coef, dtype=float)
    nz = coef != 0.0
    scaled = np.zeros_like(coef)
    if nz.any():
        lo = np.log10(np.abs(coef[nz]).min())
        scaled[nz] = np.sign(coef[nz]) * (np.log10(np.abs(coef[nz])) - lo + 1.0)
    vmax = float(np.abs(scaled).max()) or 1.0
    n_t, n_f = coef.shape
    fig, ax = plt.subplots(figsize=(max(5.0, 0.75 * n_f + 2.0), 1.0 + 0.7 * n_t))
    im = ax.imshow(scaled, cmap="RdBu_r", vmin=-vmax, vmax=vmax, aspect="auto")
    ax.set_xticks(range(n_f), model.feature_names, rotation=45, ha="right")
    ax.set_yticks(range(n_t), [lhs(tg) for tg in model.targets])
    for i in range(n_t):
        for j in range(n_f):
            if nz[i, j]:
                txt = f"{coef[i, j]:.3g}"
                if model.coef_std is not None and np.isfinite(model.coef_std[i, j]):
                    txt += f"\n±{model.coef_std[i, j]:.2g}"
                dark = abs(scaled[i, j]) > 0.6 * vmax
                ax.text(j, i, txt, ha="center", va="center", fontsize=7, color="white" if dark else "black")
    cb = fig.colorbar(im, ax=ax, fraction=0.04)
    cb.set_label("sign·log-magnitude")
    ax.set_title(title or f"{model.method}, λ = {model.threshold:g}")
    fig.tight_layout()
    return _save(fig, path)


def plot_derivatives(model: SindyModel, data: IdentData, path: str | Path, title: str | None = None,
                     max_points: int = 4000) -> Path:
    """Predicted vs measured derivatives of every target with a derivative in ``data``.

    Raises
    ------
    IdentificationError
        If ``data`` holds no derivative of any target.
    """
    targets = [tg for tg in model.targets if tg in data.derivatives]
    if not targets:
        raise IdentificationError(f"{data.source}: no derivative of {model.targets} to plot against")
    pred = model.predict(data)
    step = max(1, len(data) // max_points)
    fig, axes = plt.subplots(len(targets), 2, figsize=(10, 2.8 * len(targets)), squeeze=False,
                             gridspec_kw={"width_ratios": [3, 1]}, constrained_layout=True)
    for row, tg in zip(axes, targets, strict=True):
        meas, p = data.derivatives[tg], pred[tg]
        row[0].plot(data.t[::step], meas[::step], lw=0.8, label="measured (estimated)")
        row[0].plot(data.t[::step], p[::step], lw=0.8, label="model")
        row[0].set_ylabel(lhs(tg))
        row[0].legend(fontsize=7, loc="upper right")
        row[1].plot(meas[::step], p[::step], ".", ms=1.5)
        lim = [float(min(meas.min(), p.min())), float(max(meas.max(), p.max()))]
        row[1].plot(lim, lim, "k--", lw=0.8)
        mse = float(np.mean((p - meas) ** 2))
        row[1].set_title(f"MSE {short_number(mse)}", fontsize=8)
        row[1].set_xlabel("measured")
        row[1].set_ylabel("model")
    axes[-1][0].set_xlabel("t [s] (recording time)")
    fit_title(axes[0][0], title or f"held-out derivatives: {source_label(data.source)}")
    return _save(fig, path)


def plot_free_run(t: np.ndarray, measured: Mapping[str, np.ndarray], simulated: Mapping[str, np.ndarray],
                  path: str | Path, t_split: float | None = None, title: str | None = None,
                  states: Sequence[str] | None = None, extra: Mapping[str, np.ndarray] | None = None) -> Path:
    """Free-run overlay: measured vs simulated states (one panel per state).

    With ``t_split`` the simulated curve is drawn as two runs, each with its legend entry: the
    free run over the training part (before ``t_split``) and the one over the held-out part (from
    it), the boundary marked and named in the legend. The y-limits follow the measured state; a
    free run that leaves them is cut there with a note (:func:`clip_to_recorded`).

    Parameters
    ----------
    t : ndarray, shape (N,)
        Time [s], the recording's own time (as in :func:`plot_derivatives`).
    measured, simulated : mapping state -> ndarray (N,)
    t_split : float, optional
        Start of the held-out part [s].
    title : str, optional
    states : sequence of str, optional
        Panels (default: every state both measured and simulated).
    extra : mapping label -> ndarray (N,), optional
        Further curves on the θ panel (e.g. another model's output).

    Raises
    ------
    IdentificationError
        If no state is both measured and simulated.
    """
    names = list(states) if states is not None else [s for s in simulated if s in measured]
    if not names:
        raise IdentificationError("plot_free_run: no state is both measured and simulated")
    t = np.asarray(t, dtype=float)
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 2.6 * len(names)), sharex=True, squeeze=False,
                             constrained_layout=True)
    held = t >= t_split if t_split is not None else np.ones(t.size, dtype=bool)
    for ax, s in zip(axes[:, 0], names, strict=True):
        ax.plot(t, measured[s], lw=0.8, color="k", label="measured")
        sim = np.asarray(simulated[s], dtype=float)
        models: dict[str, Any] = {}
        if t_split is not None and not held.all():
            models["free run, training"] = (t[~held], sim[~held])
        models["free run, held out" if t_split is not None else "free run"] = (t[held], sim[held])
        colors = ("tab:blue", "tab:red")[-len(models):]  # the held-out (or only) run in red
        for (lab, (tm, ym)), color in zip(models.items(), colors, strict=True):
            ax.plot(tm, ym, lw=0.9, color=color, label=lab)
        if s == "theta" and extra:
            for lab, y in extra.items():
                ax.plot(t, y, lw=0.8, ls="--", label=lab)
                models[lab] = np.asarray(y, dtype=float)
        if t_split is not None:
            ax.axvline(t_split, color="gray", ls=":", lw=1.0,
                       label=f"held-out start (t = {short_number(t_split, 4)} s)")
        symbol, _, unit = _STATE_LABEL.get(s, s).partition(" ")
        clip_to_recorded(ax, t, measured[s], models, symbol=symbol, unit=unit.strip("[]"))
        ax.set_ylabel(_STATE_LABEL.get(s, s))
        ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("t [s] (recording time)")
    fit_title(axes[0, 0], title or "free run")
    return _save(fig, path)
