"""Where-analysis of the sim-to-real gap (aeropend_ident.gap.where) on synthetic recordings.

A recording is simulated from the thesis rig with one effect changed (the "real" rig); the
where-analysis of the *nominal* thesis rig must put the gap in the right subsystem, and a
recording of the nominal rig itself (with measurement noise) must show no significant gap.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_ident.errors import GapInputError
from aeropend_ident.gap.residual_tests import (
    ALPHA,
    alignment_lag,
    input_cross_correlation,
    ljung_box,
    timing_lag_seen,
)
from aeropend_ident.gap.where import THETA_ONLY_CHAIN, locate_gap
from aeropend_sim.excitation import aprbs
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import simulate

DT = 0.01
RIG = load_rig("thesis_rig")


@pytest.fixture(scope="module")
def duty() -> np.ndarray:
    sig = aprbs(20.0, lo=0.3, hi=0.8, min_hold=0.3, max_hold=1.5, seed=1, dt=DT)
    d = sig.duty.copy()
    d[:50] = 0.0  # start at rest: motor off, rod hanging (the free run's initial state is exact)
    return d


def _record(rig, duty, channels=None, noise=False) -> Recording:
    if noise:
        rig = rig.with_effects(sensor_noise=True)
    tr = simulate(rig, duty, dt=DT, seed=3)
    return Recording.from_trajectory(tr, channels=channels, source="synthetic")


def test_nominal_recording_has_white_residual_and_no_gap(duty):
    rep = locate_gap(RIG, [_record(RIG, duty, noise=True)])
    rec = rep.recordings[0]
    assert rec.whiteness["p_value"] > ALPHA
    assert not rep.significant
    assert not any(e.flagged for e in rec.equations)
    assert rep.subsystem is None
    assert rec.free_run["nrmse"] < 0.01
    assert "no significant gap" in rep.verdict()[0]


def test_armature_resistance_error_is_electrical(duty):
    real = RIG.with_params("motor", R_a=1.5 * RIG.motor.R_a)
    rep = locate_gap(RIG, [_record(real, duty)])
    assert rep.significant
    assert rep.located[0]["equation"] == "armature" and rep.located[0]["flagged"]
    assert rep.subsystem == "electrical"
    arm = rep.recordings[0].equation("armature")
    # the missing voltage is (1.5 - 1)·R_a·i_a: relative to v_a it is a sizeable fraction
    assert arm.relative > 0.05
    assert not rep.recordings[0].equation("rotor").flagged
    assert not rep.recordings[0].equation("pendulum").flagged


def test_rotor_coulomb_friction_is_in_the_rotor_equation(duty):
    t_c = 2e-4
    real = RIG.with_effects(coulomb_friction=True).with_params("motor", T_c=t_c)
    rep = locate_gap(RIG, [_record(real, duty)])
    rotor = rep.recordings[0].equation("rotor")
    assert rotor.flagged and rep.subsystem == "motor"
    assert rep.located[0]["equation"] == "rotor"
    # the residual is the missing friction torque: mean ≈ T_c on a rotor that always spins forward
    assert rotor.mean == pytest.approx(t_c, rel=0.15)
    assert not rep.recordings[0].equation("armature").flagged
    assert not rep.recordings[0].equation("pendulum").flagged


@pytest.mark.parametrize("channels", [None, ("theta",)])
def test_pendulum_friction_error_is_in_the_pendulum_equation(duty, channels):
    real = RIG.with_effects(coulomb_friction=True).with_params("pendulum", coulomb_over_J=0.5)
    rep = locate_gap(RIG, [_record(real, duty, channels)])
    pend = rep.recordings[0].equation("pendulum")
    assert pend.flagged
    assert pend.top_group == "friction" and pend.groups["friction"] > 0.6
    assert rep.subsystem == "pendulum"
    if channels == ("theta",):
        assert {nc["equation"] for nc in rep.not_checked} == {"actuator", "armature", "rotor"}
        assert any("not checked: rotor" in v for v in rep.verdict())


def test_theta_only_actuator_error_points_to_the_actuator_chain(duty):
    real = RIG.with_params("thrust", K_q=0.8 * RIG.thrust.K_q)
    rep = locate_gap(RIG, [_record(real, duty, ("theta",))])
    assert rep.located[0]["equation"] == "pendulum" and rep.located[0]["top_group"] == "thrust"
    assert rep.subsystem == THETA_ONLY_CHAIN
    # with the rotor speed recorded the same error is aerodynamic (thrust from measured ω)
    rep2 = locate_gap(RIG, [_record(real, duty, ("theta", "omega_rotor", "i_a", "v_a"))])
    assert rep2.subsystem == "aerodynamic"


def test_input_delay_gives_alignment_lag_and_actuator_residual(duty):
    delay = 0.10
    real = RIG.with_effects(input_delay=True).with_params("actuator", input_delay=delay)
    rep = locate_gap(RIG, [_record(real, duty, ("theta",))])
    lag = rep.recordings[0].alignment["lag_samples"]
    assert abs(lag - round(delay / DT)) <= 1
    assert any("delayed by" in v for v in rep.verdict())
    # the lead/lag makes run_gap ask the effect diagnosis to confirm the timing effects
    assert timing_lag_seen(rep.recordings[0].alignment)
    assert not timing_lag_seen(locate_gap(RIG, [_record(RIG, duty, ("theta",))]).recordings[0].alignment)
    rep_v = locate_gap(RIG, [_record(real, duty, ("theta", "v_a"))])
    assert rep_v.subsystem == "actuator"


def test_ljung_box_white_vs_coloured():
    rng = np.random.default_rng(0)
    e = rng.standard_normal(2000)
    assert ljung_box(e)["p_value"] > ALPHA
    ar = np.empty_like(e)
    ar[0] = e[0]
    for k in range(1, e.size):
        ar[k] = 0.6 * ar[k - 1] + e[k]
    lb = ljung_box(ar)
    assert lb["p_value"] < 1e-6 and lb["max_lag"] == 1
    assert lb["acf"][0] == pytest.approx(0.6, abs=0.05)


def test_cross_correlation_peak_at_the_residual_delay():
    rng = np.random.default_rng(1)
    u = rng.standard_normal(3000)
    e = np.concatenate((np.zeros(7), u[:-7])) + 0.5 * rng.standard_normal(3000)
    xc = input_cross_correlation(u, e, dt=0.01)
    assert xc["peak_lag_samples"] == 7 and xc["correlated"]
    assert xc["max_abs"] == pytest.approx(1 / math.sqrt(1.25), abs=0.05)
    white = input_cross_correlation(u, rng.standard_normal(3000), dt=0.01)
    assert not white["correlated"]
    t = np.arange(2000) * 0.01
    y = np.sin(2 * np.pi * 0.4 * t) + 0.3 * np.sin(2 * np.pi * 1.3 * t)
    assert alignment_lag(np.roll(y, 12), y, 0.01)["lag_samples"] == 12


def test_bad_inputs_are_refused(duty):
    rec = _record(RIG, duty, ("theta",))
    with pytest.raises(GapInputError, match="no recordings"):
        locate_gap(RIG, [])
    no_theta = Recording(t=rec.t, duty=rec.duty, channels={"i_a": np.ones(rec.t.size)}, source="x")
    with pytest.raises(GapInputError, match="theta"):
        locate_gap(RIG, [no_theta])
    th = rec.channels["theta"].copy()
    th[100] = np.nan
    with pytest.raises(GapInputError, match="NaN"):
        locate_gap(RIG, [Recording(t=rec.t, duty=rec.duty, channels={"theta": th}, source="nan")])
    with pytest.raises(GapInputError, match="samples"):
        locate_gap(RIG, [rec.slice(40, 70)])
    with pytest.raises(GapInputError, match="horizon"):
        locate_gap(RIG, [rec], horizon=0.0)


def test_nominal_that_flips_over_is_reported(duty):
    rec = _record(RIG, duty, ("theta",))
    strong = RIG.with_params("thrust", K_q=6.0 * RIG.thrust.K_q)  # thrust above the largest gravity torque
    rep = locate_gap(strong, [rec])
    r = rep.recordings[0]
    assert r.free_run["diverged"] and np.max(np.abs(r.theta_free)) > math.pi
    assert any("flips over the pivot" in v for v in rep.verdict())
    assert r.short_horizon["nrmse"] < r.free_run["nrmse"]
    assert not locate_gap(RIG, [rec]).recordings[0].free_run["diverged"]


def test_drift_between_repeats_is_reported():
    cycle = np.concatenate([np.full(300, 0.0), np.full(300, 0.5)])
    d = np.tile(cycle, 5)  # 30 s: five repeats of the same two holds
    rec = _record(RIG, d, ("theta",))
    clean = locate_gap(RIG, [rec]).recordings[0]
    # the model repeats exactly what the rig repeats (here: the same partly decayed swings)
    assert all(
        rp["count"] == 5 and abs(rp["measured_spread"] - rp["simulated_spread"]) < 0.005
        for rp in clean.repeats
    )
    assert not any("time-varying effect" in v for v in locate_gap(RIG, [rec]).verdict())
    drift = 0.004 * rec.t  # 0.24 rad/min sensor drift
    drifting = Recording(
        t=rec.t, duty=rec.duty, channels={"theta": rec.channels["theta"] + drift}, source="drift"
    )
    rep = locate_gap(RIG, [drifting])
    rp = {round(r["duty"], 3): r for r in rep.recordings[0].repeats}
    assert rp[0.5]["measured_drift_per_min"] == pytest.approx(0.24, rel=0.1)
    assert rp[0.5]["measured_spread"] == pytest.approx(0.004 * 24.0, rel=0.1)
    assert any("time-varying effect" in v for v in rep.verdict())


def test_esc_rig_checks_its_rotor_response_and_says_which_checks_it_has_not(duty):
    """An ESC rig has no armature voltage or current: those checks are 'not applicable to family
    esc' (not 'needs i_a'), and the rotor check is its speed response (ω_ss(τ) − ω₁)/T_m − ω̇₁. A
    speed response 3× slower than the rig file says is located there."""
    from bench.fixtures.component_rigs import rig as family_rig

    nominal = family_rig("esc").with_params("sensors", snr_db=55.0)
    ok = locate_gap(nominal, [_record(nominal, duty, ("theta", "omega_rotor"), noise=True)]).recordings[0]
    for name in ("actuator", "armature"):
        e = ok.equation(name)
        assert not e.checked and e.note.startswith("not applicable to family esc"), e.note
    rotor = ok.equation("rotor")
    assert rotor.checked and rotor.unit == "rad/s^2" and not rotor.flagged
    assert set(rotor.groups) <= {"set_point", "response", "offset"}
    slow = nominal.with_params("motor", T_m=3.0 * nominal.motor.T_m)
    rep = locate_gap(nominal, [_record(slow, duty, ("theta", "omega_rotor"), noise=True)])
    rotor = rep.recordings[0].equation("rotor")
    assert rep.significant and rotor.flagged and rotor.relative > 0.05 and rep.subsystem == "motor"
    assert rotor.top_group == "response"


def test_a_recording_on_one_or_two_lattice_values_is_judged_against_the_sensors_resolution():
    """A free decay come to rest on a 12-bit encoder sits on one or two lattice values: its own noise
    reads 0, and a residual of a fraction of a quantum was "significant" (an effect-free H-bridge rig
    at held-out NRMSE 0.00034, bench_control_family). The rig's stated quantum is the floor."""
    q = 2.0 * math.pi / 4096.0
    rig = RIG.with_effects(quantisation=True).with_params("sensors", theta_quantum=q)
    t = np.arange(1000) * DT
    theta = np.zeros(t.size)
    for k in range(20, t.size, 60):
        theta[k:k + 8] = q  # the rod at rest, its reading flipping to the next lattice value now and then
    rec = Recording(t=t, duty=np.zeros(t.size), channels={"theta": theta}, source="decay at rest")
    rep = locate_gap(rig, [rec])
    assert rep.recordings[0].free_run["rms_error"] < q  # within a quantum: nothing to find
    assert not rep.significant  # before: "significant" (its own noise, read on two values, was 0)
