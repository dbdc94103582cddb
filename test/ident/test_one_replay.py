"""One rig on one recording: one free run and one θ figure in every command (issue 60, item 1).

``compare``, ``rig check``, ``rig fit``, ``baseline``, ``gap`` and ``gap-batch`` replay a rig file on
a recording through :func:`aeropend_ident.greybox.replay.free_run`. Before, each had its own start
(one sample and zero rate, a smoothed start refined per rig, the fit's own start values), so the
issue's user read 0.405, 0.4047 and "diverges at 3.1 s" for one rig on one recording. Here the rig
``rig fit`` writes from a recording is replayed on that recording by every command's entry point
(the mains, reading the figure each writes; ``rig check`` prints it only, to 4 decimals) and the
figures agree to 1e-9; a rig whose thrust spins the rod over the top gets no figure anywhere, only
the divergence time.

The recordings are simulated (thesis rig with rod friction and sensor noise, angle only, 100 Hz),
as in test/ident/cli/test_gap.py.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from aeropend_ident.cli.baseline import main as baseline_main
from aeropend_ident.cli.compare import main as compare_main
from aeropend_ident.cli.gap import main as gap_main
from aeropend_ident.cli.gap_batch import diagnose_session
from aeropend_ident.cli.rig import main as rig_main
from aeropend_ident.gap.batch import Session, SessionCase, drift_markdown
from aeropend_ident.greybox.replay import START_WINDOW, free_run, initial_state
from aeropend_ident.greybox.rig_check import check_rig
from aeropend_ident.greybox.rig_fit import fit_rig
from aeropend_ident.io.bag_writer import write_bag
from aeropend_sim.excitation import aprbs
from aeropend_sim.params import TO_BE_FITTED, load_rig, rig_to_dict
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import simulate

DT = 0.01
NOMINAL = load_rig("thesis_rig")
REAL = NOMINAL.with_effects(coulomb_friction=True, sensor_noise=True).with_params("pendulum",
                                                                                  coulomb_over_J=0.5)


def _recording(seed: int, duration: float) -> Recording:
    d = aprbs(duration, lo=0.3, hi=0.8, min_hold=0.3, max_hold=1.5, seed=seed, dt=DT).duty.copy()
    d[:50] = 0.0
    return Recording.from_trajectory(simulate(REAL, d, dt=DT, seed=seed), channels=("theta",),
                                     source=f"synthetic seed {seed}")


def _quiet(fn, *args, **kwargs):
    """Call ``fn`` with stdout captured: (its result, the text it printed)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        out = fn(*args, **kwargs)
    return out, buf.getvalue()


@pytest.fixture(scope="module")
def case(tmp_path_factory) -> dict:
    """Two bags and the rig ``rig fit`` writes from the second (its damping c/J left to fit)."""
    root = tmp_path_factory.mktemp("one_replay")
    fit_bag = write_bag(_recording(1, 16.0), root / "fit", rig_name="thesis_rig")
    rec_bag = write_bag(_recording(2, 12.0), root / "rec", rig_name="thesis_rig")
    doc = rig_to_dict(NOMINAL)
    doc["name"] = "lab_rig"
    doc["pendulum"]["c_over_J"]["source"] = TO_BE_FITTED
    start = root / "start.yaml"
    start.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    fitted = root / "fitted.yaml"
    assert _quiet(rig_main, ["fit", str(start), str(rec_bag), "-o", str(fitted), "-q"])[0] == 0
    return {"root": root, "fit": fit_bag, "rec": rec_bag, "rig": fitted, "start": start}


def _compare(rig: Path, rec: Path, out: Path) -> dict:
    assert _quiet(compare_main, [str(rec), "--rig", str(rig), "-o", str(out), "--no-plots"])[0] == 0
    doc = json.loads((out / "compare.json").read_text(encoding="utf-8"))
    (scores,) = doc["scores"].values()
    (one,) = scores.values()
    return one


def _baseline(rig: Path, fit: Path, rec: Path, out: Path) -> dict:
    assert _quiet(baseline_main, [str(fit), "--held-out", str(rec), "--rig", str(rig), "-o", str(out),
                                  "--params", "pendulum.c_over_J"])[0] == 0
    return json.loads((out / "report.json").read_text(encoding="utf-8"))


