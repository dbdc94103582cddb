"""Unit tests of aeropend_sim.sim_core: parameter validation and scheduling arithmetic (no ROS)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from aeropend_sim.params import load_rig, shipped_rigs
from aeropend_sim.sim_core import (
    CommandHold,
    PlantClock,
    RealtimeSchedule,
    SimConfigError,
    make_settings,
    parse_bool,
    parse_effects,
    parse_initial_state,
    sample_stamp_ns,
)
from aeropend_sim.simulation import PlantStepper

RIG = "thesis_rig" if "thesis_rig" in shipped_rigs() else "thesis_sim"


# ------------------------------------------------------------------------------------- effects
def test_parse_effects_list_and_comma_string():
    assert parse_effects(["dead_zone=true", "armature_inductance=quasi_static"]) == {
        "dead_zone": True, "armature_inductance": "quasi_static",
    }
    assert parse_effects("back_emf=off, end_stops=1") == {"back_emf": False, "end_stops": True}
    assert parse_effects(None) == {} and parse_effects([]) == {}
    assert parse_effects(["dead_zone=true", "dead_zone=false"]) == {"dead_zone": False}


@pytest.mark.parametrize(
    "items, needle",
    [
        (["warp=true"], "unknown effect 'warp'"),
        (["dead_zone"], "not of the form name=value"),
        (["dead_zone=maybe"], "dead_zone = 'maybe' is not a boolean"),
        (["armature_inductance=static"], "armature_inductance = 'static'"),
        (["=true"], "not of the form"),
    ],
)
def test_parse_effects_errors(items, needle):
    with pytest.raises(SimConfigError, match=needle.replace("(", r"\(").replace("[", r"\[")):
        parse_effects(items)


def test_parse_bool():
    assert parse_bool("x", True) is True and parse_bool("x", "OFF") is False and parse_bool("x", 1) is True
    with pytest.raises(SimConfigError, match="x = 2 is not a boolean"):
        parse_bool("x", 2)


# ------------------------------------------------------------------------------------- initial state
def test_initial_state_variants():
    np.testing.assert_array_equal(parse_initial_state(None, None), np.zeros(5))
    np.testing.assert_array_equal(parse_initial_state(0.3, []), [0.3, 0, 0, 0, 0])
    full = [0.2, 0.1, 0.05, 3.0, 0.4]
    np.testing.assert_array_equal(parse_initial_state(None, full), full)
    with pytest.raises(SimConfigError, match=r"initial_state has 4 value\(s\)"):
        parse_initial_state(None, [0.1, 0.0, 0.0, 0.0])
    with pytest.raises(SimConfigError, match="non-finite"):
        parse_initial_state(None, [0.1, math.nan, 0.0, 0.0, 0.0])
    with pytest.raises(SimConfigError, match=r"initial_theta = 0\.5 conflicts with initial_state\[0\]"):
        parse_initial_state(0.5, [0.1, 0.0, 0.0, 0.0, 0.0])
    with pytest.raises(SimConfigError, match="initial_theta = 'up' is not a number"):
        parse_initial_state("up", None)


# ------------------------------------------------------------------------------------- settings
def test_make_settings_applies_overrides():
    s = make_settings(rig=RIG, effects=["dead_zone=true"], mode="lockstep", seed=4, noise=True,
                      initial_theta=0.25)
    assert s.rig.effects.dead_zone is True
    assert s.rig.effects.sensor_noise is True and s.rig.effects.quantisation is True
    assert s.publish_clock is True  # lock-step default
    assert s.mode == "lockstep" and s.seed == 4 and s.x0[0] == 0.25
    assert s.period_s == pytest.approx(2.048e-3)
    # an explicit effects override wins over the noise switch
    s2 = make_settings(rig=RIG, effects=["quantisation=false"], noise=True)
    assert s2.rig.effects.sensor_noise is True and s2.rig.effects.quantisation is False
    assert s2.publish_clock is False  # real-time default
    assert make_settings(rig=RIG, publish_clock="true").publish_clock is True


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        ({"rig": "nope"}, "rig = 'nope': no rig named 'nope'"),
        ({"rig": ""}, "rig = ''"),
        ({"mode": "fast"}, "mode = 'fast'; expected one of"),
        ({"seed": -1}, "seed = -1; expected an integer >= 0"),
        ({"seed": 1.5}, "seed = 1.5"),
        ({"command_timeout": 0.0}, "command_timeout = 0 s"),
        ({"command_timeout": "abc"}, "command_timeout = 'abc' is not a number"),
        ({"frame_id": ""}, "frame_id = ''"),
        ({"noise": "sometimes"}, "noise = 'sometimes' is not a boolean"),
        ({"rig": "/tmp/definitely_missing_rig.yaml"}, "does not exist"),
        ({"rt_priority": 120}, "rt_priority = 120; expected an integer in [0, 99]"),
        ({"min_subscribers": 0}, "min_subscribers = 0; expected an integer >= 1"),
        ({"min_subscribers": True}, "min_subscribers = True"),
        ({"min_clock_subscribers": -1}, "min_clock_subscribers = -1; expected an integer >= 0"),
        ({"min_clock_subscribers": 1.0}, "min_clock_subscribers = 1.0; expected an integer >= 0"),
    ],
)
def test_make_settings_errors(kwargs, needle):
    args = {"rig": RIG, **kwargs}
    with pytest.raises(SimConfigError) as info:
        make_settings(**args)
    assert needle in str(info.value)


# ------------------------------------------------------------------------------------- timing
def test_sample_stamps_do_not_drift():
    assert sample_stamp_ns(0, 2.048e-3) == 0
    assert sample_stamp_ns(1, 2.048e-3) == 2_048_000
    assert sample_stamp_ns(10_000_000, 2.048e-3, origin_ns=5) == 20_480_000_000_005
    ks = np.arange(0, 1_000_000, 9973)
    assert all(sample_stamp_ns(int(k), 2.048e-3) == int(k) * 2_048_000 for k in ks)


def test_schedule_absolute_deadlines_and_reanchor():
    sch = RealtimeSchedule(period_ns=2_048_000, start_ns=1_000_000_000)
    assert sch.deadline_ns(0) == 1_000_000_000
    assert sch.deadline_ns(5) == 1_000_000_000 + 5 * 2_048_000
    # waking 300 µs late does not shift later deadlines (no accumulation)
    assert sch.on_wake(5, sch.deadline_ns(5) + 300_000) == 300_000
    assert sch.deadline_ns(6) == 1_000_000_000 + 6 * 2_048_000
    assert sch.overruns == 0
    # exactly one period late is not an overrun
    assert sch.on_wake(6, sch.deadline_ns(6) + 2_048_000) == 2_048_000 and sch.overruns == 0
    # 5 ms late: overrun, re-anchored at the wake-up instant
    wake = sch.deadline_ns(7) + 5_000_000
    assert sch.on_wake(7, wake) == 5_000_000
    assert sch.overruns == 1 and sch.dropped_ns == 5_000_000
    assert sch.deadline_ns(7) == wake and sch.deadline_ns(8) == wake + 2_048_000
    assert sch.max_lateness_ns == 5_000_000
    with pytest.raises(ValueError, match="period_ns = 0"):
        RealtimeSchedule(0, 0)


def test_command_hold_validation_and_timeout():
    hold = CommandHold(timeout_ns=250_000_000)
    assert hold.value(0) == 0.0  # nothing received yet: motor off
    assert hold.offer(0.4, 1_000) is None
    assert hold.value(200_000_000) == 0.4
    reason = hold.offer(math.nan, 2_000)
    assert reason is not None and "nan" in reason
    reason = hold.offer(1.5, 3_000)
    assert reason is not None and "1.5" in reason and "outside [0, 1]" in reason
    assert hold.rejected == 2 and hold.accepted == 1
    assert hold.value(250_000_999) == 0.4  # rejected commands did not change the held value
    assert hold.value(250_001_001) == 0.0 and hold.timed_out and hold.timeouts == 1
    assert hold.value(300_000_000) == 0.0 and hold.timeouts == 1  # one timeout event
    assert hold.offer(0.6, 400_000_000) is None
    assert hold.value(400_000_001) == 0.6 and not hold.timed_out
    forever = CommandHold(timeout_ns=None)
    forever.offer(0.3, 0)
    assert forever.value(10**15) == 0.3


def test_plant_clock_matches_stepper_and_wire_convention():
    settings = make_settings(rig=RIG, mode="lockstep", seed=3, noise=True)
    clock = PlantClock(settings, origin_ns=1_000)
    ref = PlantStepper(load_rig(RIG).with_effects(sensor_noise=True, quantisation=True), seed=3)
    assert clock.last.stamp_ns == 1_000 and clock.last.duty == 0.0
    assert clock.last.theta == ref.sample()["theta"]
    for k, u in enumerate([0.5, 0.5, 0.2]):
        s = clock.advance(u)
        r = ref.step(u)
        assert s.stamp_ns == 1_000 + (k + 1) * 2_048_000
        assert s.duty == u
        assert (s.theta, s.i_a, s.v_a) == (r["theta"], r["i_a"], r["v_a"])


def test_a_warmed_clock_started_later_gives_the_samples_of_a_cold_one():
    """``sim_node`` builds and warms its plant before it offers its topics and stamps sample 0 when
    the sampler starts (bench/repro/sim_start_stall.py): same samples, bit for bit, as a clock built
    at the start; only sample 0 can be re-stamped."""
    settings = make_settings(rig=RIG, mode="realtime", seed=5, noise=True)
    cold = PlantClock(settings, origin_ns=7_000)
    warm = PlantClock(settings, origin_ns=0)
    warm.stepper.warm()
    warm.start_at(7_000)
    assert warm.last == cold.last
    for u in [0.0, 0.4, 0.4, 0.1]:
        assert warm.advance(u) == cold.advance(u)
    assert np.array_equal(warm.stepper.x, cold.stepper.x)
    with pytest.raises(RuntimeError, match="sample 4"):
        warm.start_at(0)


def test_set_rig_continues_from_the_state_and_refuses_a_new_delay_line():
    rig = load_rig(RIG)
    a, b = PlantStepper(rig), PlantStepper(rig)
    for _ in range(200):
        a.step(0.6)
        b.step(0.6)
    b.set_rig(rig.with_params("actuator", dead_zone=0.1).with_effects(dead_zone=True))
    assert np.array_equal(a.x, b.x)  # same state at the switch
    a2, b2 = a.step(0.6), b.step(0.6)
    # the dead zone lowers the effective duty: the rotor accelerates less than without it
    assert b2["omega_rotor"] < a2["omega_rotor"]
    delayed = rig.with_params("actuator", input_delay=0.01).with_effects(input_delay=True)
    with pytest.raises(ValueError, match="input delay"):
        b.set_rig(delayed)
    with pytest.raises(ValueError, match="sample period"):
        b.set_rig(dataclasses.replace(rig, sample_period=1e-3))
