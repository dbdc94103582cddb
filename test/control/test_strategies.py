"""Strategies and gain design (aeropend_control.strategies / design / design_gains / metrics).

* pole placement against the analytic I-PD formulas;
* feedback linearisation cancels the nonlinearity exactly: the continuous closed loop on the
  nominal model's pendulum equation, with the thrust applied ideally (actuator dynamics
  removed, exact θ̇), equals the designed linear system to 1e-6;
* the per-sample controllers on the nominal ``thesis_rig`` (full model with motor dynamics,
  simulated by ``PlantStepper``, controller at every 2.048 ms sample, θ measured only) meet
  thesis Table 6.1 and the issue's goal at θ = 0.2, 0.4, 0.7 rad.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from scipy.integrate import solve_ivp

from aeropend_control.design import (
    DesignError,
    PoleSpec,
    design_cascade,
    design_fl,
    design_small_signal,
    place_ipd,
    reachable_grid,
)
from aeropend_control.design_gains import main
from aeropend_control.metrics import GOAL, TABLE_6_1, step_metrics
from aeropend_control.strategies import (
    FeedbackLinearizationPID,
    Measurement,
    MotorCascade,
    SmallSignalPID,
    StrategyError,
    VelocityEstimator,
    make_strategy,
)
from aeropend_sim.model import OMEGA, THETA_DOT, PlantModel
from aeropend_sim.params import load_rig
from aeropend_sim.simulation import PlantStepper

RIG = load_rig("thesis_rig")
SPEC = PoleSpec()  # ω_n 9 rad/s, ζ 0.7, ρ 1: poles −6.3 ± 6.427j, −9


def test_place_ipd_matches_analytic_formulas() -> None:
    # s³ + 21.6 s² + 194.4 s + 729 = (s + 9)(s² + 12.6 s + 81)
    assert place_ipd(0.0, 0.0, 1.0, SPEC) == pytest.approx((194.4, 729.0, 21.6), rel=1e-10)
    m = PlantModel(RIG)
    d = design_small_signal(RIG, 0.4, SPEC)
    assert d.a0 == pytest.approx(m.a_g * math.cos(0.4), rel=1e-12)  # from the Jacobian (Eq. 6.2)
    assert d.a1 == pytest.approx(m.a_c, rel=1e-12)
    assert d.kp == pytest.approx((194.4 - m.a_g * math.cos(0.4)) / m.b_f, rel=1e-10)
    assert d.kd == pytest.approx((21.6 - m.a_c) / m.b_f, rel=1e-10)
    assert d.ki == pytest.approx(729.0 / m.b_f, rel=1e-10)
    assert d.u_op == pytest.approx(m.a_g * math.sin(0.4) / m.b_f, rel=1e-12)
    with pytest.raises(DesignError, match=r"zeta = 1\.5"):
        PoleSpec(9.0, 1.5).poles()
    with pytest.raises(DesignError, match=r"theta_op = 3\.2"):
        design_small_signal(RIG, 3.2)  # past π: no equilibrium (the thrust only lifts)
    leaning = design_small_signal(RIG, 2.0)  # past π/2 gravity destabilises: a0 = (mgd/J)·cos θ₀ < 0
    assert leaning.a0 == pytest.approx(m.a_g * math.cos(2.0), rel=1e-9) and leaning.a0 < 0.0 < leaning.kp


def test_predicted_metrics_are_python_control_step_info() -> None:
    import control  # python-control, imported here: collection does not pay for it
    d = design_fl(RIG, SPEC)
    info = control.step_info(control.tf([729.0], [1.0, 21.6, 194.4, 729.0]), T=np.arange(0, 5.0005, 1e-3))
    assert d.predicted.rise_time == pytest.approx(info["RiseTime"], abs=1e-9)
    assert d.predicted.settling_time == pytest.approx(info["SettlingTime"], abs=1e-9)
    assert d.predicted.overshoot == pytest.approx(info["Overshoot"], abs=1e-9)
    assert d.predicted.meets(TABLE_6_1) and d.predicted.meets(GOAL)


def test_step_samples_are_python_control_step_response() -> None:
    """The doubling of the exact discretisation gives python-control's samples (its per-sample loop
    was half of ``design_gains``' time): a transfer function, a lightly damped state-space loop with
    a feedthrough, a stiff one at 0.1 ms and an unstable one."""
    import control

    from aeropend_control.design import step_samples
    loops = [(control.tf([729.0], [1.0, 21.6, 194.4, 729.0]), 1e-3, 5001),
             (control.ss([[0.0, 1.0], [-400.0, -0.8]], [[0.0], [400.0]], [[1.0, 0.0]], [[0.25]]), 1e-3, 3001),
             (control.tf([5e4], [1.0, 300.0, 2.2e4, 5e4]), 1e-4, 5001),
             (control.tf([1.0], [1.0, -0.5]), 1e-3, 2001)]
    for sys, dt, n in loops:
        _, want = control.step_response(sys, np.arange(n) * dt)
        want = np.asarray(want).ravel()
        got = step_samples(sys, n, dt)
        assert got.shape == (n,)
        assert np.max(np.abs(got - want)) <= 1e-9 * np.max(np.abs(want)), sys
    assert step_samples(control.tf([2.0], [1.0, 2.0]), 1, 1e-3).tolist() == [0.0]


def _ideal_thrust_accel(model: PlantModel, theta: float, theta_dot: float, f: float) -> float:
    """θ̈ of the nominal model's pendulum equation with thrust f applied ideally."""
    w1 = model.n * math.copysign(abs(f / model.K_q) ** (1.0 / model.alpha), f)
    x = np.array([theta, theta_dot, 0.0, w1, 0.0])
    return model.rhs(0.0, x, 0.0)[THETA_DOT]


