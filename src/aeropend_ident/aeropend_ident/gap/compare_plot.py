"""Overlay figures of :func:`aeropend_ident.gap.compare.compare`: recorded vs simulated channels."""

from __future__ import annotations

from pathlib import Path

from aeropend_ident.gap.compare import UNITS, CompareResult

#: Channel titles.
TITLES = {"theta": "θ", "i_a": "i_a", "v_a": "v_a", "omega_rotor": "ω₁"}


def plot_overlay(result: CompareResult, recording: str, path: str | Path) -> Path:
    """One recording: a panel per compared channel (recorded + every rig's free run), duty below.

    The axes span the recorded range ±50 %: a replay that leaves it runs off the panel (its
    NRMSE in the legend says by how much).

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
    fig, axes = plt.subplots(len(chans) + 1, 1, figsize=(10, 2.2 * (len(chans) + 1)), sharex=True)
    t = tr["t"]
    for ax, c in zip(axes, chans, strict=False):
        ax.plot(t, tr["measured"][c], color="0.2", lw=0.8, label="recorded")
        for label, sim in tr["simulated"].items():
            sc = result.scores[label][recording]["channels"][c]
            ax.plot(t, sim[c], lw=1.0,
                    label=f"{label} (NRMSE {sc['nrmse']:.3g}, fit {sc['fit_percent']:.1f} %)")
        lo, hi = float(min(tr["measured"][c])), float(max(tr["measured"][c]))
        pad = 0.5 * (hi - lo) or 0.1 * max(abs(hi), 1e-3)
        ax.set_ylim(lo - pad, hi + pad)  # a diverging replay must not hide the recording
        ax.set_ylabel(f"{TITLES.get(c, c)} [{UNITS.get(c, '')}]")
        ax.legend(loc="upper right", fontsize=7)
    axes[-1].step(t, tr["duty"], where="post", color="k", lw=0.8)
    axes[-1].set_ylabel("duty τ [1]")
    axes[-1].set_xlabel("t [s]")
    axes[0].set_title(f"compare: {recording}")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
