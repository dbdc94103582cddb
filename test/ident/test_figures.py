"""What the figures show (issue 34, item 8), checked on the matplotlib objects before they are saved.

* Numbers in titles have a few significant digits (a cross-correlation peak lag read
  ``0.6450000000000000244 s``) and long titles wrap to their axes instead of being cut off.
* A model that diverges (the nominal ``etchepareborda_rig`` spins the rod to ~6000 rad) is cut at
  the recorded range with a note saying when it leaves and how far it goes; the recorded curve
  keeps the axes (:mod:`aeropend_ident.io.overlay_axes`, used by every overlay figure).
* ``identify``'s ``free_run.png`` names every line in its legend (the training and the held-out
  free run, the held-out start) and uses the recording's own time, as ``derivatives.png`` does.
* The gap report's effect-set bars are horizontal, one label per row: no two labels overlap.

The ``saved_figures`` fixture (conftest) records every Figure as it is saved.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from aeropend_ident.io.overlay_axes import PAD, REACH, clip_to_recorded, fit_title, short_number
from aeropend_ident.sindy.plots import plot_free_run

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real"
ETCHEPAREBORDA = REAL / "BA-Etchepareborda__adaptive-control-aeropendulum" / "openloop_steps_0_100_180.csv"
AEROSHIELD = REAL / "gergelytakacs__AutomationShield" / "AeroShield" / "Identification_Data.csv"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"real data folder {REAL} is missing")


def _texts(ax) -> list[str]:
    return [t.get_text() for t in ax.texts]


def _legend(ax) -> list[str]:
    leg = ax.get_legend()
    return [t.get_text() for t in leg.get_texts()] if leg is not None else []


def _renderer(fig):
    """A renderer of a saved (closed) figure: an Agg canvas, the figure drawn as it was saved."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def _inside(inner, outer, tol: float = 1.0) -> bool:
    return (inner.x0 >= outer.x0 - tol and inner.x1 <= outer.x1 + tol and inner.y0 >= outer.y0 - tol
            and inner.y1 <= outer.y1 + tol)


# --------------------------------------------------------------------------- the shared rules
def test_short_number_keeps_a_few_significant_digits() -> None:
    assert short_number(np.longdouble("0.6450000000000000244")) == "0.645"
    assert short_number(6312.7, 2) == "6.3e3"
    assert short_number(2.5e-5) == "2.5e-5"
    assert short_number(0.143) == "0.143"
    assert short_number(float("inf")) == "inf"


def test_a_diverging_model_is_cut_at_the_recorded_range_with_a_note() -> None:
    t = np.arange(0.0, 10.0, 0.01)
    recorded = 0.5 + 0.3 * np.sin(t)
    fitted = recorded + 0.05
    nominal = np.where(t < 8.475, recorded, 1.2 + 6300.0 * (t - 8.47) / (t[-1] - 8.47))  # spins over the top
    fig, ax = plt.subplots()
    ax.plot(t, recorded)
    ax.plot(t, nominal)
    ax.plot(t, fitted)
    out = clip_to_recorded(ax, t, recorded, {"nominal model": nominal, "fitted model": fitted})
    lo, hi = ax.get_ylim()
    span = np.ptp(recorded)
    # the recorded curve keeps the axes: inside the limits, at least 40 % of their height
    assert lo < recorded.min() and hi > recorded.max()
    assert span / (hi - lo) > 0.4
    assert hi <= recorded.max() + REACH * span + 2.0 * PAD * (hi - lo)
    # only the diverging model is named, with when it leaves and how far it goes
    assert [e.label for e in out] == ["nominal model"]
    assert _texts(ax) == ["nominal model diverges at t = 8.48 s: θ → 6.3e3 rad"]
    # the note sits in a band below every recorded sample (it never covers the recorded curve)
    fig.canvas.draw()
    note = ax.texts[0].get_window_extent()
    low = ax.transData.transform((0.0, recorded.min()))[1]
    assert note.y1 < low
    plt.close(fig)