@pytest.mark.parametrize("cancel_damping", [True, False])
def test_fl_law_cancels_nonlinearity_pointwise(cancel_damping: bool) -> None:
    ctl = FeedbackLinearizationPID(RIG, cancel_damping=cancel_damping)
    m = ctl.model
    rng = np.random.default_rng(1)
    for th, thd, v in rng.uniform([0.0, -3.0, -20.0], [1.4, 3.0, 20.0], size=(50, 3)):
        acc = _ideal_thrust_accel(m, th, thd, ctl.law(th, thd, v))
        expected = v if cancel_damping else v - m.a_c * thd  # Eq. 6.6
        assert acc == pytest.approx(expected, abs=1e-9)
        assert ctl.v_for_thrust(th, thd, ctl.law(th, thd, v)) == pytest.approx(v, abs=1e-12)


@pytest.mark.parametrize("cancel_damping", [True, False])
@pytest.mark.parametrize("r", [0.4, 0.7])
def test_fl_closed_loop_equals_designed_linear_system(cancel_damping: bool, r: float) -> None:
    import control  # python-control, imported here: collection does not pay for it
    design = design_fl(RIG, SPEC, cancel_damping)
    ctl = FeedbackLinearizationPID(RIG, design=design, cancel_damping=cancel_damping)
    d, m = ctl.design, ctl.model

    def rhs(t: float, s: np.ndarray) -> list[float]:
        z, th, thd = s
        v = d.ki * z - d.kp * th - d.kd * thd  # I-PD, b = c = 0
        return [r - th, thd, _ideal_thrust_accel(m, th, thd, ctl.law(th, thd, v))]

    t = np.linspace(0.0, 3.0, 601)
    sol = solve_ivp(rhs, (0.0, 3.0), [0.0, 0.0, 0.0], t_eval=t, rtol=1e-11, atol=1e-13, method="DOP853")
    lin = control.tf([d.g * d.ki], [1.0, d.a1 + d.g * d.kd, d.a0 + d.g * d.kp, d.g * d.ki])
    _, y = control.forced_response(lin, t, np.full_like(t, r))
    assert np.max(np.abs(sol.y[1] - np.asarray(y).ravel())) < 1e-6


def _run(name: str, r: float, horizon: float = 3.0, **opts: object) -> tuple[np.ndarray, np.ndarray, list]:
    ctl = make_strategy(name, RIG, **opts)
    plant = PlantStepper(RIG)
    n = round(horizon / RIG.sample_period)
    theta, duty, outs = np.empty(n), np.empty(n), []
    s = plant.sample()
    for k in range(n):
        theta[k] = s["theta"]
        o = ctl.step(r, Measurement(s["theta"], s["omega_rotor"], s["i_a"]))
        duty[k] = o.duty
        outs.append(o)
        s = plant.step(o.duty)
    return theta, duty, outs


