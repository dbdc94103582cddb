"""Axes rules shared by every recorded-vs-model figure: the plotted range and titles that fit.

A model that diverges (a nominal rig whose thrust spins the rod over the top to 6000 rad) must
not set the axis limits: autoscaling to it flattens the recorded curve, and the fitted one, into a
line. Every overlay figure (:func:`aeropend_ident.greybox.baseline.plot_overlay`,
:func:`aeropend_ident.sindy.plots.plot_free_run`, :func:`aeropend_ident.gap.figures.fig_overlay`,
:func:`aeropend_ident.gap.compare_plot.plot_overlay`) draws its curves and then calls
:func:`clip_to_recorded`: the y-limits follow the recorded curve and the models, but never further
than :data:`REACH` recorded ranges beyond the recorded one; a model that leaves that window is cut
at the axes' edge and named in a note on the axes ("nominal model leaves the plotted range at
t = 8.94 s: θ → 6.3e3 rad"). :func:`fit_title` wraps a title to its axes' width so that nothing is
cut off, and :func:`short_number` writes numbers with a few significant digits.

**Divergence** (:func:`diverges`, the one rule of every tool): a simulated angle that turns
non-finite or leaves the recorded range by more than :data:`DIVERGENCE_SPANS` recorded spans, and by
at least :data:`MIN_DIVERGENCE_RAD` (a quarter turn), (a rod that spins over the top, a free run that
blows up) *diverges*: the tools report that instead of an
NRMSE or a shrink between such runs (a figure computed on them would only measure how far the run
went), and the figures' note says "diverges" for it (:func:`clip_to_recorded`).

No matplotlib import at module level: the functions work on the Axes they are given.
"""

from __future__ import annotations

import dataclasses
import math
import textwrap
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

#: How far beyond the recorded range [lo, hi] a model may widen the plotted range, as a share of
#: the recorded span hi − lo (0.5: the axis spans at most twice the recorded range, and the
#: recorded curve keeps at least half of the height).
REACH = 0.5
#: Padding added to the plotted range on each side, as a share of it.
PAD = 0.04
#: Share of the axes' width a title line may take before it is wrapped.
WRAP_AT = 0.97
#: A model diverges when it leaves the recorded range [lo, hi] by more than this many recorded spans
#: hi − lo (or turns non-finite): wider than the plotted window (:data:`REACH`), so a model cut in a
#: figure for readability is not yet called divergent.
DIVERGENCE_SPANS = 1.0
#: Least departure [rad] beyond the recorded range that counts as divergence, whatever the span: a
#: quarter turn. A held-out step that moves 0.2 rad and a nominal rig that settles 0.3 rad lower are
#: a large error, scored as one (an NRMSE), not a run that left the recorded regime; a rod that swings
#: a quarter turn past everything the recorded one did (over the top from hanging) has.
MIN_DIVERGENCE_RAD = math.pi / 2
#: A scored part whose own θ range is below this share of the whole recording's is a hold (it barely
#: moves): its NRMSE and its divergence window use the whole recording's range (baseline, identify).
HOLD_RANGE_SHARE = 0.1


def short_number(v: float, digits: int = 3) -> str:
    """``v`` with ``digits`` significant digits; a power of ten as ``6.3e3`` (no ``+``, no leading zeros).

    Examples: 0.6450000000000000244 → ``0.645``, 6312.7 → ``6.31e3``, 2.5e-05 → ``2.5e-5``,
    inf → ``inf``.
    """
    v = float(v)
    if not math.isfinite(v):
        return str(v)
    text = f"{v:.{digits}g}"
    if "e" in text:
        mant, exp = text.split("e")
        text = f"{mant}e{int(exp)}"
    return text


@dataclass(frozen=True)
class Excursion:
    """Where a model leaves the plotted range: ``label``, first time ``t`` [s] outside (or non-finite)
    and the ``extreme`` value it reaches beyond the range (±inf / nan when it blows up)."""

    label: str
    t: float
    extreme: float
    diverged: bool = False

    def note(self, symbol: str, unit: str) -> str:
        """``"<label> leaves the plotted range at t = … s: <symbol> → <extreme> <unit>"``, or
        ``"<label> diverges at t = … s: …"`` when it went beyond the divergence window (a NaN:
        ``"<label> diverges at t = … s (NaN from there)"``)."""
        if math.isnan(self.extreme):
            return f"{self.label} diverges at t = {short_number(self.t)} s (NaN from there)"
        what = "diverges" if self.diverged or math.isinf(self.extreme) else "leaves the plotted range"
        return (f"{self.label} {what} at t = {short_number(self.t)} s: "
                f"{symbol} → {short_number(self.extreme, 2)} {unit}").rstrip()