def test_a_model_near_the_recording_widens_the_axes_and_gets_no_note() -> None:
    t = np.linspace(0.0, 5.0, 500)
    recorded = np.sin(t)
    overshoot = 1.3 * np.sin(t)  # 30 % more swing: drawn whole
    blowup = np.where(t < 2.0, recorded, np.nan)  # a free run that stops (NaN) at t = 2 s
    fig, ax = plt.subplots()
    out = clip_to_recorded(ax, t, recorded, {"model": overshoot})
    lo, hi = ax.get_ylim()
    assert out == [] and _texts(ax) == [] and lo < overshoot.min() and hi > overshoot.max()
    out = clip_to_recorded(ax, t, recorded, {"free run": blowup}, symbol="θ̇", unit="rad/s")
    assert [e.note("θ̇", "rad/s") for e in out] == ["free run diverges at t = 2 s (NaN from there)"]
    plt.close(fig)


def test_a_long_title_wraps_inside_its_axes() -> None:
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(8, 3), constrained_layout=True)
    long = ("input-residual cross-correlation (prewhitened): peak 0.143 at 0.645 s, p = 1.2e-5 on "
            "a recording with a long name run_bag[6930:9900]")
    fit_title(a1, long)
    fit_title(a2, "short title")
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    assert "\n" in a1.title.get_text() and a1.title.get_text().replace("\n", " ") == long
    assert a2.title.get_text() == "short title"
    assert a1.title.get_window_extent(renderer).width <= a1.get_window_extent(renderer).width + 1.0
    assert _inside(a1.title.get_window_extent(renderer), fig.bbox)
    plt.close(fig)


# --------------------------------------------------------------------------- gap report figures
def test_gap_tests_figure_title_has_short_numbers_and_fits(saved_figures) -> None:
    from aeropend_ident.gap.figures import fig_tests

    lags = np.arange(-50, 51)
    rec = SimpleNamespace(
        t=np.arange(2000) * 0.02, dt=0.02,
        whiteness={"acf": list(np.linspace(0.9, 0.1, 20)), "q": 1.3579e5, "p_value": 0.0},
        input_xcorr={"lags": list(lags), "rho": list(np.exp(-((lags - 32) / 5.0) ** 2) * 0.143),
                     "bound": 0.031, "peak_lag_s": np.longdouble("0.6450000000000000244"),
                     "max_abs": 0.14300000000001, "p_value": 1.234567e-5})
    png = fig_tests(SimpleNamespace(recordings=[rec]))
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    fig = saved_figures[-1]
    a1, a2 = fig.axes
    assert a1.get_title().replace("\n", " ") == "residual autocorrelation: Ljung-Box Q = 1.36e5, p = 0"
    assert a2.get_title().replace("\n", " ") == (
        "input-residual cross-correlation (prewhitened): peak 0.143 at 0.645 s, p = 1.23e-5")
    renderer = _renderer(fig)
    for ax in (a1, a2):  # nothing cut off: each title within its own axes' width and the figure
        box = ax.title.get_window_extent(renderer)
        assert box.width <= ax.get_window_extent(renderer).width + 1.0 and _inside(box, fig.bbox)


def _ranking(name: str, expl: float, conf: float) -> dict:
    return {"effect": name, "validation_explained": expl, "presence": conf}


