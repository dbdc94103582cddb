"""A quantised angle is data, not an effect to fit (issue 34, item 7).

The thesis rig's acquisition (and the simulated plant with noise on) records θ through a 10-bit
ADC: every angle lies on a lattice of step q = 2π/1024. The gap diagnosis detects that quantum
from the recorded values; it must then *describe* the recording with it (the corrected rig's
sensor LSB, the noise floor q/√12) and never hand it to a fit: the attainable-shrink step refits
the chosen effects on each held-out recording, and it used to fail there with
"effect(s) ['quantisation'] are detected from the data, not fitted", losing the whole report.
The main job's own bag is checked end to end in ``test_gap_main_bag.py``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from aeropend_ident.errors import GapError
from aeropend_ident.gap.drift import noise_floor
from aeropend_ident.gap.effects import EffectContext, detect_quantum, measurement_noise
from aeropend_ident.gap.sessions import attainable
from aeropend_ident.gap.which.data import prepare
from aeropend_ident.gap.which.diagnosis import diagnose_effects
from aeropend_ident.gap.which.fitting import fit_effects
from aeropend_ident.greybox.fit import noise_level
from aeropend_sim.params import load_rig
from bench.fixtures.gap_synth import make_case

RIG = load_rig("thesis_rig")
Q = 0.015  # rad: a coarse angle LSB, far above the rig file's (quantisation off in it)
pytestmark = pytest.mark.xdist_group("test_quantised")  # its module fixture is made once, by one worker


@pytest.fixture(scope="module")
def quantised():
    """A synthetic angle-only recording of the thesis rig quantised to Q, and its diagnosis."""
    case = make_case(RIG, ["quantisation"], 24, fit_duration=8.0, held_out_steps=3, channels=("theta",),
                     truth={"quantisation": {"theta_quantum": Q}}, snr_db=60.0)
    return case, diagnose_effects(RIG, case.fit, case.held_out, max_effects=2)


def test_detected_quantum_is_reported_never_chosen(quantised) -> None:
    _, d = quantised
    assert d.chosen == []  # nothing to fit: the plant itself is the nominal one
    assert d.detected == {"quantisation": {"theta_quantum": pytest.approx(Q, rel=1e-6)}}
    entry = d.ranking[0]
    assert entry["effect"] == "quantisation" and entry["detected"] is True
    assert "detected from the recorded values, not fitted" in d.reason
    # the corrected rig describes the sensor with it
    assert d.corrected_rig.effects.quantisation
    assert d.corrected_rig.sensors.theta_quantum == pytest.approx(Q, rel=1e-6)
    doc = json.loads(json.dumps(d.as_dict()))
    assert doc["detected"]["quantisation"]["theta_quantum"] == pytest.approx(Q, rel=1e-6)
    assert doc["chosen"] == []


def test_attainable_step_handles_a_detected_quantum(quantised) -> None:
    case, d = quantised
    rows = attainable(RIG, d, case.held_out, max_effects=2, best_set=True, fit=case.fit)
    assert len(rows) == len(case.held_out)
    for row, rec in zip(rows, case.held_out, strict=True):
        assert "oracle_drift_error" not in row and "oracle_best_error" not in row
        # the detected quantum is the noise floor: at least its rounding noise q/√12 over the range
        floor = Q / math.sqrt(12.0) / float(np.ptp(rec.channels["theta"]))
        assert row["noise_floor"] >= floor * (1.0 - 1e-9)
        # no dynamic effect was chosen: the corrected rig replays as the nominal one, and the gap
        # that is left is at the quantisation floor (the plant is the nominal rig)
        assert row["corrected"] == pytest.approx(row["nominal"], rel=1e-12)
        assert row["nominal"] < 1.5 * row["noise_floor"]
        assert row["oracle_best_effects"] == []  # the held-out diagnosis names no effect to fit either


def test_a_direct_effect_is_still_refused_by_the_fit(quantised) -> None:
    case, _ = quantised
    preps = prepare(case.fit, frozenset({"theta"}))
    ctx = EffectContext.from_data(RIG, case.fit[0].channels["theta"], case.fit[0].duty)
    with pytest.raises(GapError, match=r"\['quantisation'\] are detected from the data, not fitted"):
        fit_effects(RIG, ["quantisation"], preps, ctx)


def test_measurement_noise_is_at_least_the_rounding_noise_of_a_detected_quantum() -> None:
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 20.0, 0.002)
    slow = 0.4 + 0.3 * np.sin(0.2 * t)  # slow motion: most samples repeat the previous LSB
    q = 2.0 * math.pi / 1024.0
    y = np.round(slow / q) * q
    assert detect_quantum(y) == pytest.approx(q, rel=1e-9)
    assert noise_level(y) == 0.0  # the white-noise estimate alone reads a quantised log as noiseless
    assert measurement_noise(y) == pytest.approx(q / math.sqrt(12.0), rel=1e-9)
    # white noise above the LSB: the white noise dominates
    noisy = np.round((slow + rng.normal(0.0, 4.0 * q, t.size)) / q) * q
    assert measurement_noise(noisy) == pytest.approx(4.0 * q, rel=0.1)
    # not on a lattice: no quantum, plain white-noise estimate
    z = slow + rng.normal(0.0, 1e-3, t.size)
    assert detect_quantum(z) == 0.0 and measurement_noise(z) == noise_level(z)
    # the attainable step's floor uses the same estimate
    prep = prepare([_rec(t, y)], frozenset({"theta"}))[0]
    assert noise_floor(prep) == pytest.approx(q / math.sqrt(12.0) / float(np.ptp(y)), rel=1e-9)


def test_a_lattice_printed_with_a_few_decimals_is_still_a_lattice() -> None:
    # AeroShield's logs: a 1.534 mrad step written to 1e-6 rad, so that one-step gaps read 1.533 or
    # 1.534 mrad and the smallest gap's lattice drifts off the values within a few hundred steps
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 20.0, 0.004)
    q = 1.5339808e-3
    slow = 0.6 + 0.5 * np.sin(0.3 * t) + rng.normal(0.0, 0.3 * q, t.size)
    for decimals in (6, 5):
        y = np.round(np.round(slow / q) * q + 0.0123, decimals)
        assert detect_quantum(y) == pytest.approx(q, rel=2e-4)
        # the noise floor is the lattice's (q/√12 at least), where the MAD of Δ²θ read almost 0
        assert measurement_noise(y) >= q / math.sqrt(12.0) * (1 - 2e-4)
    # not lattices: a continuous channel held for five samples (fewer distinct values than a third),
    # and values on two steps at once (0.09° and 0.1°, a log that mixes two scalings)
    held = np.repeat(np.cumsum(rng.normal(0.0, 0.01, 2000)), 5)
    assert detect_quantum(held) == 0.0
    k = np.cumsum(rng.integers(1, 3, 600))
    mixed = np.where(np.arange(600) % 3 == 0, k * 0.0017453, k * 0.0015708)
    assert detect_quantum(np.repeat(np.round(mixed, 7), 4)) == 0.0


@pytest.mark.parametrize("rate", [50.0, 100.0, 490.0])
def test_the_noise_estimate_on_a_lattice_follows_the_noise_not_the_lattice(rate: float) -> None:
    # On a 10-bit lattice the second differences take the values k·q only, so their MAD snaps to
    # 0, q or 2q and 1.4826·MAD/√6 reads one of three values whatever the noise: 2.0× the true
    # noise RMS at σ = q/12 and 50 Hz, 0.9× at σ = 0.6 q. The estimate on a lattice follows σ.
    q = 2.0 * math.pi / 1024.0
    t = np.arange(0.0, 40.0, 1.0 / rate)
    clean = 0.4 + 0.3 * np.sin(0.2 * t) + 0.1 * np.sin(1.3 * t)
    ratios, mad_ratios, estimates = [], [], []
    for k in (1 / 12, 1 / 6, 1 / 3, 0.6, 1.0, 2.0):
        y = np.round((clean + np.random.default_rng(1).normal(0.0, k * q, t.size)) / q) * q
        true = float(np.sqrt(np.mean((y - clean) ** 2)))  # white noise and rounding together
        estimates.append(measurement_noise(y))
        ratios.append(estimates[-1] / true)
        mad_ratios.append(max(noise_level(y), q / math.sqrt(12.0)) / true)
    assert np.all(np.abs(np.array(ratios) - 1.0) <= 0.09), ratios
    assert max(abs(r - 1.0) for r in mad_ratios) >= 0.13  # the lattice-locked estimate it replaces
    assert np.all(np.diff(estimates) > 0.0)  # it rises with the noise (the MAD one is flat for σ ≤ q/3)


def _rec(t: np.ndarray, theta: np.ndarray):
    from aeropend_sim.recording import Recording

    return Recording(t=t, duty=np.full(t.size, 0.5), channels={"theta": theta}, source="lattice")


@pytest.mark.slow
def test_an_optional_section_that_fails_is_reported_and_the_report_is_written(quantised, tmp_path,
                                                                                monkeypatch) -> None:
    """No command fails after its main result exists: a failing optional section (here the attainable
    shrink, and one figure) is reported with its reason in the terminal, report.json and report.html."""
    from aeropend_ident.gap import figures, sessions
    from aeropend_ident.gap.report import terminal_summary, write_report
    from aeropend_ident.gap.run import run_gap

    case, _ = quantised

    def broken(*_a, **_k):
        raise GapError("held-out recording too short for the oracle fit")

    def broken_figure(*_a, **_k):
        raise ValueError("no residual to draw")

    monkeypatch.setattr(sessions, "attainable", broken)
    monkeypatch.setattr(figures, "fig_tests", broken_figure)
    res = run_gap(RIG, case.fit, case.held_out, predict=False, max_effects=1)
    assert res.attainable is None
    assert res.not_computed == {"attainable shrink": "held-out recording too short for the oracle fit"}
    assert res.headline()["detected"]["quantisation"]["theta_quantum"] == pytest.approx(Q, rel=1e-6)
    paths = write_report(res, tmp_path)
    doc = json.loads(paths["report"].read_text())
    assert doc["not_computed"] == {"attainable shrink": "held-out recording too short for the oracle fit",
                                   "figure tests": "ValueError: no residual to draw"}
    assert doc["after"]["attainable"] is None
    html = paths["html"].read_text()
    assert "figure tests not drawn: ValueError: no residual to draw" in html
    assert "<b>attainable shrink</b>: held-out recording too short" in html
    assert "Detected from the recorded values" in html and "theta_quantum = 0.015 rad" in html
    assert not (tmp_path / "figures" / "tests.png").exists() and paths["fig_overlay"].is_file()
    text = terminal_summary(res)
    assert "NOT COMPUTED: attainable shrink: held-out recording too short for the oracle fit" in text
    assert "detected from the recorded values (not fitted): quantisation (theta_quantum = 0.015 rad)" in text
    # the corrected rig file carries the quantum, with where it came from
    from aeropend_sim.params import load_rig as load

    rig = load(paths["corrected_rig"])
    assert rig.effects.quantisation and rig.sensors.theta_quantum == pytest.approx(Q, rel=1e-6)
    assert "detected from the recorded values" in paths["corrected_rig"].read_text()


def test_the_above_noise_margin_counts_the_holds_of_a_rounding_error() -> None:
    # white noise far below a lattice step: a rod holding still keeps one rounding error per hold,
    # so the mean square of the rounding error over k holds scatters by 0.894/√k of q²/12
    from types import SimpleNamespace

    from aeropend_ident.gap.which.context import ROUNDING_CHANCE_Z, _rounding_chance
    from aeropend_ident.gap.which.data import _noise_var

    rng = np.random.default_rng(4)
    q = 6.0e-3
    theta = rng.uniform(0.0, 1.0, (40_000, 4))
    e2 = np.mean((q * np.round(theta / q) - theta) ** 2, axis=1)
    assert np.std(e2) / np.mean(e2) == pytest.approx(0.894 / 2.0, rel=0.03)
    # four holds of equal length on neighbouring lattice values: four independent errors
    held = SimpleNamespace(y={"theta": np.repeat(np.arange(4) * q, 500)}, scale={"theta": 1.0})
    assert _noise_var(held.y["theta"]) == pytest.approx(q * q / 12.0, rel=1e-9)
    margin = _rounding_chance([held])["theta"]
    assert margin == pytest.approx(ROUNDING_CHANCE_Z * 0.894 / 2.0 * q * q / 12.0, rel=1e-3)
    # two such recordings: twice the noise part, its spread √2 as large
    assert _rounding_chance([held, held])["theta"] == pytest.approx(math.sqrt(2.0) * margin, rel=1e-9)
    # white noise (or a moving unquantised signal) changes at every sample: no rounding error held
    white = SimpleNamespace(y={"theta": rng.normal(0.0, 1e-3, 2000)}, scale={"theta": 1.0})
    assert _rounding_chance([white])["theta"] == 0.0


@pytest.mark.slow
def test_an_effect_free_closed_loop_holding_on_a_coarse_encoder_shows_no_gap() -> None:
    # Lab benchmark case 21: effect-free, closed loop without dither at 50 Hz, a 10-bit encoder
    # (q 6.1 mrad) over white noise of 0.4 mrad. Its nominal validation error was 1.43× its noise
    # part, over the 1.25 of a gap, and a voltage drop of -0.0016 V fitted to the holds' rounding
    # errors was chosen (presence 0.00). Its runs of one recorded value count 17 effective holds:
    # the rounding part's spread is 0.22 of it, and the error is at the noise floor.
    from bench import bench_gap_lab as lab

    spec, res = lab.diagnosed(21)
    assert spec["kind"] == "none" and spec["rate_hz"] == 50 and spec["quantiser"] == "encoder_10bit"
    d = res.diagnosis
    assert d.chosen == [] and not any(r.get("status") == "named" for r in d.ranking)
    assert "nominal validation error is at the noise floor" in d.reason
    assert "(closest: theta, 1.20× against 1.30×)" in d.reason