def plotted_range(recorded: Any, models: Mapping[str, Any] | None = None) -> tuple[float, float]:
    """y-limits (lo, hi) of an overlay: the recorded range widened to the models' finite values, at
    most :data:`REACH` recorded spans beyond it, padded by :data:`PAD`.

    Parameters
    ----------
    recorded : array_like, shape (n,)
        The recorded channel (NaNs ignored).
    models : mapping label -> array_like or (t, y), optional
        The model curves drawn on the same axes (only their y values matter here).

    Returns
    -------
    (float, float)
        lo < hi.
    """
    lo_r, hi_r = _finite_range(recorded)
    span = hi_r - lo_r or 0.1 * max(abs(hi_r), 1e-3)
    win_lo, win_hi = lo_r - REACH * span, hi_r + REACH * span
    lo, hi = lo_r, hi_r
    for m in (models or {}).values():
        ylo, yhi = _finite_range(m[1] if isinstance(m, tuple) else m, (lo_r, hi_r))
        lo, hi = min(lo, max(ylo, win_lo)), max(hi, min(yhi, win_hi))
    if hi <= lo:
        lo, hi = lo - 0.5 * span, hi + 0.5 * span
    pad = PAD * (hi - lo)
    return lo - pad, hi + pad


def excursions(t: Any, models: Mapping[str, Any], lo: float, hi: float) -> list[Excursion]:
    """The models that leave [lo, hi] (or turn non-finite), each with when and how far.

    Parameters
    ----------
    t : array_like, shape (n,)
        Time [s] of the samples.
    models : mapping label -> array_like shape (n,), or label -> (t_model, y_model)
        A model on its own time grid as a tuple (e.g. a free run over part of the record).
    lo, hi : float
        Plotted range.
    """
    out = []
    for label, m in models.items():
        tt, yy = (np.asarray(m[0], dtype=float), np.asarray(m[1], dtype=float)) if isinstance(m, tuple) \
            else (np.asarray(t, dtype=float), np.asarray(m, dtype=float))
        bad = ~np.isfinite(yy) | (yy < lo) | (yy > hi)
        if not bad.any():
            continue
        k = int(np.argmax(bad))
        nonfinite = yy[~np.isfinite(yy)]
        if nonfinite.size:
            extreme = float(nonfinite[0])
        else:
            above, below = float(np.max(yy)) - hi, lo - float(np.min(yy))
            extreme = float(np.max(yy)) if above >= below else float(np.min(yy))
        out.append(Excursion(label, float(tt[k]), extreme))
    return out


def clip_to_recorded(ax: Any, t: Any, recorded: Any, models: Mapping[str, Any], *, symbol: str = "θ",
                     unit: str = "rad", fontsize: float = 8.0) -> list[Excursion]:
    """Set the y-limits of an overlay axes by :func:`plotted_range` and note every model that leaves them.

    The curves must already be drawn; a model outside the limits is cut at the axes' edge (matplotlib
    clips lines to the axes) and gets one line in a note at the lower left of the axes
    (:meth:`Excursion.note`), in a band added below the plotted range so that the note never covers
    the recorded curve. The recorded curve is never cut: the limits always contain it.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    t : array_like, shape (n,)
        Time [s] of the model samples (the x data of the model curves).
    recorded : array_like
        Recorded channel (its range sets the limits).
    models : mapping label -> array_like shape (n,), or label -> (t_model, y_model)
        Model curves on this axes, by the name the note gives them (e.g. ``"nominal model"``);
        a tuple for a model on its own time grid.
    symbol, unit : str
        How the note names the quantity (``θ``, ``rad``).
    fontsize : float

    Returns
    -------
    list of Excursion
        The models that leave the plotted range (empty: everything fits).
    """
    lo, hi = plotted_range(recorded, models)
    # a diverging model's note gives its divergence time (the one rule, :func:`diverges`), not the
    # earlier time it left the plotted range: the figure and the tables name one time
    far = {e.label: e for e in excursions(t, models, *divergence_window(recorded))}
    out = [dataclasses.replace(far.get(e.label, e), diverged=e.label in far)
           for e in excursions(t, models, lo, hi)]
    if out:
        # a band below the plotted range holds the note, so that it never covers the recorded curve
        fig = ax.get_figure()
        height_pt = max(ax.get_position().height * fig.get_figheight() * 72.0, 1.0)
        share = min((len(out) * 1.5 * fontsize + 8.0) / height_pt, 0.4)
        lo -= share / (1.0 - share) * (hi - lo)
        ax.text(0.01, 0.02, "\n".join(e.note(symbol, unit) for e in out), transform=ax.transAxes,
                ha="left", va="bottom", fontsize=fontsize, color="tab:red",
                bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.85, "edgecolor": "tab:red"})
    ax.set_ylim(lo, hi)
    return out


def divergence_window(recorded: Any, span: float | None = None) -> tuple[float, float]:
    """The range a model must stay in not to diverge: the recorded [lo, hi] widened on each side by
    :data:`DIVERGENCE_SPANS` spans, and by at least :data:`MIN_DIVERGENCE_RAD`.

    Parameters
    ----------
    recorded : array_like
        The recorded channel (NaNs ignored).
    span : float, optional
        The span to widen by (default hi − lo of ``recorded``; a tool scoring a part that barely
        moves, e.g. a held-out hold, passes the span of the whole recording).
    """
    lo, hi = _finite_range(recorded)
    widen = max(DIVERGENCE_SPANS * _span(recorded, span), MIN_DIVERGENCE_RAD)
    return lo - widen, hi + widen