def _gap(rig: Path, fit: Path, rec: Path, out: Path) -> tuple[dict, str]:
    rc, text = _quiet(gap_main, [str(fit), "--held-out", str(rec), "--rig", str(rig), "-o", str(out), "-q",
                                 "--no-oracle", "--max-effects", "1"])
    assert rc == 0
    return json.loads((out / "report.json").read_text(encoding="utf-8"))["headline"], text


@pytest.mark.slow
def test_one_rig_on_one_recording_gives_one_figure_in_every_command(case) -> None:
    root, rig, rec = case["root"], case["rig"], case["rec"]
    # rig fit: the fitted rig's figure on the recording it was fitted to
    res, _ = _quiet(fit_rig, case["start"], [str(rec)])
    (fit_fig,) = res.nrmse.values()
    assert fit_fig is not None and 0.0 < fit_fig < 0.5
    # compare: compare.json
    cmp = _compare(rig, rec, root / "cmp")
    figures = {"rig fit": fit_fig, "compare": cmp["channels"]["theta"]["nrmse"]}
    # baseline: the nominal (the rig file as given) on the held-out recording, report.json
    base = _baseline(rig, case["fit"], rec, root / "base")
    figures["baseline"] = base["metrics"]["heldout"]["nominal"]["nrmse"]
    # gap: the nominal rig's held-out figure, report.json's headline; gap-batch: its session row
    head, text = _gap(rig, case["fit"], rec, root / "gap")
    figures["gap"] = head["heldout_nrmse_nominal"]
    row = diagnose_session(SessionCase(Session("s1", (str(case["fit"]),), (str(rec),)), str(rig),
                                       str(root / "batch"), ["--no-oracle", "--max-effects", "1"]))
    figures["gap-batch"] = row["nrmse_before"]
    ref = figures["compare"]
    assert all(abs(v - ref) <= 1e-9 for v in figures.values()), figures
    # rig check prints the figure (4 decimals) and the start, the same line as rig fit's summary
    line = next(ln for ln in check_rig(rig, [str(rec)]).splitlines() if ln.startswith("free-run θ on"))
    assert f"NRMSE {ref:.4f} (start: θ₀ = " in line
    assert line.split(": ", 1)[1] in res.summary()
    # the start is the one rule's, stated in every report
    s = cmp["free_run"]["initial_state"]
    for other in (base["metrics"]["heldout"]["nominal"]["initial_state"],
                  head["heldout_free_run"]["nominal"][0]["initial_state"]):
        assert other["rule"] == s["rule"] and other["samples"] == s["samples"] == 10
        assert all(other[k] == pytest.approx(s[k], abs=1e-12) for k in ("theta0", "theta_dot0", "duty0"))
    assert f"{s['theta0']:.3g}"[:4] in line and "; free-run start " in text
    assert f"{ref:.4g}" in drift_markdown([row], None)


def test_the_start_is_the_recordings_own_quadratic_fit() -> None:
    """θ₀, θ̇₀: a quadratic through the first START_WINDOW seconds; the same for every rig."""
    t = np.arange(300) * DT
    theta = 0.3 + 0.5 * t - 0.8 * t**2 + 0.2 * np.sin(3.0 * t) * 0.0
    duty = np.full(t.size, 0.45)
    a = initial_state(NOMINAL, theta, duty, DT)
    b = initial_state(load_rig("thesis_sim"), theta, duty, DT)
    assert a.samples == round(START_WINDOW / DT)
    assert a.theta0 == pytest.approx(0.3, abs=1e-12) and a.theta_dot0 == pytest.approx(0.5, abs=1e-9)
    assert (a.theta0, a.theta_dot0) == (b.theta0, b.theta_dot0)
    assert a.theta0_sd == pytest.approx(0.0, abs=1e-12)  # a noise-free record: no uncertainty
    noisy = theta + np.random.default_rng(0).normal(0.0, 0.01, t.size)
    c = initial_state(NOMINAL, noisy, duty, DT)
    assert 0.002 < c.theta0_sd < 0.01 and c.theta_dot0_sd > c.theta0_sd / START_WINDOW
    # the rig's frame: θ_model = θ_rec / scale + offset
    d = initial_state(NOMINAL, theta, duty, DT, theta_offset=0.1, theta_scale=2.0)
    assert d.x[0] == pytest.approx(0.3 / 2.0 + 0.1) and d.x[1] == pytest.approx(0.25)


