"""Controllers on the independent truth plant (issue 19): the sample-by-sample truth stepper, the
rig file's recording frame, and the loop from a ``gap``-corrected rig file back to control."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from aeropend_control.controller_core import ControllerConfigError, ControllerLoop, make_settings
from aeropend_sim.recording_frame import RecordingFrame, read_recording_frame
from bench.fixtures import truth_plant as tp
from bench.fixtures.truth_rig import lab_rig_doc, write_rig

RIGS = Path(__file__).resolve().parents[2] / "src/aeropend_sim/aeropend_sim/rigs"


def test_truth_stepper_reproduces_the_batch_simulation_bit_for_bit():
    effects = {"actuator_lag": 0.04, "dead_zone": 0.07, "coulomb_friction": 1.2, "input_delay": 3 * tp.DT,
               "sensor_offset": 0.03, "thrust_coefficient": 0.9}
    plant = tp.TruthPlant(effects=effects)
    duty = tp.aprbs(6.0, seed=4)
    batch = plant.simulate(duty)
    st = tp.TruthStepper(plant)
    theta, omega, rec = [], [], []
    for u in duty:
        s = st.sample()
        theta.append(st.state[0])
        omega.append(s["omega_rotor"])
        rec.append(s["theta"])
        st.step(u)
    assert np.array_equal(batch["theta"], theta)
    assert np.array_equal(batch["omega_rotor"], omega)
    assert np.array_equal(batch["theta_recorded"], rec)
    assert batch["theta"].max() > 0.2  # the run moved the rod (0.229 rad)
    with pytest.raises(tp.TruthError, match="duty"):
        st.step(1.2)


def test_truth_stepper_noise_has_the_stated_sigma():
    st = tp.TruthStepper(tp.TruthPlant(), sigma={"theta": 2e-3}, seed=1)
    x = np.array([st.step(0.0)["theta"] for _ in range(4000)])  # rod at rest: the reading is noise
    assert np.std(x) == pytest.approx(2e-3, rel=0.05)
    with pytest.raises(tp.TruthError, match="channels"):
        tp.TruthStepper(tp.TruthPlant(), sigma={"speed": 1.0})


def _rig_with_frame(tmp_path: Path, frame: dict) -> Path:
    doc = yaml.safe_load((RIGS / "thesis_sim.yaml").read_text(encoding="utf-8"))
    doc["recording_frame"] = frame
    return write_rig(doc, tmp_path / "rig.yaml")


def test_the_loop_runs_on_the_model_angle_of_the_rig_files_recording_frame(tmp_path):
    path = _rig_with_frame(tmp_path, {
        "theta_offset": {"value": 0.1, "unit": "rad", "source": "gap diagnosis: fitted sensor offset"},
        "theta_scale": {"value": 1.25, "unit": "1", "source": "gap diagnosis: fitted sensor gain"}})
    assert read_recording_frame(path) == RecordingFrame(0.1, 1.25)
    assert read_recording_frame("thesis_sim") == RecordingFrame()
    loop = ControllerLoop(make_settings(rig=str(path), strategy="fl_pid", mode="lockstep", reference=0.3))
    loop.on_sample(0, 0.25)  # recorded 0.25 rad = model 0.25/1.25 + 0.1 = 0.3 rad
    assert loop.last_signals[2] == pytest.approx(0.3)
    assert loop.last_signals[3] == pytest.approx(0.0)  # at the reference: no error


def test_a_malformed_recording_frame_is_refused_naming_the_key(tmp_path):
    path = _rig_with_frame(tmp_path, {"theta_offset": {"value": 0.1, "unit": "deg", "source": "x"}})
    with pytest.raises(ControllerConfigError, match=r"recording_frame\.theta_offset has unit 'deg'"):
        make_settings(rig=str(path))
    path = _rig_with_frame(tmp_path, {"theta_scale": {"value": 0.0, "unit": "1", "source": "x"}})
    with pytest.raises(ControllerConfigError, match=r"theta_scale = 0\.0 must be finite and > 0"):
        make_settings(rig=str(path))


@pytest.mark.slow
def test_design_gains_schedules_a_weak_rig_up_to_its_reach(tmp_path, capsys):
    from aeropend_control.design_gains import main

    # the ideal drive: reach ≈ 0.67 rad < the grid's 1.1 rad
    rig = write_rig(lab_rig_doc(), tmp_path / "weak.yaml")
    out = tmp_path / "gains.yaml"
    assert main(["--rig", str(rig), "-o", str(out)]) == 0
    gains = yaml.safe_load(out.read_text(encoding="utf-8"))
    reach = gains["reach_rad"]
    assert 0.6 < reach < 0.72
    ops = [d["theta_op"] for d in gains["small_signal"]]
    assert ops[-1] == pytest.approx(reach) and all(math.isfinite(x) for x in ops)
    assert "reach" in capsys.readouterr().out


def _lag_rig(tmp_path: Path, lag: float | None, delay: float = 0.0) -> str:
    """The thesis_sim rig with an ideal drive (the truth plant's nominal), optionally declaring a
    drive lag as gap's corrected rig does."""
    doc = lab_rig_doc()
    if lag is not None:
        doc["effects"]["actuator_lag"] = True
        doc["actuator"]["lag_time_constant"]["value"] = lag
    if delay:
        doc["effects"]["input_delay"] = True
        doc["actuator"]["input_delay"]["value"] = delay
    return str(write_rig(doc, tmp_path / f"rig_{lag}.yaml"))


def _step_on_truth(rig: str, strategy: str, plant: tp.TruthPlant, r: float = 0.2,
                   n: int = 2000, detune: bool = True, detuned: list | None = None) -> np.ndarray:
    """θ of a step from rest; ``detune=False`` keeps a cascade's design fixed; the cascade's
    detuned bandwidths are appended to ``detuned``."""
    loop = ControllerLoop(make_settings(rig=rig, strategy=strategy, mode="lockstep", reference=r))
    inner = getattr(loop.strategy, "inner", None)
    if inner is not None and not detune:
        inner.monitor = None
    st = tp.TruthStepper(plant)
    s, theta, events = st.sample(), np.empty(n), []
    for k in range(n):
        theta[k] = st.state[0]
        s = st.step(loop.on_sample(k * 2_048_000, s["theta"], s["omega_rotor"], s["i_a"]))
        if loop.detune_event is not None:  # what the node logs, once per detuning
            events.append(loop.detune_event)
    if inner is not None and detuned is not None:
        detuned.extend(inner.detuned)
        assert [after for _, after in events] == inner.detuned
    return theta


@pytest.mark.slow
def test_a_rig_file_that_knows_the_drive_lag_gives_a_better_controller(tmp_path):
    """Truth plant with a 50 ms drive lag, 2 samples delay, dead zone 0.04 and rod Coulomb friction
    1 rad/s²: FL designed on a rig file that declares it (thrust loop
    on the predicted thrust) overshoots less; the cascade designed on a rig file that declares the
    lag and delay (bandwidths limited by them) does not limit-cycle and is never detuned, the one
    designed on the nominal rig does with its design held fixed."""
    from aeropend_control.design import design_cascade
    from aeropend_control.drive_design import THRUST_LOOP_GAIN, default_thrust_gain
    from aeropend_sim.params import load_rig

    plant = tp.TruthPlant(effects={"actuator_lag": 0.05, "input_delay": 2 * tp.DT, "dead_zone": 0.04,
                                   "coulomb_friction": 1.0})
    nominal, known = _lag_rig(tmp_path, None), _lag_rig(tmp_path, 0.05, 2 * tp.DT)
    assert default_thrust_gain(load_rig(nominal)) == 0.0
    assert default_thrust_gain(load_rig(known)) == THRUST_LOOP_GAIN
    d = design_cascade(load_rig(known))
    assert d.omega_speed == pytest.approx(math.tan(math.radians(55.0)) / (0.05 + 2 * tp.DT))  # 26.4 < 45
    assert d.omega_current == pytest.approx(2.5 * d.omega_speed)

    def overshoot(th: np.ndarray) -> float:
        return (th.max() - 0.2) / 0.2 * 100.0

    fl_nom, fl_known = (_step_on_truth(rig, "fl_pid", plant) for rig in (nominal, known))
    assert overshoot(fl_nom) > 15.0 and overshoot(fl_known) < 0.7 * overshoot(fl_nom)
    tail = slice(-500, None)  # last 1 s
    cas_fixed = _step_on_truth(nominal, "cascade", plant, detune=False)
    assert np.ptp(cas_fixed[tail]) > 0.005  # sustained oscillation (7 mrad peak to peak measured)
    known_detuned: list[float] = []
    cas_known = _step_on_truth(known, "cascade", plant, detuned=known_detuned)
    assert np.ptp(cas_known[tail]) < 0.002 and abs(cas_known[tail].mean() - 0.2) < 0.004
    assert known_detuned == []  # the declared lag's design does not cycle: never changed


def test_the_cascade_detunes_itself_out_of_a_limit_cycle_an_unknown_drive_lag_causes(tmp_path):
    """Same truth plant, cascade designed on the nominal rig file (it does not know the 50 ms lag):
    with a fixed design the duty bangs between its limits and θ oscillates for ever; the limit-cycle
    monitor detects it, the speed loop is redesigned at 30 rad/s (45 × 2/3) and the rod settles in
    the 2 % band. On the nominal truth plant (no lag) the design is never touched."""
    plant = tp.TruthPlant(effects={"actuator_lag": 0.05, "input_delay": 2 * tp.DT, "dead_zone": 0.04,
                                   "coulomb_friction": 1.0})
    nominal = _lag_rig(tmp_path, None)
    tail = slice(-500, None)  # last 1 s of 4 s
    fixed = _step_on_truth(nominal, "cascade", plant, detune=False)
    detuned: list[float] = []
    adaptive = _step_on_truth(nominal, "cascade", plant, detuned=detuned)
    assert np.ptp(fixed[tail]) > 0.005
    assert detuned == [pytest.approx(30.0)]
    assert np.ptp(adaptive[tail]) < 0.002 and abs(adaptive[tail].mean() - 0.2) < 0.004
    for strategy in ("cascade", "fl_cascade"):
        clean: list[float] = []
        theta = _step_on_truth(nominal, strategy, tp.TruthPlant(), detuned=clean)
        assert clean == [] and abs(theta[tail].mean() - 0.2) < 0.004


GAP_RIG = Path(__file__).resolve().parents[1] / "data" / "gap_corrected_rig.yaml"


@pytest.mark.slow
def test_design_gains_and_every_strategy_take_the_rig_file_gap_wrote(tmp_path, capsys):
    """``corrected_rig.yaml`` as ``gap`` wrote it for plant 1 of the independent closed-loop
    benchmark (``corrected_rig_dict`` of ``run_gap`` on a 40 s APRBS recording; effects added:
    actuator lag, thrust coefficient, dead zone): design_gains designs on it, the four strategies
    start on it through the node's settings, the declared lag switches on the thrust loop and limits
    the cascade's speed loop, and the loop holds the nominal rig's simulator at a set point."""
    from aeropend_control.design_gains import main
    from aeropend_control.drive_design import THRUST_LOOP_GAIN
    from aeropend_sim.params import load_rig

    rig = load_rig(GAP_RIG)
    assert rig.effects.actuator_lag and rig.actuator.lag_time_constant > 0.0
    assert main(["--rig", str(GAP_RIG), "-o", str(tmp_path / "gains.yaml")]) == 0
    assert "reach" in capsys.readouterr().out
    gains = yaml.safe_load((tmp_path / "gains.yaml").read_text(encoding="utf-8"))
    for name in ("small_signal", "fl_pid", "cascade", "fl_cascade"):
        loop = ControllerLoop(make_settings(rig=str(GAP_RIG), strategy=name, mode="lockstep", reference=0.3))
        outer = getattr(loop.strategy, "outer", loop.strategy)
        assert outer.thrust_gain == THRUST_LOOP_GAIN
        if name in ("small_signal", "fl_pid"):  # design_gains prints the design the node runs
            spec = loop.settings.spec
            assert gains["pole_spec"][name] == {"omega_n": spec.omega_n, "zeta": spec.zeta, "rho": spec.rho}
            assert loop.settings.spec.zeta > 0.7  # the robust choice on a rig that declares its drive
        if name == "fl_pid":
            assert (outer.design.kp, outer.design.ki, outer.design.kd) == pytest.approx(
                (gains["fl_pid"]["kp"], gains["fl_pid"]["ki"], gains["fl_pid"]["kd"]))
        if name in ("cascade", "fl_cascade"):
            assert loop.strategy.inner.design.omega_speed < 45.0
    plant = tp.TruthPlant()  # the nominal plant: a corrected rig must still hold it
    theta = _step_on_truth(str(GAP_RIG), "fl_pid", plant, r=0.3, n=1500)
    assert abs(theta[-250:].mean() - 0.3) < 0.006


@pytest.mark.slow
def test_gap_on_one_recording_then_the_controllers_on_the_rig_file_it_wrote(tmp_path):
    """End to end, as a lab would: a 20 s open-loop APRBS recording of a truth plant whose drive
    has a 50 ms lag and 2 samples of delay (50 dB noise) → ``run_gap`` → ``corrected_rig.yaml`` →
    every strategy designed on it (drive-chain design, thrust loop, lag-limited cascade) steps to
    0.3 rad on that plant. Designed on the nominal rig the FL and small-signal loops overshoot 15-17 %,
    the cascades 7.5-8.6 %; on the corrected rig (robust ω_n and ζ, ``drive_design.robust_spec``)
    every strategy settles within 0.85 s (0.54-0.78 s) and overshoots less than 3 % (0.44-0.75 %),
    at most a quarter of what it does designed on the nominal rig (measured 0.03-0.09 times)."""
    from aeropend_ident.gap.result import corrected_rig_dict
    from aeropend_ident.gap.run import run_gap
    from aeropend_ident.io.split import time_ordered
    from aeropend_sim.params import load_rig
    from aeropend_sim.recording import Recording

    plant = tp.TruthPlant(effects={"actuator_lag": 0.05, "input_delay": 2 * tp.DT})
    nominal = str(write_rig(lab_rig_doc(), tmp_path / "nominal.yaml"))
    tr = tp.record(plant, tp.aprbs(20.0, seed=3), 50.0, 4)
    rec = Recording(t=tr.t, duty=tr.duty, channels=dict(tr.channels), source="truth",
                    meta={"synthetic": True})
    fit, held, rule = time_ordered([rec], 0.7)
    res = run_gap(load_rig(nominal), fit, held, rig_ref=nominal, split_rule=rule, seed=0, max_effects=3)
    assert "actuator_lag" in res.diagnosis.chosen
    corrected = tmp_path / "corrected_rig.yaml"
    corrected.write_text(yaml.safe_dump(corrected_rig_dict(res), sort_keys=False, allow_unicode=True),
                         encoding="utf-8")
    t = np.arange(2500) * tp.DT
    for strategy in ("fl_pid", "small_signal", "cascade", "fl_cascade"):
        mp = {}
        for name, rig in (("nominal", nominal), ("corrected", str(corrected))):
            theta = _step_on_truth(rig, strategy, plant, r=0.3, n=t.size)
            band = np.abs(theta - 0.3) > 0.02 * 0.3
            ts = t[np.flatnonzero(band)[-1] + 1]
            mp[name] = max(0.0, (theta.max() - 0.3) / 0.3 * 100.0)
        assert ts <= 0.85, (strategy, ts)
        assert mp["corrected"] < 3.0 and mp["corrected"] <= 0.25 * mp["nominal"], (strategy, mp)


def test_a_rig_file_that_declares_coulomb_friction_designs_on_the_viscous_damping_alone(tmp_path):
    """The rod's Coulomb friction in a rig file (as ``gap`` writes it when it names the effect) has
    no small-signal damping: its regularised sign is steep only below v_ε = 0.01 rad/s. Counted as
    damping (a1 = c/J + (T_f/J)/v_ε ≈ 230 1/s with T_f/J = 2.15 rad/s²) it made the small-signal loop
    and the cascade above it oscillate (overshoot 218 % and 76 %, no settling, on a tuning plant of
    the independent benchmark). Designed on c/J alone, both settle on a truth plant with that
    friction."""
    from aeropend_control.design import design_small_signal
    from aeropend_sim.model import PlantModel
    from aeropend_sim.params import load_rig

    doc = lab_rig_doc()
    doc["effects"]["coulomb_friction"] = True
    doc["pendulum"]["coulomb_over_J"] = {"value": 2.15, "unit": "rad/s^2", "source": "test"}
    path = str(write_rig(doc, tmp_path / "coulomb.yaml"))
    rig = load_rig(path)
    m = PlantModel(rig)
    x_eq, tau_eq = m.equilibrium(0.3)
    A, _ = m.jacobian(x_eq, tau_eq)
    assert -A[1, 1] > 200.0  # the simulation's regularised sign at rest
    assert design_small_signal(rig, 0.3).a1 == pytest.approx(m.a_c)
    plant = tp.TruthPlant(effects={"coulomb_friction": 2.15})
    t = np.arange(2500) * tp.DT
    for strategy in ("small_signal", "cascade"):
        theta = _step_on_truth(path, strategy, plant, r=0.3, n=t.size)
        band = np.abs(theta - 0.3) > 0.02 * 0.3
        assert not band[-500:].any(), strategy  # settled over the last second
        assert (theta.max() - 0.3) / 0.3 < 0.1, strategy
