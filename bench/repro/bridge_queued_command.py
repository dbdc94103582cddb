"""Reproducer (CI flake, 2026-11-30): the fresh-clone CI of the commit that ordered the suite's slow
modules first failed ``test_bridge_lifecycle_transitions``: after deactivate → activate, a non-zero
Duty frame reached the firmware although the only non-zero commands had been published while the
bridge was inactive ("the command held before deactivation is not applied again").

The mechanism: rclpy's executor takes **one** message per subscription per wait, and a ready
subscription before a ready service. When the bridge's executor is behind (a loaded machine), the
duty commands published while it was inactive wait in the subscription's queue (depth 10) beside
the activate request: the first is taken and ignored (inactive), then the activate request is
served, then the rest are taken **after** the activation and forwarded as fresh commands.

This script makes the executor late on purpose: it configures and activates the ``bridge`` against
the pty fake firmware, deactivates it, stops the bridge process (SIGSTOP), publishes duty 0.5 ten
times and sends the activate request, continues the bridge (SIGCONT) and lists the Duty frames the
firmware reads after the activation. Before the fix (bridge_node ``_on_command``): 9-10 non-zero
frames in each run; with it: duty 0 only. A first fix that judged by the DDS reception time alone
(on the bridge's own clock) held on the idle machine and beside busy loops, and failed once in 8
runs beside the parallel bridge tests (4 commands, received after the activation although sent
before it); the fix also drops a command whose source time, from a clock that agrees with the
bridge's within 5 s, is before the activation (``bridge_core.sent_before``): 0 failures in 6 such
runs.

Usage: ``python -m bench.repro.bridge_queued_command``
"""

from __future__ import annotations

import os
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from std_msgs.msg import Float64

from aeropend_bridge.fake_mcu import FakeMcu
from aeropend_bridge.protocol import Duty
from aeropend_sim.contract import TOPIC_DUTY_CYCLE
from aeropend_sim.ros.harness import (
    isolated_env,
    node_command,
    private_node,
    random_domain,
    reap,
    stop,
    wait_for_server,
)
from aeropend_sim.ros.ros_contract import COMMAND_QOS

NODE = "/aeropend_bridge"


def _spin(executor, seconds: float, until=None) -> bool:
    """Spin ``executor`` for up to ``seconds``, or until ``until()`` holds; return ``until()`` (True
    without one)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end and not (until is not None and until()):
        executor.spin_once(timeout_sec=0.01)
    return until() if until is not None else True


def _request(client, transition: int):
    return client.call_async(ChangeState.Request(transition=Transition(id=transition)))


def _done(executor, future, timeout: float = 15.0) -> bool:
    """Whether the lifecycle transition ``future`` succeeded within ``timeout`` [s]."""
    return _spin(executor, timeout, future.done) and bool(future.result().success)


def queued_commands_applied() -> tuple[int, list[int]]:
    """Run the sequence of the module doc; return the number of Duty frames the firmware read in the
    second after the activation and the non-zero ones among them (``Duty.value``, 65535 = 1)."""
    with tempfile.TemporaryDirectory() as tmp:
        return _run(Path(tmp) / "ttyACM_fake")


def _run(link: Path) -> tuple[int, list[int]]:
    mcu = FakeMcu(link).start()
    domain = random_domain(101, 200)
    proc = subprocess.Popen([*node_command("bridge", "aeropend_bridge.bridge_node"), "--ros-args", "-p",
                             "autostart:=false", "-p", f"port:={link}"], env=isolated_env(domain),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        with private_node("repro_manager", domain) as (node, executor):
            pub = node.create_publisher(Float64, TOPIC_DUTY_CYCLE, COMMAND_QOS)
            change = node.create_client(ChangeState, f"{NODE}/change_state")
            wait_for_server(node.create_client(GetState, f"{NODE}/get_state"), executor, GetState.Request(),
                            30.0)
            assert change.wait_for_service(timeout_sec=30.0)
            for name in ("CONFIGURE", "ACTIVATE", "DEACTIVATE"):
                assert _done(executor, _request(change, getattr(Transition, f"TRANSITION_{name}"))), name
            _spin(executor, 0.5)  # the publisher matched by the bridge's subscription
            os.kill(proc.pid, signal.SIGSTOP)  # the bridge's executor falls behind
            for _ in range(10):
                pub.publish(Float64(data=0.5))
                time.sleep(0.01)
            n_cmd = len(mcu.commands)
            future = _request(change, Transition.TRANSITION_ACTIVATE)
            time.sleep(0.2)
            os.kill(proc.pid, signal.SIGCONT)
            assert _done(executor, future), "activate failed"
            _spin(executor, 1.0)
            duties = [f.value for _, f in mcu.commands[n_cmd:] if isinstance(f, Duty)]
            return len(duties), [d for d in duties if d != 0]
    finally:
        stop(proc)
        reap(proc)
        mcu.stop()


def main() -> None:
    n, nonzero = queued_commands_applied()
    print(f"Duty frames after the activation: {n}, non-zero: {len(nonzero)} {sorted(set(nonzero))[:4]}")
    print("queued commands from before the activation were applied" if nonzero else
          "no command from before the activation was applied")


if __name__ == "__main__":
    main()
