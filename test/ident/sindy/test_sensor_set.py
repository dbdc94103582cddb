"""Identification with the rig's real sensor set: θ without θ̇ (issue 18).

The pendulum equation is fitted in the second-order weak form (θ̈ and θ̇ integrated onto the test
functions) from the recorded angle alone, with the physics-structured library (no direct i_a or
v_a in θ̈). Truth: the independent plant ``bench/fixtures/truth_plant.py`` (no aeropend code) driven by
``density_prbs`` (120 s, seed 5), noise σ = RMS/10^(SNR/20) on θ, i_a, v_a, ω₁; no θ̇ channel.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from aeropend_ident.errors import IdentificationError
from aeropend_ident.sindy.libraries import lagged_square, pendulum_library, physics_structured_library
from aeropend_ident.sindy.model import IdentData
from aeropend_ident.sindy.second_order import fit_pendulum
from aeropend_ident.sindy.weak_quadrature import SecondOrderTestFunctions
from aeropend_sim.excitation import density_modulated_prbs
from bench.fixtures import truth_plant as tp
from bench.fixtures.truth_rig import lab_rig_doc, write_rig

#: One worker runs this module: its module fixture (a 120 s truth run, 4.6 s) was made again on every
#: worker that got one of its tests (docs/testing.md, Groups).
pytestmark = [pytest.mark.xdist_group("test_sensor_set"), pytest.mark.slow]

P = tp.PlantParams()
#: The true pendulum equation from the truth plant's physical parameters.
TRUE_PENDULUM = {"θ̇": -P.c_over_J, "sin(θ)": -P.mgd_over_J, "ω₁²": P.L_over_J * P.K_q * tp.GEAR**2}


@pytest.fixture(scope="module")
def truth_run() -> dict[str, np.ndarray]:
    """Noise-free response of the independent plant to density_prbs 120 s (seed 5)."""
    return tp.TruthPlant().simulate(density_modulated_prbs(120.0, seed=5).duty)


def _training(true: dict[str, np.ndarray], snr: float, seed: int) -> IdentData:
    """First 75 % of the record as the rig's sensors give it: θ, i_a, v_a, ω₁ (no θ̇), noisy."""
    meas = tp.add_noise(true, snr, seed)
    n = int(0.75 * true["t"].size)
    return IdentData(t=true["t"][:n], variables={**{k: meas[k][:n] for k in tp.CHANNELS},
                                                 "duty": true["duty"][:n]}, source=f"truth {snr:g} dB")


def test_second_order_weights_integrate_derivatives_by_parts():
    """∫φ''·x = ∫φ·ẍ and −∫φ'·x = ∫φ·ẋ for x = sin(3t) + 0.2t² sampled at 490 Hz."""
    t = np.arange(0.0, 10.0, 2.048e-3)
    x, xd, xdd = np.sin(3 * t) + 0.2 * t**2, 3 * np.cos(3 * t) + 0.4 * t, -9 * np.sin(3 * t) + 0.4
    tf = SecondOrderTestFunctions(t, K=40, p=4, H_xt=0.2)
    scale = np.abs(tf.integrate(xdd)).max()
    assert np.abs(tf.acceleration(x) - tf.integrate(xdd)).max() < 1e-4 * scale
    assert np.abs(tf.rate(x) - tf.integrate(xd)).max() < 1e-5 * np.abs(tf.integrate(xd)).max()
    with pytest.raises(ValueError, match="p >= 2"):
        SecondOrderTestFunctions(t, K=40, p=1, H_xt=0.2)


def test_lagged_square_has_no_noise_bias():
    """E[(ω + e)²] = ω² + σ²; the neighbour product's mean is ω² (σ = 10 % of ω here)."""
    rng = np.random.default_rng(0)
    w = 4.0 + np.sin(np.linspace(0.0, 20.0, 200_000))
    noisy = w + 0.4 * rng.standard_normal(w.size)
    cand = lagged_square("omega_rotor")
    plain = cand.func({"omega_rotor": noisy}).mean() / (w**2).mean() - 1.0
    lagged = cand.regressor({"omega_rotor": noisy}).mean() / (w**2).mean() - 1.0
    assert plain == pytest.approx(0.16 / (w**2).mean(), rel=0.05)  # the σ² bias, ≈ 1 %
    assert abs(lagged) < 1e-3