def test_a_free_run_that_spins_over_the_top_has_no_nrmse_only_its_divergence_time() -> None:
    t = np.arange(1000) * DT
    duty = np.where(t < 2.0, 0.3, 0.9)
    rec = simulate(NOMINAL, duty, dt=DT)
    strong = NOMINAL.with_params("thrust", K_q=NOMINAL.thrust.K_q * 6.0)
    run = free_run(strong, t, duty, rec.theta)
    assert run.nrmse is None and run.diverged
    lo, hi = float(np.min(rec.theta)), float(np.max(rec.theta))
    bound = hi + max(hi - lo, np.pi / 2)
    k = int(np.argmax(run.theta > bound))  # the first sample beyond the window
    assert run.diverged_at == pytest.approx(t[k]) and run.theta[k - 1] <= bound
    assert run.figure().startswith(f"DIVERGES: diverges at t = {run.diverged_at:.3g} s")
    same = free_run(NOMINAL, t, duty, rec.theta)
    assert same.nrmse is not None and same.nrmse < 0.05 and same.diverged_at is None


@pytest.fixture(scope="module")
def strong(case) -> Path:
    """The fitted rig with 4× its thrust: the rod spins over the top on the recording."""
    doc = yaml.safe_load(case["rig"].read_text(encoding="utf-8"))
    doc["thrust"]["K_q"]["value"] *= 4.0
    path = case["root"] / "strong.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    return path


def _diverges_at(text: str) -> float:
    return float(re.search(r"diverges at t = ([0-9.e+-]+) s", text).group(1))


def test_compare_shows_no_figure_for_a_diverging_run(case, strong) -> None:
    one = _compare(strong, case["rec"], case["root"] / "cmp_strong")
    th = one["channels"]["theta"]
    assert th["nrmse"] is None and th["fit_percent"] is None
    assert _diverges_at(th["diverges"]) == pytest.approx(one["free_run"]["diverged_at"], rel=1e-3)


def test_rig_check_and_rig_fit_show_no_figure_for_a_diverging_run(case, strong) -> None:
    text = check_rig(strong, [str(case["rec"])])
    line = next(ln for ln in text.splitlines() if ln.startswith("free-run θ on"))
    assert "DIVERGES: diverges at t = " in line and "NRMSE" not in line
    doc = yaml.safe_load(strong.read_text(encoding="utf-8"))
    doc["pendulum"]["c_over_J"]["source"] = TO_BE_FITTED
    start = case["root"] / "strong_start.yaml"
    start.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    res, _ = _quiet(fit_rig, start, [str(case["rec"])])
    (fig,) = res.nrmse.values()
    if fig is None:  # the fit cannot tame 4× thrust with the damping alone
        (why,) = res.divergence.values()
        assert "NRMSE" not in next(ln for ln in res.summary().splitlines() if why in ln)


def test_baseline_shows_no_figure_for_a_diverging_run(case, strong) -> None:
    base = _baseline(strong, case["fit"], case["rec"], case["root"] / "base_strong")
    nom = base["metrics"]["heldout"]["nominal"]
    assert nom["nrmse"] is None and nom["diverged_at_s"] > 0.0
    assert any("nominal model diverges at t = " in w for w in base["warnings"])


@pytest.mark.slow
def test_gap_and_gap_batch_show_no_figure_for_a_diverging_run(case, strong) -> None:
    head, text = _gap(strong, case["fit"], case["rec"], case["root"] / "gap_strong")
    assert head["heldout_nrmse_nominal"] is None and head["heldout_shrink"] is None
    assert "nominal" in head["heldout_divergence"] and "no NRMSE or shrink figure" in text
    session = Session("s2", (str(case["fit"]),), (str(case["rec"]),))
    row = diagnose_session(SessionCase(session, str(strong), str(case["root"] / "batch_strong"),
                                       ["--no-oracle", "--max-effects", "1"]))
    assert row["nrmse_before"] is None
    assert "diverges →" in drift_markdown([row], None)


