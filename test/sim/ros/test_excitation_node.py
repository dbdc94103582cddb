"""Tests of the excitation node: configuration merging, lock-step feeder, --print, and a real
plant <-> excitation lock-step ping-pong in separate processes."""

from __future__ import annotations

import signal
import subprocess
import time

import numpy as np
import pytest

from aeropend_sim.excitation import ExcitationError, lhs_steps, make_signal, staircase
from aeropend_sim.params import shipped_rigs
from aeropend_sim.ros.excitation_node import (
    LockstepFeeder,
    build_arg_parser,
    resolve_config,
    ros_param_overrides,
    strip_ros_args,
)
from aeropend_sim.ros.harness import (
    isolate_process,
    isolated_env,
    node_command,
    private_node,
    random_domain,
    reap,
    stop,
)

RIG = "thesis_rig" if "thesis_rig" in shipped_rigs() else "thesis_sim"
PERIOD_NS = 2_048_000


# ------------------------------------------------------------------------------------- pure
def test_flags_override_ros_parameters():
    argv = ["--signal", "staircase", "--levels", "0.3", "0.5", "--hold", "0.5",
            "--ros-args", "-p", "signal:=lhs", "-p", "mode:=lockstep", "-p", "seed:=4"]
    flags = build_arg_parser().parse_args(strip_ros_args(argv))
    params = ros_param_overrides(argv)
    assert params == {"signal": "lhs", "mode": "lockstep", "seed": 4}
    with pytest.raises(ExcitationError, match=r"signal 'staircase' has no parameter\(s\) \['seed'\]"):
        resolve_config(params, flags)  # seed is not an argument of a staircase
    del params["seed"]
    cfg = resolve_config(params, flags)
    assert cfg.mode == "lockstep" and cfg.zero_at_end is False  # lock-step default
    np.testing.assert_array_equal(cfg.signal.duty, staircase([0.3, 0.5], 0.5).duty)


def test_resolve_config_from_parameters_only():
    cfg = resolve_config({"signal": "lhs", "seed": 1, "n": 5, "levels": None, "mode": None})
    assert cfg.mode == "realtime" and cfg.zero_at_end is True  # real-time default: safe stop
    np.testing.assert_array_equal(cfg.signal.duty, lhs_steps(5, seed=1).duty)
    # ROS double arrays arrive as array.array
    import array

    cfg = resolve_config({"signal": "staircase", "levels": array.array("d", [0.2, 0.4]), "hold": 0.01})
    assert cfg.signal.levels.tolist() == [0.2, 0.4]


@pytest.mark.parametrize(
    "params, needle",
    [
        ({"signal": "chirp"}, "unknown signal kind 'chirp'"),
        ({"mode": "fast"}, "mode = 'fast'"),
        ({"wait_timeout": -1.0}, "wait_timeout = -1.0"),
        ({"zero_at_end": "maybe"}, "zero_at_end = 'maybe'"),
        ({"bogus": 1}, "unknown parameter(s) ['bogus']"),
        ({"signal": "lhs", "tau_max": 1.3}, "tau_max = 1.3"),
        ({"min_subscribers": 0}, "min_subscribers = 0"),
    ],
)
def test_resolve_config_errors(params, needle):
    with pytest.raises(ExcitationError) as info:
        resolve_config(params)
    assert needle in str(info.value)


def test_lockstep_feeder_answers_each_new_sample_once():
    feeder = LockstepFeeder(np.array([0.1, 0.2, 0.3]))
    assert feeder.on_sample(0) == 0.1
    assert feeder.on_sample(0) == 0.1  # re-published sample 0: the command was lost, resend
    assert feeder.resent == 1
    assert feeder.on_sample(PERIOD_NS) == 0.2
    assert feeder.on_sample(0) is None  # stale sample
    assert feeder.on_sample(2 * PERIOD_NS) == 0.3
    assert feeder.done and feeder.sent == 3
    assert feeder.on_sample(3 * PERIOD_NS) is None  # signal exhausted


def test_lockstep_feeder_answers_a_repeat_again_only_for_a_reader_matched_since():
    # The plant advances once per command. A repeat of sample k that crossed the answer to k on
    # the wire must not be answered again (the plant would apply duty[k] for two periods and the
    # signal would shift by a sample), unless a duty reader matched after the answer went out.
    feeder = LockstepFeeder(np.array([0.1, 0.2, 0.3]))
    assert feeder.on_sample(0, matched=1) == 0.1
    feeder.mark_published(1)  # the answer went out to the one reader (the plant)
    assert feeder.on_sample(0, matched=1) is None  # it got it: no second command
    assert (feeder.resent, feeder.skipped) == (0, 1)
    assert feeder.on_sample(PERIOD_NS, matched=1) == 0.2
    feeder.mark_published(1)  # this answer reached only a recorder; the plant matches afterwards
    assert feeder.on_sample(PERIOD_NS, matched=2) == 0.2  # the late plant may have missed it
    feeder.mark_published(2)
    assert feeder.on_sample(PERIOD_NS, matched=2) is None
    assert (feeder.sent, feeder.resent, feeder.skipped) == (2, 1, 2)
    # the whole signal goes out once per new sample, in order
    assert feeder.on_sample(2 * PERIOD_NS, matched=2) == 0.3 and feeder.done


