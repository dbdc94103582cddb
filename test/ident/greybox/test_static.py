"""Static estimators (thesis §4.4) against the thesis' own Tables 4.1/4.2 and Eqs. 4.3-4.5."""

from __future__ import annotations

import numpy as np
import pytest

from aeropend_ident.errors import StaticEstimationError
from aeropend_ident.greybox.static import (
    armature_resistance,
    armature_time_constant,
    back_emf_constant,
    fit_hbridge_map,
    fit_thrust_law,
    rpm_to_rad_s,
    v_per_rpm_to_si,
)
from aeropend_sim.params import load_rig
from aeropend_sim.simulation import simulate

# Thesis Table 4.1: stall armature voltage [V] and current [A] (21 rows, as printed).
TABLE_41_VA = [0.48, 0.60, 0.29, 1.42, 1.47, 0.35, 0.89, 0.74, 1.31, 1.54, 0.78, 1.58, 0.79, 0.99, 1.76,
               0.57, 0.37, 1.93, 1.37, 2.44, 1.09]
TABLE_41_IA = [0.44, 0.55, 0.25, 1.30, 1.33, 0.30, 0.85, 0.69, 1.17, 1.40, 0.74, 1.57, 0.73, 0.96, 1.67,
               0.52, 0.35, 1.89, 1.32, 2.28, 0.99]
# Thesis Table 4.2: steady v_a [V], i_a [A], ω₁ [RPM] (strobe speed through the gear ratio).
TABLE_42_VA = [1.08, 1.182, 1.272, 1.377, 1.483, 1.561, 1.666, 1.781, 1.864, 1.974]
TABLE_42_IA = [0.29, 0.33, 0.35, 0.4, 0.45, 0.5, 0.55, 0.61, 0.65, 0.7]
TABLE_42_RPM = [1158, 1235, 1306, 1402, 1485, 1561, 1638, 1734, 1805, 1885]
TABLE_42_K = [6.619934856e-4, 6.684402018e-4, 6.847902019e-4, 6.742762768e-4, 6.715175383e-4,
              6.538620054e-4, 6.543423154e-4, 6.470698432e-4, 6.438833666e-4, 6.462672905e-4]


def test_table_41_armature_resistance() -> None:
    est = armature_resistance(TABLE_41_VA, TABLE_41_IA)
    assert est.unit == "ohm" and est.rows.shape == (21,)
    assert round(est.value, 2) == 1.08
    assert round(est.std, 2) == 0.04


def test_table_42_back_emf_constant() -> None:
    est = back_emf_constant(TABLE_42_VA, TABLE_42_IA, TABLE_42_RPM, R_a=1.08)
    assert est.per_rpm.value == pytest.approx(6.606e-4, rel=2e-4)
    assert est.per_rpm.std == pytest.approx(1.38e-5, rel=0.02)
    # each row matches the thesis' printed K_ω within 0.1 % (the thesis used unrounded inputs)
    np.testing.assert_allclose(est.per_rpm.rows, TABLE_42_K, rtol=1e-3)
    assert est.si == pytest.approx(6.3085e-3, rel=3e-4)
    # the same rows given in rad/s give the same constant
    est2 = back_emf_constant(TABLE_42_VA, TABLE_42_IA, rpm_to_rad_s(np.array(TABLE_42_RPM)), 1.08, "rad/s")
    assert est2.si == pytest.approx(est.si, rel=1e-12)
    assert v_per_rpm_to_si(6.606e-4) == pytest.approx(6.3083e-3, rel=1e-4)


