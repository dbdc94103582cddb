"""The lab-conditions gap benchmark (bench/bench_gap_lab.py): its case list and the logger's transforms
(bench/fixtures/lab_logging.py) do what they say, with numbers; no gap run (the bench is the run)."""

from __future__ import annotations

import ast
import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from bench import bench_gap_lab as lab
from bench.fixtures import lab_logging as ll
from bench.fixtures import truth_plant as tp


@pytest.fixture(scope="module")
def cases():
    return lab.case_list()


def test_case_list_counts_and_is_deterministic(cases):
    assert len(cases) >= 120
    assert cases == lab.case_list()
    kinds = Counter(c["kind"] for c in cases)
    assert kinds["single"] >= 40 and kinds["triple"] >= 20 and kinds["ooc"] >= 20 and kinds["none"] >= 20
    assert len({c["seed"] for c in cases}) == len(cases)
    assert [c["index"] for c in cases] == list(range(len(cases)))
    # closed loop in at least half the cases, both with and without dither; all three modes per kind
    modes = Counter(c["mode"] for c in cases)
    assert modes["closed"] + modes["closed_dither"] >= len(cases) / 2 and min(modes.values()) > 0
    assert all(c["dither"] > 0 for c in cases if c["mode"] == "closed_dither")
    assert all(c["dither"] == 0 for c in cases if c["mode"] != "closed_dither")
    for k in lab.KINDS:
        assert {c["mode"] for c in cases if c["kind"] == k} == set(lab.MODES)
    # angle + duty in most cases, every channel in some
    ch = Counter(c["channels"] for c in cases)
    assert 0 < ch["all"] < ch["theta"]
    # every rate, each at its whole-sample decimation of the 2.048 ms truth
    assert Counter(c["rate_hz"] for c in cases).keys() == set(lab.RATES)
    assert {(c["rate_hz"], c["every"]) for c in cases} == {(50, 10), (100, 5), (200, 2), (490, 1)}
    # lattices, jitter and dropped rows in some cases, in their ranges
    quant = [c for c in cases if c["quantiser"]]
    assert 0 < len(quant) < len(cases) / 2 and {c["quantiser"] for c in quant} == set(ll.QUANTISERS)
    jit = [c["jitter"] for c in cases if c["jitter"]]
    drop = [c["drop"] for c in cases if c["drop"]]
    assert jit and all(0.01 <= x <= 0.05 for x in jit)
    assert drop and all(0.005 <= x <= 0.02 for x in drop)
    # roughly half the pairs drift, by 8-30 % of one of the three quantities, both signs
    drift = [c for c in cases if c["drift"]]
    assert abs(len(drift) - len(cases) / 2) <= len(cases) / 10
    assert {c["drift"] for c in drift} == {"thrust_coefficient", "gravity", "viscous_friction"}
    assert all(0.08 <= abs(c["drift_size"]) <= 0.30 for c in drift)
    assert {math.copysign(1.0, c["drift_size"]) for c in drift} == {1.0, -1.0}
    assert all(c["drift_size"] == 0.0 for c in cases if not c["drift"])
    # nominal rigs: the thesis' and drawn variants
    assert Counter(c["variant"] for c in cases).keys() == {True, False}


def test_case_truths_fit_the_catalog_and_the_channels(cases):
    from aeropend_ident.gap.effects import catalog

    cat = {e.name: e for e in catalog("dc_hbridge")}
    for c in cases:
        have = set(tp.CHANNELS) if c["channels"] == "all" else {"theta"}
        if c["kind"] == "none":
            assert c["effects"] == []
        elif c["kind"] == "ooc":
            assert len(c["effects"]) == 1 and c["effects"][0] in tp.OUT_OF_CATALOG
        else:
            assert len(c["effects"]) == (1 if c["kind"] == "single" else 3)
            for e in c["effects"]:
                assert set(cat[e].needs_channels) <= have, (c["id"], e)
        if c["kind"] == "triple":
            a, b, d = (cat[e] for e in c["effects"])
            assert len({a.subsystem, b.subsystem, d.subsystem}) == 3
            for x in (a, b, d):
                assert not set(x.confusable_with) & (set(c["effects"]) - {x.name})
    # the single cases cover every catalog effect the angle reveals, and the motor ones with every channel
    singles = {c["effects"][0] for c in cases if c["kind"] == "single"}
    assert {"back_emf", "armature_inductance", "torque_constant", "propeller_drag"} <= singles
    assert {"dead_zone", "input_delay", "gravity", "sensor_offset", "end_stops"} <= singles
    quick = lab.quick_indices(cases)
    assert len(quick) == 12
    assert {(cases[i]["kind"], cases[i]["mode"]) for i in quick} == {(k, m) for k in lab.KINDS
                                                                      for m in lab.MODES}


