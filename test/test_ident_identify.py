"""The identification command on a contract bag (write_bag of a simulated thesis_sim run)."""

from __future__ import annotations

import time

import pytest
import yaml

from aeropend_ident.bags import write_bag
from aeropend_ident.identify import main
from aeropend_sim.excitation import aprbs
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulate import simulate


@pytest.fixture(scope="module")
def noisy_run():
    rig = load_rig("thesis_sim").with_effects(sensor_noise=True).with_params("sensors", snr_db=50)
    return simulate(rig, aprbs(20.0, lo=0.2, hi=0.9, min_hold=0.02, max_hold=0.3, seed=1).duty, seed=3)


def test_identify_bag_50db(noisy_run, tmp_path, capsys) -> None:
    bag = write_bag(Recording.from_trajectory(noisy_run), tmp_path / "run")
    out = tmp_path / "res"
    t0 = time.perf_counter()
    assert main([str(bag), "--rig", "thesis_sim", "--out", str(out)]) == 0
    wall = time.perf_counter() - t0
    doc = yaml.safe_load((out / "model.yaml").read_text(encoding="utf-8"))
    assert set(doc["equations"]) == {"theta_dot", "i_a", "omega_rotor"}
    assert set(doc["equations"]["theta_dot"]["terms"]) >= {"θ̇", "sin(θ)", "ω₁²"}
    assert doc["derived_parameters"]["K_q"]["value"] == pytest.approx(1e-4, rel=0.02)
    assert (out / "summary.json").is_file() and "θ̈ =" in capsys.readouterr().out
    assert wall < 30.0


def test_identify_angle_only_bag_and_errors(noisy_run, tmp_path, capsys) -> None:
    rec = Recording.from_trajectory(noisy_run, channels=("theta",))
    bag = write_bag(rec, tmp_path / "theta_only")
    assert main([str(bag), "--out", str(tmp_path / "r1"), "--library", "physics"]) == 0
    doc = yaml.safe_load((tmp_path / "r1" / "model.yaml").read_text(encoding="utf-8"))
    assert list(doc["equations"]) == ["theta_dot"]  # no current or rotor equation without i_a, ω₁
    assert main([str(tmp_path / "missing_bag"), "--out", str(tmp_path / "r2")]) == 2
    assert "identify:" in capsys.readouterr().err