@pytest.mark.parametrize("name", ["fl_pid", "small_signal", "cascade", "fl_cascade"])
@pytest.mark.parametrize("r", [0.2, 0.4, 0.7])
def test_step_on_nominal_rig_meets_table_6_1_and_goal(name: str, r: float) -> None:
    theta, duty, _ = _run(name, r)
    t = np.arange(theta.size) * RIG.sample_period
    met = step_metrics(t, theta, r)
    assert met.failures(TABLE_6_1) == []
    assert met.failures(GOAL) == []  # ts ≤ 1 s, Mp ≤ 5 %, |e_ss| ≤ 1 mrad
    assert 0.25 < met.rise_time < 0.4 and 0.6 < met.peak_time < 0.85 and met.overshoot < 2.5
    assert duty.min() >= 0.0 and duty.max() <= 1.0
    # steady state holds the equilibrium duty of the model
    assert duty[-1] == pytest.approx(PlantModel(RIG).equilibrium(r)[1], abs=1e-3)


def test_small_signal_fixed_operating_point_and_scheduling_bumpless() -> None:
    theta, _, _ = _run("small_signal_fixed", 0.4, theta_op=0.4)
    met = step_metrics(np.arange(theta.size) * RIG.sample_period, theta, 0.4)
    assert met.meets(TABLE_6_1)
    ctl = make_strategy("small_signal", RIG)
    plant = PlantStepper(RIG)
    s, outs, thetas = plant.sample(), [], []
    for k in range(1500):
        r = 0.3 if k < 700 else 0.6  # operating point changes at sample 700
        thetas.append(s["theta"])
        outs.append(ctl.step(r, Measurement(s["theta"])))
        s = plant.step(outs[-1].duty)
    # bumpless: the thrust moves only by the I-PD's own increment ki·h·(r − θ) − kp·Δθ − kd·ΔD,
    # not by the jump of f₀ (0.0925 N) between the operating points 0.3 and 0.6 rad
    d06 = design_small_signal(RIG, 0.6, SmallSignalPID.default_spec)
    df = outs[700].thrust - outs[699].thrust
    expected = d06.ki * RIG.sample_period * (0.6 - thetas[700])
    assert abs(thetas[700] - 0.3) < 1e-3
    assert df == pytest.approx(expected, abs=1e-3)
    assert outs[-1].error == pytest.approx(0.0, abs=2e-3)


def test_nan_measurement_holds_duty_and_flags() -> None:
    ctl = make_strategy("fl_pid", RIG)
    o1 = ctl.step(0.4, Measurement(0.0))
    o2 = ctl.step(0.4, Measurement(math.nan))
    assert o2.nan_input and o2.duty == o1.duty
    assert not ctl.step(0.4, Measurement(0.001)).nan_input


def test_velocity_estimator_ramp() -> None:
    est = VelocityEstimator(0.002, 0.01)
    vals = [est.update(0.5 * 0.002 * k) for k in range(400)]
    rho = 0.01 / 0.012
    for k, v in enumerate(vals):
        assert v == pytest.approx(0.5 * (1.0 - rho**k), abs=1e-12)


def test_bad_strategy_config_names_value() -> None:
    with pytest.raises(StrategyError, match="'pd'"):
        make_strategy("pd", RIG)
    with pytest.raises(StrategyError, match="theta_op"):
        make_strategy("small_signal_fixed", RIG)
    with pytest.raises(StrategyError, match="'lut'"):
        make_strategy("fl_pid", RIG, allocator="lut")
    assert OMEGA == 3  # state layout the ideal-thrust helper relies on


