"""Reproducer: a lock-step repeat answered twice makes the plant advance twice on one command.

Issue 19 stop 31: a fresh-clone CI run failed ``test_two_rigs_in_namespaces_each_with_its_controller``.
The /rig2 trace lagged the batch loop by one sample from sample 2 on: its θ at sample 3 was the batch
θ at sample 2. Cause: the lock-step plant (``sim_node``) re-publishes its last sample after
0.5 s without a command (``LOCKSTEP_REPUBLISH_S``) and advances once per command it receives;
commands carry no stamp. The controller answered a repeated stamp again. When its first answer
took longer than 0.5 s (start-up under load), the repeat crossed that answer, both answers arrived,
and the plant applied the first duty for two periods.

This script runs a real ``sim_node`` in lock-step and a commander that answers sample 0 only after
``--delay`` s (0.7 s: past the re-publish) and every later sample at once. With ``--policy old``
it also answers repeats (the controller before the fix). With ``--policy new`` it answers a repeat
only if a duty reader matched since its first answer (the fix in ``controller_node._control``). It
prints the commands sent, the sim's samples and the stamps seen::

    .venv/bin/python -m bench.repro.lockstep_double_answer --policy old   # sim_steps = commands, 1 ahead
    .venv/bin/python -m bench.repro.lockstep_double_answer --policy new   # sim_steps = commands

With the old policy the sim steps once more than the new samples answered
(``sim_steps_minus_answered`` 1), so the trajectory lags one sample. With the new policy the two
counts are equal (0). Measured 2026-11-25: old 1, new 0.

``--commander excitation`` answers with the excitation node's own
:class:`~aeropend_sim.ros.excitation_node.LockstepFeeder` instead (the same race: it answered every
repeat with the previous command; ``--policy old`` calls it without the matched-reader count, as
the node did, ``--policy new`` with it, as the node does now). Measured 2026-11-25: old 1, new 0.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

from aeropend_sim.ros.harness import isolated_env, node_command, random_domain, reap


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--policy", choices=("old", "new"), default="old")
    ap.add_argument("--delay", type=float, default=0.7, help="delay of the first answer [s]")
    ap.add_argument("--answers", type=int, default=20, help="new samples to answer")
    ap.add_argument("--commander", choices=("controller", "excitation"), default="controller",
                    help="repeat rule: the controller node's, or the excitation node's LockstepFeeder")
    a = ap.parse_args(argv)

    import os

    import numpy as np
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from aeropend_sim.contract import REL_DUTY_CYCLE, REL_JOINT_STATES
    from aeropend_sim.ros.excitation_node import LockstepFeeder
    from aeropend_sim.ros.ros_contract import COMMAND_QOS_LOCKSTEP, SAMPLE_QOS_LOCKSTEP

    domain = random_domain()
    env = isolated_env(domain)
    os.environ.update(env)
    sim = subprocess.Popen([*node_command("sim_node"), "--ros-args", "-p", "mode:=lockstep",
                            "-p", "rig:=thesis_rig", "-p", "publish_clock:=false"],
                           env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rclpy.init(domain_id=domain)
    node = rclpy.create_node("repro_commander")
    pub = node.create_publisher(Float64, REL_DUTY_CYCLE, COMMAND_QOS_LOCKSTEP)
    state = {"last": None, "matched": 0, "commands": 0, "repeats": 0, "answered": 0, "stamps": []}
    feeder = LockstepFeeder(np.full(a.answers, 0.3))

    def answer(duty: float) -> None:
        state["matched"] = pub.get_subscription_count()
        pub.publish(Float64(data=duty))
        state["commands"] += 1

    def on_sample(msg: JointState) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        state["stamps"].append(stamp)
        if pub.get_subscription_count() == 0 or state["answered"] >= a.answers:
            return
        if a.commander == "excitation":
            new = stamp != feeder.last_stamp
            if new and feeder.sent == 0:
                time.sleep(a.delay)
            matched = pub.get_subscription_count()
            duty = feeder.on_sample(stamp, matched if a.policy == "new" else None)
            state["repeats"] += int(not new)
            state["answered"] = feeder.sent
            if duty is not None:
                feeder.mark_published(matched)
                answer(duty)
            return
        if stamp == state["last"]:
            state["repeats"] += 1
            if a.policy == "old" or pub.get_subscription_count() > state["matched"]:
                answer(0.3)
            return
        state["last"] = stamp
        if state["answered"] == 0:
            time.sleep(a.delay)  # a slow first answer: the plant re-publishes sample 0 meanwhile
        state["answered"] += 1
        answer(0.3)

    node.create_subscription(JointState, REL_JOINT_STATES, on_sample, SAMPLE_QOS_LOCKSTEP)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    end = time.monotonic() + 30.0
    try:
        while state["answered"] < a.answers and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        t = time.monotonic() + 1.0
        while time.monotonic() < t:
            ex.spin_once(timeout_sec=0.05)
    finally:
        node.destroy_node()
        rclpy.shutdown()
        reap(sim)
    stamps = sorted(set(state["stamps"]))
    period = 2_048_000
    out = {"policy": a.policy, "delay_s": a.delay, "commands": state["commands"],
           "new_samples_answered": state["answered"], "repeats_seen": state["repeats"],
           "sim_steps": round((stamps[-1] - stamps[0]) / period) if stamps else 0}
    out["sim_steps_minus_answered"] = out["sim_steps"] - out["new_samples_answered"]
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