def test_ros_param_overrides_syntax_error():
    with pytest.raises(ExcitationError, match="name:=value"):
        ros_param_overrides(["--ros-args", "-p", "seed=1"])


# ------------------------------------------------------------------------------------- --print
def test_print_outputs_csv_without_ros():
    out = subprocess.run(
        [*node_command("excitation", "aeropend_sim.ros.excitation_node"), "--print", "--ros-args",
         "-p", "signal:=prbs", "-p", "order:=4", "-p", "clock:=2", "-p", "seed:=3"],
        capture_output=True, text=True, timeout=60, check=True,
    )
    lines = out.stdout.strip().splitlines()
    assert lines[0] == "t,duty"
    duty = np.array([float(ln.split(",")[1]) for ln in lines[1:]])
    np.testing.assert_array_equal(duty, make_signal("prbs", order=4, clock=2, seed=3).duty)


def test_print_bad_signal_exits_2():
    out = subprocess.run(
        [*node_command("excitation", "aeropend_sim.ros.excitation_node"), "--print", "--signal", "staircase",
         "--levels", "0.2", "1.4", "--hold", "1"],
        capture_output=True, text=True, timeout=60,
    )
    assert out.returncode == 2
    assert "levels[1] = 1.4" in out.stderr


# ------------------------------------------------------------------------------------- ROS ping-pong
@pytest.mark.ros
@pytest.mark.timeout(60)
def test_lockstep_plant_excitation_ping_pong(monkeypatch):
    pytest.importorskip("rclpy")
    from sensor_msgs.msg import JointState

    from aeropend_sim.ros.ros_contract import SAMPLE_QOS_LOCKSTEP

    domain = random_domain()
    isolate_process(monkeypatch, domain)
    env = isolated_env(domain)
    sig = staircase([0.45, 0.3, 0.55], [0.2, 0.1, 0.15])
    n = len(sig)
    seen: dict[int, float] = {}

    def on_js(msg: JointState) -> None:
        seen[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = msg.effort[1]

    exc = None
    with private_node("ping_pong_observer", domain) as (node, ex):
        node.create_subscription(JointState, "/aeropend/joint_states", on_js, SAMPLE_QOS_LOCKSTEP)
        plant = subprocess.Popen(
            [*node_command("sim_node", "aeropend_sim.ros.sim_node"), "--ros-args", "-p", f"rig:={RIG}",
             "-p", "mode:=lockstep"],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        try:
            # the observer must be matched before the ping-pong starts: wait for (re-published) sample 0
            end = time.monotonic() + 20
            while time.monotonic() < end and 0 not in seen:
                ex.spin_once(timeout_sec=0.01)
            assert 0 in seen, "plant sample 0 not received within 20 s"
            exc = subprocess.Popen(
                [*node_command("excitation", "aeropend_sim.ros.excitation_node"), "--signal", "staircase",
                 "--levels", "0.45", "0.3", "0.55", "--hold", "0.2", "0.1", "0.15", "--mode", "lockstep"],
                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            )
            end = time.monotonic() + 45
            while time.monotonic() < end and exc.poll() is None:
                ex.spin_once(timeout_sec=0.01)
            _, exc_err = exc.communicate(timeout=10)
            assert exc.returncode == 0, exc_err
            end = time.monotonic() + 5
            while time.monotonic() < end and n * PERIOD_NS not in seen:
                ex.spin_once(timeout_sec=0.01)
            assert plant.poll() is None
            plant_err = stop(plant, signal.SIGINT, timeout=10).stderr
        finally:
            reap(exc, plant)
    assert plant.returncode == 0
    # exactly one plant sample per command, stamped k·T_s, carrying the command that produced it
    assert sorted(seen) == [k * PERIOD_NS for k in range(n + 1)]
    np.testing.assert_array_equal([seen[(k + 1) * PERIOD_NS] for k in range(n)], sig.duty)
    assert f"commands={n}" in plant_err and "rejected=0" in plant_err
    assert f"sent {n} commands" in exc_err
