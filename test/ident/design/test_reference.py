"""Closed-loop (reference) designs (issue 63, item 4): set points for the lab's controller.

Two candidates that differ in one effect (a 20 ms actuator lag on thesis_sim, the angle alone at
48.8 Hz), the lab's controller the controller node's default strategy designed on the nominal rig
file. The designed set points separate the candidates in closed loop at least as well as the
seeded set-point sequence the search starts from; recorded in closed loop on the independent
truth plant (bench/fixtures/truth_plant.py, driven by the same controller) they keep every limit
and name the truth; the design's files are what the controller node reads.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import yaml

from aeropend_ident.design import reference as ref
from aeropend_ident.design.discriminate import design_discrimination, evidence
from aeropend_ident.design.parameters import design_parameters
from aeropend_ident.design.sequence import DesignError, Limits, check_limits

#: One worker runs this module: its module fixture (a closed-loop design, 9 s) was made again on every
#: worker that got one of its tests (docs/testing.md, Groups).
# slow: the module's closed-loop design takes ~10 s of the fast subset (docs/testing.md)
pytestmark = [pytest.mark.xdist_group("test_reference"), pytest.mark.slow]

DT = 0.02048  # 48.8 Hz: 10 truth samples
SIGMA = {"theta": 3e-3}
LIMITS = Limits(duty_min=0.0, duty_max=1.0, max_slew=1.0 / DT, theta_min=-0.2, theta_max=1.0, dt=DT)
SHAPE = ref.AprbsShape(duration=12.0, segments=8, min_hold=0.5, max_hold=3.0)


@pytest.fixture(scope="module")
def loop(pair):
    return ref.lab_controller("thesis_sim", {}, DT)


@pytest.fixture(scope="module")
def designed(pair, loop):
    return ref.design_reference(pair, loop, SIGMA, LIMITS, SHAPE, seed=0, max_evaluations=40)


def test_set_points_lie_in_the_angle_range_within_the_reach(designed, loop):
    lo, hi = ref.set_point_range(LIMITS, loop.reach, SIGMA["theta"])
    levels = [r for _t, r in designed.steps[1:]]
    assert designed.steps[0] == (0.0, 0.0) and len(levels) == SHAPE.segments
    assert all(lo <= r <= hi for r in levels) and hi <= LIMITS.theta_max and lo >= 0.0
    times = [t for t, _r in designed.steps]
    assert all(b > a for a, b in itertools.pairwise(times)) and times[-1] < SHAPE.duration
    grid = ref.on_grid(designed.steps, designed.reference.size, DT)
    np.testing.assert_array_equal(grid, designed.reference)
    with pytest.raises(DesignError, match="no set point"):
        ref.set_point_range(Limits(theta_min=-0.5, theta_max=-0.1, dt=DT), loop.reach, 3e-3)


def test_design_separates_at_least_as_well_as_its_start_and_is_reproducible(pair, loop, designed):
    assert designed.value >= designed.baseline_value
    assert designed.min_divergence >= designed.baseline_min_divergence
    assert designed.min_divergence > 100.0  # a 20 ms lag shows in closed loop at 3 mrad of noise
    assert designed.stopped_by in ("evaluations", "converged")
    n = designed.duty.size
    p = ref.rank_first_probability(pair, loop, designed.steps, n, SIGMA, LIMITS, draws=50)
    assert p["mean"] == pytest.approx(1.0) and set(p["loop"]) == {"nominal", "actuator_lag"}
    assert all(r["status"] == "ok" for r in p["loop"].values())
    # again, each generation's loops and the prediction's in two worker processes: the same, bit for bit
    with ref.ClosedLoopPredictor(pair, loop, tuple(SIGMA), DT, n, workers=2) as pred:
        again = ref.design_reference(pair, loop, SIGMA, LIMITS, SHAPE, seed=0, max_evaluations=40,
                                     predictor=pred)
        calls = pred.calls
        p_again = ref.rank_first_probability(pair, loop, again.steps, n, SIGMA, LIMITS, draws=50,
                                             predictor=pred)
        assert pred._pool is not None  # the loops did run in the workers
        # the loop on the driver (candidate 0) was the search's best, kept: only the others ran
        assert pred.calls == calls + len(pair) - 1
        (kept_out, kept_run), = pred.many([(again.steps, 0)])
        assert pred.calls == calls + len(pair) - 1
    fresh_out, fresh_run = ref.ClosedLoopPredictor(pair, loop, tuple(SIGMA), DT, n)(again.steps, 0)
    np.testing.assert_array_equal(kept_run.duty, fresh_run.duty)
    for c, y in fresh_out.items():
        np.testing.assert_array_equal(kept_out[c], y)
    assert again.steps == designed.steps and again.evaluations == designed.evaluations
    assert (again.value, again.baseline_value, again.min_divergence) == (
        designed.value, designed.baseline_value, designed.min_divergence)
    np.testing.assert_array_equal(again.duty, designed.duty)
    np.testing.assert_array_equal(again.theta, designed.theta)
    assert p_again == p


def test_recorded_on_the_truth_plant_in_closed_loop_it_keeps_every_limit(pair, loop, designed):
    from bench.fixtures.truth_loop import drive_truth
    from bench.fixtures.truth_plant import TruthPlant

    for effects, seed in (({"actuator_lag": 0.02}, 3), ({}, 4)):
        run = drive_truth(TruthPlant(effects=effects), loop, designed.steps, designed.duty.size, every=10,
                          sigma=SIGMA, quantum=2 * np.pi / 4096, seed=seed)
        assert not run["diverged"]
        chk = check_limits(run["duty"], LIMITS, run["theta_recorded"])
        assert chk["ok"], chk
        assert np.abs(run["theta_recorded"][: round(0.5 / DT)]).max() < 0.02  # the lead-in: set point 0


def test_a_closed_loop_recording_names_its_truth(pair, loop, designed):
    """Each candidate in turn is the plant under the lab's loop, its angle seen with noise; the
    candidates replayed on the logged command name it (the verdict the lab reads)."""
    from aeropend_control.verify.closed_loop import drive

    for b, cand in enumerate(pair):
        rng = np.random.default_rng(10 + b)
        lp = __import__("copy").deepcopy(loop)
        lp.reference.steps = list(designed.steps)
        plant = cand.rig.with_effects(sensor_noise=False, quantisation=False)
        run = drive(lp, ref.dataclasses.replace(plant, sample_period=DT), designed.duty.size, seed=None,
                    sensor=lambda th, rng=rng: th + float(rng.normal(0.0, SIGMA["theta"])))
        assert run.status == "ok"
        ev = evidence(pair, np.clip(run.duty, 0.0, 1.0), {"theta": run.seen}, SIGMA, DT)
        assert ev["named"] == cand.name, ev["chi2"]
        assert ev["best_rms_over_noise"] < 1.2


def test_a_limit_the_lab_states_on_the_command_is_held_by_the_loop(pair, loop):
    """A slew limit the controller's steps break is a penalty: every sequence that keeps it scores above."""
    tight = Limits(duty_min=0.0, duty_max=1.0, max_slew=2.0, theta_min=-0.2, theta_max=1.0, dt=DT)
    out, run = ref.ClosedLoopPredictor(pair, loop, ("theta",), DT, 300)(
        ref.reference_steps(np.full(SHAPE.size, 0.5), SHAPE, tight, (0.1, 0.8)))
    assert ref.loop_penalty(run, tight, 3e-3) < 0.0 <= ref.loop_penalty(run, LIMITS, 3e-3)
    assert ref.reference_criterion(out, run, SIGMA, tight) < 0.0


