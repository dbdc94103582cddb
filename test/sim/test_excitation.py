"""Tests of aeropend_sim.excitation: durations, bounds, LHS stratification, PRBS properties."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_sim.contract import SAMPLE_PERIOD_S
from aeropend_sim.excitation import (
    SIGNALS,
    ExcitationError,
    aprbs,
    density_modulated_prbs,
    lhs_steps,
    make_signal,
    prbs,
    signal_parameters,
    staircase,
    step,
)

DT = SAMPLE_PERIOD_S


def _runs(duty: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Levels and lengths (in samples) of the constant runs of a signal."""
    change = np.flatnonzero(np.diff(duty) != 0.0) + 1
    starts = np.concatenate(([0], change))
    lengths = np.diff(np.concatenate((starts, [duty.size])))
    return duty[starts], lengths


# ------------------------------------------------------------------------------------- step
def test_step_exact_samples_and_levels():
    sig = step(0.45, 3.0, initial=0.1, step_time=1.0, dt=0.01)
    assert len(sig) == 300
    assert sig.duration == pytest.approx(3.0, abs=1e-12)
    np.testing.assert_array_equal(sig.duty[:100], 0.1)
    np.testing.assert_array_equal(sig.duty[100:], 0.45)
    np.testing.assert_allclose(sig.t, np.arange(300) * 0.01)
    np.testing.assert_allclose(sig.holds, [1.0, 2.0])


def test_step_at_zero_is_constant():
    sig = step(0.3, 0.5, dt=0.01)
    np.testing.assert_array_equal(sig.duty, np.full(50, 0.3))
    assert sig.levels.tolist() == [0.3]


# ------------------------------------------------------------------------------------- staircase
def test_staircase_per_level_holds_exact_at_rig_rate():
    levels = [0.3, 0.5, 0.2, 0.7]
    holds = [0.512, 1.024, 0.2048, 2.048]  # whole multiples of 2.048 ms: 250, 500, 100, 1000
    sig = staircase(levels, holds)
    assert len(sig) == 1850
    run_levels, run_len = _runs(sig.duty)
    assert run_levels.tolist() == levels
    assert run_len.tolist() == [250, 500, 100, 1000]
    assert sig.holds.sum() == pytest.approx(sig.duration)


def test_staircase_rounding_does_not_drift():
    # 1 s holds are 488.28 samples: cumulative rounding keeps the total within half a sample.
    sig = staircase([0.3, 0.4] * 25, 1.0)
    assert abs(sig.duration - 50.0) <= 0.5 * DT
    _, run_len = _runs(sig.duty)
    assert set(run_len.tolist()) <= {488, 489}


def test_staircase_validation_messages():
    with pytest.raises(ExcitationError, match=r"levels\[1\] = 1.2"):
        staircase([0.3, 1.2], 1.0)
    with pytest.raises(ExcitationError, match=r"hold\[0\] = -1"):
        staircase([0.3], -1.0)
    with pytest.raises(ExcitationError, match="expected 1 or one per level"):
        staircase([0.3, 0.4, 0.5], [1.0, 2.0])
    with pytest.raises(ExcitationError, match="shorter than half a sample"):
        staircase([0.3], 1e-4)
    with pytest.raises(ExcitationError, match="not a duty cycle"):
        staircase([math.nan], 1.0)


# ------------------------------------------------------------------------------------- PRBS
@pytest.mark.parametrize("order", [3, 5, 7, 10])
def test_prbs_is_maximum_length_and_balanced(order):
    period = 2**order - 1
    sig = prbs(order, lo=0.2, hi=0.6, clock=1, periods=2, seed=4)
    assert len(sig) == 2 * period
    bits = np.where(sig.duty == 0.6, 1, -1)
    assert set(np.unique(sig.duty).tolist()) == {0.2, 0.6}
    first, second = bits[:period], bits[period:]
    np.testing.assert_array_equal(first, second)  # periodic with period 2^m - 1
    assert first.sum() == 1  # balanced: 2^(m-1) ones, 2^(m-1) - 1 zeros
    # maximum length: no shorter period, and the circular autocorrelation is two-valued
    for p in range(1, period):
        if period % p == 0:
            assert not np.array_equal(first, np.roll(first, p))
    acf = np.array([np.dot(first, np.roll(first, s)) for s in range(period)])
    assert acf[0] == period
    np.testing.assert_array_equal(acf[1:], -1)


def test_prbs_clock_holds_each_bit():
    sig = prbs(4, clock=7, seed=1)
    assert len(sig) == 15 * 7
    _, run_len = _runs(sig.duty)
    assert np.all(run_len % 7 == 0)
    assert sig.holds.sum() == pytest.approx(15 * 7 * DT)


