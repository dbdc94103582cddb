"""A state no channel holds, carried across a cut of the run (issue 64 item 3, motor heating).

A validation stretch carved from a running session starts with the winding warm. The replay of
such a stretch (the diagnosis' batched replays and the one free run its figures come from) starts
its winding temperature T_m where the candidate's own replay of the commands before the cut ends
(:attr:`aeropend_sim.recording.Recording.duty_before`); the truth here is the whole run simulated
in one piece. Before this, the stretch was replayed from a cold winding and the diagnosis named
heating in 2 of 8 heated plants of ``bench/bench_gap_heating.py``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from aeropend_ident.gap.effects import MeasurementMap
from aeropend_ident.gap.which.data import prepare, replay_many, replay_reference
from aeropend_ident.gap.which.metrics import one_free_run
from aeropend_sim.model import plant_model
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import simulate

ALPHA, R_TH, C_TH = 3.93e-3, 20.0, 0.5  # copper; 20 K/W; τ_th = 10 s


def _heated():
    return load_rig("thesis_rig").with_params("motor", alpha_R=ALPHA, R_th=R_TH, C_th=C_TH).with_effects(
        motor_heating=True, sensor_noise=False, quantisation=False)


def test_a_slice_keeps_the_commands_of_the_run_before_it():
    rec = Recording(t=np.arange(10) * 0.01, duty=np.linspace(0.0, 0.9, 10), channels={"theta": np.zeros(10)})
    head, tail = rec.split(0.5)
    assert rec.duty_before is None and head.duty_before is None
    np.testing.assert_array_equal(tail.duty_before, rec.duty[:5])
    np.testing.assert_array_equal(tail.slice(2, 5).duty_before, rec.duty[:7])
    np.testing.assert_array_equal(tail.slice(0, 5).duty_before, rec.duty[:5])
    with pytest.raises(ValueError, match=r"duty_before has shape \(2, 2\), expected \(M,\)"):
        dataclasses.replace(rec, duty_before=np.zeros((2, 2)))


def test_a_stretch_cut_from_a_running_session_starts_with_the_winding_where_the_run_left_it():
    rig = _heated()
    dt = rig.sample_period
    n = round(30.0 / dt)
    duty = np.repeat(np.random.default_rng(3).uniform(0.45, 0.8, 15), -(-n // 15))[:n]
    whole = simulate(rig, duty)
    t_m = plant_model(rig).states.index("T_m")
    rec = Recording(t=np.arange(n) * dt, duty=duty,
                    channels={"theta": whole.true["theta"], "i_a": whole.true["i_a"]})
    k = round(0.7 * n)
    assert whole.x[k, t_m] > 3.0  # the winding is warm at the cut
    stretch = rec.slice(k, n)
    warm = prepare([stretch], frozenset({"theta", "i_a"}))[0]
    cold = prepare([dataclasses.replace(stretch, duty_before=None)], frozenset({"theta", "i_a"}))[0]

    ref = replay_reference(rig, MeasurementMap(), warm)
    assert ref["_x"][0, t_m] == pytest.approx(whole.x[k, t_m], rel=2e-3)
    assert replay_reference(rig, MeasurementMap(), cold)["_x"][0, t_m] == 0.0

    # the compiled replays the diagnosis ranks with: the carried start follows the recorded current
    (w,), (c,) = replay_many([(rig, MeasurementMap())], warm), replay_many([(rig, MeasurementMap())], cold)
    i_rec = stretch.channels["i_a"]
    err_warm = float(np.sqrt(np.mean((w["i_a"] - i_rec) ** 2)))
    err_cold = float(np.sqrt(np.mean((c["i_a"] - i_rec) ** 2)))
    assert err_warm < 0.1 * err_cold
    # the one free run the reported figures come from carries it the same way
    runs = [one_free_run(rig, MeasurementMap(), p).channels["i_a"] - i_rec for p in (warm, cold)]
    assert float(np.sqrt(np.mean(runs[0] ** 2))) < 0.1 * float(np.sqrt(np.mean(runs[1] ** 2)))
    # and a rig without the effect replays the stretch as before
    plain = load_rig("thesis_rig").with_effects(sensor_noise=False, quantisation=False)
    row = [(plain, MeasurementMap())]
    (a,), (b,) = replay_many(row, warm), replay_many(row, cold)
    np.testing.assert_array_equal(a["theta"], b["theta"])


def test_baseline_replays_a_held_out_part_from_the_winding_its_fit_part_left():
    """``baseline`` scores the held-out part of a recording as the continuation of its fit part."""
    from aeropend_ident.greybox.baseline import _replay
    from aeropend_ident.greybox.uniform import UniformData

    rig = _heated()
    dt = rig.sample_period
    n = round(30.0 / dt)
    duty = np.repeat(np.random.default_rng(4).uniform(0.45, 0.8, 15), -(-n // 15))[:n]
    theta = simulate(rig, duty).true["theta"]
    k = round(0.7 * n)

    def part(a: int, b: int) -> UniformData:
        return UniformData(t=np.arange(b - a) * dt, duty=duty[a:b], theta=theta[a:b], dt=dt, resampled=False,
                           decimate=1, source="run")

    held, fit = part(k, n), part(0, k)
    err = [float(np.sqrt(np.mean((_replay(rig, 0.0, held, h, None).theta - held.theta) ** 2)))
           for h in (fit, None)]
    assert err[0] < 0.1 * err[1]