def _span(recorded: Any, span: float | None) -> float:
    """The span a departure is measured in: ``span``, else hi − lo of ``recorded`` (never 0)."""
    lo, hi = _finite_range(recorded)
    width = (hi - lo) if span is None else float(span)
    return width if width > 0.0 else 0.1 * max(abs(hi), 1e-3)


def hold_span(recorded: Any, span_all: float) -> float | None:
    """The span a part is measured in when it is a hold, else None (its own range is used).

    Parameters
    ----------
    recorded : array_like
        The part's recorded channel (NaNs ignored).
    span_all : float
        hi − lo of the whole recording (or of all recordings) the part belongs to.

    Returns
    -------
    float or None
        ``span_all`` when the part's own range is below :data:`HOLD_RANGE_SHARE` of it.
    """
    lo, hi = _finite_range(recorded)
    return float(span_all) if span_all > 0.0 and (hi - lo) < HOLD_RANGE_SHARE * span_all else None


def diverges(theta_sim: Any, theta_meas: Any, t: Any = None, span: float | None = None,
             symbol: str = "θ", unit: str = "rad") -> str | None:
    """Whether a simulated angle diverges from the recorded one: the reason, or None.

    The one divergence rule of every tool (the module docstring): the simulation turns non-finite,
    or leaves the recorded range by more than :data:`DIVERGENCE_SPANS` recorded spans
    (:func:`divergence_window`). Baseline, identify, compare and gap report such a run as
    divergence instead of an NRMSE or a shrink.

    Parameters
    ----------
    theta_sim, theta_meas : array_like, shape (n,)
        Simulated and recorded angle [rad] on the same samples.
    t : array_like, shape (n,), optional
        Time [s] of the samples (for the message; default the sample index).
    span : float, optional
        Recorded span to measure the departure in (see :func:`divergence_window`).
    symbol, unit : str
        How the message names the quantity.

    Returns
    -------
    str or None
        E.g. ``"diverges at t = 8.48 s: θ → 6.3e3 rad, beyond the recorded range [0.2, 0.8] rad by
        more than a quarter turn"``; None when it stays within the window.
    """
    sim = np.asarray(theta_sim, dtype=float)
    tt = np.arange(sim.size, dtype=float) if t is None else np.asarray(t, dtype=float)
    lo, hi = divergence_window(theta_meas, span)
    found = excursions(tt, {"": sim}, lo, hi)
    if not found:
        return None
    e = found[0]
    at = f"t = {short_number(e.t)} s" if t is not None else f"sample {int(e.t)}"
    if not math.isfinite(e.extreme):
        return f"diverges at {at} ({symbol} is not finite from there)"
    rlo, rhi = _finite_range(theta_meas)
    width = short_number(_span(theta_meas, span))
    quarter = MIN_DIVERGENCE_RAD >= DIVERGENCE_SPANS * _span(theta_meas, span)
    margin = ("a quarter turn" if quarter
              else f"{short_number(DIVERGENCE_SPANS)} recorded span(s) ({width} {unit})")
    return (f"diverges at {at}: {symbol} → {short_number(e.extreme, 2)} {unit}, beyond the recorded range "
            f"[{short_number(rlo)}, {short_number(rhi)}] {unit} by more than {margin}")


def fit_title(ax: Any, text: str, fontsize: float = 9.0, **kwargs: Any) -> Any:
    """``ax.set_title`` with ``text`` wrapped at word boundaries to the axes' width (nothing cut off).

    The axes' width is taken after the figure's layout engine (constrained layout) has placed it,
    and the title's width is measured by the figure's renderer; a title wider than the axes is
    wrapped to the number of characters that fit (explicit line breaks in ``text`` are kept).

    Returns
    -------
    matplotlib.text.Text
        The title.
    """
    fig = ax.get_figure()
    engine = fig.get_layout_engine()
    if engine is not None:
        engine.execute(fig)
    if not hasattr(fig.canvas, "get_renderer"):  # a Figure made without pyplot: measure with Agg
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig)
    renderer = fig.canvas.get_renderer()
    avail = ax.get_window_extent(renderer).width
    title = ax.set_title(text, fontsize=fontsize, **kwargs)
    lines = text.split("\n")
    need = title.get_window_extent(renderer).width
    if need > WRAP_AT * avail:
        chars = max(20, int(max(len(x) for x in lines) * WRAP_AT * avail / need))
        title.set_text("\n".join(textwrap.fill(x, chars, break_long_words=False) for x in lines))
    return title


def _finite_range(y: Any, default: tuple[float, float] = (0.0, 1.0)) -> tuple[float, float]:
    yy = np.asarray(y, dtype=float)
    yy = yy[np.isfinite(yy)]
    if not yy.size:
        return default
    return float(np.min(yy)), float(np.max(yy))
