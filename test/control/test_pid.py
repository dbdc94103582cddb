"""Unit tests of the discrete PID (aeropend_control.pid) against analytic responses."""

from __future__ import annotations

import math

import pytest

from aeropend_control.pid import PID, PIDConfigError, PIDGains

H = 0.01


def test_p_only_step_and_setpoint_weight() -> None:
    pid = PID(PIDGains(kp=2.0), H)
    assert [pid.update(1.0, 0.0) for _ in range(3)] == [2.0, 2.0, 2.0]
    pid = PID(PIDGains(kp=2.0, b=0.25), H)
    assert pid.update(1.0, 0.1) == pytest.approx(2.0 * (0.25 - 0.1), abs=1e-15)


@pytest.mark.parametrize(("method", "offset"), [("backward_euler", 1), ("forward_euler", 0), ("tustin", 1)])
def test_integrator_ramp(method: str, offset: int) -> None:
    pid = PID(PIDGains(ki=3.0, method=method), H)
    out = [pid.update(1.0, 0.0) for _ in range(50)]
    for k, u in enumerate(out):
        assert u == pytest.approx(3.0 * H * (k + offset), abs=1e-12)


def test_tustin_trapezoid_on_error_change() -> None:
    pid = PID(PIDGains(ki=2.0, method="tustin"), H)
    pid.update(1.0, 0.0)  # I = h·ki·1
    u = pid.update(3.0, 0.0)  # + h·ki·(1 + 3)/2
    assert u == pytest.approx(2.0 * H * (1.0 + 2.0), abs=1e-14)


def _windup_run(anti_windup: str, n_pos: int = 100) -> list[float]:
    """Integrator with limits ±1: error +1 for n_pos samples, then −1."""
    pid = PID(PIDGains(ki=3.0, u_min=-1.0, u_max=1.0, anti_windup=anti_windup), H)
    out = [pid.update(1.0, 0.0) for _ in range(n_pos)]
    out += [pid.update(-1.0, 0.0) for _ in range(200)]
    return out


def test_windup_present_without_anti_windup() -> None:
    out = _windup_run("none")
    # I after 100 steps = 100·0.03 = 3; after m negative steps 3 − 0.03·m < 1 first at m = 67
    first_off = next(m for m, u in enumerate(out[100:], start=1) if u < 1.0)
    assert first_off == 67


@pytest.mark.parametrize("scheme", ["back_calculation", "conditional"])
def test_windup_absent_with_anti_windup(scheme: str) -> None:
    out = _windup_run(scheme)
    first_off = next(m for m, u in enumerate(out[100:], start=1) if u < 1.0)
    assert first_off <= 2
    # after leaving saturation the output ramps down at ki·h per sample
    assert out[110] - out[111] == pytest.approx(0.03, abs=1e-12)


def test_conditional_integration_freezes_below_limit() -> None:
    out = _windup_run("conditional")
    assert max(out[:100]) == pytest.approx(33 * 0.03, abs=1e-12)  # 34th increment rejected
    assert out[100] == pytest.approx(32 * 0.03, abs=1e-12)


def test_back_calculation_fixed_point() -> None:
    # kp = 0, kt = 1/h (default): implicit fixed point I = u_max + h·ki·e
    pid2 = PID(PIDGains(ki=3.0, u_min=-1.0, u_max=1.0), H)
    for _ in range(300):
        pid2.update(1.0, 0.0)
    assert pid2.i == pytest.approx(1.0 + 0.03, abs=1e-9)
    assert pid2.saturated == 1


def test_no_derivative_kick_on_setpoint_step() -> None:
    pid = PID(PIDGains(kd=1.0, tf=0.02), H)
    for _ in range(5):
        pid.update(0.0, 0.0)
    assert pid.update(1.0, 0.0) == 0.0 and pid.d == 0.0
    kick = PID(PIDGains(kd=1.0, tf=0.02, c=1.0), H)
    for _ in range(5):
        kick.update(0.0, 0.0)
    assert kick.update(1.0, 0.0) == pytest.approx(1.0 / (0.02 + H), rel=1e-12)


