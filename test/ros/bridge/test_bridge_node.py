"""The ``bridge`` node in a subprocess against the pty fake MCU (multi-process ROS 2 test).

Checks the topic contract (both sample topics, same stamp, SI units from the rig's LSBs),
stamps from the MCU clock (490.2 Hz), duty forwarding, NaN / out-of-range rejection, the
bridge's 100 ms command watchdog, diagnostics, unplug/replug and duty 0 on shutdown.
"""

from __future__ import annotations

import math
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import BatteryState, JointState
from std_msgs.msg import Float64

from aeropend_bridge.bridge_core import Calibration
from aeropend_bridge.fake_mcu import FakeMcu
from aeropend_bridge.protocol import Duty
from aeropend_sim.contract import TOPIC_ARMATURE, TOPIC_DUTY_CYCLE, TOPIC_JOINT_STATES
from aeropend_sim.params import load_rig
from aeropend_sim.ros.harness import (
    frozen_gc,
    isolated_env,
    node_command,
    private_node,
    random_domain,
    reap,
    stop,
)
from aeropend_sim.ros.ros_contract import COMMAND_QOS, SAMPLE_SUB_QOS, sample_from_msgs

pytestmark = [
    pytest.mark.ros,
    # real time, as test_bridge_swap: the fake MCU's 490 Hz stream from a thread of this process, the
    # bridge's sample-rate diagnostic over its last second of host time and its 100 ms command watchdog.
    # Beside the parallel suite (the clean-clone CI of c986505) the diagnostic read 425 Hz while the
    # MCU-clock stamps were 490.18 Hz apart: frames were late on the host, not lost on the wire; beside
    # three or four CPU hogs it read within 5 % in 7 of 7 runs
    pytest.mark.exclusive,
    pytest.mark.timeout(60),
]
BRIDGE = node_command("bridge", "aeropend_bridge.bridge_node")


