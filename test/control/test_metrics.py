"""Step metrics (aeropend_control.metrics) against analytic first- and second-order responses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_control.metrics import GOAL, TABLE_6_1, MetricsError, StepMetrics, step_metrics

DT = 1e-4


def test_first_order_from_offset_and_delayed_step() -> None:
    tau, y0, r, t_step = 0.2, 0.1, 0.5, 0.3
    t = np.arange(0.0, 3.0, DT)
    y = np.where(t < t_step, y0, y0 + (r - y0) * (1.0 - np.exp(-(t - t_step) / tau)))
    m = step_metrics(t, y, r, t_step=t_step)
    assert m.step == pytest.approx(0.4)
    assert m.rise_time == pytest.approx(tau * math.log(9.0), abs=2 * DT)  # 10-90 %
    assert m.settling_time == pytest.approx(tau * math.log(50.0), abs=2 * DT)  # 2 % band
    assert m.overshoot == 0.0
    assert m.steady_state_error == pytest.approx(0.0, abs=1e-6)


def test_second_order_overshoot_and_peak_time() -> None:
    zeta, wn, r = 0.5, 5.0, 0.4
    wd = wn * math.sqrt(1 - zeta**2)
    t = np.arange(0.0, 5.0, DT)
    phi = math.acos(zeta)
    y = r * (1 - np.exp(-zeta * wn * t) * np.sin(wd * t + phi) / math.sqrt(1 - zeta**2))
    m = step_metrics(t, y, r)
    assert m.overshoot == pytest.approx(100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2)), abs=1e-3)
    assert m.peak_time == pytest.approx(math.pi / wd, abs=2 * DT)
    assert m.meets(TABLE_6_1) and "overshoot" in " ".join(m.failures(GOAL))


def test_steady_state_error_and_unsettled() -> None:
    t = np.arange(0.0, 2.0, DT)
    y = 0.9 * 0.4 * (1 - np.exp(-t / 0.1))  # settles 10 % short of r = 0.4
    m = step_metrics(t, y, 0.4)
    assert m.steady_state_error == pytest.approx(0.04, abs=1e-6)
    assert math.isnan(m.settling_time) and not m.meets(TABLE_6_1)
    m2 = step_metrics(t, 0.5 * 0.4 * (1 - np.exp(-t / 0.1)), 0.4)  # never reaches 90 %
    assert math.isnan(m2.rise_time)


def test_bad_input_named() -> None:
    t = np.arange(0.0, 1.0, 0.01)
    with pytest.raises(MetricsError, match="t_step"):
        step_metrics(t, t, 1.0, t_step=5.0)
    with pytest.raises(MetricsError, match="non-zero"):
        step_metrics(t, np.zeros_like(t), 0.0)
    with pytest.raises(MetricsError, match="equal length"):
        step_metrics(t, t[:-1], 1.0)
    assert StepMetrics(0.4, 0.3, 0.6, 0.7, 1.0, 0.0).meets(GOAL)
