"""Catalog of candidate effects for the gap diagnosis: switching, bounds, validation, recovery.

Each catalog effect is recovered by the grey-box output-error fit of
:func:`aeropend_ident.gap.which.fitting.fit_effects` on a short synthetic recording of the nominal rig
with that effect added at a known magnitude.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_ident.errors import GapError
from aeropend_ident.gap.effects import (
    CATALOG,
    EFFECTS,
    EffectContext,
    MeasurementMap,
    apply_effects,
    check_recordings,
    get_effect,
    identifiable,
)
from aeropend_ident.gap.which.data import FIT_CHANNELS, prepare, residuals
from aeropend_ident.gap.which.fitting import fit_effects
from aeropend_ident.greybox.fit import motor_equilibrium
from aeropend_sim.components import registry
from aeropend_sim.excitation import aprbs
from aeropend_sim.model import PlantModel
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording
from bench.fixtures.gap_synth import draw_truth, record

RIG = load_rig("thesis_rig")
SUBSYSTEMS = {"electrical", "motor", "aerodynamic", "pendulum", "actuator", "sensor"}


def _ctx(rig=RIG):
    t = np.arange(3000) * rig.sample_period
    duty = np.where(t > 1.0, 0.6, 0.2)
    return EffectContext.from_data(rig, 0.5 * np.sin(t), duty)


def test_catalog_of_the_thesis_rig_has_valid_physical_entries():
    # the catalog is the registry's (test_components_diagnosis.py checks it entry by entry)
    names = [e.name for e in CATALOG]
    assert names == [d.name for d in registry.diagnoses("dc_hbridge") if d.kind != "drift"]
    ctx = _ctx()
    for e in CATALOG:
        assert e.subsystem in SUBSYSTEMS
        assert set(e.needs_channels) <= set(FIT_CHANNELS)
        assert e.parameters
        for p in e.parameters:
            r = p.bind(ctx)
            assert r.lower < r.upper and r.lower <= r.probe <= r.upper, (e.name, p.name, r)
            assert r.probe != r.off, (e.name, p.name)
            if r.log:
                assert r.lower > 0
        for other in (*e.confusable_with, *e.exclusive_with):
            assert other in EFFECTS
    # parameters carry SI units, not scale factors (the inertia ratio J/J_nominal is the exception:
    # the rig stores only per-inertia ratios)
    units = {(e.name, p.name): p.unit for e in CATALOG for p in e.parameters}
    assert units["propeller_drag", "K_d"] == "N*m*s^2/rad^2"
    assert units["thrust_coefficient", "K_q"] == "N*s^2/rad^2"
    assert units["input_delay", "input_delay"] == "s" and units["armature_resistance", "R_a"] == "ohm"
    assert units["rotor_friction", "B_m"] == "N*m*s/rad"


def test_ranges_reach_physical_sizes_of_effects_the_nominal_omits():
    # thesis_sim has no propeller drag (K_d = 0): the drag search must reach the drag that halves
    # the steady rotor speed at the largest recorded duty cycle, whatever the nominal value
    rig = load_rig("thesis_sim")
    ctx = _ctx(rig)
    r = get_effect("propeller_drag").ranges(ctx)["K_d"]
    w = 0.5 * ctx.omega_max
    k_half = ctx.rotor_torque(w, without="propeller_drag") / w**2
    assert r.off == 0.0 and r.lower <= 1e-3 * k_half and r.upper >= 2.0 * k_half
    halved = get_effect("propeller_drag").apply(rig, {"K_d": k_half})
    _, w_nom, _ = motor_equilibrium(rig, ctx.duty_max)
    _, w_half, _ = motor_equilibrium(halved, ctx.duty_max)
    assert w_half == pytest.approx(0.5 * w_nom, rel=1e-6)
    # the same for the rotor's viscous friction (thesis_rig: B_m tiny next to the drag)
    b_half = ctx.rotor_torque(w, without="rotor_viscous_friction") / w
    slowed = get_effect("rotor_friction").apply(rig, {"B_m": b_half})
    assert motor_equilibrium(slowed, ctx.duty_max)[1] == pytest.approx(0.5 * w_nom, rel=1e-6)
    # the issue's drag −2.0·ω₁|ω₁| s⁻¹ on the thesis' simulated plant is K_d = 2·J_m: inside the range
    assert r.lower < 2.0 * rig.motor.J_m < r.upper
    # and the rotor's brush friction, which neither rig models
    t_half = (ctx.rotor_torque(w, without="rotor_coulomb_friction")
              / math.tanh(w / rig.motor.rotor_friction_velocity))
    braked = get_effect("rotor_brush_friction").apply(rig, {"T_c": t_half})
    assert motor_equilibrium(braked, ctx.duty_max)[1] == pytest.approx(0.5 * w_nom, rel=1e-6)
    assert get_effect("rotor_brush_friction").ranges(ctx)["T_c"].upper >= 2.0 * t_half


def test_apply_switches_effect_and_sets_the_physical_value():
    r = get_effect("dead_zone").apply(RIG, {"dead_zone": 0.1})
    assert r.effects.dead_zone and r.actuator.dead_zone == 0.1
    r = get_effect("actuator_lag").apply(RIG, {"lag_time_constant": 0.07})
    assert r.effects.actuator_lag and r.actuator.lag_time_constant == 0.07
    r = get_effect("back_emf").apply(RIG, {"K_omega": 2.0e-3})
    assert r.motor.K_omega == 2.0e-3
    r = get_effect("hbridge_drop").apply(RIG, {"V_drop": 0.2})
    assert r.actuator.hbridge_k0 == pytest.approx(RIG.actuator.hbridge_k0 - 0.2)
    for name, key, section in (("armature_resistance", "R_a", "motor"), ("torque_constant", "K_t", "motor"),
                               ("rotor_friction", "B_m", "motor"), ("propeller_drag", "K_d", "motor"),
                               ("thrust_coefficient", "K_q", "thrust"),
                               ("gravity", "mgd_over_J", "pendulum")):
        value = 1.3 * getattr(getattr(RIG, section), key) + 1e-9
        assert getattr(getattr(get_effect(name).apply(RIG, {key: value}), section), key) == value
    r = get_effect("thrust_law").apply(RIG, {"K_q": 3e-6, "exponent": 1.8})
    assert r.effects.thrust_exponent and r.thrust.exponent == 1.8 and r.thrust.K_q == 3e-6
    # the nominal rig is unchanged (frozen dataclasses)
    assert not RIG.effects.dead_zone and RIG.actuator.dead_zone == 0.0


def test_rig_values_name_every_field_an_effect_writes():
    ideal = RIG.with_effects(hbridge_map=False)
    rv = get_effect("hbridge_drop").rig_values(ideal, {"V_drop": 0.3})
    assert rv["hbridge_drop.V_drop"] == 0.3
    assert rv["actuator.v_supply"] == pytest.approx(ideal.actuator.v_supply - 0.3)
    assert rv["actuator.dead_zone"] == pytest.approx(0.3 / ideal.actuator.v_supply)
    rv = get_effect("inertia").rig_values(RIG, {"J_scale": 1.25})
    assert rv["pendulum.L_over_J"] == pytest.approx(RIG.pendulum.L_over_J / 1.25)
    assert rv["pendulum.mgd_over_J"] == pytest.approx(RIG.pendulum.mgd_over_J / 1.25)
    rv = get_effect("sensor_offset").rig_values(RIG, {"theta_offset": 0.04})
    assert rv == {"sensor_offset.theta_offset": 0.04, "measurement.theta_offset": 0.04}


def test_switching_an_effect_on_leaves_the_terms_the_nominal_had_off():
    # a rig without viscous friction: adding the rotor's B_m must not switch the rod's c/J on
    rig = RIG.with_effects(viscous_friction=False)  # the legacy switch: rod and rotor halves off
    r = get_effect("rotor_friction").apply(rig, {"B_m": 1e-5})
    assert r.effects.rotor_viscous_friction and r.motor.B_m == 1e-5 and not r.effects.rod_viscous_friction
    r = get_effect("viscous_friction").apply(rig, {"c_over_J": 2.0})
    assert r.effects.rod_viscous_friction and r.pendulum.c_over_J == 2.0
    assert not r.effects.rotor_viscous_friction
    r = get_effect("coulomb_friction").apply(RIG, {"coulomb_over_J": 1.0})
    assert r.effects.rod_coulomb_friction and not r.effects.rotor_coulomb_friction


def test_hbridge_drop_on_ideal_map_is_a_clipped_voltage_offset():
    ideal = RIG.with_effects(hbridge_map=False)
    r = get_effect("hbridge_drop").apply(ideal, {"V_drop": 0.3})
    m = PlantModel(r)
    for tau in (0.0, 0.1, 0.13, 0.5, 1.0):
        expected = max(0.0, ideal.actuator.v_supply * tau - 0.3)
        assert m.armature_voltage(tau) == pytest.approx(expected, abs=1e-12)


def test_supply_voltage_scales_the_drive_map_and_composes_with_a_bridge_drop():
    # a drift-only entry (never a diagnosis candidate): V_s scales v_a(τ) on both maps
    assert get_effect("supply_voltage").kind == "drift" and "supply_voltage" not in [e.name for e in CATALOG]
    for rig in (RIG, RIG.with_effects(hbridge_map=False)):
        m0 = PlantModel(rig)
        m = PlantModel(get_effect("supply_voltage").apply(rig, {"v_supply": 0.8 * rig.actuator.v_supply}))
        for tau in (0.2, 0.5, 1.0):
            assert m.armature_voltage(tau) == pytest.approx(0.8 * m0.armature_voltage(tau), rel=1e-12)
    # ideal map: a 12 V supply that dropped to 10 V, and a 0.3 V bridge drop: v_a = max(0, 10·τ − 0.3)
    ideal = RIG.with_effects(hbridge_map=False).with_params("actuator", v_supply=12.0)
    r, _ = apply_effects(ideal, {"hbridge_drop": {"V_drop": 0.3}, "supply_voltage": {"v_supply": 10.0}})
    m = PlantModel(r)
    for tau in (0.0, 0.02, 0.1, 0.5, 1.0):
        assert m.armature_voltage(tau) == pytest.approx(max(0.0, 10.0 * tau - 0.3), abs=1e-12)


def test_thrust_law_sets_level_and_shape():
    r = get_effect("thrust_law").apply(RIG, {"K_q": 2 * RIG.thrust.K_q, "exponent": 2.3})
    n = RIG.motor.gear_ratio
    for w2 in (10.0, 50.0):
        assert PlantModel(r).thrust(n * w2) == pytest.approx(2 * RIG.thrust.K_q * w2**2.3, rel=1e-12)


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
        get_effect("dead_zone").apply(RIG, {"dead_zone": 0.99})
    with pytest.raises(GapError, match="outside"):
        get_effect("propeller_drag").apply(RIG, {"K_d": -1e-6})
    with pytest.raises(GapError, match="no value for K_d"):
        get_effect("propeller_drag").apply(RIG, {})
    with pytest.raises(GapError, match="no parameter 'tau'"):
        get_effect("dead_zone").apply(RIG, {"tau": 0.1})


def test_identifiability_from_recorded_channels():
    theta_only = frozenset({"theta"})
    for name in ("back_emf", "armature_inductance", "armature_resistance", "torque_constant"):
        assert "needs i_a" in identifiable(EFFECTS[name], theta_only)
    for name in ("propeller_drag", "rotor_friction"):
        assert "needs omega_rotor" in identifiable(EFFECTS[name], theta_only)
    for name in ("dead_zone", "input_delay", "coulomb_friction", "sensor_offset", "thrust_coefficient",
                 "thrust_law"):
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
    with pytest.raises(GapError, match="duty cycle is constant in every one of the fit recordings"):
        check_recordings([r], "fit recordings", need_changing_input=True)
    still = _rec(theta=np.full(400, 0.2))
    still.duty[:] = 0.4
    with pytest.raises(GapError, match="θ is constant"):  # a hold under which nothing moves
        check_recordings([_rec(), still])
    with pytest.raises(GapError, match=r"expected aeropend_sim\.recording\.Recording"):
        check_recordings([{"theta": [0.0]}])


# ------------------------------------------------------------------ recovery of each effect
#: Physical truths (SI) on the thesis rig, chosen by hand; a catalog effect without a row here (a
#: new one) is recovered at a truth drawn from the ranges declared with it (:func:`_truth`).
_P, _M, _T = RIG.pendulum, RIG.motor, RIG.thrust
TRUTH = {
    "hbridge_drop": {"V_drop": 0.2}, "dead_zone": {"dead_zone": 0.08},
    "back_emf": {"K_omega": 1.6 * _M.K_omega}, "armature_resistance": {"R_a": 1.4 * _M.R_a},
    "armature_inductance": {"L_a": 8.0 * _M.L_a}, "torque_constant": {"K_t": 0.75 * _M.K_t},
    "rotor_friction": {"B_m": 6.0 * _M.B_m}, "coulomb_friction": {"coulomb_over_J": 1.0},
    "viscous_friction": {"c_over_J": 2.0 * _P.c_over_J}, "thrust_coefficient": {"K_q": 0.85 * _T.K_q},
    "propeller_drag": {"K_d": 2.0 * _M.K_d}, "actuator_lag": {"lag_time_constant": 0.08},
    "input_delay": {"input_delay": 0.06}, "gravity": {"mgd_over_J": 1.2 * _P.mgd_over_J},
    "inertia": {"J_scale": 1.3}, "end_stops": {"theta_max": 0.7}, "sensor_offset": {"theta_offset": 0.06},
    "sensor_scale": {"theta_scale": 1.1}, "motor_time_constant": {"J_m": 3.0 * _M.J_m},
    # a micro-motor's winding warming by about 40 K here (R_a +16 %) with a thermal time constant
    # R_th·C_th = 3 s, a quarter of the recording: one far shorter than τ_th determines C_th only
    "motor_heating": {"R_th": 150.0, "C_th": 0.02},
}
#: Relative tolerance on the effect size |value − nominal| (50 dB noise, 12 s recording).
REL_TOL = 0.1


#: Every fitted effect of the thesis rig's catalog (refinements are tried only after what they refine).
FITTED = sorted(e.name for e in CATALOG if e.kind != "direct" and not e.refines)


def _truth(name: str) -> dict[str, float]:
    return TRUTH.get(name) or draw_truth(name, np.random.default_rng(7), RIG)


@pytest.mark.parametrize("name", FITTED)
def test_each_effect_recovered_by_output_error_fit(name):
    truth = {name: _truth(name)}
    real, meas = apply_effects(RIG, truth)
    real = real.with_params("sensors", snr_db=50.0).with_effects(sensor_noise=True)
    dt = RIG.sample_period
    duty = np.concatenate([np.zeros(200), aprbs(12.0, lo=0.1, hi=0.72, min_hold=0.4, max_hold=2.0, seed=3,
                                                 dt=dt).duty])
    rec = record(real, meas, duty, seed=5, channels=FIT_CHANNELS, source=f"unit-{name}")
    preps = prepare([rec], frozenset(FIT_CHANNELS))
    ctx = EffectContext.from_data(RIG, rec.channels["theta"], rec.duty)
    res = fit_effects(RIG, [name], preps, ctx)
    for pname, true_v in truth[name].items():
        off = get_effect(name).ranges(ctx)[pname].off
        got = res.values[name][pname]
        assert abs(got - true_v) <= REL_TOL * abs(true_v - off), (name, got, true_v)
    # the fitted error is at the noise floor: far below the nominal error
    nominal = residuals(RIG, MeasurementMap(), preps)
    assert res.sse < 0.05 * float(nominal @ nominal)


def test_fit_leaves_a_log_parameter_started_at_its_nominal_value():
    # regression: a log parameter at its nominal value has optimiser coordinate 0, where scipy's
    # relative finite-difference step collapses to 1e-8 and the gradient reads 0 (the fit never
    # left its start); the absolute step of fit_effects must move it
    truth = {"gravity": {"mgd_over_J": 0.8 * _P.mgd_over_J}}
    real, meas = apply_effects(RIG, truth)
    duty = np.concatenate([np.zeros(200), aprbs(8.0, lo=0.1, hi=0.72, min_hold=0.4, max_hold=2.0, seed=4,
                                                 dt=RIG.sample_period).duty])
    rec = record(real.with_params("sensors", snr_db=50.0).with_effects(sensor_noise=True), meas, duty, seed=6,
                 channels=("theta",), source="unit-start")
    preps = prepare([rec], frozenset({"theta"}))
    ctx = EffectContext.from_data(RIG, rec.channels["theta"], rec.duty)
    res = fit_effects(RIG, ["gravity"], preps, ctx, start={"gravity": {"mgd_over_J": _P.mgd_over_J}},
                      scan=False)
    assert res.values["gravity"]["mgd_over_J"] == pytest.approx(0.8 * _P.mgd_over_J, rel=0.01)


def test_a_fit_refuses_an_effect_of_another_family_by_name():
    # an ESC's speed response on an H-bridge rig read the rig's missing T_m (AttributeError) before
    rec = Recording(t=np.arange(200) * 0.01, duty=np.full(200, 0.5), channels={"theta": np.zeros(200)})
    preps = prepare([rec], frozenset({"theta"}))
    ctx = EffectContext.from_data(RIG, rec.channels["theta"], rec.duty)
    with pytest.raises(GapError, match=r"\['esc_response'\] are not hypotheses for a dc_hbridge rig"):
        fit_effects(RIG, ["inertia", "esc_response"], preps, ctx)


def test_a_parameter_rig_fit_left_at_a_bound_has_its_effects_confirmed():
    """Issue 60 item 5: a rig fit value at its search bound may have absorbed an effect; gap confirms
    the catalog effects that set that parameter (and those confusable with them), and says so."""
    from aeropend_ident.gap.run import bound_effects
    from aeropend_ident.greybox.rig_fit_result import BOUND_FLAG
    from aeropend_sim.params import load_rig, rig_from_dict, rig_to_dict

    doc = rig_to_dict(load_rig("thesis_rig"))
    assert bound_effects(rig_from_dict(doc)) == ([], [])
    flag = f"fitted (rig fit): 0.12 ± 0.001 1; {BOUND_FLAG} 0.12 (searched 0 … 0.12)"
    doc["actuator"]["dead_zone"]["source"] = flag
    notes, effects = bound_effects(rig_from_dict(doc))
    assert effects == ["dead_zone", "hbridge_drop"]
    assert len(notes) == 1 and notes[0].startswith("rig fit left actuator.dead_zone at a search bound")
