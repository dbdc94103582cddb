"""SINDy, ensemble, weak and discrepancy SINDy on the thesis' simulated plant (thesis ch. 5) and Lorenz.

Ground truth: thesis_sim is exactly θ̈ = −13.82 θ̇ − 131.75 sin θ + 1.7285 ω₁²,
di_a/dt = −8.6957 i_a − 1.0217 ω₁ + 4.3478 v_a, dω₁/dt = 4519.1 i_a − 192.31 ω₁ (the equations
printed with thesis Figs. 5.3/5.4; K_t/J_m = 0.235/5.2001e-5 = 4519.14 in the rig file).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml
from scipy.integrate import solve_ivp

from aeropend_ident.errors import IdentificationError
from aeropend_ident.sindy.core import fit
from aeropend_ident.sindy.libraries import (
    collinearity_report,
    physics_library,
    structured_library,
    thesis_library,
)
from aeropend_ident.sindy.model import (
    IdentData,
    data_from_trajectory,
    free_run,
    model_derivatives,
    save_model,
    structure_errors,
)
from aeropend_ident.sindy.preprocess import add_derivatives
from aeropend_ident.sindy.sweep import select_threshold, sweep_threshold
from aeropend_sim.excitation import aprbs
from aeropend_sim.model import PlantModel
from aeropend_sim.params import load_rig
from aeropend_sim.simulation import simulate

RIG = load_rig("thesis_sim")
KT_JM = RIG.motor.K_t / RIG.motor.J_m
TRUTH = {
    "theta_dot": {"θ̇": -13.82, "sin(θ)": -131.75, "ω₁²": 1.7285},
    "i_a": {"i_a": -8.6957, "ω₁": -1.0217, "v_a": 4.3478},
    "omega_rotor": {"i_a": KT_JM, "ω₁": -192.31},
}


@pytest.fixture(scope="module")
def traj():
    """20 s APRBS with short holds (20-300 ms) so the motor transients are excited."""
    sig = aprbs(20.0, lo=0.2, hi=0.9, min_hold=0.02, max_hold=0.3, seed=1)
    return simulate(RIG, sig.duty)


def _assert_exact(model, tol: float) -> None:
    errs = structure_errors(model, TRUTH)
    for tg, e in errs.items():
        assert e["false_positive"] == [] and e["false_negative"] == [], (tg, model.equations())
        assert e["max_rel_error"] < tol, (tg, e, model.equations())


def test_model_derivatives_are_the_models_right_hand_side_at_each_sample_bit_for_bit(traj) -> None:
    """The exact derivatives and discrepancy SINDy's f_model come from the compiled loop; each row
    is PlantModel.rhs at that sample, as the per-sample Python loop they replaced gave."""
    model = PlantModel(RIG)
    data = data_from_trajectory(traj, RIG, exact_derivatives=True)
    loop = np.array([model.rhs(0.0, xk, uk) for xk, uk in zip(traj.x, traj.x[:, 4], strict=True)])
    for i, k in enumerate(("theta", "theta_dot", "i_a", "omega_rotor")):
        assert np.array_equal(data.derivatives[k], loop[:, i]), k
    measured = data_from_trajectory(traj)
    f = model_derivatives(RIG, measured, ("theta_dot", "omega_rotor"))
    v = measured.variables
    x = np.column_stack([v["theta"], v["theta_dot"], v["i_a"], v["omega_rotor"], v["duty"]])
    loop = np.array([model.rhs(0.0, xk, uk) for xk, uk in zip(x, v["duty"], strict=True)])
    assert np.array_equal(f["theta_dot"], loop[:, 1]) and np.array_equal(f["omega_rotor"], loop[:, 3])
    assert np.abs(f["theta_dot"]).max() > 1.0  # a moving plant, not a trivial zero


def test_exact_derivatives_thesis_library_recovers_all_equations(traj) -> None:
    data = data_from_trajectory(traj, RIG, exact_derivatives=True)
    lib = thesis_library()
    assert len(lib) == 31  # the rows of thesis Figs. 5.3/5.4
    m = fit(data, lib, threshold=0.05)
    _assert_exact(m, 1e-4)
    p = m.derived_parameters(gear_ratio=RIG.motor.gear_ratio, L_over_J=RIG.pendulum.L_over_J)
    assert p["K_q"][0] == pytest.approx(1e-4, rel=1e-3)
    assert p["c_over_J"][0] == pytest.approx(13.82, rel=1e-4)
    assert p["mgd_over_J"][0] == pytest.approx(131.75, rel=1e-4)
    assert p["L_a"][0] == pytest.approx(0.23, rel=1e-3)
    assert p["R_a"][0] == pytest.approx(2.0, rel=1e-3)
    assert p["K_omega"][0] == pytest.approx(0.235, rel=1e-3)
    assert p["B_m_over_J_m"][0] == pytest.approx(192.31, rel=1e-3)
    eqs = m.equations()
    assert eqs[0].startswith("θ̈ = − 13.82 θ̇") and "sin(θ)" in eqs[0] and "ω₁²" in eqs[0]
    # held-out derivative MSE is at round-off level (thesis §5.2.2 reports 1e-25)
    train, test = data.split(0.75)
    m2 = fit(train, lib, threshold=0.05)
    assert max(m2.test_mse(test).values()) < 1e-12


def test_finite_difference_derivatives_physics_library(traj) -> None:
    data = add_derivatives(data_from_trajectory(traj, RIG), method="finite_difference")
    m = fit(data, physics_library(), threshold=0.05, exclude_input_steps=3)
    _assert_exact(m, 0.015)  # measured: max 0.5 % (di_a/dt's i_a term)
    # without leaving out the samples next to the duty steps the current equation is wrong
    bad = fit(data, physics_library(), threshold=0.05)
    assert structure_errors(bad, TRUTH)["i_a"]["max_rel_error"] > 1.0


def test_weak_sindy_50db_pendulum_equation(traj) -> None:
    noisy = RIG.with_effects(sensor_noise=True).with_params("sensors", snr_db=50)
    tr = simulate(noisy, traj.duty, seed=3)
    data = data_from_trajectory(tr, noisy, measured=True)
    # ridge 1 on the unit-RMS scale shrinks the near-null combination of i_a, ω₁ and v_a (collinear at
    # steady state) that the exact hold quadrature otherwise leaves in θ̈; λ is then enforced on the refit
    m = fit(data, physics_library(), targets=["theta_dot"], threshold=0.2, method="weak", K=200, H_xt=0.05,
            alpha=1.0)
    e = structure_errors(m, {"theta_dot": TRUTH["theta_dot"]})["theta_dot"]
    assert e["false_positive"] == [] and e["false_negative"] == [], m.equations()
    assert e["max_rel_error"] < 0.01  # measured 0.2 %
    k_q = m.derived_parameters(RIG.motor.gear_ratio, RIG.pendulum.L_over_J)["K_q"][0]
    assert abs(k_q / 1e-4 - 1) < 0.01  # thesis WSINDy at 50 dB: 70 % off


def test_weak_sindy_noise_free_pendulum_exact_with_thesis_library(traj) -> None:
    data = data_from_trajectory(traj, RIG)
    m = fit(data, thesis_library(), targets=["theta_dot"], threshold=0.05, method="weak", K=400, H_xt=0.05)
    e = structure_errors(m, {"theta_dot": TRUTH["theta_dot"]})["theta_dot"]
    assert e["false_positive"] == [] and e["false_negative"] == [], m.equations()
    assert e["max_rel_error"] < 0.005


def test_ensemble_inclusion_and_spread(traj) -> None:
    data = add_derivatives(data_from_trajectory(traj, RIG), method="finite_difference")
    lib = physics_library(extras=("theta", "bias"))
    m = fit(data, lib, targets=["theta_dot"], threshold=0.05, method="ensemble", n_models=30)
    assert m.inclusion is not None and m.coef_std is not None
    incl = dict(zip(m.feature_names, m.inclusion[0], strict=True))
    for name in TRUTH["theta_dot"]:
        assert incl[name] == 1.0
    assert max(v for k, v in incl.items() if k not in TRUTH["theta_dot"]) == 0.0
    spread = dict(zip(m.feature_names, m.coef_std[0], strict=True))
    assert spread["ω₁²"] / 1.7285 < 1e-3
    assert "±" in m.equations()[0] and "[p=1.00]" in m.equations()[0]


def test_discrepancy_sindy_thesis_section_5_4(traj) -> None:
    # thesis §5.4: approximate model θ̈ = −131.5 sin ψ − 13.82 θ̇ + 1.65 ω₁² (true 131.75, 1.7285)
    base = RIG.with_params("pendulum", mgd_over_J=131.5, L_over_J=RIG.pendulum.L_over_J * 1.65 / 1.7285)
    base = dataclasses.replace(base, name="approx")
    data = data_from_trajectory(traj, RIG, exact_derivatives=True)
    m = fit(data, thesis_library(), threshold=0.01, base=base)
    assert m.terms("theta_dot") == {
        "sin(θ)": pytest.approx(-0.25, rel=1e-3), "ω₁²": pytest.approx(1.7285 - 1.65, rel=1e-3),
    }
    assert m.terms("i_a") == {} and m.terms("omega_rotor") == {}
    assert m.equations()[0] == "θ̈ = f_approx + 0.0785 ω₁² − 0.25 sin(θ)"
    train, test = data.split(0.75)
    assert max(fit(train, thesis_library(), threshold=0.01, base=base).test_mse(test).values()) < 1e-12
    # weak form of the discrepancy (thesis Fig. 5.14): same corrections, no derivative needed
    mw = fit(data_from_trajectory(traj, RIG), physics_library(), targets=["theta_dot"], threshold=0.01,
             method="weak", base=base, K=400, H_xt=0.05)
    assert set(mw.terms("theta_dot")) == {"sin(θ)", "ω₁²"}
    assert mw.coefficient("theta_dot", "sin(θ)") == pytest.approx(-0.25, rel=0.05)
    assert mw.coefficient("theta_dot", "ω₁²") == pytest.approx(0.0785, rel=0.05)


def test_threshold_sweep_and_information_criterion(traj) -> None:
    # Savitzky-Golay derivatives with the window chosen by cross-validation (not by hand)
    data = add_derivatives(data_from_trajectory(traj, RIG), method="savgol")
    train, test = data.split(0.75)
    lib = physics_library(extras=("theta", "bias", "cos_theta"))
    pts, models = sweep_threshold(train, test, lib, [0.0, 0.01, 0.2, 1.0], exclude_input_steps=3)
    assert [p.threshold for p in pts] == [0.0, 0.01, 0.2, 1.0]
    assert pts[0].n_terms["theta_dot"] == len(lib)  # λ = 0: dense
    best = select_threshold(pts, "bic")
    assert best.n_terms == {"theta_dot": 3, "i_a": 3, "omega_rotor": 2}
    _assert_exact(models[best.threshold], 0.03)  # measured: max 2.2 % (di_a/dt i_a term)
    assert select_threshold(pts, "test").n_terms == best.n_terms


def test_refuses_current_equation_without_current(traj) -> None:
    data = data_from_trajectory(traj, RIG)
    del data.variables["i_a"]
    with pytest.raises(IdentificationError, match=r"armature-current equation di_a/dt needs the state i_a"):
        fit(data, physics_library(variables=("theta", "theta_dot", "omega_rotor", "v_a")),
            targets=["i_a"], method="weak")
    with pytest.raises(IdentificationError, match=r"library candidate\(s\) \['i_a'\] need \['i_a'\]"):
        fit(data, physics_library(), targets=["theta_dot"], method="weak")
    with pytest.raises(IdentificationError, match="strong-form SINDy needs dtheta_dot/dt"):
        fit(data, physics_library(variables=("theta", "theta_dot", "omega_rotor")), targets=["theta_dot"])
    with pytest.raises(IdentificationError, match="method = 'lasso'"):
        fit(data, physics_library(), method="lasso")


def test_refuses_unexcited_data() -> None:
    rest = simulate(RIG, np.zeros(2000))
    data = data_from_trajectory(rest, RIG, exact_derivatives=True)
    with pytest.raises(IdentificationError, match="rank deficient"):
        fit(data, thesis_library())
    with pytest.raises(IdentificationError, match="non-finite"):
        IdentData(t=np.arange(5.0), variables={"theta": np.array([0, 1, np.nan, 0, 0])})


def test_collinearity_report_flags_small_angle_and_small_current(traj) -> None:
    data = data_from_trajectory(traj, RIG)
    lib = thesis_library()
    rep = collinearity_report(lib.evaluate(data.variables), lib.names, threshold=0.9998)
    pairs = {(a, b) for a, b, _ in rep.pairs}
    assert ("i_a", "sin(i_a)") in pairs and ("θ", "sin(θ)") in pairs
    assert rep.rank == 31 and 1e6 < rep.condition_number < 1e9
    assert "condition number" in rep.summary()


def _lorenz_data(dt: float = 0.002, t_end: float = 10.0) -> IdentData:
    def f(_t, s):
        x, y, z = s
        return [10 * (y - x), x * (28 - z) - y, x * y - 8 / 3 * z]

    t = np.arange(0.0, t_end, dt)
    sol = solve_ivp(f, (0, t_end), [-8.0, 8.0, 27.0], t_eval=t, rtol=1e-11, atol=1e-11).y
    der = np.array([f(0, s) for s in sol.T]).T
    return IdentData(t=t, variables={"x": sol[0], "y": sol[1], "z": sol[2]},
                     derivatives={"x": der[0], "y": der[1], "z": der[2]}, source="lorenz")


LORENZ = {"x": {"x": -10.0, "y": 10.0}, "y": {"x": 28.0, "y": -1.0, "x·z": -1.0},
          "z": {"z": -8 / 3, "x·y": 1.0}}


def test_lorenz_sindy_weak_and_discrepancy() -> None:
    """Thesis §3.3 case study as a regression test of the three estimators."""
    data = _lorenz_data()
    lib = thesis_library(variables=("x", "y", "z"), trig=False)
    for method, kw, tol in (("sindy", {}, 1e-6), ("weak", {"K": 300}, 1e-3)):
        m = fit(data, lib, targets=["x", "y", "z"], threshold=0.05, method=method, **kw)
        for tg, e in structure_errors(m, LORENZ).items():
            assert e["false_positive"] == [] and e["false_negative"] == [], (method, m.equations())
            assert e["max_rel_error"] < tol, (method, tg, e)
    assert m.equations()[2].startswith("dz/dt = − 2.667 z + 1 x·y")

    def approx(d: IdentData) -> dict[str, np.ndarray]:  # ρ = 25 instead of 28
        x, y, z = d.variables["x"], d.variables["y"], d.variables["z"]
        return {"x": 10 * (y - x), "y": x * (25 - z) - y, "z": x * y - 8 / 3 * z}

    for method in ("sindy", "weak"):
        md = fit(data, lib, targets=["x", "y", "z"], threshold=0.05, method=method, base=approx, K=300)
        assert md.terms("x") == {} and md.terms("z") == {}
        assert md.terms("y") == {"x": pytest.approx(3.0, rel=1e-3)}


def test_structured_library_per_equation_weak_50db(traj) -> None:
    """One physically plausible library per equation (incl. θ, cos θ, 1, sgn θ̇, ω₁ for θ̈)."""
    libs = structured_library()
    assert set(libs) == {"theta", "theta_dot", "i_a", "omega_rotor"} and len(libs["theta_dot"]) == 8
    noisy = RIG.with_effects(sensor_noise=True).with_params("sensors", snr_db=50)
    data = data_from_trajectory(simulate(noisy, traj.duty, seed=3), noisy, measured=True)
    m = fit(data, libs, targets=["theta_dot", "omega_rotor"], threshold=0.5, method="weak", K=300, H_xt=0.05)
    assert m.feature_names[: len(libs["theta_dot"])] == libs["theta_dot"].names  # union of the libraries
    e = structure_errors(m, {"theta_dot": TRUTH["theta_dot"]})["theta_dot"]
    assert e["false_positive"] == [] and e["false_negative"] == [], m.equations()
    assert e["max_rel_error"] < 0.01
    k_q = m.derived_parameters(RIG.motor.gear_ratio, RIG.pendulum.L_over_J)["K_q"][0]
    assert abs(k_q / 1e-4 - 1) < 0.01
    assert "sgn(ω₁)" in m.feature_names and m.terms("omega_rotor")  # the rotor equation was fitted too
    with pytest.raises(IdentificationError, match=r"no library for target\(s\) \['i_a'\]"):
        fit(data, {"theta_dot": libs["theta_dot"]}, targets=["theta_dot", "i_a"], method="weak")


def test_free_run_of_identified_model(traj) -> None:
    data = data_from_trajectory(traj, RIG, exact_derivatives=True)
    train, test = data.split(0.75)
    m = fit(train, physics_library(), threshold=0.05)
    fr = free_run(m, test, substeps=1)
    assert set(fr.nrmse) == {"theta", "theta_dot", "i_a", "omega_rotor"}
    assert max(fr.nrmse.values()) < 1e-5  # the exact model reproduces the held-out run
    no_current = IdentData(t=test.t, variables={k: v for k, v in test.variables.items() if k != "i_a"})
    with pytest.raises(IdentificationError, match=r"free run needs \['i_a'\]"):
        free_run(m, no_current)


def test_model_file_yaml(traj, tmp_path) -> None:
    data = add_derivatives(data_from_trajectory(traj, RIG), method="finite_difference")
    train, test = data.split(0.75)
    m = fit(train, physics_library(), threshold=0.05, method="ensemble", n_models=10, exclude_input_steps=3)
    path = tmp_path / "model.yaml"
    save_model(path, m, gear_ratio=RIG.motor.gear_ratio, L_over_J=RIG.pendulum.L_over_J,
               test_mse=m.test_mse(test, exclude_input_steps=3), provenance={"rig": RIG.name})
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    assert doc["method"] == "ensemble" and doc["threshold"] == 0.05
    terms = doc["equations"]["theta_dot"]["terms"]
    assert set(terms) == {"θ̇", "sin(θ)", "ω₁²"} and terms["ω₁²"]["inclusion"] == 1.0 and "std" in terms["ω₁²"]
    assert doc["derived_parameters"]["K_q"]["unit"] == "N*s^2/rad^2"
    assert doc["derived_parameters"]["K_q"]["value"] == pytest.approx(1e-4, rel=0.01)
    assert doc["equations_text"][0].startswith("θ̈ = ") and set(doc["test_mse"]) == set(TRUTH)
