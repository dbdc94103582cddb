"""``bridge_check``: exercise a running bridge node and report every departure from the contract.

Usage::

    bridge_check --node /aeropend_bridge                 # the aeropend bridge (drives the motor!)
    bridge_check --node /my_lab/quanser_bridge --duty 0.2
    bridge_check --node /aeropend_sim                    # the simulated plant (mode:=realtime)

The checker finds the node in the ROS graph, reads its topics, types and QoS, subscribes to its
``aeropend/joint_states`` and ``aeropend/armature`` (in its namespace) and publishes
``aeropend/duty_cycle``: τ = ``--duty`` at 50 Hz for ``--drive`` s, then the same τ interleaved
with NaN and 1.5 (both must be ignored), then silence for ``--silence`` s (τ must fall to 0 within
``--silence-limit`` s). **It drives the motor**: clear the propeller. The clauses and their limits
are those of :mod:`aeropend_bridge.conformance` (docs/hardware.md, "Contract for bridge nodes").

Exit status: 0 when the node conforms, 1 on any departure (each one printed) or when the node is
not found, 2 on a usage error.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from aeropend_bridge.conformance import Observation, evaluate, report

DESCRIPTION = "Exercise a running bridge node and report every departure from the topic contract."


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``bridge_check``."""
    p = argparse.ArgumentParser(
        prog="bridge_check", description=DESCRIPTION + " It drives the motor with duty commands.",
        epilog="Exit status 0: conforms; 1: departures (printed) or node not found; 2: usage error. "
               "Contract: docs/hardware.md#contract-for-bridge-nodes")
    p.add_argument("--node", required=True, help="node name, e.g. /aeropend_bridge or /rig2/my_bridge")
    p.add_argument("--duty", type=float, default=0.3,
                   help="τ commanded while driving, in [0.2, 1] (default 0.3)")
    p.add_argument("--drive", type=float, default=2.0, help="seconds of valid commands (default 2)")
    p.add_argument("--silence", type=float, default=1.0,
                   help="seconds without commands at the end (default 1)")
    p.add_argument("--silence-limit", type=float, default=0.25,
                   help="τ must be 0 this long after the last command [s] (default 0.25, the contract's)")
    p.add_argument("--discover", type=float, default=10.0, help="seconds to wait for the node (default 10)")
    return p


def _split(name: str) -> tuple[str, str]:
    name = "/" + name.strip("/")
    ns, _, base = name.rpartition("/")
    return ns or "/", base


def _qos_names(profile: object) -> tuple[str, str]:
    rel = getattr(profile.reliability, "name", str(profile.reliability))  # type: ignore[attr-defined]
    dur = getattr(profile.durability, "name", str(profile.durability))  # type: ignore[attr-defined]
    return rel, dur


def _graph(node: object, obs: Observation, ns: str, base: str, wait_s: float) -> None:
    """Fill the node's topics and QoS (retried until the contract topics show up or ``wait_s``)."""
    from aeropend_sim.contract import REL_ARMATURE, REL_DUTY_CYCLE, REL_JOINT_STATES, namespaced

    wanted = {namespaced(REL_JOINT_STATES, ns), namespaced(REL_ARMATURE, ns)}
    end = time.monotonic() + wait_s
    while True:
        pubs = node.get_publisher_names_and_types_by_node(base, ns)  # type: ignore[attr-defined]
        subs = node.get_subscriber_names_and_types_by_node(base, ns)  # type: ignore[attr-defined]
        obs.publishers = {t: list(ty) for t, ty in pubs}
        obs.subscribers = {t: list(ty) for t, ty in subs}
        if wanted <= set(obs.publishers) and namespaced(REL_DUTY_CYCLE, ns) in obs.subscribers:
            break
        if time.monotonic() > end:
            break
        time.sleep(0.1)
    for kind, topics, info in (("pub", wanted, node.get_publishers_info_by_topic),  # type: ignore[attr-defined]
                               ("sub", {namespaced(REL_DUTY_CYCLE, ns)},
                                node.get_subscriptions_info_by_topic)):  # type: ignore[attr-defined]
        for topic in sorted(topics):
            for ep in info(topic):
                if ep.node_name == base and (ep.node_namespace or "/") == ns:
                    obs.qos[f"{kind} {topic}"] = _qos_names(ep.qos_profile)


