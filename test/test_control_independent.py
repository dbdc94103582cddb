"""Controllers on the independent truth plant (issue 19): the sample-by-sample truth stepper, the
rig file's recording frame, and the loop from a ``gap``-corrected rig file back to control."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from aeropend_control.controller_core import ControllerConfigError, ControllerLoop, make_settings
from aeropend_control.frame import RecordingFrame, read_recording_frame

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

import truth_plant as tp  # noqa: E402

RIGS = Path(__file__).resolve().parents[1] / "src/aeropend_sim/aeropend_sim/rigs"


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
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(doc, allow_unicode=True), encoding="utf-8")
    return path


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
    with pytest.raises(ControllerConfigError, match="recording_frame.theta_offset has unit 'deg'"):
        make_settings(rig=str(path))
    path = _rig_with_frame(tmp_path, {"theta_scale": {"value": 0.0, "unit": "1", "source": "x"}})
    with pytest.raises(ControllerConfigError, match="theta_scale = 0.0 must be finite and > 0"):
        make_settings(rig=str(path))


def test_design_gains_schedules_a_weak_rig_up_to_its_reach(tmp_path, capsys):
    from aeropend_control.design import main

    doc = yaml.safe_load((RIGS / "thesis_sim.yaml").read_text(encoding="utf-8"))
    doc["effects"]["hbridge_map"] = False
    doc["actuator"]["v_supply"]["value"] = 2.32  # ideal drive: reach ≈ 0.67 rad < the grid's 1.1 rad
    rig = tmp_path / "weak.yaml"
    rig.write_text(yaml.safe_dump(doc, allow_unicode=True), encoding="utf-8")
    out = tmp_path / "gains.yaml"
    assert main(["--rig", str(rig), "-o", str(out)]) == 0
    gains = yaml.safe_load(out.read_text(encoding="utf-8"))
    reach = gains["reach_rad"]
    assert 0.6 < reach < 0.72
    ops = [d["theta_op"] for d in gains["small_signal"]]
    assert ops[-1] == pytest.approx(reach) and all(math.isfinite(x) for x in ops)
    assert "reach" in capsys.readouterr().out