def test_prbs_seed_sets_phase():
    a, b, c = prbs(6, seed=1), prbs(6, seed=1), prbs(6, seed=2)
    np.testing.assert_array_equal(a.duty, b.duty)
    assert not np.array_equal(a.duty, c.duty)
    # a different seed is a circular shift of the same m-sequence
    bits_a, bits_c = a.duty[::10], c.duty[::10]
    assert any(np.array_equal(bits_a, np.roll(bits_c, s)) for s in range(63))


def test_prbs_validation():
    with pytest.raises(ExcitationError, match=r"lo = 0\.6 must be < hi = 0\.3"):
        prbs(5, lo=0.6, hi=0.3)
    with pytest.raises(ExcitationError, match=r"order = 1 must be in \[2, 32\]"):
        prbs(1)
    with pytest.raises(ExcitationError, match="clock = 0"):
        prbs(5, clock=0)
    with pytest.raises(ExcitationError, match="not an integer"):
        prbs(5, clock=2.5)


# ------------------------------------------------------------------------------------- APRBS
def test_aprbs_bounds_holds_and_duration():
    sig = aprbs(20.0, lo=0.25, hi=0.55, min_hold=0.1, max_hold=0.5, seed=11)
    assert len(sig) == round(20.0 / DT)
    assert sig.duty.min() >= 0.25 and sig.duty.max() <= 0.55
    counts = np.rint(sig.holds / DT).astype(int)
    assert counts.sum() == len(sig)
    n_min, n_max = math.ceil(0.1 / DT), math.floor(0.5 / DT)
    assert np.all(counts[:-1] >= n_min) and np.all(counts <= n_max)
    np.testing.assert_array_equal(np.repeat(sig.levels, counts), sig.duty)
    assert len(set(sig.levels.tolist())) == sig.levels.size  # random levels, all distinct


def test_aprbs_reproducible():
    a = aprbs(5.0, seed=3)
    b = aprbs(5.0, seed=3)
    c = aprbs(5.0, seed=4)
    np.testing.assert_array_equal(a.duty, b.duty)
    assert not np.array_equal(a.duty, c.duty)


# ---------------------------------------------------------------- density-modulated binary
def test_density_prbs_is_binary_with_fast_holds_and_exact_duration():
    sig = density_modulated_prbs(30.0, lo=0.1, hi=0.95, min_hold=0.005, max_hold=0.03, seed=5)
    assert len(sig) == round(30.0 / DT)
    assert set(np.unique(sig.duty).tolist()) == {0.1, 0.95}
    counts = np.rint(sig.holds / DT).astype(int)
    assert counts.sum() == len(sig)
    np.testing.assert_array_equal(np.repeat(sig.levels, counts), sig.duty)
    assert np.all(sig.levels[1:] != sig.levels[:-1])  # equal neighbours merged
    assert np.all(counts[:-1] >= math.ceil(0.005 / DT))  # merged runs are at least one fast hold
    same = make_signal("density_prbs", duration=30.0, lo=0.1, hi=0.95, seed=5)
    np.testing.assert_array_equal(same.duty, sig.duty)


@pytest.mark.parametrize("density", [0.2, 0.5, 0.8])
def test_density_prbs_mean_follows_the_density(density: float):
    sig = density_modulated_prbs(120.0, density_lo=density, density_hi=density, seed=2)
    # fraction of time high = density (holds are i.i.d., so ~1/sqrt(#holds) scatter, here ≈ 0.01)
    assert abs(sig.duty.mean() - density) < 0.03