def test_gap_effects_bars_are_horizontal_and_their_labels_do_not_overlap(saved_figures) -> None:
    from aeropend_ident.gap.figures import fig_effects

    eff = ["motor_time_constant", "viscous_friction", "actuator_lag"]
    validation = [{"effects": [], "nrmse": 0.0704}, {"effects": eff[:1], "nrmse": 0.0443},
                  {"effects": eff[:2], "nrmse": 0.0285}, {"effects": eff, "nrmse": 0.0199},
                  {"effects": eff, "nrmse": 0.0195, "refinement": True}]
    test = [{"effects": [], "nrmse": 0.0612}, {"effects": eff, "nrmse": 0.0440}]
    diag = SimpleNamespace(
        ranking=[_ranking("quantisation", 0.01, 1.0),
                 *(_ranking(n, 0.6 - 0.1 * k, 0.9) for k, n in enumerate(eff)),
                 _ranking("sensor_scale", 0.05, 0.0), _ranking("hbridge_drop", 0.04, 0.0)],
        validation=validation, chosen=eff, detected={"quantisation": {"theta_quantum": 0.0061}})
    fig_effects(SimpleNamespace(diagnosis=diag, test=test))
    fig = saved_figures[-1]
    a1, a2 = fig.axes
    ranked = [t.get_text() for t in a1.get_yticklabels()]
    assert ranked[-1] == "quantisation (detected)" and "viscous_friction (chosen)" in ranked
    # one horizontal bar per effect set, its length the NRMSE
    widths = sorted(p.get_width() for p in a2.patches)
    assert widths == pytest.approx(sorted(r["nrmse"] for r in validation + test))
    labels = a2.get_yticklabels()
    assert len(labels) == 7
    assert labels[0].get_text().startswith("validation: nominal")
    assert labels[4].get_text().endswith("(refinement)")
    assert labels[-1].get_text().replace("\n", " ") == (
        "held out: +motor_time_constant +viscous_friction +actuator_lag")
    renderer = _renderer(fig)
    boxes = [lab.get_window_extent(renderer) for lab in labels]
    for b1, b2 in itertools.combinations(boxes, 2):
        assert not b1.overlaps(b2)
    for box in boxes:
        assert _inside(box, fig.bbox)


def test_gap_overlay_clips_a_simulator_that_spins_away(saved_figures) -> None:
    from aeropend_ident.gap.figures import fig_overlay

    t = np.arange(0.0, 6.0, 0.002)
    theta = 0.7 + 0.3 * np.cos(1.3 * t)
    spin = np.minimum(1.12 + 3000.0 * t**2, 14.3)
    ov = {"source": "run_bag[6930:9900]", "t": t, "duty": np.full(t.size, 0.5), "theta": theta,
          "nominal": spin, "corrected": theta + 0.01,
          "metrics": {"nominal": {"nrmse": None, "diverges": "diverges at t = 0.022 s: θ → 14 rad"},
                      "corrected": {"nrmse": 0.0412}}}
    fig_overlay(SimpleNamespace(overlays=[ov]))
    ax = saved_figures[-1].axes[0]
    lo, hi = ax.get_ylim()
    assert lo < theta.min() and theta.max() < hi < theta.max() + np.ptp(theta)
    # no NRMSE of a run that left the recorded range (issue 60 item 4): the title says it diverges
    assert ax.get_title() == "run_bag[6930:9900]: nominal diverges -> corrected NRMSE 0.0412"
    # the note gives the divergence time of the one rule (θ beyond 1.0 + π/2 rad: 1.12 + 3000 t² = 2.571
    # at t = 0.022 s), not the earlier time it left the plotted range (0.01 s): one time in figure and table
    assert _texts(ax) == ["nominal simulator diverges at t = 0.022 s: θ → 14 rad"]
    assert _legend(ax) == ["recorded (held out)", "nominal simulator", "corrected simulator"]


# --------------------------------------------------------------------------- identify's free run
def test_free_run_names_every_line_and_uses_the_recording_time(tmp_path, saved_figures) -> None:
    t = np.arange(40.0, 72.0, 0.015)
    theta = 0.3 + 0.1 * np.sin(t)
    sim = theta + 0.01
    sim[t > 60.0] = np.nan  # the held-out free run diverges at 60 s
    plot_free_run(t, {"theta": theta}, {"theta": sim}, tmp_path / "free_run.png", t_split=50.52)
    ax = saved_figures[-1].axes[0]
    assert _legend(ax) == ["measured", "free run, training", "free run, held out",
                           "held-out start (t = 50.52 s)"]
    x0, x1 = ax.get_xlim()
    assert x0 < 40.0 < 72.0 < x1 and x0 > 38.0  # the recording's own time, not re-based to 0
    assert ax.get_xlabel() == "t [s] (recording time)"
    assert _texts(ax) == ["free run, held out diverges at t = 60 s (NaN from there)"]


