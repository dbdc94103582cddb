"""Multi-process ROS 2 closed loop: ``sim_node`` (lock-step) ↔ ``controller``, each in a subprocess.

The controller subscribes to the plant and writes its own trace (no third subscriber on the
lock-step plant). Random ROS_DOMAIN_ID in 1..100, localhost discovery; processes are killed in
``finally``.
"""

from __future__ import annotations

import csv
import signal
import subprocess
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from aeropend_control.metrics import GOAL, TABLE_6_1, step_metrics
from aeropend_control.strategies import Measurement, make_strategy
from aeropend_sim.params import load_rig
from aeropend_sim.ros.harness import (
    isolated_env,
    node_command,
    private_node,
    random_domain,
    reap,
    stop,
    summary_count,
    wait_for_server,
)
from aeropend_sim.simulation import PlantStepper
from bench.fixtures.closed_loop import closed_loop

pytestmark = [pytest.mark.ros, pytest.mark.timeout(90)]


@pytest.mark.parametrize("strategy", ["fl_pid", "small_signal", "fl_cascade"])
def test_lockstep_closed_loop_step_to_0_4(tmp_path: Path, strategy: str) -> None:
    trace = tmp_path / "trace.csv"
    env = isolated_env(random_domain())
    sim = subprocess.Popen([*node_command("sim_node"), "--ros-args", "-p", "mode:=lockstep",
                            "-p", "rig:=thesis_rig"],
                           env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ctl = None
    try:
        ctl = subprocess.Popen(
            [*node_command("controller"), "--ros-args", "-p", "mode:=lockstep", "-p", f"strategy:={strategy}",
             "-p", "steps:=[0.0, 0.4]", "-p", "duration:=3.0", "-p", f"trace:={trace}"],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        ctl_out, _ = ctl.communicate(timeout=60)
        assert ctl.returncode == 0, ctl_out
        sim_out = stop(sim, signal.SIGTERM, timeout=10).stdout
    finally:
        reap(ctl, sim)
    rows = list(csv.reader(trace.open()))
    data = np.array(rows[1:], dtype=float)
    t, theta, duty = data[:, 0], data[:, 2], data[:, 7]
    assert t[-1] >= 3.0 and np.allclose(np.diff(t), 2.048e-3, atol=1e-9)  # one command per sample
    met = step_metrics(t, theta, 0.4)
    assert met.failures(TABLE_6_1) == [] and met.failures(GOAL) == []
    # every controller command reached the plant, plus the duty 0 sent on shutdown
    assert summary_count(sim_out, "commands") == summary_count(ctl_out, "commands") + 1
    # the ROS loop is the batch loop: same plant, same controller, same samples
    rig = load_rig("thesis_rig")
    ref_ctl, plant = make_strategy(strategy, rig), PlantStepper(rig)
    s = plant.sample()
    # BatteryState.current is float32 on the wire: the cascade sees i_a rounded to ~1e-8 relative
    tol = 1e-6 if "i_a" in ref_ctl.needs else 1e-9
    for k in range(len(t)):
        assert abs(s["theta"] - theta[k]) < tol, f"sample {k}"
        d = ref_ctl.step(0.4, Measurement(s["theta"], s["omega_rotor"], s["i_a"])).duty
        assert abs(d - duty[k]) < tol, f"sample {k}"
        s = plant.step(d)


@pytest.mark.parametrize(("param", "needle"), [
    ("strategy:=pd", "strategy = 'pd'"),
    ("min_subscribers:=0", "min_subscribers = 0; expected an integer >= 1"),
])
def test_controller_refuses_bad_configuration(param: str, needle: str) -> None:
    proc = subprocess.run([*node_command("controller"), "--ros-args", "-p", param],
                          env=isolated_env(random_domain()), capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert needle in proc.stderr + proc.stdout


def test_reference_topic_drives_the_lockstep_loop(tmp_path: Path) -> None:
    """No step parameter: the set point comes from /aeropend/reference (std_msgs/Float64), published
    by this test process; the internal signals are checked on /aeropend/controller/signals."""
    from std_msgs.msg import Float64, Float64MultiArray

    from aeropend_control.controller_core import SIGNALS
    from aeropend_control.controller_node import TOPIC_REFERENCE, TOPIC_SIGNALS

    domain = random_domain()
    trace = tmp_path / "trace.csv"
    env = isolated_env(domain)
    sim = ctl = None
    signals: list[list[float]] = []
    with private_node("test_reference", domain) as (node, ex):
        try:
            pub = node.create_publisher(Float64, TOPIC_REFERENCE, 10)
            node.create_subscription(Float64MultiArray, TOPIC_SIGNALS,
                                     lambda m: signals.append(list(m.data)), 50)
            # controller first (it waits for samples), then the plant once this node is matched to
            # the controller both ways, so the set point reaches it within a few samples of being sent
            ctl = subprocess.Popen(
                [*node_command("controller"), "--ros-args", "-p", "mode:=lockstep", "-p", "strategy:=fl_pid",
                 "-p", "duration:=4.0", "-p", f"trace:={trace}"],
                env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            deadline = time.monotonic() + 40.0

            def matched() -> bool:
                return pub.get_subscription_count() > 0 and node.count_publishers(TOPIC_SIGNALS) > 0

            while not matched() and time.monotonic() < deadline:
                ex.spin_once(timeout_sec=0.05)
            assert pub.get_subscription_count() > 0, "controller not discovered"
            sim = subprocess.Popen([*node_command("sim_node"), "--ros-args", "-p", "mode:=lockstep"],
                                   env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            deadline = time.monotonic() + 80.0
            while ctl.poll() is None and time.monotonic() < deadline:
                ex.spin_once(timeout_sec=0.01)
                if signals and signals[-1][0] >= 0.5:  # 0.5 s of sample time at rest, then the set point
                    pub.publish(Float64(data=0.3))
            ctl_out = ctl.communicate(timeout=30)[0]
            assert ctl.returncode == 0, ctl_out
        finally:
            reap(ctl, sim)
    data = np.array(list(csv.reader(trace.open()))[1:], dtype=float)
    col = {name: data[:, i] for i, name in enumerate(SIGNALS)}
    on = np.flatnonzero(col["reference"] == 0.3)
    assert on.size > 0, "the topic reference never reached the controller"
    k0 = int(on[0])
    assert np.all(col["reference"][:k0] == 0.0) and np.all(col["reference"][k0:] == 0.3)
    t = col["t"][k0:] - col["t"][k0]
    assert t[-1] >= 1.5, f"reference arrived too late ({col['t'][k0]:.2f} s of 4 s)"
    assert np.all(np.abs(col["theta"][:k0]) < 1e-3)  # at rest before the set point
    met = step_metrics(t, col["theta"][k0:] - col["theta"][k0], 0.3 - col["theta"][k0])
    assert met.failures(TABLE_6_1) == []
    assert abs(col["theta"][-1] - 0.3) < 2e-3
    # the internal signals topic carries the same rows as the trace (labelled layout)
    assert signals and all(len(row) == len(SIGNALS) for row in signals)
    assert any(row[SIGNALS.index("reference")] == 0.3 for row in signals)


def test_live_parameters_change_the_running_controller(tmp_path: Path) -> None:
    """``ros2 param set`` across processes: a slower pole pattern set on the running controller
    (before its plant starts, so the run is reproducible sample by sample; the bumpless take-over
    mid-run is tested on the core, test_control_node) gives the slower design's commands; a refused
    value and a read-only parameter are rejected with a reason and change nothing."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    from aeropend_control.controller_core import SIGNALS, ControllerLoop, make_settings
    from aeropend_control.controller_node import NODE_NAME

    domain = random_domain()
    trace = tmp_path / "trace.csv"
    env = isolated_env(domain)
    steps = [0.0, 0.0, 1.5, 0.4]
    sim = ctl = None
    with private_node("test_live_params", domain) as (node, ex):
        try:
            client = node.create_client(SetParameters, f"/{NODE_NAME}/set_parameters")
            ctl = subprocess.Popen(
                [*node_command("controller"), "--ros-args", "-p", "mode:=lockstep", "-p", "strategy:=fl_pid",
                 "-p", f"steps:={steps}", "-p", "duration:=4.0", "-p", f"trace:={trace}"],
                env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            # available both ways; an empty SetParameters changes nothing
            wait_for_server(client, ex, SetParameters.Request(parameters=[]), 40.0)

            def call(**values: object) -> list:
                req = SetParameters.Request(
                    parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
                fut = client.call_async(req)
                ex.spin_until_future_complete(fut, timeout_sec=20.0)
                assert fut.done(), f"set_parameters {values} not answered"
                return fut.result().results

            bad, = call(zeta=-0.5)
            assert not bad.successful and "zeta" in bad.reason
            ro, = call(strategy="cascade")
            assert not ro.successful and "read-only" in ro.reason
            ok, = call(omega_n=5.0)
            assert ok.successful, ok.reason
            sim = subprocess.Popen([*node_command("sim_node"), "--ros-args", "-p", "mode:=lockstep"],
                                   env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            ctl_out = ctl.communicate(timeout=80)[0]
            assert ctl.returncode == 0, ctl_out
        finally:
            reap(ctl, sim)
    data = np.array(list(csv.reader(trace.open()))[1:], dtype=float)
    col = {name: data[:, i] for i, name in enumerate(SIGNALS)}
    # the run is the batch loop with omega_n = 5 (the change came before the first sample here),
    # and its step is the slow design's, not the default's
    for omega_n, same in ((5.0, True), (None, False)):
        loop = ControllerLoop(make_settings(strategy="fl_pid", steps=steps, mode="lockstep", omega_n=omega_n))
        duty = [d for _, d in closed_loop(loop, len(col["t"]))]
        assert np.allclose(duty, col["duty"], atol=1e-9) == same


def test_a_live_pole_change_in_realtime_mode_is_designed_off_the_executor() -> None:
    """On a rig file that declares its drive (the stored ``gap`` rig) a new small-signal pole pattern
    takes ≈ 0.5 s to design, longer than the firmware's 250 ms command watchdog. In real-time mode
    ``set_parameters`` returns with the loop still on its old gains and the new reference already
    applied; the finished design is then taken over between samples, and the loop's commands equal
    those of a loop designed with the new poles from the start. A ``reference`` change alone
    reuses the running design (no robust-ζ search, no redesign)."""
    import rclpy
    from rclpy.parameter import Parameter

    from aeropend_control.controller_core import ControllerLoop, make_settings
    from aeropend_control.controller_node import ControllerNode
    from aeropend_control.strategies import base

    rig = str(Path(__file__).resolve().parents[2] / "data" / "gap_corrected_rig.yaml")
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=random_domain())
    node = None
    try:
        node = ControllerNode(context=ctx, parameter_overrides=[
            Parameter("rig", value=rig), Parameter("strategy", value="small_signal")])
        spec0 = node.loop.settings.spec
        assert spec0.zeta > 0.7  # the robust ζ of a rig that declares its drive

        designs: list[object] = []
        real_robust_spec = base.robust_spec  # the robust-ζ search of Strategy.default_spec_for
        base.robust_spec = lambda *a, **k: designs.append(a) or real_robust_spec(*a, **k)
        try:
            ok, = node.set_parameters([Parameter("reference", value=0.2)])
        finally:
            base.robust_spec = real_robust_spec
        assert ok.successful and designs == [] and node._redesign is None
        assert node.loop.settings.spec == spec0 and node.loop.reference.initial == 0.2

        ok = node.set_parameters_atomically([Parameter("omega_n", value=10.0),
                                             Parameter("reference", value=0.3)])
        assert ok.successful, ok.reason
        assert node.loop.settings.spec == spec0 and node.loop.reference.initial == 0.3
        assert node._redesign is not None
        node._redesign[1].result(timeout=60.0)
        assert node.take_over_redesign()
        assert node.loop.settings.spec == replace(spec0, omega_n=10.0)

        fresh = ControllerLoop(make_settings(rig=rig, strategy="small_signal", omega_n=10.0, reference=0.3))
        for k in range(100):
            theta = 0.3 * (1.0 - np.exp(-k / 60.0))
            assert node.loop.on_sample(k * 2_048_000, theta) == pytest.approx(
                fresh.on_sample(k * 2_048_000, theta), abs=1e-12)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=ctx)


def test_a_lockstep_repeat_is_answered_again_only_for_a_reader_matched_since() -> None:
    """The lock-step plant re-publishes its last sample after 0.5 s without a command and advances
    once per command it receives. When the controller's first answer is slow (start-up under load),
    the plant's repeat arrives after an answer that is already on its way; answering the repeat too
    made the plant advance twice on one command, and the whole trajectory lagged one sample (CI
    failure of ``test_two_rigs_in_namespaces_each_with_its_controller``; reproducer
    ``bench/repro/lockstep_double_answer.py``). A repeat is answered again only when a duty reader
    matched after the first answer: that reader (a late plant) may have missed it."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64

    from aeropend_control.controller_node import ControllerNode
    from aeropend_sim.ros.ros_contract import COMMAND_QOS_LOCKSTEP

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=random_domain())
    node = peer = None
    try:
        node = ControllerNode(context=ctx, parameter_overrides=[Parameter("mode", value="lockstep")])
        peer = rclpy.create_node("duty_reader", context=ctx)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        ex.add_node(peer)
        got: list[list[float]] = [[], []]
        topic = node._pub_duty.topic_name

        def spin_until(cond, timeout: float = 10.0) -> bool:
            end = time.monotonic() + timeout
            while not cond() and time.monotonic() < end:
                ex.spin_once(timeout_sec=0.02)
            return cond()

        peer.create_subscription(Float64, topic, lambda m: got[0].append(m.data), COMMAND_QOS_LOCKSTEP)
        assert spin_until(lambda: node._pub_duty.get_subscription_count() == 1)
        node._control(0, 0.0)  # sample 0
        node._control(0, 0.0)  # the plant's repeat of sample 0: the reader has the answer already
        assert not spin_until(lambda: len(got[0]) > 1, timeout=1.0)
        assert len(got[0]) == 1 and node.loop.repeats == 1
        peer.create_subscription(Float64, topic, lambda m: got[1].append(m.data), COMMAND_QOS_LOCKSTEP)
        assert spin_until(lambda: node._pub_duty.get_subscription_count() == 2)
        node._control(0, 0.0)  # a reader matched since the answer: answered again
        assert spin_until(lambda: len(got[1]) == 1)
        assert got[1] == got[0][:1]
    finally:
        for n in (node, peer):
            if n is not None:
                n.destroy_node()
        rclpy.shutdown(context=ctx)