def run_check(args: argparse.Namespace) -> tuple[Observation, int]:
    """Find the node, drive it, observe it; return the observation and 0 (or 1: node not found)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import BatteryState, JointState
    from std_msgs.msg import Float64

    from aeropend_sim.contract import REL_ARMATURE, REL_DUTY_CYCLE, REL_JOINT_STATES, namespaced
    from aeropend_sim.ros.ros_contract import COMMAND_QOS, SAMPLE_SUB_QOS

    ns, base = _split(args.node)
    obs = Observation(node=f"{ns.rstrip('/')}/{base}", duty=args.duty, silence_limit_s=args.silence_limit,
                      namespace=ns)
    node = rclpy.create_node(f"aeropend_bridge_check_{int(time.time() * 1e3) % 100000}")
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    end = time.monotonic() + args.discover
    while not any(n == base and (s or "/") == ns for n, s in node.get_node_names_and_namespaces()):
        if time.monotonic() > end:
            seen = sorted(f"{s.rstrip('/')}/{n}" for n, s in node.get_node_names_and_namespaces())
            print(f"bridge_check: no node {obs.node} in the ROS graph after {args.discover:g} s "
                  f"(nodes seen: {seen})", file=sys.stderr)
            return obs, 1
        ex.spin_once(timeout_sec=0.1)
    _graph(node, obs, ns, base, 3.0)
    mono = time.monotonic_ns
    obs.recv_to_ros_ns = time.time_ns() - mono()
    node.create_subscription(JointState, namespaced(REL_JOINT_STATES, ns), lambda m: obs.js.append(
        (mono(), m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, list(m.name), list(m.position),
         list(m.velocity), list(m.effort))), SAMPLE_SUB_QOS)
    node.create_subscription(BatteryState, namespaced(REL_ARMATURE, ns), lambda m: obs.arm.append(
        (mono(), m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, m.voltage, m.current)), SAMPLE_SUB_QOS)
    if node.get_publishers_info_by_topic("/clock"):
        node.create_subscription(Clock, "/clock", lambda m: obs.clock_ns.append(
            (mono(), m.clock.sec * 10**9 + m.clock.nanosec)), SAMPLE_SUB_QOS)
    pub = node.create_publisher(Float64, namespaced(REL_DUTY_CYCLE, ns), COMMAND_QOS)
    end = time.monotonic() + 3.0
    while pub.get_subscription_count() == 0 and time.monotonic() < end:
        ex.spin_once(timeout_sec=0.05)
    schedule = (("drive", args.drive, (args.duty,)), ("invalid", 0.6, (math.nan, args.duty, 1.5, args.duty)),
                ("silence", args.silence, ()))
    for phase, seconds, values in schedule:
        t0 = mono()
        k, nxt = 0, 0
        # a valid command every 20 ms in every phase: the invalid ones go between them, so a node's
        # watchdog sees the same valid rate while it rejects them (at one valid command per 40 ms a
        # 50 ms watchdog tripped on a loaded host, and the check blamed the rejection)
        valid = sum(1 for v in values if 0.0 <= v <= 1.0)
        period_ns = 20_000_000 * valid // len(values) if values else 0
        while mono() - t0 < seconds * 1e9:
            if values and mono() >= nxt:
                v = values[k % len(values)]
                pub.publish(Float64(data=v))
                obs.commands.append((mono(), v))
                k, nxt = k + 1, mono() + period_ns
            ex.spin_once(timeout_sec=0.002)
        obs.phases[phase] = (t0, mono())
    node.destroy_node()
    return obs, 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``bridge_check``; returns the exit status (0 conforms, 1 departures, 2 usage)."""
    args = build_parser().parse_args(argv)
    if not 0.2 <= args.duty <= 1.0 or min(args.drive, args.silence, args.silence_limit) <= 0:
        print("bridge_check: --duty must be in [0.2, 1] and the durations > 0", file=sys.stderr)
        return 2
    import rclpy
    from rclpy.executors import ExternalShutdownException

    rclpy.init()
    try:
        obs, status = run_check(args)
        if status:
            return status
        findings = evaluate(obs)
        print(report(obs, findings), flush=True)
        return 0 if all(f.ok for f in findings) else 1
    except (KeyboardInterrupt, ExternalShutdownException):
        return 1
    finally:
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