def test_titles_name_the_recording_by_its_file() -> None:
    from aeropend_ident.sindy.plots import source_label

    assert source_label("reports/main/run_bag+d/dt(savgol)[7425:9900]") == "run_bag[7425:9900]"
    assert source_label("/x/Identification_Data.csv[3368:4812]") == "Identification_Data.csv[3368:4812]"
    assert source_label("synthetic seed 3") == "synthetic seed 3"


@pytest.mark.slow
@needs_real
@pytest.mark.real_data
def test_identify_free_run_and_derivatives_share_the_recording_time(tmp_path, monkeypatch,
                                                                     saved_figures) -> None:
    from aeropend_ident.cli.identify import main as identify_main
    from aeropend_ident.sindy import identify

    monkeypatch.setattr(identify.os, "cpu_count", lambda: 1)  # draw every plot in this process
    rc = identify_main([str(AEROSHIELD), "--preset", "aeroshield_ident", "--rig", "aeroshield_rig",
                        "--train-fraction", "0.7", "--out", str(tmp_path)])
    assert rc == 0
    free = next(f for f in saved_figures if any("free run" in t for a in f.axes for t in _legend(a)))
    deriv = next(f for f in saved_figures
                 if f.axes and f.axes[0].get_title().startswith("held-out derivatives"))
    ax_free, ax_der = free.axes[0], deriv.axes[0]
    legend = _legend(ax_free)
    assert legend[:3] == ["measured", "free run, training", "free run, held out"]
    split = float(re.fullmatch(r"held-out start \(t = ([\d.]+) s\)", legend[3]).group(1))
    # the held-out part starts at 70 % of the 72 s log, in the recording's time, in both figures
    held_x = np.concatenate([line.get_xdata() for line in ax_free.get_lines()
                             if line.get_label() == "free run, held out"])
    der_x = ax_der.get_lines()[0].get_xdata()
    assert split == pytest.approx(50.5, abs=0.1)
    assert held_x.min() == pytest.approx(der_x.min(), abs=0.02)
    assert held_x.max() == pytest.approx(der_x.max(), abs=0.02)
    assert ax_free.get_xlabel() == ax_der.get_xlabel() == "t [s] (recording time)"


# --------------------------------------------------------------------------- baseline, real rig
@needs_real
@pytest.mark.real_data
def test_baseline_draws_the_spinning_nominal_model_clipped_with_a_note(tmp_path, saved_figures) -> None:
    from aeropend_ident.cli.baseline import main as baseline_main

    rc = baseline_main([str(ETCHEPAREBORDA), "--preset", "etchepareborda_openloop", "--rig",
                        "etchepareborda_rig", "-o", str(tmp_path)])
    assert rc == 0 and (tmp_path / "overlay.png").is_file()
    ax = saved_figures[-1].axes[0]
    recorded = np.concatenate([line.get_ydata() for line in ax.get_lines() if line.get_color() == "black"])
    lo, hi = ax.get_ylim()
    assert lo < np.nanmin(recorded) and hi > np.nanmax(recorded)
    assert np.ptp(recorded) / (hi - lo) > 0.4  # not flattened into a line
    notes = [t for t in _texts(ax) if t.startswith("nominal model diverges")]
    assert len(notes) == 1
    # the overlay's warning says the same for the held-out part, where no NRMSE is given
    (warning,) = [t for t in _texts(ax) if t.startswith("WARNING")]
    assert "nominal model diverges" in warning and "no NRMSE is given" in warning
    m = re.fullmatch(r"nominal model diverges at t = ([\d.]+) s: θ → ([\d.]+)e3 rad",
                     notes[0])
    assert m and 0.0 < float(m.group(1)) < 20.0 and float(m.group(2)) > 1.0
    assert _legend(ax) == ["recorded", "nominal model", "fitted model"]
    assert "e+0" not in ax.get_title()


