"""Grey-box output-error fit: parameter recovery on simulated data, data checks, error paths."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_ident.errors import IdentificationError
from aeropend_ident.greybox.fit import fit_greybox, initial_velocity, motor_equilibrium
from aeropend_ident.greybox.parameters import (
    THETA_OFFSET,
    apply_parameters,
    default_parameters,
    rig_theta_offset,
)
from aeropend_ident.greybox.uniform import uniform_data
from aeropend_sim.excitation import aprbs
from aeropend_sim.model import PlantModel
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import simulate

DT = 0.01
#: Quasi-static armature: the thesis rig at 100 Hz (the fit only sees θ).
RIG = load_rig("thesis_rig").with_effects(armature_inductance="quasi_static")


def _duty(seed: int = 3, duration: float = 40.0) -> np.ndarray:
    """1 s at rest (motor off), then an APRBS in [0.3, 0.9] with 0.5-3 s holds."""
    sig = aprbs(duration, lo=0.3, hi=0.9, min_hold=0.5, max_hold=3.0, seed=seed, dt=DT)
    return np.concatenate([np.zeros(100), sig.duty])


def _theta_recording(rig, duty: np.ndarray, noise: float = 0.0, seed: int = 0) -> Recording:
    traj = simulate(rig, duty, dt=DT)
    theta = traj.theta + np.random.default_rng(seed).normal(0.0, noise, traj.theta.size)
    return Recording(t=traj.t, duty=duty, channels={"theta": theta}, source="simulated")


def _truth(rig, names: list[str]) -> dict[str, float]:
    return {n: getattr(getattr(rig, n.split(".")[0]), n.split(".")[1]) for n in names}


@pytest.mark.parametrize(
    ("switches", "extra", "factors"),
    [
        ({}, {}, (1.3, 0.7, 1.35)),
        ({"dead_zone": True}, {"actuator": {"dead_zone": 0.2}}, (0.75, 1.4, 0.65, 1.25)),
        ({"dead_zone": True, "actuator_lag": True},
         {"actuator": {"dead_zone": 0.15, "lag_time_constant": 0.12}}, (1.25, 0.7, 1.3, 0.8, 1.4)),
    ],
    ids=["pendulum+thrust-scale", "with-dead-zone", "with-dead-zone-and-lag"],
)
def test_recovers_parameters_within_one_percent(switches, extra, factors):
    rig = RIG.with_effects(**switches)
    for section, values in extra.items():
        rig = rig.with_params(section, **values)
    names = default_parameters(rig)
    assert len(names) == len(factors)
    truth = _truth(rig, names)
    rec = _theta_recording(rig, _duty())
    start = {n: truth[n] * f for n, f in zip(names, factors, strict=True)}
    res = fit_greybox(rec, rig, initial=start)
    assert res.success
    for p in res.parameters:
        assert p.initial == pytest.approx(start[p.name])
        assert p.value == pytest.approx(truth[p.name], rel=0.01), p.name
    assert res.nrmse < 1e-3
    assert res.cost < 1e-4 * res.initial_cost
    # the fitted rig carries the fitted values
    for n in names:
        section, field = n.split(".")
        assert getattr(getattr(res.rig, section), field) == pytest.approx(res.value(n))


def test_standard_errors_cover_the_truth_on_noisy_data():
    rig = RIG.with_effects(dead_zone=True).with_params("actuator", dead_zone=0.2)
    names = default_parameters(rig)
    truth = _truth(rig, names)
    rec = _theta_recording(rig, _duty(seed=5), noise=0.01, seed=11)
    res = fit_greybox(rec, rig, initial={n: v * 1.2 for n, v in truth.items()})
    for p in res.parameters:
        assert 0.0 < p.std_error < 0.05 * abs(p.value), p.name
        assert abs(p.value - truth[p.name]) < 5.0 * p.std_error, p.name
    # residual is the noise: NRMSE ≈ σ / range
    assert res.metrics["rms_error"] == pytest.approx(0.01, rel=0.1)


def test_motor_equilibrium_is_a_steady_state():
    for rig in (RIG, load_rig("jahoyosr_rig"), load_rig("aeroshield_rig")):
        model = PlantModel(rig)
        for duty in (0.0, 0.3, 0.8):
            i_a, w, tf = motor_equilibrium(rig, duty)
            x = np.array([0.0, 0.0, i_a, w, tf])
            d = model.rhs(0.0, x, duty)
            assert abs(d[3]) <= 1e-9 * max(1.0, abs(w) / model.J_m * 1e-6), (rig.name, duty)
            if duty > 0.0 and model.armature_voltage(duty) > 0.0:
                assert w > 0.0


def test_motor_equilibrium_reads_no_rod_or_sensor_parameter():
    """The cache key of motor_equilibrium leaves out ROD_SECTIONS: no term of the motor chain it
    evaluates may read a parameter there, in any family, and a cached result equals a fresh one."""
    from aeropend_ident.greybox import fit as fit_module
    from aeropend_sim.components import registry

    slots = {"duty", "drive", "armature", "rotor_torque", "rotor_response"}
    for fam in registry.families():
        keys = {k.partition(".")[2]: k for k in registry.family_params(fam.name)}
        for part in (*registry.family_parts(fam.name), *registry.family_effects(fam.name)):
            for term in part.terms:
                if term.slot in slots:
                    rod = [keys[n] for n in term.param_names if keys[n].startswith(fit_module.ROD_SECTIONS)]
                    assert not rod, (fam.name, part.name, rod)
    heavier = RIG.with_params("pendulum", mgd_over_J=2.0 * RIG.pendulum.mgd_over_J)
    first = motor_equilibrium(RIG, 0.6)
    fit_module._equilibria.clear()
    assert motor_equilibrium(heavier, 0.6) == first  # computed afresh for the other rod
    assert motor_equilibrium(RIG.with_params("motor", R_a=2.0 * RIG.motor.R_a), 0.6)[0] != first[0]


def test_initial_velocity_of_a_parabola_is_exact():
    t = np.arange(10) * 0.02
    theta = 0.3 + 1.7 * t - 4.0 * t**2
    assert initial_velocity(theta, 0.02) == pytest.approx(1.7, rel=1e-9)


def test_nonuniform_log_is_resampled_with_zero_order_hold_duty():
    t = np.array([0.0, 0.1, 0.2, 0.4, 0.5] + [0.6 + 0.1 * k for k in range(120)])
    duty = np.full(t.size, 0.6)
    duty[:4] = [0.2, 0.2, 0.3, 0.2]  # 0.3 commanded at t = 0.2 and held over the gap to t = 0.4
    theta = 2.0 * t
    rec = Recording(t=t, duty=duty, channels={"theta": theta}, source="gappy")
    data = uniform_data(rec)
    assert data.resampled
    assert data.dt == pytest.approx(0.1)
    assert np.allclose(np.diff(data.t), 0.1)
    assert np.allclose(data.theta, 2.0 * data.t)  # linear interpolation
    assert data.duty[:6].tolist() == [0.2, 0.2, 0.3, 0.3, 0.2, 0.6]  # zero-order hold, not interpolation
    dec = uniform_data(rec, decimate=2)
    assert dec.dt == pytest.approx(0.2)
    assert dec.duty[:3].tolist() == pytest.approx([0.2, 0.3, 0.4])  # block means
    assert dec.theta[:3].tolist() == pytest.approx([0.0, 0.4, 0.8])


def test_see_saw_offset_moves_end_stops_with_it():
    rig = load_rig("jahoyosr_rig")
    off = rig_theta_offset("jahoyosr_rig")
    assert off == pytest.approx(math.pi / 2, abs=1e-6)
    assert THETA_OFFSET in default_parameters(rig, off)
    assert rig_theta_offset("aeroshield_rig") == 0.0
    moved, new_off = apply_parameters(rig, {THETA_OFFSET: off - 0.1}, off)
    assert new_off == pytest.approx(off - 0.1)
    # the stops stay at the same recorded-frame angle: θ_rec = θ_model − offset
    assert moved.pendulum.theta_min - new_off == pytest.approx(rig.pendulum.theta_min - off)
    assert moved.pendulum.theta_max - new_off == pytest.approx(rig.pendulum.theta_max - off)
    # recorded frame of the jahoyosr stops: README §5 −37.4° .. +37°
    assert math.degrees(rig.pendulum.theta_min - off) == pytest.approx(-37.4, abs=1e-4)
    assert math.degrees(rig.pendulum.theta_max - off) == pytest.approx(37.0, abs=1e-4)


# ------------------------------------------------------------------------------ refusals
def _good() -> Recording:
    duty = _duty(duration=5.0)
    theta = np.linspace(0, 0.5, duty.size)
    return Recording(t=np.arange(duty.size) * DT, duty=duty, channels={"theta": theta}, source="rec.csv")


def test_missing_theta_is_refused():
    rec = _good()
    rec = Recording(t=rec.t, duty=rec.duty, channels={"omega_rotor": np.ones(len(rec))}, source="rec.csv")
    with pytest.raises(IdentificationError, match=r"rec\.csv: recording has no 'theta' channel.*omega_rotor"):
        fit_greybox(rec, RIG)


def test_constant_duty_is_refused_when_nothing_moves_or_a_constant_input_cannot_explain_theta():
    rec = _good()
    rec.duty[:] = 0.4
    rec.channels["theta"][:] = 0.3 + 1e-3 * np.random.default_rng(0).standard_normal(len(rec))
    unexcited = (r"rec\.csv: the duty cycle is constant \(0\.4\) and θ stays within .* rad of where it "
                 r"starts: nothing excites the rig")
    with pytest.raises(IdentificationError, match=unexcited):
        fit_greybox(rec, RIG)
    # a staircase response logged without its command: the rod rests, then moves again
    driven = _theta_recording(RIG, 0.45 + 0.1 * np.floor(np.arange(800) * DT / 2.0))
    rec = Recording(t=driven.t, duty=np.full(len(driven), 0.4), channels=driven.channels, source="rec.csv")
    with pytest.raises(IdentificationError, match=r"rec\.csv: a constant input \(the duty cycle is 0\.4 "
                                                  r"throughout\) cannot explain this log: θ turns back down"):
        fit_greybox(rec, RIG)


@pytest.mark.parametrize("what", ["theta", "duty"])
def test_nans_are_refused(what):
    rec = _good()
    arr = rec.channels["theta"] if what == "theta" else rec.duty
    arr[123] = np.nan
    with pytest.raises(IdentificationError, match=rf"{what} has 1 NaN/inf value\(s\), first at sample 123"):
        fit_greybox(rec, RIG)


def test_too_short_is_refused():
    rec = _good().slice(0, 30)
    rec.duty[15:] = 0.5
    with pytest.raises(IdentificationError, match=r"only 30 samples; a grey-box fit needs at least 50"):
        fit_greybox(rec, RIG)


def test_duty_outside_unit_interval_is_refused():
    rec = _good()
    rec.duty[200] = 1.5
    with pytest.raises(IdentificationError, match=r"duty\[200\] = 1\.5 is outside \[0, 1\]"):
        fit_greybox(rec, RIG)


def test_parameter_requests_are_checked():
    rec = _good()
    with pytest.raises(IdentificationError,
                       match=r"coulomb_over_J'.*needs effects\.rod_coulomb_friction = True"):
        fit_greybox(rec, RIG, ["pendulum.coulomb_over_J"])
    with pytest.raises(IdentificationError, match=r"pendulum has no field 'mass'"):
        fit_greybox(rec, RIG, ["pendulum.mass"])
    with pytest.raises(IdentificationError, match=r"non-fittable section 'sensors'"):
        fit_greybox(rec, RIG, ["sensors.snr_db"])
    with pytest.raises(IdentificationError, match=r"requested more than once"):
        fit_greybox(rec, RIG, ["pendulum.c_over_J", "pendulum.c_over_J"])
    with pytest.raises(IdentificationError, match=r"initial value -1\.0 .*outside the bounds"):
        fit_greybox(rec, RIG.with_effects(dead_zone=True), ["actuator.dead_zone"],
                    initial={"actuator.dead_zone": -1.0})


def test_a_quantised_log_frees_the_start_within_its_rounding_noise():
    # a 12-bit encoder's lattice and no white noise (AeroShield's angle at 15 ms rarely changes): the
    # MAD of Δ²θ reads 0 there, which held the start at the rounded first samples; the noise floor
    # of the detected quantum (measurement_noise: q/√12) frees it within five of that
    q = 2.0 * math.pi / 4096
    clean = _theta_recording(RIG, _duty())
    theta = q * np.round(clean.channels["theta"] / q + 0.45) - 0.45 * q  # the rod at rest reads -0.45 q
    rec = Recording(t=clean.t, duty=clean.duty, channels={"theta": theta}, source="quantised")
    held = fit_greybox(rec, RIG, fit_initial_state=False)
    free = fit_greybox(rec, RIG)
    shift = np.subtract(free.initial_state, held.initial_state)
    assert shift[0] != 0.0
    assert abs(shift[0]) <= 5.0 * q / math.sqrt(12.0) * (1 + 1e-9)
    assert free.cost <= held.cost


def test_baseline_calls_a_fit_worse_only_beyond_its_printed_precision() -> None:
    """A held-out NRMSE equal to the nominal's to 4 digits is not "worse … (+0 %)" (issue 60)."""
    from types import SimpleNamespace

    from aeropend_ident.greybox.baseline import _warnings

    def warn(nominal: float, fitted: float) -> list[str]:
        metrics = {"heldout": {"nominal": {"nrmse": nominal}, "fitted": {"nrmse": fitted}}}
        return _warnings(SimpleNamespace(parameters=[]), metrics, {})

    assert warn(0.003581, 0.003581 * 1.001) == []
    (text,) = warn(0.003581, 0.0040)
    assert "worse than the nominal: held-out NRMSE nominal 0.003581 -> fitted 0.004 (+12%)" in text