def test_inductance_from_simulated_stall_step() -> None:
    # thesis_rig (R_a 1.08 Ω, L_a 2.2 mH) at stall: no back-EMF, a duty step at t = 10 ms
    rig = load_rig("thesis_rig").with_effects(back_emf=False)
    dt = 5e-5
    duty = np.where(np.arange(int(0.03 / dt)) * dt >= 0.01, 0.5, 0.0)
    traj = simulate(rig, duty, dt=dt)
    tau_true = rig.motor.L_a / rig.motor.R_a
    r63 = armature_time_constant(traj.t, traj.i_a, t_step=0.01, R_a=1.08)
    assert r63.tau_e == pytest.approx(tau_true, rel=0.01)
    assert r63.L_a == pytest.approx(2.2e-3, rel=0.01)
    # at the rig's own 490 Hz sampling the 63 % rule is coarse; the exponential fit is not
    traj490 = simulate(rig, np.where(np.arange(20) >= 5, 0.5, 0.0))
    t_step = 5 * rig.sample_period
    fit = armature_time_constant(traj490.t, traj490.i_a, t_step=t_step, R_a=1.08, method="fit")
    assert fit.L_a == pytest.approx(2.2e-3, rel=0.01)
    coarse = armature_time_constant(traj490.t, traj490.i_a, t_step=t_step, R_a=1.08)
    assert coarse.L_a == pytest.approx(2.2e-3, rel=0.1)  # one sample per τ_e: interpolation is coarse


def test_hbridge_map_eq_43_roundtrip() -> None:
    k0, k1, k2, k3 = -0.2914, 6.8e-4, 1.469e7, 4.3629e4
    tau = np.linspace(0.05, 1.0, 30)
    v = k0 + k1 * np.sqrt(k2 * tau + k3)
    m = fit_hbridge_map(tau, v)
    assert (m.k0, m.k1) == (pytest.approx(k0, abs=1e-6), k1)
    assert m.k2 == pytest.approx(k2, rel=1e-5) and m.k3 == pytest.approx(k3, rel=1e-4)
    assert m.voltage(0.4314) == pytest.approx(1.43, abs=0.01)
    np.testing.assert_allclose(m.duty(m.voltage(tau)), tau, atol=1e-9)
    # noisy data (σ = 5 mV, the thesis' MSE 2.6e-5 V²) still gives the curve within 10 mV
    rng = np.random.default_rng(1)
    m2 = fit_hbridge_map(tau, v + rng.normal(0, 5e-3, tau.size))
    assert np.max(np.abs(m2.voltage(tau) - v)) < 0.01
    assert m2.mse == pytest.approx(2.5e-5, rel=0.6)


def test_thrust_law_eq_44_and_inverse_eq_45() -> None:
    v = np.linspace(0.2, 2.4, 25)
    f = 0.054 * v**2 + 0.0435 * v + 0.0029
    law = fit_thrust_law(v, f)
    assert (law.a, law.b, law.c) == (pytest.approx(0.054), pytest.approx(0.0435), pytest.approx(0.0029))
    p, q, r, s = law.inverse_constants()
    assert (p, q, r, s) == (pytest.approx(-0.4028, abs=1e-4), pytest.approx(9.2593, abs=1e-4),
                            pytest.approx(0.0013, abs=5e-5), pytest.approx(0.2160, abs=1e-4))
    np.testing.assert_allclose(law.voltage(law.thrust(v)), v, atol=1e-12)


def test_errors_name_bad_values() -> None:
    with pytest.raises(StaticEstimationError, match=r"i_a\[1\] = 0.0"):
        armature_resistance([1.0, 1.0], [1.0, 0.0])
    with pytest.raises(StaticEstimationError, match=r"v_a\[0\] = nan"):
        armature_resistance([float("nan")], [1.0])
    with pytest.raises(StaticEstimationError, match="same length"):
        back_emf_constant([1.0, 2.0], [0.1], [100.0, 200.0], 1.08)
    with pytest.raises(StaticEstimationError, match="omega_unit"):
        back_emf_constant([1.0], [0.1], [100.0], 1.08, omega_unit="hz")
    with pytest.raises(StaticEstimationError, match="too small"):
        armature_time_constant(np.arange(10.0), np.ones(10), t_step=2.0)
    with pytest.raises(StaticEstimationError, match="below the fitted law"):
        fit_thrust_law([0, 1, 2], [0.0029, 0.1004, 0.3059]).voltage(-1.0)