def _held_decay(hold: float, theta0: float = 1.2, seconds: float = 8.0, seed: int = 3) -> tuple:
    """A free decay (τ = 0) of the thesis rig from rest at ``theta0``, after ``hold`` s held there;
    θ with white noise σ = 3 mrad: (t, duty, θ, the noise-free decay)."""
    n = round(seconds / DT)
    duty = np.zeros(n)
    free = simulate(NOMINAL, duty, x0=np.array([theta0, 0.0, 0.0, 0.0, 0.0]), dt=DT).theta
    k = round(hold / DT)
    clean = np.concatenate([np.full(k, theta0), free])
    noisy = clean + np.random.default_rng(seed).normal(0.0, 0.003, clean.size)
    return np.arange(clean.size) * DT, np.zeros(clean.size), noisy, clean


def test_a_rod_held_then_released_is_replayed_from_its_release() -> None:
    """A constant-command log that begins with the rod held (cychitivav's free swing: 1.6 s at 83°
    before the release) is replayed from the release; from t = 0 the same rig is a swing out of phase."""
    t, duty, theta, _ = _held_decay(1.5)
    run = free_run(NOMINAL, t, duty, theta)
    assert run.initial.released_at == pytest.approx(1.5, abs=0.05)
    assert "rod at rest until t = 1.5" in run.initial.describe()
    assert run.nrmse is not None and run.nrmse < 0.02
    assert run.theta.shape == t.shape and np.allclose(run.theta[:100], run.initial.theta0)
    # scored from the release: the held head (error ≈ the noise) does not dilute the figure
    k = round(run.initial.released_at / DT)
    assert run.nrmse == pytest.approx(float(np.sqrt(np.mean((run.theta[k:] - theta[k:]) ** 2)))
                                      / float(np.ptp(theta[k:])), rel=1e-12)
    # released at once (a swing's peak) or a command that changes: no hold
    t0, duty0, theta0, _ = _held_decay(0.0)
    assert free_run(NOMINAL, t0, duty0, theta0).initial.released_at == 0.0
    steps = duty.copy()
    steps[300:] = 0.5
    assert free_run(NOMINAL, t, steps, theta).initial.released_at == 0.0


def test_the_noise_of_a_log_written_in_bursts_is_its_measured_noise() -> None:
    """A logger that writes 10 samples, then nothing for 25 grid steps: the samples filled on straight
    lines between the bursts are not measurements (they read as noiseless: θ₀ ± 2e-17 rad)."""
    from aeropend_ident.greybox.fit import measurement_noise
    t, _, theta, _ = _held_decay(0.0, seconds=20.0)
    filled = theta.copy()
    for a in range(10, t.size, 35):
        b = min(a + 25, t.size - 1)
        filled[a:b] = np.interp(t[a:b], [t[a - 1], t[b]], [theta[a - 1], theta[b]])
    sigma = measurement_noise(filled)
    assert 0.0025 < sigma < 0.0036, sigma  # σ = 3 mrad: 9 % of the noise's second differences span gaps


@pytest.mark.slow
def test_rig_fit_fits_a_held_decay_from_its_release(tmp_path) -> None:
    """``rig fit`` on that log: the rod's time scale and damping from the swing after the release
    (from t = 0 the output error's best constant rod was a slow, damped one: mgd/J 3.17 for 54.5)."""
    t, duty, theta, _ = _held_decay(1.5, seconds=10.0)
    bag = write_bag(Recording(t=t, duty=duty, channels={"theta": theta}, source="held decay"),
                    tmp_path / "decay", rig_name="thesis_rig")
    doc = rig_to_dict(NOMINAL)
    doc["name"] = "lab_rig"
    for key in ("mgd_over_J", "c_over_J"):
        doc["pendulum"][key]["source"] = TO_BE_FITTED
        doc["pendulum"][key]["value"] *= 0.5
    start = tmp_path / "start.yaml"
    start.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    result = fit_rig(start, [str(bag)])
    got = {o.key: o for o in result.outcomes}
    for key in ("mgd_over_J", "c_over_J"):
        o = got[f"pendulum.{key}"]
        truth = getattr(NOMINAL.pendulum, key)
        assert o.status == "fitted" and abs(o.value - truth) <= max(3.0 * o.std, 0.02 * truth), (key, o)
    (run,) = result.runs.values()
    assert run.initial.released_at == pytest.approx(1.5, abs=0.05) and run.nrmse < 0.02
