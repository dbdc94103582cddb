"""Overlay figures of :func:`aeropend_ident.gap.compare.compare`: recorded vs simulated channels."""

from __future__ import annotations

from pathlib import Path

from aeropend_ident.gap.compare import UNITS, CompareResult
from aeropend_ident.io.overlay_axes import clip_to_recorded, fit_title
from aeropend_ident.io.overlay_axes import short_number as num

#: Channel titles.
TITLES = {"theta": "θ", "i_a": "i_a", "v_a": "v_a", "omega_rotor": "ω₁"}


def plot_overlay(result: CompareResult, recording: str, path: str | Path) -> Path:
    """One recording: a panel per compared channel (recorded + every rig's free run), duty below.

    The y-limits follow the recorded channel (:func:`aeropend_ident.io.overlay_axes.clip_to_recorded`):
    a replay that leaves them runs off the panel, with a note saying when and how far.

    Parameters
    ----------
    result : CompareResult
    recording : str
        Recording label (``result.recordings[k]["label"]``).
    path : str or Path
        PNG written.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    KeyError
        If ``recording`` is not a label of ``result``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tr = result.traces[recording]
    chans = list(tr["measured"])
    fig, axes = plt.subplots(len(chans) + 1, 1, figsize=(10, 2.2 * (len(chans) + 1)), sharex=True,
                             constrained_layout=True)
    t = tr["t"]
    for ax, c in zip(axes, chans, strict=False):
        ax.plot(t, tr["measured"][c], color="0.2", lw=0.8, label="recorded")
        for label, sim in tr["simulated"].items():
            sc = result.scores[label][recording].get("channels", {}).get(c)
            what = ("not simulated" if sc is None else "diverges" if sc.get("diverges")
                    else f"NRMSE {num(sc['nrmse'])}, fit {sc['fit_percent']:.1f} %")
            ax.plot(t, sim[c], lw=1.0, label=f"{label} ({what})")
        # a diverging replay must not hide the recording
        clip_to_recorded(ax, t, tr["measured"][c], {label: sim[c] for label, sim in tr["simulated"].items()},
                         symbol=TITLES.get(c, c), unit=UNITS.get(c, ""))
        ax.set_ylabel(f"{TITLES.get(c, c)} [{UNITS.get(c, '')}]")
        ax.legend(loc="upper right", fontsize=7)
    axes[-1].step(t, tr["duty"], where="post", color="k", lw=0.8)
    axes[-1].set_ylabel("duty τ [1]")
    axes[-1].set_xlabel("t [s]")
    fit_title(axes[0], f"compare: {recording}", fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path
