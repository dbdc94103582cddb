"""θ̇ observer (aeropend_control.observer): Kalman gain, tracking, disturbance, noise vs difference."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from aeropend_control.observer import (
    ObserverError,
    ObserverSpec,
    PendulumObserver,
    ThrustPredictor,
    kalman_gain,
)
from aeropend_control.strategies import VelocityEstimator
from aeropend_sim.model import OMEGA, TAU_F, THETA, THETA_DOT, PlantModel
from aeropend_sim.params import Rig, load_rig
from aeropend_sim.simulation import PlantStepper

RIG = load_rig("thesis_rig")
H = RIG.sample_period


def test_gain_is_the_limit_of_the_kalman_recursion() -> None:
    spec = ObserverSpec()
    Ad, Bd, M = kalman_gain(2.0, H, spec)
    # ZOH of θ̈ = −2·θ̇ + u + d, checked against the closed form
    e = math.exp(-2.0 * H)
    assert Ad[1, 1] == pytest.approx(e, rel=1e-12) and Bd[1] == pytest.approx((1 - e) / 2.0, rel=1e-12)
    assert Ad[0, 1] == pytest.approx((1 - e) / 2.0, rel=1e-12)
    # iterate the time-varying Kalman filter (predict/correct) until the gain stops changing
    G = np.array([[0.0, 0.0], [H, 0.0], [0.0, 1.0]])
    Q = G @ np.diag([spec.sigma_accel**2, spec.sigma_dist**2]) @ G.T
    C = np.array([1.0, 0.0, 0.0])
    P = np.eye(3)
    for _ in range(20000):
        K = P @ C / (C @ P @ C + spec.sigma_theta**2)
        P = Ad @ ((np.eye(3) - np.outer(K, C)) @ P) @ Ad.T + Q
    np.testing.assert_allclose(M, P @ C / (C @ P @ C + spec.sigma_theta**2), rtol=1e-6)
    assert np.all(np.abs(np.linalg.eigvals((np.eye(3) - np.outer(M, C)) @ Ad)) < 1.0)


def test_bad_spec_names_the_value() -> None:
    with pytest.raises(ObserverError, match="sigma_theta = -1"):
        PendulumObserver(PlantModel(RIG), H, ObserverSpec(sigma_theta=-1.0))
    with pytest.raises(ObserverError, match="dt = 0"):
        PendulumObserver(PlantModel(RIG), 0.0)


def _open_loop(rig: Rig, duty_of_k: Callable[[int], float], n: int, seed: int = 0) -> tuple:
    plant = PlantStepper(rig, seed=seed)
    obs = PendulumObserver(PlantModel(RIG), H)
    dif = VelocityEstimator(H, 0.01)
    s = plant.sample()
    true, est, diff = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        true[k] = plant.x[THETA_DOT]
        est[k] = obs.correct(s["theta"])
        diff[k] = dif.update(s["theta"])
        duty = duty_of_k(k)
        obs.predict(duty)
        s = plant.step(duty)
    return true, est, diff, obs, plant


def test_tracks_theta_dot_on_the_nominal_rig_without_lag() -> None:
    # open-loop duty steps 0 -> 0.45 -> 0.3: the pendulum swings up and oscillates
    true, est, diff, obs, plant = _open_loop(RIG, lambda k: 0.45 if k < 600 else 0.3, 1500)
    err_obs, err_dif = np.abs(est - true)[50:], np.abs(diff - true)[50:]
    assert np.max(np.abs(true)) > 1.0  # a real motion, rad/s
    assert err_obs.max() < 0.02  # model-based: no filter lag
    assert err_dif.max() > 5 * err_obs.max()  # the 10 ms filtered difference lags
    assert obs.theta == pytest.approx(plant.x[THETA], abs=1e-3)


def test_noise_rejection_at_50_dB() -> None:
    noisy = RIG.with_effects(sensor_noise=True)
    true, est, diff, _, _ = _open_loop(noisy, lambda k: 0.4, 2000, seed=3)
    rms_obs = float(np.sqrt(np.mean((est - true)[200:] ** 2)))
    rms_dif = float(np.sqrt(np.mean((diff - true)[200:] ** 2)))
    assert rms_obs < 0.05 and rms_dif > 3 * rms_obs


def test_disturbance_state_estimates_an_unmodelled_constant_acceleration() -> None:
    # pendulum with an extra constant acceleration d0 the observer's model lacks (e.g. a friction
    # or thrust offset), driven by the thrust the observer's own motor predictor computes
    m = PlantModel(RIG)
    obs = PendulumObserver(m, H)
    duty, d0 = 0.35, -0.8  # rad/s²
    th, thd = 0.0, 0.0
    for _ in range(3000):
        obs.correct(th)
        w0 = obs.thrust.omega
        f = obs.thrust.advance(duty)  # mean thrust over the period (the predictor's estimate)
        obs.thrust.omega = w0
        obs.predict(duty)
        for _ in range(20):  # Euler substeps of the true pendulum
            acc = -m.a_g * math.sin(th) - m.a_c * thd + m.b_f * f + d0
            th, thd = th + H / 20 * thd, thd + H / 20 * acc
    assert abs(thd) < 1e-3 and th > 0.1  # at rest at the equilibrium shifted by d0
    assert obs.dist_k == pytest.approx(d0, abs=0.02)
    assert obs.theta_k == pytest.approx(th, abs=1e-4)


def _closed_loop(rig: Rig, r: float, estimator: str) -> tuple[np.ndarray, np.ndarray]:
    from aeropend_control.strategies import Measurement, make_strategy

    ctl = make_strategy("fl_pid", RIG, estimator=estimator)
    plant = PlantStepper(rig, seed=0)
    n = round(3.0 / H)
    true, duty = np.empty(n), np.empty(n)
    s = plant.sample()
    for k in range(n):
        true[k] = plant.x[THETA]
        duty[k] = ctl.step(r, Measurement(s["theta"])).duty
        s = plant.step(duty[k])
    return true, duty


def test_closed_loop_at_50_dB_observer_vs_difference() -> None:
    from aeropend_control.metrics import GOAL, TABLE_6_1, step_metrics

    noisy = RIG.with_effects(sensor_noise=True)
    t = np.arange(round(3.0 / H)) * H
    true_o, duty_o = _closed_loop(noisy, 0.2, "observer")
    true_d, duty_d = _closed_loop(noisy, 0.2, "difference")
    met_o, met_d = step_metrics(t, true_o, 0.2), step_metrics(t, true_d, 0.2)
    assert met_o.failures(TABLE_6_1) == [] and met_o.failures(GOAL) == []
    assert met_o.settling_time < 0.6 < met_d.settling_time  # the difference's noise widens the settling
    tail = slice(-round(1.0 / H), None)
    assert np.std(duty_o[tail]) < 0.5 * np.std(duty_d[tail])  # far less actuator noise


def _python_rotor_step(pred: ThrustPredictor, m: PlantModel, duty: float) -> tuple[float, float, float]:
    """The thrust predictor's step written in Python on the rotor model's generated right-hand side
    and ``m``'s thrust (what :meth:`ThrustPredictor.advance` computed before its compiled kernel):
    (ω₁, τ_f, mean f)."""
    rhs, rest, h = pred._rotor.rhs, pred._rest.tolist(), pred.dt
    duty = pred._fifo[0] if pred._fifo else duty  # the command of n_delay samples ago

    def deriv(w: float, tf: float) -> tuple[float, float]:
        x = list(rest)
        x[OMEGA], x[TAU_F] = w, min(max(tf, 0.0), 1.0)
        f = rhs(0.0, x, duty)
        return f[OMEGA], f[TAU_F]

    w, tf = pred.omega, pred.tau_f
    d1 = deriv(w, tf)
    d2 = deriv(w + 0.5 * h * d1[0], tf + 0.5 * h * d1[1])
    d3 = deriv(w + 0.5 * h * d2[0], tf + 0.5 * h * d2[1])
    d4 = deriv(w + h * d3[0], tf + h * d3[1])
    w_mid = max(w + 0.5 * h * d2[0], 0.0)
    w_end = max(w + h * (d1[0] + 2.0 * d2[0] + 2.0 * d3[0] + d4[0]) / 6.0, 0.0)
    tf_end = tf + h * (d1[1] + 2.0 * d2[1] + 2.0 * d3[1] + d4[1]) / 6.0
    return w_end, tf_end, (m.thrust(w) + 4.0 * m.thrust(w_mid) + m.thrust(w_end)) / 6.0


@pytest.mark.parametrize("family", ["dc_hbridge", "voltage_amplifier", "esc"])
def test_the_compiled_thrust_predictor_is_the_models_arithmetic_bit_for_bit(family: str, tmp_path) -> None:
    from aeropend_sim.rigfile.template import new_rig_text

    path = tmp_path / f"{family}.yaml"
    stated = {"actuator.lag_time_constant": 0.03}  # a lag; a voltage family's winding heats too
    if family != "esc":
        stated.update({"motor.alpha_R": 0.004, "motor.R_th": 3.0, "motor.C_th": 40.0})
    path.write_text(new_rig_text(family, stated, name=family, file=path.name), encoding="utf-8")
    rig = load_rig(path)
    model = PlantModel(rig)
    pred = ThrustPredictor(model, 1.0 / 200.0)
    rng = np.random.default_rng(0)
    for duty in rng.uniform(-0.1, 1.1, 300).clip(0.0, 1.0):  # the clipped command, as advance() sees it
        want = _python_rotor_step(pred, model, float(duty))
        f = pred.advance(float(duty))
        assert (pred.omega, pred.tau_f, f) == want
    assert pred.omega > 0.0 and f > 0.0