def test_density_prbs_slow_density_moves_the_local_mean():
    sig = density_modulated_prbs(120.0, density_lo=0.1, density_hi=0.9, density_min_hold=2.0,
                                 density_max_hold=4.0, seed=3)
    n = round(1.0 / DT)
    local = sig.duty[: len(sig) // n * n].reshape(-1, n).mean(axis=1)  # 1 s windows
    assert local.min() < 0.3 and local.max() > 0.7  # the pendulum sees a slowly moving mean thrust


def test_density_prbs_reproducible_and_validated():
    a, b = density_modulated_prbs(5.0, seed=3), density_modulated_prbs(5.0, seed=3)
    np.testing.assert_array_equal(a.duty, b.duty)
    assert not np.array_equal(a.duty, density_modulated_prbs(5.0, seed=4).duty)
    with pytest.raises(ExcitationError, match=r"density_hi = 1\.2"):
        density_modulated_prbs(5.0, density_hi=1.2)
    with pytest.raises(ExcitationError, match=r"density_lo = 0\.8 must be <= density_hi = 0\.5"):
        density_modulated_prbs(5.0, density_lo=0.8, density_hi=0.5)


def test_aprbs_validation():
    with pytest.raises(ExcitationError, match="min_hold = 2 must be <= max_hold = 1"):
        aprbs(5.0, min_hold=2.0, max_hold=1.0)
    with pytest.raises(ExcitationError, match="no whole number of samples"):
        aprbs(5.0, min_hold=0.0025, max_hold=0.0030)
    with pytest.raises(ExcitationError, match=r"hi = 1\.5"):
        aprbs(5.0, hi=1.5)
    with pytest.raises(ExcitationError, match=r"duration = 0"):
        aprbs(0.0)


# ------------------------------------------------------------------------------------- LHS (thesis §5.1)
@pytest.mark.parametrize("n, seed", [(10, 0), (10, 7), (25, 3)])
def test_lhs_one_point_per_interval_on_each_axis(n, seed):
    tau_lo, tau_hi, t_lo, t_hi = 0.3, 0.6, 0.5, 4.0
    sig = lhs_steps(n, tau_min=tau_lo, tau_max=tau_hi, hold_min=t_lo, hold_max=t_hi, seed=seed)
    tau, hold = sig.design[:, 0], sig.design[:, 1]
    assert sig.design.shape == (n, 2)
    tau_bin = np.floor((tau - tau_lo) / (tau_hi - tau_lo) * n).astype(int)
    hold_bin = np.floor((hold - t_lo) / (t_hi - t_lo) * n).astype(int)
    assert sorted(tau_bin.tolist()) == list(range(n))
    assert sorted(hold_bin.tolist()) == list(range(n))


def test_lhs_signal_is_the_staircase_of_the_design():
    sig = lhs_steps(10, tau_min=0.35, tau_max=0.65, hold_min=1.0, hold_max=5.0, seed=5)
    run_levels, run_len = _runs(sig.duty)
    np.testing.assert_array_equal(run_levels, sig.design[:, 0])  # steps in the order drawn
    np.testing.assert_allclose(run_len * DT, sig.design[:, 1], atol=DT)
    assert abs(sig.duration - sig.design[:, 1].sum()) <= 0.5 * DT
    assert sig.duty.min() >= 0.35 and sig.duty.max() <= 0.65


def test_lhs_seed():
    a, b, c = lhs_steps(seed=1), lhs_steps(seed=1), lhs_steps(seed=2)
    np.testing.assert_array_equal(a.duty, b.duty)
    np.testing.assert_array_equal(a.design, b.design)
    assert not np.array_equal(a.design, c.design)


def test_lhs_validation():
    with pytest.raises(ExcitationError, match=r"tau_min = 0\.7 must be < tau_max = 0\.4"):
        lhs_steps(tau_min=0.7, tau_max=0.4)
    with pytest.raises(ExcitationError, match=r"tau_max = -0\.1"):
        lhs_steps(tau_max=-0.1)
    with pytest.raises(ExcitationError, match=r"hold_min = -1"):
        lhs_steps(hold_min=-1.0)
    with pytest.raises(ExcitationError, match="n = 0 must be >= 1"):
        lhs_steps(0)


# ------------------------------------------------------------------------------------- dispatcher
def test_make_signal_matches_direct_calls():
    a = make_signal("lhs", n=8, seed=9, tau_min=0.4, tau_max=0.5)
    b = lhs_steps(8, seed=9, tau_min=0.4, tau_max=0.5)
    np.testing.assert_array_equal(a.duty, b.duty)
    c = make_signal("staircase", levels=[0.2, 0.4], hold=0.1, dt=0.01, seed=None)
    np.testing.assert_array_equal(c.duty, np.repeat([0.2, 0.4], 10))


def test_make_signal_errors():
    with pytest.raises(ExcitationError, match="unknown signal kind 'chirp'"):
        make_signal("chirp")
    with pytest.raises(ExcitationError, match=r"no parameter\(s\) \['levls'\]"):
        make_signal("staircase", levls=[0.1], hold=1.0)
    with pytest.raises(ExcitationError, match=r"needs parameter\(s\) \['levels', 'hold'\]"):
        make_signal("staircase")


def test_every_kind_documents_its_parameters():
    for kind in SIGNALS:
        params = signal_parameters(kind)
        assert "dt" in params


def test_csv_roundtrip():
    sig = staircase([0.25, 0.5], 0.02, dt=0.01)
    lines = sig.to_csv().strip().splitlines()
    assert lines[0] == "t,duty"
    vals = np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]])
    np.testing.assert_allclose(vals[:, 0], [0.0, 0.01, 0.02, 0.03])
    np.testing.assert_array_equal(vals[:, 1], [0.25, 0.25, 0.5, 0.5])