def test_the_open_loop_design_refuses_the_reference_mode(pair):
    with pytest.raises(DesignError, match="design_reference is the closed-loop one"):
        design_discrimination(pair, SIGMA, LIMITS, SHAPE, mode="reference")
    with pytest.raises(DesignError, match="needs the lab's controller"):
        design_parameters(pair[0].rig, ("pendulum.c_over_J",), SIGMA, LIMITS, SHAPE, mode="reference")
    with pytest.raises(DesignError, match="expected one of"):
        design_parameters(pair[0].rig, ("pendulum.c_over_J",), SIGMA, LIMITS, SHAPE, mode="dither")


def test_the_controller_parameters_file_is_read_and_written_as_the_node_reads_it(tmp_path, pair, designed):
    from aeropend_control.controller_core import parse_steps
    from aeropend_ident.design.report import controller_params

    lab = tmp_path / "lab.yaml"
    lab.write_text("/**/aeropend_controller:\n  ros__parameters:\n    rig: thesis_sim\n"
                   "    strategy: cascade\n    omega_n: 5.0\n")
    params = ref.read_controller_params(lab)
    assert params == {"rig": "thesis_sim", "strategy": "cascade", "omega_n": 5.0}
    loop = ref.lab_controller("thesis_sim", params, DT)
    assert loop.settings.strategy == "cascade" and loop.settings.spec.omega_n == 5.0
    assert loop.settings.rig.sample_period == DT
    text = controller_params(designed.steps, {"strategy": "cascade", "rig": "thesis_sim", "omega_n": 5.0})
    doc = yaml.safe_load(text)["/**/aeropend_controller"]["ros__parameters"]
    np.testing.assert_allclose(np.array(parse_steps(doc["steps"])), np.array(designed.steps), atol=1e-9)
    assert doc["strategy"] == "cascade"
    (tmp_path / "bad.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(DesignError, match="mapping"):
        ref.read_controller_params(tmp_path / "bad.yaml")
    with pytest.raises(DesignError, match="lab's controller"):
        ref.lab_controller("thesis_sim", {"strategy": "no_such"}, DT)


def test_a_closed_loop_parameter_design_determines_the_parameter_within_the_limits(pair, loop):
    """D-optimal set points for the pendulum's damping c/J: the information comes from the command
    the loop logs (replayed as rig fit replays a closed-loop log), the limits from the loop's run."""
    from aeropend_control.verify.closed_loop import drive

    rig = pair[0].rig
    d = design_parameters(rig, ("pendulum.c_over_J",), SIGMA, LIMITS, SHAPE, seed=0, max_evaluations=30,
                          mode="reference", loop=loop)
    assert d.steps is not None and d.baseline_steps is not None and d.steps[0] == (0.0, 0.0)
    assert d.logdet >= d.baseline_logdet
    assert d.sd_after["pendulum.c_over_J"] < 0.5 * d.sd_before["pendulum.c_over_J"]
    assert check_limits(d.duty, LIMITS, d.theta)["ok"]
    lp = __import__("copy").deepcopy(loop)
    lp.reference.steps = list(d.steps)
    run = drive(lp, ref.dataclasses.replace(rig.with_effects(sensor_noise=False, quantisation=False),
                                            sample_period=DT), d.duty.size, seed=None)
    np.testing.assert_allclose(np.clip(run.duty, 0.0, 1.0), d.duty)  # the command is the loop's
