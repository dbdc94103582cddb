"""The independent truth plant of the blind benchmarks (bench/fixtures/truth_plant.py).

It must not share code with what it checks (no aeropend import at all), must agree with
aeropend's nominal simulator where both model the same plant (two independent implementations of
the thesis equations), must obey its own physics, and a lab's path through it (CSV log ->
``csv_import`` -> ``gap``) must name the effect hidden in it.
"""

from __future__ import annotations

import ast
import json
import math
from pathlib import Path

import numpy as np
import pytest

from bench.fixtures import truth_plant as tp
from bench.fixtures.truth_rig import lab_rig_doc, write_rig


def test_truth_plant_imports_nothing_from_aeropend():
    tree = ast.parse(Path(tp.__file__).read_text(encoding="utf-8"))
    modules = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            modules.add((node.module or "").split(".")[0])
    assert not {m for m in modules if m.startswith("aeropend")}
    assert modules <= {"__future__", "dataclasses", "math", "collections", "typing", "numpy", "scipy"}


def test_steady_state_matches_the_analytic_equilibrium():
    p = tp.PlantParams()
    tau = 0.8
    out = tp.TruthPlant(p).simulate(np.full(round(8.0 / tp.DT), tau))
    v = p.v_supply * tau
    i = v / (p.R_a + p.K_omega * p.K_t / p.B_m)  # armature and rotor at rest: di = dω = 0
    w = p.K_t * i / p.B_m
    theta = math.asin(p.L_over_J * p.K_q * (tp.GEAR * w) ** 2 / p.mgd_over_J)
    assert out["i_a"][-1] == pytest.approx(i, rel=1e-6)
    assert out["omega_rotor"][-1] == pytest.approx(w, rel=1e-6)
    assert out["theta"][-1] == pytest.approx(theta, rel=1e-4)
    # the thesis' printed coefficients: 1.7285 ω₁² in θ̈, 4519.2 and 192.31 in dω₁/dt
    assert p.L_over_J * p.K_q * tp.GEAR**2 == pytest.approx(1.7285, rel=1e-12)
    assert p.K_t / p.J_m == pytest.approx(4519.2, rel=1e-12)
    assert p.B_m / p.J_m == pytest.approx(192.31, rel=1e-12)


def test_agrees_with_aeropends_nominal_simulator():
    """Two implementations of the same equations (RK4 here, LSODA there) agree to 1e-5 rad."""
    from aeropend_sim.params import load_rig
    from aeropend_sim.simulation import simulate

    rig = load_rig("thesis_sim").with_effects(hbridge_map=False).with_params("actuator", v_supply=2.32)
    duty = tp.aprbs(10.0, seed=2)
    truth = tp.TruthPlant().simulate(duty)
    sim = simulate(rig, duty)
    for c in ("theta", "i_a", "omega_rotor", "v_a"):
        assert np.max(np.abs(sim.true[c] - truth[c])) < 1e-5 * max(1.0, np.ptp(truth[c]))


def test_effects_follow_their_physics():
    duty = np.concatenate([np.zeros(200), np.full(3000, 0.9)])
    base = tp.TruthPlant().simulate(duty)
    # transport delay: the whole response shifts by exactly the delay's samples
    d = tp.TruthPlant(effects={"input_delay": 10 * tp.DT}).simulate(duty)
    np.testing.assert_allclose(d["theta"][10:], base["theta"][:-10], atol=1e-12)
    # hard end stop: never passed
    s = tp.TruthPlant(effects={"end_stops": 0.4}).simulate(duty)
    assert s["theta"].max() <= 0.4 + 1e-12 and base["theta"].max() > 0.5
    # H-bridge drop: the drive output is V_s·τ − V_d
    h = tp.TruthPlant(effects={"hbridge_drop": 0.3}).simulate(duty)
    assert h["v_a"][-1] == pytest.approx(2.32 * 0.9 - 0.3)
    # propeller drag: steady speed from K_t·(v − K_ω·ω)/R_a = B_m·ω + K_d·ω² (a quadratic)
    p = tp.PlantParams()
    kd = 40.0 * p.J_m
    g = tp.TruthPlant(effects={"propeller_drag": kd}).simulate(duty)
    a, b, c = kd, p.B_m + p.K_t * p.K_omega / p.R_a, -p.K_t * 2.32 * 0.9 / p.R_a
    w = (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)
    assert g["omega_rotor"][-1] == pytest.approx(w, rel=1e-5) and w < 0.8 * base["omega_rotor"][-1]
    # sensor effects change the reading only
    o = tp.TruthPlant(effects={"sensor_offset": 0.05, "sensor_scale": 1.1}).simulate(duty)
    np.testing.assert_allclose(o["theta"], base["theta"])
    np.testing.assert_allclose(o["theta_recorded"], 1.1 * base["theta"] + 0.05)
    with pytest.raises(tp.TruthError, match="unknown truth effect"):
        tp.TruthPlant(effects={"magic": 1.0})


