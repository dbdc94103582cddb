"""Controller-node core (aeropend_control.controller_core, no ROS): settings, reference, loop."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from aeropend_control.controller_core import (
    SIGNALS,
    ControllerConfigError,
    ControllerLoop,
    ReferenceSource,
    make_settings,
    parse_steps,
)


def test_parse_steps_forms_and_errors() -> None:
    assert parse_steps([0.0, 0.4, 3.0, 0.2]) == [(0.0, 0.4), (3.0, 0.2)]
    assert parse_steps([[0, 0.4], [1, 0.7]]) == [(0.0, 0.4), (1.0, 0.7)]
    assert parse_steps(None) == [] and parse_steps([]) == []
    with pytest.raises(ControllerConfigError, match="odd length 3"):
        parse_steps([0.0, 0.4, 1.0])
    with pytest.raises(ControllerConfigError, match="strictly increasing"):
        parse_steps([1.0, 0.4, 0.5, 0.2])
    with pytest.raises(ControllerConfigError, match="'x'"):
        parse_steps([0.0, "x"])


@pytest.mark.parametrize(
    ("raw", "needle"),
    [({"strategy": "pd"}, "strategy = 'pd'"), ({"mode": "fast"}, "mode = 'fast'"),
     ({"rig": "no_such_rig"}, "no_such_rig"), ({"zeta": 1.5}, "zeta = 1.5"),
     ({"allocator": "lut"}, "allocator = 'lut'"), ({"tf": -0.1}, "tf = -0.1"),
     ({"strategy": "small_signal_fixed"}, "theta_op"), ({"duration": -1.0}, "duration = -1.0"),
     ({"omega_n": float("nan")}, "omega_n = nan")],
)
def test_bad_settings_name_the_value(raw: dict, needle: str) -> None:
    with pytest.raises(ControllerConfigError) as err:
        make_settings(**raw)
    assert needle in str(err.value)


def test_reference_latest_event_wins() -> None:
    ref = ReferenceSource(0.0, [(1.0, 0.4), (3.0, 0.2)])
    assert [ref.value(t) for t in (0.5, 1.0, 2.0, 3.5)] == [0.0, 0.4, 0.4, 0.2]
    ref.set_topic(0.7, 2.0)
    assert ref.value(2.5) == 0.7 and ref.value(3.0) == 0.2  # the later step overrides the topic
    ref.set_topic(float("nan"), 3.2)
    assert ref.value(3.5) == 0.2


def test_loop_repeated_stamp_answered_with_same_command(tmp_path: Path) -> None:
    loop = ControllerLoop(make_settings(steps=[0.0, 0.4], mode="lockstep"))
    d0 = loop.on_sample(0, 0.0)
    d1 = loop.on_sample(2_048_000, 0.0)
    assert d1 is not None and d1 > 0.0 == d0
    state = (loop.strategy.pid.i, len(loop.rows))
    assert loop.on_sample(2_048_000, 0.0) == d1 and loop.repeats == 1
    assert (loop.strategy.pid.i, len(loop.rows)) == state  # controller state untouched
    assert loop.on_sample(0, 0.0) is None and loop.stale == 1
    path = tmp_path / "trace.csv"
    loop.write_trace(path)
    rows = list(csv.reader(path.open()))
    assert tuple(rows[0]) == SIGNALS and len(rows) == 3
    assert float(rows[2][0]) == pytest.approx(2.048e-3) and float(rows[2][1]) == 0.4


def test_loop_duration() -> None:
    loop = ControllerLoop(make_settings(duration=0.004))
    for k in range(3):
        assert not loop.done()
        loop.on_sample(k * 2_048_000, 0.0)
    assert loop.done()


def test_latency_columns() -> None:
    loop = ControllerLoop(make_settings())
    loop.on_sample(1_000_000_000, 0.0, recv_ns=1_000_300_000)
    loop.mark_published(1_000_450_000)
    row = dict(zip(SIGNALS, loop.rows[-1], strict=True))
    assert row["stamp_s"] == 1.0
    assert row["recv_latency"] == pytest.approx(3e-4) and row["pub_latency"] == pytest.approx(4.5e-4)
    loop.on_sample(1_002_048_000, 0.0)  # lock-step: no receipt time -> NaN
    row = dict(zip(SIGNALS, loop.rows[-1], strict=True))
    assert math.isnan(row["recv_latency"]) and math.isnan(row["pub_latency"])
    assert row["theta_hat"] == pytest.approx(0.0, abs=1e-3)  # observer estimate of the measured 0


def test_pole_defaults_per_strategy_and_override() -> None:
    from aeropend_control.strategies import DEFAULT_SPECS

    assert make_settings(strategy="fl_pid").spec == DEFAULT_SPECS["fl_pid"]
    assert make_settings(strategy="cascade").spec.omega_n == 9.0
    s = make_settings(strategy="fl_pid", omega_n=8.0, zeta=None)
    assert (s.spec.omega_n, s.spec.zeta, s.spec.rho) == (8.0, 0.7, 1.0)
    with pytest.raises(ControllerConfigError, match="estimator = 'ekf'"):
        make_settings(estimator="ekf")
    assert make_settings(estimator="difference").estimator == "difference"
