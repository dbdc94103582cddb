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
from bench.fixtures.closed_loop import closed_loop


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
    from aeropend_control.strategies import FeedbackLinearizationPID

    assert make_settings(strategy="fl_pid").spec == FeedbackLinearizationPID.default_spec
    assert make_settings(strategy="cascade").spec.omega_n == 9.0
    s = make_settings(strategy="fl_pid", omega_n=8.0, zeta=None)
    assert (s.spec.omega_n, s.spec.zeta, s.spec.rho) == (8.0, 0.7, 1.0)
    with pytest.raises(ControllerConfigError, match="estimator = 'ekf'"):
        make_settings(estimator="ekf")
    assert make_settings(estimator="difference").estimator == "difference"


@pytest.mark.parametrize("strategy", ["fl_pid", "small_signal"])
def test_retune_while_running_is_bumpless_and_gives_the_new_design(strategy: str) -> None:
    """A pole-pattern change at rest (0.2 rad, before a step to 0.4 rad) is taken over without a
    jump of the duty, and the following step is the new design's step, not the old one's."""
    from aeropend_control.metrics import step_metrics

    steps = [0.0, 0.2, 2.0, 0.4]
    n, k_re, k_step = 2000, 800, round(2.0 / 2.048e-3)
    old = make_settings(strategy=strategy, steps=steps, mode="lockstep")
    new = make_settings(strategy=strategy, steps=steps, mode="lockstep", omega_n=5.0)
    live = closed_loop(ControllerLoop(old), n, {k_re: lambda loop: loop.retune(new)})
    slow = closed_loop(ControllerLoop(new), n)
    fast = closed_loop(ControllerLoop(old), n)
    duty = [d for _, d in live]
    assert abs(duty[k_re] - duty[k_re - 1]) < 2e-3  # bumpless: no jump at the change
    t = [(k - k_step) * 2.048e-3 for k in range(k_step, n)]

    def ts(run: list[tuple]) -> float:
        th = [x for x, _ in run[k_step:]]
        return step_metrics(t, [x - th[0] for x in th], 0.4 - th[0]).settling_time

    assert ts(live) == pytest.approx(ts(slow), rel=0.05)
    assert ts(live) > 1.3 * ts(fast)
    # read-only settings are refused, the loop keeps running unchanged
    loop = ControllerLoop(old)
    with pytest.raises(ControllerConfigError, match="strategy cannot change"):
        loop.retune(make_settings(strategy="cascade", steps=steps, mode="lockstep"))
    assert loop.settings is old


def test_retune_of_a_cascade_keeps_its_motor_loops() -> None:
    from aeropend_control.controller_core import build_strategy
    from aeropend_control.strategies import make_strategy

    s_old = make_settings(strategy="fl_cascade")
    s_new = make_settings(strategy="fl_cascade", omega_n=5.0)
    a = build_strategy(s_old)
    inner = a.inner
    a.retune(build_strategy(s_new))
    assert a.inner is inner and a.outer.design == build_strategy(s_new).outer.design
    assert make_strategy("fl_cascade", s_old.rig).outer.design != a.outer.design


def _weak_rig():
    """thesis_sim with the ideal 2.32 V drive: it cannot hold the rod above ≈ 0.7 rad (issue 19)."""
    from aeropend_sim.params import load_rig

    return load_rig("thesis_sim").with_effects(hbridge_map=False).with_params("actuator", v_supply=2.32)


def test_reachable_angle_is_the_equilibrium_with_duty_headroom() -> None:
    from aeropend_control.allocation import ModelAllocator
    from aeropend_control.design import (
        REACH_ANGLE_MAX,
        REACH_DUTY_MARGIN,
        REACH_LEAN_FLOOR,
        reachable_angle,
        reachable_grid,
    )
    from aeropend_sim.model import PlantModel
    from aeropend_sim.params import load_rig

    rig = _weak_rig()
    reach = reachable_angle(rig)
    tau = PlantModel(rig).equilibrium(reach)[1]
    assert tau == pytest.approx(1.0 - REACH_DUTY_MARGIN, abs=1e-3) and 0.5 < reach < 0.8
    grid = reachable_grid(rig)
    assert grid[-1] == reach and all(g < reach for g in grid[:-1])
    # the thesis rig (Eq. 4.3 drive) holds π/2 with headroom, so it can lean past it: its reach is where
    # the holding thrust, falling again with sin θ, is REACH_LEAN_FLOOR of the full-command thrust
    thesis = load_rig("thesis_rig")
    m, f_max = PlantModel(thesis), ModelAllocator(thesis).f_max
    assert m.equilibrium(math.pi / 2)[1] < 1.0 - REACH_DUTY_MARGIN
    lean = reachable_angle(thesis)
    assert math.pi / 2 < lean < REACH_ANGLE_MAX
    assert m.a_g * math.sin(lean) / m.b_f == pytest.approx(REACH_LEAN_FLOOR * f_max, rel=1e-3)
    assert reachable_grid(thesis)[-1] == lean


@pytest.mark.parametrize("strategy", ["fl_pid", "small_signal", "cascade", "fl_cascade"])
def test_every_strategy_starts_on_a_weak_rig_and_clamps_an_unreachable_reference(strategy: str) -> None:
    """No refusal to start on a valid rig with a smaller reach; a set point beyond the reach is
    clamped to it and flagged, and the loop holds the rod there."""
    from dataclasses import replace

    from aeropend_control.controller_core import build_strategy

    rig = _weak_rig()
    base = make_settings(strategy=strategy, steps=[0.0, 0.3, 2.0, 1.0], mode="lockstep")
    settings = replace(base, rig=rig)
    build_strategy(settings)  # the design itself accepts the rig
    loop = ControllerLoop(settings)
    n = round(7.0 / 2.048e-3)
    events: list[tuple[float, float]] = []
    # each sample's clamp event, read just before the next sample (and after the last one)
    closed_loop(loop, n, {k: lambda lp: events.append(lp.clamp_event) if lp.clamp_event else None
                          for k in range(1, n)})
    if loop.clamp_event:
        events.append(loop.clamp_event)
    col = {name: [row[i] for row in loop.rows] for i, name in enumerate(SIGNALS)}
    k2 = round(2.0 / 2.048e-3)
    assert events == [(1.0, loop.reach)]  # reported once, when the unreachable step came
    assert set(col["reference_clamped"][:k2]) == {0.0} and set(col["reference_clamped"][k2:]) == {1.0}
    assert col["reference"][-1] == loop.reach
    assert abs(col["theta"][-1] - loop.reach) < 0.02 * loop.reach  # held at the reach