def test_noise_has_the_requested_snr():
    true = tp.TruthPlant().simulate(tp.lhs_steps(20.0, seed=1))
    meas = tp.add_noise(true, 40.0, seed=3)
    for c in tp.CHANNELS:
        y = true["theta_recorded" if c == "theta" else c]
        snr = 20 * math.log10(np.sqrt(np.mean(y**2)) / np.std(meas[c] - y))
        assert snr == pytest.approx(40.0, abs=0.2)


@pytest.mark.slow
def test_a_lab_path_csv_import_gap_names_the_hidden_drag(tmp_path, truth_csv_preset):
    """CSV log of the independent plant -> ``csv_import`` mapping -> ``gap`` with a lab's rig file:
    a propeller drag the rig file omits (K_d = 0) is named and fitted in physical units."""

    from aeropend_ident.cli.gap import main

    kd = 3.0 * tp.PlantParams().J_m  # dω₁/dt gains −3·ω₁|ω₁|
    plant = tp.TruthPlant(effects={"propeller_drag": kd})
    fit = tp.record(plant, tp.lhs_steps(40.0, seed=5), 50.0, seed=6)
    held = tp.record(plant, tp.aprbs(30.0, seed=7), 50.0, seed=8)
    fit.to_csv(tmp_path / "fit.csv")
    held.to_csv(tmp_path / "held.csv")
    preset = truth_csv_preset("_truth_plant_test")
    write_rig(lab_rig_doc(), tmp_path / "rig.yaml")
    out = tmp_path / "report"
    assert main([str(tmp_path / "fit.csv"), "--held-out", str(tmp_path / "held.csv"), "--preset",
                 preset, "--rig", str(tmp_path / "rig.yaml"), "-o", str(out), "-q"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["headline"]["effects_chosen"] == ["propeller_drag"]
    drag = rep["which"]["ranking"][0]
    assert drag["parameters"]["K_d"]["unit"] == "N*m*s^2/rad^2"
    assert drag["parameters"]["K_d"]["value"] == pytest.approx(kd, rel=0.05)
    assert rep["headline"]["heldout_shrink"] > 0.9
    assert rep["headline"]["heldout_channel_shrink"]["omega_rotor"] > 0.8
    assert rep["where_which"]["agree"]


# ------------------------------------------------------------------ the other actuator families
def _family_rig(fam, params):
    from aeropend_sim.params import rig_from_dict

    return rig_from_dict(fam.rig(params, "lab"), "lab.yaml")


@pytest.mark.parametrize("family", ["esc", "voltage_amplifier"])
def test_family_plants_agree_with_aeropend_on_the_labs_rig_file(family):
    """The lab's rig file of each hidden plant (its own quantities converted as a lab does: K_v and
    battery to ω_max, pulse widths to τ_0, C_T/C_Q to K_q/K_d, geometry to mgd/J and L/J) simulates
    the same plant: two implementations agree to 1e-5 of each channel's range. The amplifier's
    armature (L_a/R_a = 0.14 ms at 2 ms) loads quasi-static; integrated as the truth does (the switch
    named), the two agree to 1e-5; the loader's quasi-static armature stays within 3e-3 (measured
    when written: θ 1.5e-4, i_a 1.7e-3, ω₁ 9e-4 of the range; each current step lags by L_a/R_a)."""
    from aeropend_sim.simulation import simulate
    from bench.fixtures import gap_families as gf

    fam = {"esc": gf.ESC, "voltage_amplifier": gf.AMPLIFIER}[family]
    rng = np.random.default_rng(4)
    for params in (fam.nominal(), fam.variant(rng)):
        rig = _family_rig(fam, params)
        assert rig.family == family
        duty = tp.aprbs(15.0, seed=3, dt=fam.dt)
        truth = fam.plant(params, {}).simulate(duty)
        if family == "voltage_amplifier":
            assert rig.effects.armature_inductance == "quasi_static"
            sim = simulate(rig, duty)
            for c in fam.channels:
                assert np.max(np.abs(sim.true[c] - truth[c])) < 3e-3 * np.ptp(truth[c]), (family, c)
            rig = rig.with_effects(armature_inductance="dynamic")
        sim = simulate(rig, duty)
        for c in fam.channels:
            assert np.max(np.abs(sim.true[c] - truth[c])) < 1e-5 * np.ptp(truth[c]), (family, c)
    if family == "esc":  # no armature channels: absent, not zeros
        assert "i_a" not in sim.true and "v_a" not in sim.true


def test_esc_plant_follows_its_throttle_map_dead_time_and_response():
    p = tp.EscParams()
    plant = tp.EscPlant(p)
    # ω_ss = K_v·V_bat·(p − p_idle)/(p_max − p_idle): nothing below the idle pulse, linear above
    w_full = p.kv_rpm * 2 * math.pi / 60 * p.battery
    assert plant.omega_ss(1.0) == pytest.approx(w_full)
    assert plant.omega_ss((p.pulse_idle - p.pulse_min) / 1000.0 - 0.01) == 0.0
    assert plant.omega_ss(0.5) == pytest.approx(w_full * (1500 - p.pulse_idle) / (2000 - p.pulse_idle))
    n = round(3.0 / plant.dt)
    duty = np.concatenate([np.zeros(10), np.full(n, 0.6)])
    out = plant.simulate(duty)
    # the dead time: nothing moves before 10 + dead-time samples; then a first-order rise with T_r
    k0 = 10 + round(p.dead_time / plant.dt)
    assert np.all(out["omega_rotor"][: k0 + 1] == 0.0) and out["omega_rotor"][k0 + 2] > 0.0
    k = k0 + round(p.response / plant.dt)
    assert out["omega_rotor"][k] == pytest.approx((1 - math.exp(-1)) * plant.omega_ss(0.6), rel=1e-3)
    # an extra dead time shifts everything by whole samples; a lower battery scales the speed
    d = tp.EscPlant(p, {"input_delay": 0.03}).simulate(duty)
    np.testing.assert_allclose(d["omega_rotor"][3:], out["omega_rotor"][:-3], atol=1e-9)
    low = tp.EscPlant(p, {"esc_speed_range": 0.9}).simulate(duty)
    assert low["omega_rotor"][-1] == pytest.approx(0.9 * out["omega_rotor"][-1], rel=1e-6)
    # the rod at rest: (L·f) = m·g·d·sin θ with f = C_T·ρ·n²·D⁴
    f = tp.prop_thrust(p.c_t, p.diameter, out["omega_rotor"][-1])
    r = p.rod
    long = tp.EscPlant(p).simulate(np.full(round(30.0 / plant.dt), 0.6))
    held = math.asin(r.arm * f / (r.mass * tp.G_STANDARD * r.com))
    assert long["theta"][-1] == pytest.approx(held, rel=1e-3)
    with pytest.raises(tp.TruthError, match="unknown truth effect"):
        tp.EscPlant(p, {"back_emf": 1.1})


def test_amplifier_plant_steady_state_and_its_effects():
    p = tp.AmplifierParams()
    plant = tp.AmplifierPlant(p)
    n = round(6.0 / plant.dt)
    out = plant.simulate(np.full(n, 0.7))
    v = p.gain * p.v_ref * 0.7
    w = plant.steady_speed(v)
    assert out["v_a"][-1] == pytest.approx(v) and out["omega_rotor"][-1] == pytest.approx(w, rel=1e-6)
    assert out["i_a"][-1] == pytest.approx((v - p.k_e * w) / p.R_a, rel=1e-6)
    # at that speed the motor torque balances viscous friction and the propeller's drag C_Q·ρ·n²·D⁵
    q = p.c_q * tp.RHO_AIR * (w / (2 * math.pi)) ** 2 * p.diameter**5
    assert p.k_t * out["i_a"][-1] == pytest.approx(p.B * w + q, rel=1e-6)
    # brush friction slows the rotor; an output offset adds to the commanded voltage
    slow = tp.AmplifierPlant(p, {"rotor_brush_friction": 2e-3}).simulate(np.full(n, 0.7))
    ws = slow["omega_rotor"][-1]
    qs = p.c_q * tp.RHO_AIR * (ws / (2 * math.pi)) ** 2 * p.diameter**5
    assert ws < w - 5.0
    assert p.k_t * slow["i_a"][-1] == pytest.approx(p.B * ws + qs + 2e-3, rel=1e-6)
    off = tp.AmplifierPlant(p, {"amplifier_offset": 0.5}).simulate(np.full(10, 0.7))
    assert off["v_a"][-1] == pytest.approx(v + 0.5)


@pytest.mark.slow
@pytest.mark.parametrize("family", ["esc", "voltage_amplifier"])
def test_baseline_fits_each_family_on_its_hidden_plant(family, tmp_path):
    """``baseline`` (the grey-box fit of θ-only data) on an ESC and an amplifier rig: a rod whose
    damping is 1.6× and whose gravity torque is 0.9× what the lab's rig file says; the fit finds
    both (L/J absorbs the thrust scale) and the held-out error falls."""
    from aeropend_ident.greybox.baseline import run_baseline
    from aeropend_sim.recording import Recording
    from bench.fixtures import gap_families as gf

    fam = {"esc": gf.ESC, "voltage_amplifier": gf.AMPLIFIER}[family]
    params = fam.nominal()
    plant = fam.plant(params, {"viscous_friction": 1.6, "gravity": 0.9})
    duty = tp.aprbs(40.0, seed=11, dt=fam.dt)
    rec = tp.record(plant, duty, 50.0, seed=12, channels=("theta",))
    recording = Recording(t=rec.t, duty=rec.duty, channels=dict(rec.channels), source=f"{family}-truth")
    rig = _family_rig(fam, params)
    rep = run_baseline(recording, rig, tmp_path / "out", train_fraction=0.7)
    r = params.rod
    fitted = {p["name"]: p["value"] for p in rep["parameters"]}
    mgd = r.mass * tp.G_STANDARD * r.com / r.inertia
    assert fitted["pendulum.c_over_J"] == pytest.approx(1.6 * r.damping / r.inertia, rel=0.02)
    assert fitted["pendulum.mgd_over_J"] == pytest.approx(0.9 * mgd, rel=0.02)
    held = rep["metrics"]["heldout"]
    assert held["fitted"]["nrmse"] < 0.3 * held["nominal"]["nrmse"]
    assert (tmp_path / "out" / "fitted_rig.yaml").is_file()


@pytest.mark.slow
def test_a_lab_path_with_an_esc_rig_names_a_slow_speed_response(tmp_path, truth_csv_preset):
    """An ESC rig's lab path: CSV logs of θ and the ESC's rotor speed -> ``csv_import`` -> ``gap``
    with the minimal ESC rig file. The rotor follows the throttle 2.5× more slowly than the rig
    file says (a heavier propeller): named esc_response, T_m fitted, no armature check or
    hypothesis reported (an ESC has no armature), and a report written like any other."""
    import yaml

    from aeropend_ident.cli.gap import main
    from bench.fixtures import gap_families as gf

    p = tp.EscParams()
    plant = tp.EscPlant(p, {"esc_response": 2.5})
    fit = tp.record(plant, tp.lhs_steps(40.0, seed=5, dt=plant.dt), 50.0, seed=6, channels=plant.channels)
    held = tp.record(plant, tp.aprbs(30.0, seed=7, dt=plant.dt), 50.0, seed=8, channels=plant.channels)
    fit.to_csv(tmp_path / "fit.csv")
    held.to_csv(tmp_path / "held.csv")
    preset = truth_csv_preset("_truth_esc_test", ("omega_rotor",))
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(gf.esc_rig(p, "lab_esc"), allow_unicode=True))
    out = tmp_path / "report"
    assert main([str(tmp_path / "fit.csv"), "--held-out", str(tmp_path / "held.csv"), "--preset", preset,
                 "--rig", str(tmp_path / "rig.yaml"), "-o", str(out), "-q"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["headline"]["effects_chosen"][0] == "esc_response"
    top = rep["which"]["ranking"][0]
    assert top["parameters"]["T_m"]["value"] == pytest.approx(2.5 * p.response, rel=0.05)
    candidates = ({r["effect"] for r in rep["which"]["ranking"]}
                  | {x["effect"] for x in rep["which"]["not_identifiable"]})
    assert not candidates & {"back_emf", "armature_resistance", "rotor_friction", "propeller_drag"}
    assert rep["headline"]["heldout_shrink"] > 0.8
    assert (out / "report.html").is_file() and (out / "corrected_rig.yaml").is_file()