@pytest.mark.parametrize("method", ["backward_euler", "forward_euler", "tustin"])
def test_filtered_derivative_on_ramp(method: str) -> None:
    a, tf, kd = 0.5, 0.05, 2.0
    pid = PID(PIDGains(kd=kd, tf=tf, method=method), H)
    out = [pid.update(0.0, a * H * k) for k in range(200)]
    rho = {"backward_euler": tf / (tf + H), "forward_euler": 1 - H / tf,
           "tustin": (2 * tf - H) / (2 * tf + H)}[method]
    for k, u in enumerate(out):
        assert u == pytest.approx(-kd * a * (1.0 - rho**k), abs=1e-12)


def test_clamp() -> None:
    pid = PID(PIDGains(kp=10.0, u_min=0.0, u_max=1.0, anti_windup="none"), H)
    assert pid.update(1.0, 0.0) == 1.0 and pid.saturated == 1
    assert pid.update(-1.0, 0.0) == 0.0 and pid.saturated == -1
    assert pid.update(0.05, 0.0) == pytest.approx(0.5) and pid.saturated == 0


def test_bumpless_gain_change() -> None:
    pid = PID(PIDGains(kp=1.0, ki=2.0, b=1.0), H)
    for _ in range(10):
        u = pid.update(0.5, 0.2)
    pid.set_gains(PIDGains(kp=4.0, ki=2.0, b=0.0))
    # next output = old output + one integration step of the same error
    assert pid.update(0.5, 0.2) == pytest.approx(u + H * 2.0 * 0.3, abs=1e-12)


def test_manual_auto_bumpless() -> None:
    pid = PID(PIDGains(kp=1.0, ki=5.0, u_min=0.0, u_max=1.0), H)
    pid.set_manual(0.3)
    for _ in range(5):
        assert pid.update(0.4, 0.1) == 0.3
    pid.set_auto()
    assert pid.update(0.4, 0.1) == pytest.approx(0.3 + H * 5.0 * 0.3, abs=1e-12)


def test_nan_holds_last_output() -> None:
    pid = PID(PIDGains(kp=1.0, ki=1.0), H)
    u = pid.update(1.0, 0.0)
    state = (pid.i, pid.output)
    assert pid.update(math.nan, 0.0) == u and pid.nan_flag and pid.nan_count == 1
    assert pid.update(1.0, math.inf) == u and pid.nan_count == 2
    assert (pid.i, pid.output) == state
    pid.update(1.0, 0.0)
    assert not pid.nan_flag


@pytest.mark.parametrize(
    ("kwargs", "dt", "needle"),
    [({"kp": math.nan}, H, "kp = nan"), ({"tf": -1.0}, H, "tf = -1.0"),
     ({"u_min": 1.0, "u_max": 0.0}, H, "u_min = 1.0"), ({"method": "euler"}, H, "'euler'"),
     ({"anti_windup": "x"}, H, "'x'"), ({"kd": 1.0, "tf": 0.001, "method": "forward_euler"}, H, "tf = 0.001"),
     ({}, 0.0, "dt = 0.0")],
)
def test_bad_config_names_value(kwargs: dict, dt: float, needle: str) -> None:
    with pytest.raises(PIDConfigError, match=needle.replace("(", r"\(").replace(".", r"\.")):
        PID(PIDGains(**kwargs), dt)


def test_external_derivative_replaces_the_filtered_difference() -> None:
    pid = PID(PIDGains(kp=2.0, ki=0.0, kd=0.5, b=0.0, c=0.0, tf=0.01), 0.01)
    u = pid.update(1.0, 0.2, dy=3.0)
    assert pid.d == pytest.approx(-1.5) and u == pytest.approx(-2.0 * 0.2 - 1.5)
    assert pid.update(1.0, 0.2, dy=math.nan) == u and pid.nan_flag  # non-finite dy holds the output
    with pytest.raises(PIDConfigError, match=r"c = 1\.0"):
        PID(PIDGains(kp=1.0, kd=1.0, c=1.0), 0.01).update(1.0, 0.0, dy=0.0)