def test_physics_structured_library_keeps_i_a_and_v_a_out_of_the_pendulum():
    libs = physics_structured_library()
    assert set(libs) == {"theta_dot", "i_a", "omega_rotor"}
    assert libs["theta_dot"].names == ["θ̇", "sin(θ)", "ω₁²", "sgn(θ̇)"]
    assert not {"i_a", "v_a"} & set(libs["theta_dot"].variables)
    assert libs["i_a"].names == ["i_a", "ω₁", "v_a"]
    assert libs["omega_rotor"].names == ["i_a", "ω₁", "ω₁²"]
    assert "theta_dot" not in physics_structured_library(("theta", "i_a", "v_a"))  # no ω₁: no thrust


@pytest.mark.parametrize("snr, seed, kq_tol, coef_tol", [(30.0, 1, 0.015, 0.015), (30.0, 2, 0.015, 0.015),
                                                         (20.0, 1, 0.05, 0.05)])
def test_pendulum_from_angle_alone(truth_run, snr, seed, kq_tol, coef_tol):
    """θ̈ from θ and ω₁ only: structure exact (friction candidate pruned), K_q and every coefficient
    close (measured: 30 dB seeds 1/2 K_q +0.10 / −0.43 %, 20 dB seed 1 −0.44 %; the issue's bar is
    5 % at 30 dB and 10 % at 20 dB); λ chosen by BIC from the grid and reported."""
    fit = fit_pendulum(_training(truth_run, snr, seed))
    terms = fit.model.terms("theta_dot")
    assert set(terms) == set(TRUE_PENDULUM), fit.model.equations()
    for name, c in TRUE_PENDULUM.items():
        assert terms[name] == pytest.approx(c, rel=kq_tol if name == "ω₁²" else coef_tol), name
    assert fit.threshold in [s["threshold"] for s in fit.sweep]
    assert min(fit.sweep, key=lambda s: s["bic"])["bic"] == pytest.approx(
        next(s["bic"] for s in fit.sweep if s["threshold"] == fit.threshold))


def test_pendulum_refuses_a_rod_that_never_moves(truth_run):
    n = 20_000
    data = IdentData(t=truth_run["t"][:n], variables={"theta": np.zeros(n), "omega_rotor": np.full(n, 3.0)})
    with pytest.raises(IdentificationError, match="rank deficient"):
        fit_pendulum(data, pendulum_library(friction=False))


@pytest.mark.slow
def test_identify_csv_of_the_rig_sensor_set_30db(truth_run, tmp_path, truth_csv_preset):
    """A lab's path: truth-plant CSV (θ, i_a, v_a, ω₁; no θ̇) -> csv_import -> identify --method weak-iv
    with the default physics-structured library: no spurious i_a / ω₁ / v_a in θ̈ (today's estimator
    put −724 i_a + 26.8 ω₁ + 15.7 v_a there and K_q −10 %), all three structures exact, K_q within
    1.5 % and the rotor equation within 1 % (measured +0.11 %, −0.33 %, −0.32 %). The output-error
    step (bench/bench_ident_sensor_set.py) is left out: on 88 200 samples its Jacobian SVD alone
    exceeded the 600 s test timeout on the loaded 2-core machine."""
    import yaml

    from aeropend_ident.cli.identify import main

    rec = tp.record(tp.TruthPlant(), truth_run["duty"], 30.0, seed=1)
    rec.to_csv(tmp_path / "log.csv")
    preset = truth_csv_preset("_sensor_set_test")
    write_rig(lab_rig_doc(), tmp_path / "rig.yaml")
    out = tmp_path / "res"
    assert main([str(tmp_path / "log.csv"), "--preset", preset, "--rig", str(tmp_path / "rig.yaml"),
                 "--method", "weak-iv", "--no-plots", "--quiet", "--out", str(out)]) == 0
    doc = yaml.safe_load((out / "model.yaml").read_text(encoding="utf-8"))
    eqs = {tg: {n: e["coefficient"] for n, e in v["terms"].items()} for tg, v in doc["equations"].items()}
    assert set(eqs["theta_dot"]) == {"θ̇", "sin(θ)", "ω₁²"}
    assert set(eqs["i_a"]) == {"i_a", "ω₁", "v_a"}
    assert set(eqs["omega_rotor"]) == {"i_a", "ω₁"}
    assert doc["derived_parameters"]["K_q"]["value"] == pytest.approx(P.K_q, rel=0.015)
    assert eqs["omega_rotor"]["i_a"] == pytest.approx(P.K_t / P.J_m, rel=0.01)
    assert eqs["omega_rotor"]["ω₁"] == pytest.approx(-P.B_m / P.J_m, rel=0.01)
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["pendulum"]["threshold"] in [s["threshold"] for s in summary["pendulum"]["sweep"]]
    assert summary["heldout"][0]["nrmse_range"] < 0.03
