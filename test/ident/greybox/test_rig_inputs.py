"""rig fit's inputs (``aeropend_ident.greybox.rig_inputs``): a recording with gaps.

A free swing logged in bursts (5 ms samples, then a 128 ms gap: cychitivav's ``data_pendulum``)
is put on the uniform 5 ms grid by the one resampling; the noise its decay analysis uses must be
the recorded samples' noise, not the noise of the grid, whose interpolated stretches are straight
lines (before the fix the grid's estimate was ~1e-17 rad, every noise wiggle counted as a swing
extremum, and the envelope's period came out 0.19 s for a 1 s swing).
"""

from __future__ import annotations

import numpy as np
import pytest

from aeropend_ident.greybox.decay import analyse_decay
from aeropend_ident.greybox.rig_inputs import time_series
from aeropend_sim.recording import Recording

SIGMA = 0.005           # white angle noise [rad]
PERIOD = 1.0            # swing period [s]


def _bursty_decay(seed: int) -> Recording:
    rng = np.random.default_rng(seed)
    t = np.concatenate([k * 0.16 + np.arange(4) * 0.005 for k in range(100)])  # 4 samples, then a gap
    theta = 0.8 * np.exp(-0.15 * t) * np.cos(2 * np.pi * t / PERIOD) + rng.normal(0.0, SIGMA, t.size)
    return Recording(t=t, duty=np.zeros_like(t), channels={"theta": theta}, source="bursty.csv")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_of_a_gappy_recording_is_measured_on_its_samples(seed):
    ts = time_series(_bursty_decay(seed))
    assert ts.data.resampled and ts.kind == "free decay"
    assert 0.5 * SIGMA < ts.noise < 2.0 * SIGMA


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_decay_period_of_a_gappy_recording(seed):
    ts = time_series(_bursty_decay(seed))
    env = analyse_decay(ts.data.t, ts.data.theta, ts.noise)
    assert env.period == pytest.approx(PERIOD, rel=0.1)


def test_recorded_noise_of_a_uniform_recording_is_noise_level():
    from aeropend_ident.greybox.fit import noise_level
    from aeropend_ident.greybox.rig_inputs import recorded_noise
    rng = np.random.default_rng(3)
    t = np.arange(2000) * 0.01
    theta = 0.3 * np.sin(2.0 * t) + rng.normal(0.0, SIGMA, t.size)
    assert recorded_noise(t, theta) == noise_level(theta)


def test_a_fast_log_is_fitted_on_the_grid_the_rod_needs_and_replayed_on_its_own():
    """Issue 60 item 3: a 500 Hz log is fitted on every 2nd sample (the rod's dynamics need no finer
    than FIT_GRID_MAX, 5 ms), the duty cycle averaged over each pair; its own 2 ms grid is kept for the
    reported figures; a 100 Hz log keeps its grid."""
    from aeropend_ident.greybox.rig_inputs import FIT_GRID_MAX, fit_grid
    from aeropend_sim.params import load_rig

    grid = fit_grid(load_rig("thesis_rig"))
    assert 0.0 < grid <= FIT_GRID_MAX == 0.005
    t = np.arange(5000) * 0.002
    duty = np.where(t < 3.0, 0.2, 0.5)
    duty[1501] = 0.9  # one sample, averaged with its neighbour on the fit grid
    rec = Recording(t=t, duty=duty, channels={"theta": np.sin(t)}, source="fast.csv")
    ts = time_series(rec, grid)
    k = int(grid // 0.002)
    assert k == 2 and ts.data.decimate == 2 and ts.data.dt == pytest.approx(0.004)
    assert len(ts.data) == 2500 and ts.replayed is ts.full and len(ts.full) == 5000
    assert ts.data.duty[750] == pytest.approx(0.7) and ts.data.theta[750] == pytest.approx(np.sin(3.0))
    slow = Recording(t=t[::5], duty=duty[::5], channels={"theta": np.sin(t[::5])}, source="slow.csv")
    ts = time_series(slow, grid)
    assert ts.full is None and ts.data.dt == pytest.approx(0.01) and ts.replayed is ts.data