class Client:
    def __init__(self, domain: int) -> None:
        self._stack = ExitStack()
        self.node, self.executor = self._stack.enter_context(private_node("bridge_test_client", domain))
        self.js: list[JointState] = []
        self.arm: dict[int, BatteryState] = {}
        self.diag: list[DiagnosticArray] = []
        self.node.create_subscription(JointState, TOPIC_JOINT_STATES, self.js.append, SAMPLE_SUB_QOS)
        self.node.create_subscription(BatteryState, TOPIC_ARMATURE, self._on_arm, SAMPLE_SUB_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diag.append, 10)
        self.pub = self.node.create_publisher(Float64, TOPIC_DUTY_CYCLE, COMMAND_QOS)
        self.last_pub = 0.0  # time.monotonic() of the last command published

    def _on_arm(self, msg: BatteryState) -> None:
        self.arm[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = msg

    def spin_until(self, cond: Callable[[], bool], timeout: float, publish: float | None = None) -> bool:
        end = time.monotonic() + timeout
        next_pub = 0.0
        while time.monotonic() < end:
            if cond():
                return True
            if publish is not None and time.monotonic() >= next_pub:
                self.pub.publish(Float64(data=publish))
                self.last_pub = time.monotonic()
                next_pub = time.monotonic() + 0.02
            self.executor.spin_once(timeout_sec=0.005)
        return cond()

    def close(self) -> None:
        self._stack.close()


def _diag_value(arr: DiagnosticArray, key: str) -> str:
    return {kv.key: kv.value for kv in arr.status[0].values}[key]


@pytest.fixture
def frozen_heap() -> Iterator[None]:
    """This process' heap frozen for the test (:func:`~aeropend_sim.ros.harness.frozen_gc`): the fake
    firmware is a thread of it, and a full collection of the heap the earlier exclusive tests left
    holds it past the 50 ms the duty checks allow (fresh-clone CI of 3d2308b: no Duty frame read in
    the window; ``bench/repro/fake_mcu_gc_pause.py``)."""
    with frozen_gc():
        yield


def test_bridge_node_against_fake_mcu(tmp_path: Path, frozen_heap: None) -> None:
    domain = random_domain(101, 200)
    env = isolated_env(domain)
    link = tmp_path / "ttyACM_fake"
    mcu = FakeMcu(link).start()
    proc = subprocess.Popen(
        [*BRIDGE, "--ros-args", "-p", f"port:={link}", "-p", "theta_offset:=3.141592653589793",
         "-p", "diagnostics_period:=0.5", "-p", "backoff_initial:=0.02", "-p", "backoff_max:=0.2"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    client = Client(domain)
    err = ""
    try:
        assert client.spin_until(lambda: len(client.js) > 600, 20), "no samples from the bridge"
        # --- contract: same stamp on both topics, SI units from the rig's LSBs
        cal = Calibration.from_rig(load_rig("thesis_rig"), theta_offset=math.pi)
        stamps = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in client.js]
        paired = [(m, client.arm[s]) for m, s in zip(client.js, stamps, strict=True) if s in client.arm]
        assert len(paired) > 0.9 * len(client.js)
        for js, arm in paired[-200:]:
            s = sample_from_msgs(js, arm)
            counts = s.i_a / cal.i_a_lsb
            assert abs(counts - round(counts)) < 1e-3 and 100 <= round(counts) <= 106  # float32 field
            assert -50 <= round(s.v_a / cal.v_a_lsb) <= -40
            assert abs(s.theta) <= 200 * cal.theta_lsb + 1e-9
            assert s.omega_prop == pytest.approx(2 * math.pi / (0.06 + 12 * 4e-6), rel=2e-4) or (
                2 * math.pi / 0.0605 < s.omega_prop <= 2 * math.pi / 0.06)
            assert s.omega_rotor == pytest.approx(s.omega_prop * cal.gear_ratio)
        # --- stamps from the MCU clock: 2.040 ms apart (490.2 Hz), strictly increasing
        d = np.diff(np.array(stamps[-500:], dtype=np.int64))
        assert (d > 0).all()
        rate = 1e9 / np.median(d)
        print(f"stamp rate {rate:.2f} Hz, spacing min/median/max {d.min() / 1e6:.3f}/"
              f"{np.median(d) / 1e6:.3f}/{d.max() / 1e6:.3f} ms")
        assert rate == pytest.approx(490.196, rel=0.01)
        # --- duty forwarding (50 Hz commands), then NaN / out of range rejected
        assert client.spin_until(lambda: mcu.duty_ocr == 128, 5, publish=0.5)
        n_cmd = len(mcu.commands)
        for bad in (math.nan, 1.5, -0.2):
            client.pub.publish(Float64(data=bad))
        client.spin_until(lambda: False, 0.05, publish=0.5)
        sent = [f for _, f in mcu.commands[n_cmd:] if isinstance(f, Duty)]
        assert sent and all(f.value == 32768 for f in sent), sent
        assert client.spin_until(lambda: any(abs(m.effort[1] - 128 / 255) < 1e-9 for m in client.js[-20:]), 2)
        # --- bridge watchdog: controller silent -> duty 0 on the wire within 100 ms
        silent_from = client.last_pub  # the controller (this client) goes silent now
        assert client.spin_until(lambda: mcu.duty_ocr == 0, 1)
        first_zero = min(t for t, f in mcu.commands if isinstance(f, Duty) and f.value == 0
                         and t > silent_from)
        latency = first_zero - silent_from  # both time.monotonic() of this process
        print(f"bridge watchdog: duty 0 on the wire {latency * 1e3:.1f} ms after the last command")
        assert latency <= 0.1  # spec: duty 0 within 100 ms of controller silence
        # keep-alive keeps the firmware watchdog quiet; on failure say when the commands stopped
        arrivals = np.array([t for t, _ in mcu.commands])
        gaps = np.diff(arrivals)
        k = int(np.argmax(gaps)) if gaps.size else 0
        assert mcu.watchdog_trips == 0, (
            f"firmware watchdog tripped {mcu.watchdog_trips}x; longest gap between commands "
            f"{gaps[k] * 1e3:.0f} ms, from {arrivals[k] - arrivals[0]:.3f} s after the first command "
            f"(controller silent from {silent_from - arrivals[0]:.3f} s); commands "
            f"{[type(f).__name__ for _, f in mcu.commands[max(0, k - 2):k + 3]]}")
        # --- diagnostics (a fresh message, published after the events above)
        client.diag.clear()
        assert client.spin_until(lambda: len(client.diag) >= 1, 3)
        last = client.diag[-1]
        assert last.status[0].name.startswith("aeropend_bridge")
        assert float(_diag_value(last, "rate_hz")) == pytest.approx(490.2, rel=0.05)
        assert _diag_value(last, "commands_rejected") == "3"
        assert int(_diag_value(last, "watchdog_trips")) >= 1
        # --- unplug / replug
        mcu.unplug()
        time.sleep(0.3)
        n = len(client.js)
        mcu.replug()
        assert client.spin_until(lambda: len(client.js) > n + 200, 10), "no samples after replug"
        client.diag.clear()
        assert client.spin_until(lambda: len(client.diag) >= 1, 3)
        assert _diag_value(client.diag[-1], "reconnects") == "1"
        assert _diag_value(client.diag[-1], "connected") == "True"
        # --- clean shutdown: motor off
        assert client.spin_until(lambda: mcu.duty_ocr == 128, 5, publish=0.5)
        err = stop(proc, signal.SIGINT, timeout=10).stderr
        assert proc.returncode == 0, err
        time.sleep(0.1)
        assert mcu.duty_ocr == 0
        assert "motor off" in err and "summary:" in err
        assert "rejected duty command nan" in err
    finally:
        reap(proc)
        client.close()
        mcu.stop()


def test_bridge_bad_parameter_exits_2(tmp_path: Path) -> None:
    env = isolated_env(random_domain(101, 200))
    r = subprocess.run([*BRIDGE, "--ros-args", "-p", f"port:={tmp_path}/none",
                        "-p", "command_timeout:=-1.0"], env=env, capture_output=True, text=True, timeout=30)
    assert r.returncode == 2
    assert "command_timeout = -1.0" in r.stderr