# --------------------------------------------------------------------------- a figure never costs a result
def _simulated(rig_name: str, seconds: float, channels=("theta",)):
    from aeropend_sim.excitation import aprbs
    from aeropend_sim.params import load_rig
    from aeropend_sim.recording import Recording
    from aeropend_sim.simulation import simulate

    rig = load_rig(rig_name)
    sig = aprbs(seconds, lo=0.03, hi=0.3, min_hold=1.0, max_hold=3.0, seed=5, dt=rig.sample_period)
    duty = np.concatenate([np.zeros(20), sig.duty])
    return Recording.from_trajectory(simulate(rig, duty), channels=channels, source="simulated")


def test_baseline_writes_its_report_when_the_figure_fails(tmp_path, monkeypatch, capsys) -> None:
    import json

    from aeropend_ident.cli.baseline import main as baseline_main
    from aeropend_ident.greybox import baseline
    from aeropend_ident.io.bag_writer import write_bag

    def broken(*_a, **_k):
        raise RuntimeError("no display of any kind")

    monkeypatch.setattr(baseline, "plot_overlay", broken)
    bag = write_bag(_simulated("aeroshield_rig", 20.0), tmp_path / "bag")
    assert baseline_main([str(bag), "--rig", "aeroshield_rig", "-o", str(tmp_path / "out")]) == 0
    rep = json.loads((tmp_path / "out" / "report.json").read_text())
    assert rep["not_computed"] == {"figure overlay": "RuntimeError: no display of any kind"}
    assert rep["parameters"] and (tmp_path / "out" / "fitted_rig.yaml").is_file()
    out = capsys.readouterr().out
    assert "NOT COMPUTED: figure overlay: RuntimeError: no display of any kind" in out
    assert "overlay: not drawn" in out


@pytest.mark.slow
def test_identify_writes_its_model_and_summary_when_a_plot_fails(tmp_path, monkeypatch, capsys) -> None:
    import json

    from aeropend_ident.cli.identify import main as identify_main
    from aeropend_ident.io.bag_writer import write_bag
    from aeropend_ident.sindy import identify, plots

    def broken(*_a, **_k):
        raise ValueError("free run has no finite sample")

    monkeypatch.setattr(identify.os, "cpu_count", lambda: 1)
    monkeypatch.setattr(plots, "plot_free_run", broken)
    bag = write_bag(_simulated("thesis_rig", 20.0, ("theta", "i_a", "v_a", "omega_rotor")), tmp_path / "bag")
    assert identify_main([str(bag), "--rig", "thesis_rig", "--out", str(tmp_path / "out"), "--quiet"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["not_computed"] == {"plots": "ValueError: free run has no finite sample"}
    assert (tmp_path / "out" / "model.yaml").is_file() and summary["equations"]
    assert "NOT COMPUTED: plots: ValueError: free run has no finite sample" in capsys.readouterr().out


def test_a_model_off_by_tenths_of_a_radian_is_an_error_not_a_divergence() -> None:
    """The main job's held-out step moves 0.59 → 0.80 rad (span 0.21) and the nominal rig settles near
    0.32 rad: more than one span away, yet a finite error to score (an NRMSE), not a divergence. A
    rod that goes over the top (a quarter turn beyond the recorded range) diverges."""
    from aeropend_ident.io.overlay_axes import MIN_DIVERGENCE_RAD, divergence_window, diverges

    t = np.linspace(0.0, 3.0, 301)
    recorded = 0.59 + 0.21 * (1.0 - np.exp(-3.0 * t))
    assert diverges(np.full_like(t, 0.32), recorded, t) is None
    lo, hi = divergence_window(recorded)
    assert lo == pytest.approx(0.59 - MIN_DIVERGENCE_RAD)
    assert hi == pytest.approx(0.80 + MIN_DIVERGENCE_RAD, abs=1e-3)
    over = np.where(t < 1.0, 0.6, 0.6 + 3.0 * (t - 1.0))  # spins past π from t = 1 s
    why = diverges(over, recorded, t)
    assert why is not None and "beyond the recorded range" in why and "quarter turn" in why
    # a wide recording keeps the span rule: one recorded span beyond [-0.2, 2.0] rad
    wide = np.linspace(-0.2, 2.0, 301)
    assert divergence_window(wide) == pytest.approx((-2.4, 4.2))
