"""Catalog of candidate effects for the gap diagnosis: switching, bounds, validation, recovery.

Each catalog effect is recovered by the grey-box output-error fit of
:func:`aeropend_ident.gap_which.fit_effects` on a short synthetic recording of the nominal rig
with that effect added at a known magnitude.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_ident.gap_effects import (
    CATALOG,
    EFFECTS,
    GapError,
    MeasurementMap,
    apply_effects,
    check_recordings,
    get_effect,
    identifiable,
    thrust_reference_speed,
)
from aeropend_ident.gap_synth import record
from aeropend_ident.gap_which import FIT_CHANNELS, fit_effects, prepare, residuals
from aeropend_sim.excitation import aprbs
from aeropend_sim.model import PlantModel
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording

RIG = load_rig("thesis_rig")
SUBSYSTEMS = {"electrical", "motor", "aerodynamic", "pendulum", "actuator", "sensor"}


def test_catalog_covers_the_issue_list_with_valid_entries():
    names = [e.name for e in CATALOG]
    assert len(names) == len(set(names)) == 17
    for required in ("hbridge_drop", "dead_zone", "back_emf", "armature_inductance", "coulomb_friction",
                     "viscous_friction", "thrust_exponent", "propeller_drag", "actuator_lag", "input_delay",
                     "gravity", "inertia", "end_stops", "sensor_offset", "sensor_scale", "quantisation",
                     "motor_time_constant"):
        assert required in EFFECTS
    for e in CATALOG:
        assert e.subsystem in SUBSYSTEMS
        assert set(e.needs_channels) <= set(FIT_CHANNELS)
        assert e.parameters
        for p in e.parameters:
            assert p.lower < p.upper
            assert p.lower <= p.probe <= p.upper
        for other in e.confusable_with:
            assert other in EFFECTS


def test_apply_switches_effect_and_sets_parameter():
    r = get_effect("dead_zone").apply(RIG, {"dead_zone": 0.1})
    assert r.effects.dead_zone and r.actuator.dead_zone == 0.1
    r = get_effect("actuator_lag").apply(RIG, {"lag_time_constant": 0.07})
    assert r.effects.actuator_lag and r.actuator.lag_time_constant == 0.07
    r = get_effect("back_emf").apply(RIG, {"K_omega_scale": 2.0})
    assert r.motor.K_omega == pytest.approx(2.0 * RIG.motor.K_omega)
    r = get_effect("hbridge_drop").apply(RIG, {"V_drop": 0.2})
    assert r.actuator.hbridge_k0 == pytest.approx(RIG.actuator.hbridge_k0 - 0.2)
    # the nominal rig is unchanged (frozen dataclasses)
    assert not RIG.effects.dead_zone and RIG.actuator.dead_zone == 0.0


def test_hbridge_drop_on_ideal_map_is_a_clipped_voltage_offset():
    ideal = RIG.with_effects(hbridge_map=False)
    r = get_effect("hbridge_drop").apply(ideal, {"V_drop": 0.3})
    m = PlantModel(r)
    for tau in (0.0, 0.1, 0.13, 0.5, 1.0):
        expected = max(0.0, ideal.actuator.v_supply * tau - 0.3)
        assert m.armature_voltage(tau) == pytest.approx(expected, abs=1e-12)


def test_thrust_exponent_keeps_thrust_at_the_operating_point():
    w_ref = thrust_reference_speed(RIG)
    r = get_effect("thrust_exponent").apply(RIG, {"exponent": 2.3})
    n = RIG.motor.gear_ratio
    assert PlantModel(r).thrust(n * w_ref) == pytest.approx(PlantModel(RIG).thrust(n * w_ref), rel=1e-12)
    assert PlantModel(r).thrust(2 * n * w_ref) == pytest.approx(
        PlantModel(RIG).thrust(2 * n * w_ref) * 2**0.3, rel=1e-12)


def test_inertia_scales_every_per_inertia_term():
    r = get_effect("inertia").apply(RIG, {"J_scale": 1.25})
    for f in ("mgd_over_J", "c_over_J", "L_over_J"):
        assert getattr(r.pendulum, f) == pytest.approx(getattr(RIG.pendulum, f) / 1.25)


def test_measurement_effects_compose_a_sensor_map_and_leave_the_rig():
    rig, meas = apply_effects(RIG, {"sensor_offset": {"theta_offset": 0.05},
                                    "sensor_scale": {"theta_scale": 1.1}})
    assert rig is RIG
    assert meas == MeasurementMap(theta_offset=0.05, theta_scale=1.1)
    th = np.linspace(-0.5, 1.2, 7)
    np.testing.assert_allclose(meas.to_model(meas.to_recorded(th)), th, atol=1e-15)
    np.testing.assert_allclose(meas.to_recorded(np.array([0.05])), [0.0], atol=1e-15)


def test_bad_names_and_values_raise_gap_error():
    with pytest.raises(GapError, match="unknown effect 'friction'"):
        get_effect("friction")
    with pytest.raises(GapError, match="outside"):
        get_effect("dead_zone").apply(RIG, {"dead_zone": 0.9})
    with pytest.raises(GapError, match="no parameter 'tau'"):
        get_effect("dead_zone").apply(RIG, {"tau": 0.1})


def test_identifiability_from_recorded_channels():
    theta_only = frozenset({"theta"})
    for name in ("back_emf", "armature_inductance"):
        assert "needs i_a" in identifiable(EFFECTS[name], theta_only)
    assert "needs omega_rotor" in identifiable(EFFECTS["propeller_drag"], theta_only)
    for name in ("dead_zone", "input_delay", "coulomb_friction", "sensor_offset"):
        assert identifiable(EFFECTS[name], theta_only) is None
    assert identifiable(EFFECTS["back_emf"], frozenset(FIT_CHANNELS)) is None


def _rec(n: int = 400, **channels: np.ndarray) -> Recording:
    t = np.arange(n) * 0.002048
    duty = np.where(t > 0.3, 0.5, 0.2)
    ch = {"theta": 0.1 * np.sin(t)} if not channels else channels
    return Recording(t=t, duty=duty, channels=ch, source="unit")


def test_check_recordings_errors_name_the_problem():
    assert check_recordings([_rec()]) == frozenset({"theta"})
    assert check_recordings([_rec(theta=np.zeros(400), i_a=np.ones(400))]) == frozenset({"theta", "i_a"})
    with pytest.raises(GapError, match="no fit recordings"):
        check_recordings([], "fit recordings")
    with pytest.raises(GapError, match="no 'theta' channel"):
        check_recordings([_rec(i_a=np.ones(400))])
    with pytest.raises(GapError, match="only 100 samples"):
        check_recordings([_rec(100)])
    th = np.zeros(400)
    th[17] = math.nan
    with pytest.raises(GapError, match=r"theta has 1 NaN/inf value.*sample 17"):
        check_recordings([_rec(theta=th)])
    r = _rec()
    r.duty[:] = 0.4
    with pytest.raises(GapError, match="constant duty"):
        check_recordings([r])
    with pytest.raises(GapError, match=r"expected aeropend_sim\.recording\.Recording"):
        check_recordings([{"theta": [0.0]}])


# ------------------------------------------------------------------ recovery of each effect
TRUTH = {
    "hbridge_drop": 0.2, "dead_zone": 0.08, "back_emf": 1.6, "armature_inductance": 8.0,
    "coulomb_friction": 1.0, "viscous_friction": 2.0, "thrust_exponent": 2.25, "propeller_drag": 2.0,
    "actuator_lag": 0.08, "input_delay": 0.06, "gravity": 1.2, "inertia": 1.3, "end_stops": 0.7,
    "sensor_offset": 0.06, "sensor_scale": 1.1, "motor_time_constant": 3.0,
}
#: Relative tolerance on the effect size |value − off| (50 dB noise, 12 s recording).
REL_TOL = 0.1


@pytest.mark.parametrize("name", sorted(TRUTH))
def test_each_effect_recovered_by_output_error_fit(name):
    e = get_effect(name)
    p = e.parameters[0]
    truth = {name: {p.name: TRUTH[name]}}
    real, meas = apply_effects(RIG, truth)
    real = real.with_params("sensors", snr_db=50.0).with_effects(sensor_noise=True)
    dt = RIG.sample_period
    duty = np.concatenate([np.zeros(200), aprbs(12.0, lo=0.1, hi=0.72, min_hold=0.4, max_hold=2.0, seed=3,
                                                 dt=dt).duty])
    rec = record(real, meas, duty, seed=5, channels=FIT_CHANNELS, source=f"unit-{name}")
    res = fit_effects(RIG, [name], prepare([rec], frozenset(FIT_CHANNELS)))
    got = res.values[name][p.name]
    assert abs(got - TRUTH[name]) <= REL_TOL * abs(TRUTH[name] - p.off), (name, got)
    # the fitted error is at the noise floor: far below the nominal error
    nominal = residuals(RIG, MeasurementMap(), prepare([rec], frozenset(FIT_CHANNELS)))
    assert res.sse < 0.05 * float(nominal @ nominal)
