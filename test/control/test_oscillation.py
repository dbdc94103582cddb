"""Limit-cycle detection on a loop output (aeropend_control.oscillation): known signals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_control.oscillation import OscillationMonitor, OscillationSettings

DT = 2.048e-3


def _first_detection(u: np.ndarray) -> float | None:
    mon = OscillationMonitor(DT)
    for k, x in enumerate(u):
        if mon.update(float(x)):
            return (k + 1) * DT
    return None


def test_a_bang_bang_cycle_is_detected_after_four_swings() -> None:
    t = np.arange(round(3.0 / DT)) * DT
    u = np.where(np.sin(2 * math.pi * 6.5 * t) >= 0, 1.0, 0.0)  # duty between its limits at 6.5 Hz
    when = _first_detection(u)
    # 8 alternations = 4 periods of 6.5 Hz after the first side is taken: 0.62 s
    assert when == pytest.approx(8 / (2 * 6.5), abs=0.1)


def test_a_one_sided_cycle_is_detected_too() -> None:
    t = np.arange(round(3.0 / DT)) * DT
    u = 0.7 + 0.3 * np.sign(np.sin(2 * math.pi * 6.0 * t))  # 0.4 ... 1.0: the upper limit only
    assert _first_detection(u) is not None


def test_step_transients_small_ripple_and_slow_swings_are_not_a_cycle() -> None:
    n = round(4.0 / DT)
    t = np.arange(n) * DT
    step = np.where(t < 0.15, 1.0, np.where(t < 0.3, 0.0, 0.5))  # saturate up, down, settle
    ripple = 0.5 + 0.1 * np.sin(2 * math.pi * 8.0 * t)  # inside the ±0.2 band
    slow = 0.5 + 0.45 * np.sign(np.sin(2 * math.pi * 1.5 * t))  # 3 alternations per second
    noise = 0.5 + 0.05 * np.random.default_rng(0).standard_normal(n)
    for u in (step, ripple, slow, noise):
        assert _first_detection(u) is None


def test_history_clears_after_a_report_and_nan_is_ignored() -> None:
    mon = OscillationMonitor(DT, OscillationSettings(alternations=2, window=0.5))
    seq = [0.5] * 50 + [1.0] * 20 + [float("nan")] * 5 + [0.0] * 20 + [1.0] * 20
    hits = [k for k, x in enumerate(seq) if mon.update(x)]
    assert hits == [len(seq) - 20]  # two alternations: 1 → 0 → 1; NaN samples changed nothing
    assert not mon.update(0.0)  # one new alternation after the report is not enough


def test_bad_settings_name_the_value() -> None:
    with pytest.raises(ValueError, match="amplitude"):
        OscillationMonitor(DT, OscillationSettings(amplitude=0.0))
    with pytest.raises(ValueError, match="alternations"):
        OscillationMonitor(DT, OscillationSettings(alternations=1))
    with pytest.raises(ValueError, match="dt"):
        OscillationMonitor(float("nan"))