def test_lab_logging_imports_nothing_from_aeropend():
    tree = ast.parse(Path(ll.__file__).read_text(encoding="utf-8"))
    modules = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    modules |= {(n.module or "").split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert modules <= {"__future__", "math", "collections", "numpy"}


def test_decimation_holds_the_command_over_the_logged_period():
    assert [ll.decimation(r, tp.DT) for r in (50, 100, 200, 490)] == [10, 5, 2, 1]
    u = np.arange(23, dtype=float)
    h = ll.hold_every(u, 5)
    assert h.size == 23
    np.testing.assert_array_equal(h, [0.0] * 5 + [5.0] * 5 + [10.0] * 5 + [15.0] * 5 + [20.0] * 3)
    np.testing.assert_array_equal(ll.keep_every({"u": h}, 5)["u"], [0.0, 5.0, 10.0, 15.0, 20.0])
    # open loop: the plant sees the logged duty held for k truth samples
    k = 5
    fast = ll.hold_every(tp.aprbs(3.0, seed=1), k)
    for j in range(0, fast.size - k, k):
        assert np.all(fast[j:j + k] == fast[j])


def test_closed_loop_runs_at_the_logging_rate_with_a_zero_order_hold():
    """The PD loop at k = 5: its logged θ is the truth plant's θ under the logged duty held 5
    samples (noise-free: bit for bit), stamped every 5·2.048 ms; with a lattice it sees and logs
    θ on the lattice; the dither moves the duty."""
    from aeropend_sim.params import rig_from_dict
    from bench.bench_gap_closed_loop import closed_loop
    from bench.bench_gap_independent import rig_dict

    nominal = rig_from_dict(rig_dict(tp.PlantParams(), "t"), where="test")
    plant = tp.TruthPlant(tp.PlantParams(), {"gravity": 1.1})
    run = closed_loop(plant, nominal, 3, 4.0, every=5, sigma={})
    assert run["t"].size == round(4.0 / tp.DT) // 5
    np.testing.assert_allclose(np.diff(run["t"]), 5 * tp.DT, rtol=1e-12)
    replay = plant.simulate(np.repeat(run["duty"], 5))
    np.testing.assert_array_equal(replay["theta"][::5], run["theta"])
    np.testing.assert_array_equal(replay["i_a"][::5], run["i_a"])
    q = ll.QUANTISERS["encoder_10bit"]
    lat = closed_loop(plant, nominal, 3, 4.0, every=5, sigma={}, quantum=q)
    np.testing.assert_allclose(lat["theta"] / q, np.round(lat["theta"] / q), atol=1e-9)
    assert np.ptp(lat["theta"]) > 20 * q
    dith = closed_loop(plant, nominal, 3, 4.0, every=5, sigma={}, dither=0.05)
    assert 0.01 < np.max(np.abs(dith["duty"] - run["duty"])) <= 0.5


def test_quantisation_puts_the_angle_on_its_lattice():
    assert ll.QUANTISERS["encoder_10bit"] == pytest.approx(2 * math.pi / 1024)
    assert ll.QUANTISERS["encoder_12bit"] == pytest.approx(2 * math.pi / 4096)
    assert ll.QUANTISERS["pot_adc_10bit"] == pytest.approx(math.radians(270) / 1024)
    theta = np.linspace(-0.3, 1.2, 10001)
    for q in ll.QUANTISERS.values():
        y = ll.quantise(theta, q)
        np.testing.assert_allclose(y / q, np.round(y / q), atol=1e-9)
        assert np.max(np.abs(y - theta)) <= q / 2 + 1e-12
        assert len(np.unique(np.round(y / q))) == pytest.approx(1.5 / q, abs=2)
    assert ll.quantise(0.0123, 0.01) == pytest.approx(0.01)
    np.testing.assert_array_equal(ll.quantise(theta, 0.0), theta)


def test_dropped_rows_are_isolated_and_counted():
    keep = ll.drop_rows(5000, 0.02, seed=4)
    assert keep.size == 4900
    assert keep[0] == 0 and keep[-1] == 4999
    assert np.all(np.diff(keep) <= 2)  # never two neighbours lost
    np.testing.assert_array_equal(keep, ll.drop_rows(5000, 0.02, seed=4))
    np.testing.assert_array_equal(ll.drop_rows(100, 0.0, seed=4), np.arange(100))


def test_timestamp_jitter_has_its_size_and_keeps_the_order():
    period = 0.01
    t = np.arange(20000) * period
    j = ll.jitter_stamps(t, 0.03, seed=5)
    e = j - t
    assert e[0] == 0.0 and np.all(np.diff(j) > 0)
    assert np.std(e) / period == pytest.approx(0.03, rel=0.05)
    assert np.max(np.abs(e)) <= ll.JITTER_CLIP * period
    big = ll.jitter_stamps(t, 0.5, seed=5)  # clipped: still in order
    assert np.all(np.diff(big) > 0)


@pytest.mark.slow
def test_a_built_case_is_the_log_it_claims(cases):
    """An open-loop case at 100 Hz with a lattice, jitter and lost rows: the logged duty is held,
    θ on the lattice, the stamps jittered by the share asked, the rows lost as asked; the session-2
    plant drifted by the drawn factor; the command's resampling puts it back on one grid."""
    spec = dict(next(c for c in cases if c["mode"] == "open" and c["kind"] == "single"
                     and c["channels"] == "theta"))
    spec.update(rate_hz=100, every=5, quantiser="encoder_12bit", jitter=0.03, drop=0.01,
                drift="gravity", drift_size=0.2)
    case = lab.build_case(spec)
    q = ll.QUANTISERS["encoder_12bit"]
    fit, held = case["fit"], case["held"]
    n_fit = round(lab.FIT_DURATION / tp.DT)
    rows = len(range(0, n_fit, 5))
    assert fit.t.size == rows - round(0.01 * rows)
    np.testing.assert_allclose(fit.channels["theta"] / q, np.round(fit.channels["theta"] / q), atol=1e-9)
    nominal_t = np.round(fit.t / (5 * tp.DT)) * 5 * tp.DT
    jit = (fit.t - nominal_t) / (5 * tp.DT)
    assert np.std(jit) == pytest.approx(0.03, rel=0.15)
    assert case["truth_drift_nrmse"] > 0.0
    assert set(fit.channels) == {"theta"} and set(held.channels) == {"theta"}
    rec_fit, rec_held = lab.prepared(case, spec)
    # one uniform grid again, its step the median jittered interval (within 0.1 % of the period)
    step = np.diff(rec_fit[0].t)
    assert np.allclose(step, step[0]) and step[0] == pytest.approx(5 * tp.DT, rel=1e-3)
    assert abs(len(rec_fit[0]) - rows) <= 4
    assert len(rec_held[0]) > 0.99 * round(lab.HELD_DURATION / (5 * tp.DT))


@pytest.mark.slow
def test_both_sessions_of_an_open_loop_case_have_the_lab_sensors_noise(cases):
    """One lab's sensors: the held-out session's θ noise σ is the fit session's (set by the case's
    SNR there), not a fixed SNR on each recording's own RMS, which gave a session that swings the
    rod less a quieter sensor (and its held-out error fell below any prediction made from the fit
    session)."""
    from aeropend_ident.greybox.fit import noise_level

    spec = dict(next(c for c in cases if c["mode"] == "open" and c["channels"] == "theta"))
    spec.update(rate_hz=490, every=1, quantiser=None, jitter=0.0, drop=0.0, drift=None, drift_size=0.0)
    case = lab.build_case(spec)
    s_fit, s_held = (noise_level(case[k].channels["theta"]) for k in ("fit", "held"))
    assert s_held == pytest.approx(s_fit, rel=0.05)
    # the fixture: a stated σ is the noise added, whatever the run's RMS
    plant = tp.TruthPlant(tp.PlantParams())
    first = tp.record(plant, tp.aprbs(10.0, seed=1), 45.0, 2, channels=("theta",))
    sigma = tp.noise_sigma(first.true, 45.0, ("theta",))
    quiet = tp.record(plant, np.full(first.duty.size, 0.3), 45.0, 3, channels=("theta",), sigma=sigma)
    noise = quiet.channels["theta"] - quiet.true["theta_recorded"]
    assert np.std(noise) == pytest.approx(sigma["theta"], rel=0.03)
    assert tp.noise_sigma(quiet.true, 45.0, ("theta",))["theta"] < 0.9 * sigma["theta"]


def test_width_oracle_narrowest_interval_and_its_two_limits():
    """bench_gap_width_oracle: the narrowest interval of a known law has its textbook width, and the
    oracle's width over its median follows the mixture: with no drift effect the interval is the
    within-session spread alone; with a drift far above it the upper end is the drift tail's."""
    from bench import bench_gap_width_oracle as wo

    u = np.linspace(0.0, 1.0, 10001)
    lo, hi = wo.narrowest(u, 0.8)
    assert hi - lo == pytest.approx(0.8, abs=1e-3)
    # the narrowest 80 % of a right-skewed law starts at its lower end
    e = np.random.default_rng(0).exponential(1.0, 20000)
    lo, hi = wo.narrowest(e, 0.8)
    assert lo < 0.01 and hi == pytest.approx(-math.log(0.2), rel=0.03)
    rng = np.random.default_rng(1)
    still = wo.oracle_interval(0.01, 0.0, rng, atom_sd=0.15)
    # lognormal(σ 0.15): the shortest log interval holding 80 % spans 2·1.2816σ around the median
    assert still["hi"] / still["lo"] == pytest.approx(math.exp(2 * 1.2816 * 0.15), rel=0.02)
    assert still["relative_width"] == pytest.approx(2 * math.sinh(1.2816 * 0.15), rel=0.03)
    far = wo.oracle_interval(0.001, 10.0, rng, atom_sd=0.15)  # drift effect 1.5 at 15 %: 1500× a
    # it holds 80 % to 100 % of the atom (half the draws), so the drift tail's 60 % to 80 % quantile
    # (|d| ~ U(0.08, 0.30), effect 10·|d|): its upper end lies between those two, its lower in the atom
    assert far["lo"] < 0.0012
    assert 10 * (0.08 + 0.22 * 0.6) < far["hi"] < 10 * (0.08 + 0.22 * 0.8)
    assert far["relative_width"] > 1.0