@pytest.mark.slow
def test_design_cli_writes_gains(tmp_path: pytest.TempPathFactory, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "gains.yaml"
    assert main(["--rig", "thesis_rig", "-o", str(out)]) == 0
    doc = yaml.safe_load(out.read_text())
    # unset pole parameters: the strategies' defaults (ω_n 9.5, ζ 0.7, ρ 1: kp = ω_n²(1 + 2ζρ))
    assert doc["pole_spec"]["fl_pid"] == {"omega_n": 9.5, "zeta": 0.7, "rho": 1.0}
    assert doc["fl_pid"]["kp"] == pytest.approx(216.6)
    assert [d["theta_op"] for d in doc["small_signal"]] == pytest.approx(reachable_grid(RIG))
    assert "fl_pid" in capsys.readouterr().out
    before = out.read_bytes()
    assert main(["--rig", "thesis_rig", "--omega-n", "9", "-o", str(out)]) == 2  # never replaced silently
    assert f"output file {out} exists; pass --overwrite" in capsys.readouterr().err
    assert out.read_bytes() == before
    assert main(["--rig", "thesis_rig", "--omega-n", "9", "-o", str(out), "--overwrite"]) == 0
    assert yaml.safe_load(out.read_text())["fl_pid"]["kp"] == pytest.approx(194.4)
    assert main(["--zeta", "2"]) == 2
    assert "zeta = 2.0" in capsys.readouterr().err


def test_cascade_design_gains_and_speed_loop_on_the_plant() -> None:
    m = PlantModel(RIG)
    d = design_cascade(RIG, omega_speed=60.0, omega_current=200.0)
    assert (d.kp_i, d.ki_i) == pytest.approx((m.L * 200.0, m.R * 200.0), rel=1e-12)
    w0 = m.equilibrium(0.4)[0][OMEGA]
    assert d.kp_w == pytest.approx(m.J_m * 60.0 / m.K_t, rel=1e-12)
    assert d.ki_w == pytest.approx((m.B_m + 2 * m.K_d * w0) * 60.0 / m.K_t, rel=1e-12)
    assert d.predicted.settling_time < 0.1 and d.predicted.overshoot < 5.0
    with pytest.raises(DesignError, match="i_max = -1"):
        design_cascade(RIG, i_max=-1.0)
    # speed step 0 -> ω₁ of θ = 0.4 on the full model: the PI cascade settles with zero error
    cas, plant = MotorCascade(RIG, d), PlantStepper(RIG)
    s, w = plant.sample(), []
    for _ in range(250):
        w.append(s["omega_rotor"])
        s = plant.step(cas.step(w0, s["omega_rotor"], s["i_a"]))
    met = step_metrics(np.arange(len(w)) * RIG.sample_period, np.array(w), w0)
    assert met.settling_time < 0.15 and abs(met.steady_state_error) < 1e-3 * w0
    assert 0.0 <= cas.i_ref <= d.i_max


def test_a_limit_cycle_detunes_the_cascade_without_designing_in_the_sample_call(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The detuned designs (45 → 30 → 20 rad/s, the floor) are made when the cascade is built: the
    sample that detects a limit cycle only switches gains (a design takes 1.4-8 ms, up to four samples at
    490 Hz). They are the designs ``design_cascade`` gives at those bandwidths."""
    import aeropend_control.strategies.cascade as cascade

    cas, fixed = MotorCascade(RIG), MotorCascade(RIG, detune=False)
    expected = [design_cascade(RIG, omega_speed=w, omega_current=min(120.0, 2.5 * w)) for w in (30.0, 20.0)]

    def refused(*_a, **_k):
        raise AssertionError("design_cascade called in the per-sample path")

    monkeypatch.setattr(cascade, "design_cascade", refused)
    events = []
    for _ in range(3):
        cas._detune()  # what step() calls on the sample whose duty the monitor flags as cycling
        events.append(cas.detune_event)
    assert events == [(45.0, 30.0), (30.0, 20.0), (20.0, 20.0)] and cas.detuned == [30.0, 20.0]
    assert cas.design == expected[1]
    assert (cas.speed.gains.kp, cas.speed.gains.ki) == (expected[1].kp_w, expected[1].ki_w)
    assert (cas.current.gains.kp, cas.current.gains.ki) == (expected[1].kp_i, expected[1].ki_i)
    assert fixed._detuned_designs == ()


def test_cascade_holds_duty_without_motor_measurements() -> None:
    ctl = make_strategy("fl_cascade", RIG)
    o1 = ctl.step(0.4, Measurement(0.0, 0.0, 0.0))
    o2 = ctl.step(0.4, Measurement(0.0, math.nan, 0.0))
    assert o2.nan_input and o2.duty == o1.duty


@pytest.mark.slow
def test_each_strategy_chooses_its_robust_pole_spec_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """``default_spec_for`` runs the robust-ζ search on a rig file that declares its drive (54 linear
    step responses); building a strategy runs it once, fl_cascade's outer FL loop included (it gets
    its design, not a second search whose result was thrown away)."""
    from pathlib import Path

    from aeropend_control.strategies import base, strategy_class

    rig = load_rig(str(Path(__file__).resolve().parents[1] / "data" / "gap_corrected_rig.yaml"))
    calls: list[tuple[str, bool]] = []
    real = base.robust_spec
    monkeypatch.setattr(base, "robust_spec", lambda rig, spec, kind, lin, *a: calls.append((kind, lin))
                        or real(rig, spec, kind, lin, *a))
    for name, kind, linearising in (("fl_pid", "duty", True), ("cascade", "cascade", False),
                                    ("fl_cascade", "cascade", True)):
        calls.clear()
        make_strategy(name, rig)
        assert calls == [(kind, linearising)]
        cls = strategy_class(name)
        assert (cls.drive_kind, cls.linearising) == (kind, linearising)
