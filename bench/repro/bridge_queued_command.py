"""Reproducer (CI flake, 2026-11-30 and 2026-12-01): duty commands published while the bridge was
inactive reached the firmware after its activation.

The mechanisms: rclpy's executor takes **one** message per subscription per wait, and a ready
subscription before a ready service. When the bridge's executor is behind (a loaded machine), the
duty commands published while it was inactive wait in the subscription's queue (depth 10) beside
the activate request: the first is taken and ignored (inactive), then the activate request is
served, then the rest are taken **after** the activation. And a reliable sample or request lost
while the receiving process could not run comes again only at the writer's next heartbeat, about
3 s later: in 3 of 25 runs of this script beside the ROS tests, the activation itself took 2.6 s
longer than in the others.

Two fixes that filtered an always-on subscription in its callback held on an idle machine and
failed under load: one judging by the DDS reception time (1 failure in 8 runs beside the bridge
tests), one also judging by the publisher's source time, trusted when the transit was under 5 s
(one failure in a fresh-clone CI: one duty-0.5 command applied, seen as three frames with the
keep-alive repeats). The bridge now subscribes to duty commands only while it is active
(``BridgeNode.on_activate``): a new volatile reader receives nothing published before it matched.

This script makes the executor late on purpose: it configures and activates the ``bridge`` against
the pty fake firmware, deactivates it, stops the bridge process (SIGSTOP), publishes duty 0.5 ten
times and sends the activate request, continues the bridge (SIGCONT) and lists the Duty frames the
firmware reads after the activation. Then, as a control, it waits until the bridge's new
subscription has matched and publishes duty 0.25, which must reach the firmware. Before the first
fix: 9-10 non-zero frames of duty 0.5 in each run; now none.

Usage: ``python -m bench.repro.bridge_queued_command``
"""

from __future__ import annotations

import os
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass
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


#: The duty published while the bridge is inactive, and the one published after its activation.
QUEUED, FRESH = 0.5, 0.25


@dataclass(frozen=True)
class Outcome:
    """What the firmware read after the activation, and what the bridge logged while inactive."""

    frames: int  #: Duty frames in the second after the activation
    queued_applied: int  #: of them, frames of the duty published while inactive
    fresh_applied: bool  #: the duty published after the activation reached the firmware
    warned: bool  #: the bridge warned, while inactive, that something publishes duty commands


def queued_commands_applied() -> Outcome:
    """Run the sequence of the module doc and say what reached the firmware."""
    with tempfile.TemporaryDirectory() as tmp:
        return _run(Path(tmp) / "ttyACM_fake", Path(tmp) / "bridge.log")


def _run(link: Path, log: Path) -> Outcome:
    mcu = FakeMcu(link).start()
    domain = random_domain(101, 200)
    with open(log, "wb") as err:
        proc = subprocess.Popen([*node_command("bridge", "aeropend_bridge.bridge_node"), "--ros-args", "-p",
                                 "autostart:=false", "-p", f"port:={link}"], env=isolated_env(domain),
                                stdout=subprocess.DEVNULL, stderr=err)
    try:
        with private_node("repro_manager", domain) as (node, executor):
            pub = node.create_publisher(Float64, TOPIC_DUTY_CYCLE, COMMAND_QOS)
            change = node.create_client(ChangeState, f"{NODE}/change_state")
            wait_for_server(node.create_client(GetState, f"{NODE}/get_state"), executor, GetState.Request(),
                            30.0)
            assert change.wait_for_service(timeout_sec=30.0)
            for name in ("CONFIGURE", "ACTIVATE", "DEACTIVATE"):
                assert _done(executor, _request(change, getattr(Transition, f"TRANSITION_{name}"))), name
            _spin(executor, 0.5)  # a keep-alive of the inactive bridge sees the publisher
            os.kill(proc.pid, signal.SIGSTOP)  # the bridge's executor falls behind
            for _ in range(10):
                pub.publish(Float64(data=QUEUED))
                time.sleep(0.01)
            n_cmd = len(mcu.commands)
            future = _request(change, Transition.TRANSITION_ACTIVATE)
            time.sleep(0.2)
            os.kill(proc.pid, signal.SIGCONT)
            assert _done(executor, future), "activate failed"
            _spin(executor, 1.0)
            duties = [f.value for _, f in mcu.commands[n_cmd:] if isinstance(f, Duty)]
            matched = _spin(executor, 15.0, lambda: pub.get_subscription_count() > 0)
            n_fresh = len(mcu.commands)
            if matched:
                pub.publish(Float64(data=FRESH))
                _spin(executor, 1.0, lambda: Duty.from_fraction(FRESH) in
                      [f for _, f in mcu.commands[n_fresh:]])
            fresh = Duty.from_fraction(FRESH) in [f for _, f in mcu.commands[n_fresh:]]
    finally:
        stop(proc)
        reap(proc)
        mcu.stop()
    queued = Duty.from_fraction(QUEUED).value
    return Outcome(frames=len(duties), queued_applied=sum(d == queued for d in duties), fresh_applied=fresh,
                   warned="their duty commands are not applied while the bridge is inactive" in
                   log.read_text(errors="replace"))


def main() -> None:
    out = queued_commands_applied()
    print(f"Duty frames after the activation: {out.frames}, of the duty {QUEUED} published while inactive: "
          f"{out.queued_applied}; duty {FRESH} published after it applied: {out.fresh_applied}; "
          f"inactive bridge warned of the publisher: {out.warned}")


if __name__ == "__main__":
    main()
