"""``aeropend_recorder``: record the contract topics into a rosbag2 bag (thin rclpy shell).

Subscribes with *raw* (serialised) subscriptions and writes the CDR bytes straight into a
``rosbags`` writer (:class:`aeropend_ident.io.bag_writer.BagSink`): no deserialisation, so 490 Hz
samples cost one callback each. The bag timestamp of a message is its receive time on the node
clock (ROS time: simulated time when ``use_sim_time`` is true). Each topic is registered with
the QoS its publishers offer (read from the ROS graph when its first message arrives; the
contract QoS when no publisher is visible), so ``play`` and ``ros2 bag play`` replay with the same
QoS. Discovery does not tell a writer's history (rmw reports history ``unknown``, depth 0, which
rosbag2 stores as is); the recorder writes the history and depth the topic contract prescribes
instead (keep last 10 for other topics), so every profile in the bag is one rclpy accepts
(:func:`aeropend_ident.nodes.qos.qos_from_rclpy`).

Parameters
----------
output : str
    Bag directory to create (default ``aeropend_<YYYYmmdd_HHMMSS>``).
storage : str
    ``mcap`` (default) or ``sqlite3``.
topics : string array
    Topics to record; an empty string stands for the contract topics in the recorder's
    namespace (the default, ``[""]``: ``/aeropend/*``, or ``/rig2/aeropend/*`` with
    ``-r __ns:=/rig2``); add ``/clock`` to record simulated time.
    Types of other topics are discovered from the graph.
duration : float
    Stop after this many seconds of node-clock time; 0 = until SIGINT / SIGTERM.
max_samples : int
    Stop after this many ``joint_states`` messages; 0 = no limit.
queue_depth : int
    Subscription queue depth (default 1000). The subscriptions use the contract QoS policies
    (``SAMPLE_QOS`` best effort / ``COMMAND_QOS`` reliable, volatile) with this deeper keep-last
    queue: depth does not affect QoS matching, and at 490 Hz the contract's depth 5 would drop
    samples whenever the recorder stalls for 10 ms.
reliable : bool
    Subscribe to the sample topics and ``/clock`` with the lock-step QoS (reliable, keep all;
    default false: best effort). Use it for lock-step runs, whose plant publishes samples and
    ``/clock`` that way: the recorder then loses nothing, a lagging recorder slows the loop down
    instead; a reliable subscription does not match a best-effort (real-time) publisher, nor a
    best-effort ``/clock`` (a simulator's ``rclcpp::ClockQoS``).

On SIGINT / SIGTERM the recorder first writes what is still queued (it spins until no message
has arrived for ``DRAIN_IDLE_S``, at most ``DRAIN_MAX_S``), then closes the bag.

Run as ``record --ros-args -p output:=/tmp/run -p duration:=2.0`` or with the friendly flags
``record -o /tmp/run --duration 2``. The bag is closed cleanly (valid ``metadata.yaml``) on
SIGINT, SIGTERM, duration or sample limit.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args
from rosbags.interfaces import Qos

from aeropend_ident.errors import BagError
from aeropend_ident.io.bag_writer import BagSink
from aeropend_ident.io.bags import qos_for_topic
from aeropend_ident.nodes.qos import contract_qos, message_class, qos_from_rclpy
from aeropend_sim.contract import (
    CONTRACT_TOPICS,
    TOPIC_CLOCK,
    TOPIC_DUTY_CYCLE,
    TOPIC_JOINT_STATES,
    TYPE_CLOCK,
    namespaced,
)
from aeropend_sim.ros import ros_contract
from aeropend_sim.ros.node_shell import run_node

NODE_NAME = "aeropend_recorder"
#: On stop: keep writing until no message arrived for this long [s] ...
DRAIN_IDLE_S = 0.3
#: ... but at most this long [s].
DRAIN_MAX_S = 10.0


def _known_type(topic: str) -> str | None:
    """Type of a contract topic in any namespace (``/rig2/aeropend/joint_states``) or of /clock."""
    if topic == TOPIC_CLOCK:
        return TYPE_CLOCK
    return next((t for name, t in CONTRACT_TOPICS.items() if topic.endswith(name)), None)


class RecorderNode(Node):
    """Records raw contract messages into a :class:`BagSink` (see module doc for parameters)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.declare_parameter("output", "")
        self.declare_parameter("storage", "mcap")
        self.declare_parameter("topics", [""])  # [""]: the contract topics in this node's namespace
        self.declare_parameter("duration", 0.0)
        self.declare_parameter("max_samples", 0)
        self.declare_parameter("queue_depth", 1000)
        self.declare_parameter("reliable", False)
        output = self.get_parameter("output").value or time.strftime("aeropend_%Y%m%d_%H%M%S")
        self.storage = str(self.get_parameter("storage").value)
        raw = [str(t) for t in self.get_parameter("topics").value] or [""]
        here = [namespaced(t, self.get_namespace()) for t in CONTRACT_TOPICS]  # what "" stands for
        self.topics = list(dict.fromkeys(x for t in raw for x in (here if t == "" else [t])))
        self.duration = float(self.get_parameter("duration").value)
        self.max_samples = int(self.get_parameter("max_samples").value)
        self.queue_depth = int(self.get_parameter("queue_depth").value)
        self.reliable = bool(self.get_parameter("reliable").value)
        if self.duration < 0 or self.max_samples < 0:
            raise ValueError(f"duration {self.duration} s and max_samples {self.max_samples} must be >= 0")
        self.sink = BagSink(output, storage=self.storage,  # type: ignore[arg-type]
                            custom_data={"aeropend.recorder": NODE_NAME})
        self.done = False
        self.stop_reason = ""
        self.samples = 0
        self.last_message_ns = time.monotonic_ns()
        self._types: dict[str, str] = {}
        self._subs: dict[str, Any] = {}
        self._subscribe_known()
        self._discovery = None
        if len(self._subs) < len(self.topics):
            self._discovery = self.create_timer(0.5, self._discover)
        self._started_ns = self.get_clock().now().nanoseconds
        if self.duration > 0:
            self.create_timer(0.05, self._check_duration)
        self.get_logger().info(f"recording {self.topics} to {self.sink.path} ({self.storage})"
                               + (f" for {self.duration:g} s" if self.duration else "")
                               + (f", stop after {self.max_samples} samples" if self.max_samples else ""))

    # -- subscriptions --------------------------------------------------------------------

    def _subscribe(self, topic: str, msgtype: str) -> None:
        base = ros_contract.COMMAND_QOS if topic.endswith(TOPIC_DUTY_CYCLE) else ros_contract.SAMPLE_SUB_QOS
        if topic == TOPIC_CLOCK:
            base = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
        if self.reliable:
            # lock-step samples, commands and /clock: reliable keep-all like their writers, so nothing
            # the recorder has not written yet is ever evicted (a lagging recorder slows the loop instead)
            qos = (ros_contract.CLOCK_QOS_LOCKSTEP if topic == TOPIC_CLOCK
                   else ros_contract.COMMAND_QOS_LOCKSTEP if topic.endswith(TOPIC_DUTY_CYCLE)
                   else ros_contract.SAMPLE_QOS_LOCKSTEP)
        else:
            # same policies as the contract (so matching is unchanged), deeper queue: the depth is
            # local to the subscriber and lets the recorder ride out a stall (GC, disk)
            qos = QoSProfile(history=base.history, depth=max(base.depth, self.queue_depth),
                             reliability=base.reliability, durability=base.durability)
        self._types[topic] = msgtype
        self._subs[topic] = self.create_subscription(
            message_class(msgtype), topic, lambda data, t=topic: self._on_message(t, data), qos, raw=True)

    def _subscribe_known(self) -> None:
        for topic in self.topics:
            known = _known_type(topic)
            if known is not None:
                self._subscribe(topic, known)

    def _discover(self) -> None:
        graph = dict(self.get_topic_names_and_types())
        for topic in self.topics:
            if topic not in self._subs and graph.get(topic):
                self._subscribe(topic, graph[topic][0])
                self.get_logger().info(f"discovered {topic} ({graph[topic][0]})")
        if len(self._subs) == len(self.topics) and self._discovery is not None:
            self._discovery.cancel()

    # -- recording ------------------------------------------------------------------------

    def _offered_qos(self, topic: str) -> list[Qos]:
        """The distinct QoS profiles the topic's publishers offer, each with a concrete history.

        Discovery does not carry a writer's history (rmw reports ``UNKNOWN``, depth 0): a contract
        topic gets the history and depth the contract prescribes for the reliability its
        publisher offers (a reliable sample writer is the lock-step keep-all one), any other topic
        keep-last :data:`~aeropend_ident.nodes.qos.DEFAULT_DEPTH` (:func:`qos_from_rclpy`).
        """
        found: list[Qos] = []
        for info in self.get_publishers_info_by_topic(topic):
            reliable = info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
            q = qos_from_rclpy(info.qos_profile, contract_qos(topic, reliable))
            if q not in found:
                found.append(q)
        return found or [qos_for_topic(topic)]

    def _on_message(self, topic: str, data: bytes) -> None:
        self.last_message_ns = time.monotonic_ns()
        if self.done:
            return
        stamp = self.get_clock().now().nanoseconds
        if not self.sink.has_topic(topic):
            self.sink.add_topic(topic, self._types[topic], self._offered_qos(topic))
        self.sink.write(topic, stamp, data)
        if topic.endswith(TOPIC_JOINT_STATES):
            self.samples += 1
            if self.max_samples and self.samples >= self.max_samples:
                self._stop(f"{self.samples} samples recorded")

    def _check_duration(self) -> None:
        if self.get_clock().now().nanoseconds - self._started_ns >= self.duration * 1e9:
            self._stop(f"duration {self.duration:g} s reached")

    def _stop(self, reason: str) -> None:
        if not self.done:
            self.done = True
            self.stop_reason = reason

    def close(self) -> dict[str, int]:
        """Register subscribed topics that got no message (so the bag lists them), close the bag."""
        if not self.sink.closed:
            for topic, msgtype in self._types.items():
                if not self.sink.has_topic(topic):
                    self.sink.add_topic(topic, msgtype, [qos_for_topic(topic)])
            self.sink.close()
        return dict(self.sink.counts)


def build_parser() -> argparse.ArgumentParser:
    """Friendly command-line flags (mapped onto the node parameters)."""
    p = argparse.ArgumentParser(prog="record", description="Record the aeropend contract topics into a bag. "
                                "ROS-style '--ros-args -p name:=value' parameters work too.")
    p.add_argument("-o", "--output", help="bag directory to create")
    p.add_argument("-s", "--storage", choices=["mcap", "sqlite3"])
    p.add_argument("--topics", nargs="+", help="topics to record (default: the contract topics)")
    p.add_argument("--clock", action="store_true", help="also record /clock")
    p.add_argument("--duration", type=float, help="seconds to record (0 = until Ctrl-C)")
    p.add_argument("--max-samples", type=int, help="stop after N joint_states messages")
    p.add_argument("--use-sim-time", action="store_true", help="use /clock time for stamps and duration")
    p.add_argument("--reliable", action="store_true",
                   help="reliable sample and /clock subscriptions (lock-step runs: nothing lost)")
    return p


def _overrides(args: argparse.Namespace) -> list[Parameter]:
    out = []
    if args.output:
        out.append(Parameter("output", value=args.output))
    if args.storage:
        out.append(Parameter("storage", value=args.storage))
    topics = list(args.topics) if args.topics else None
    if args.clock:
        topics = (topics or [""]) + [TOPIC_CLOCK]  # "": the contract topics in the node's namespace
    if topics:
        out.append(Parameter("topics", value=topics))
    if args.duration is not None:
        out.append(Parameter("duration", value=float(args.duration)))
    if args.max_samples is not None:
        out.append(Parameter("max_samples", value=int(args.max_samples)))
    if args.use_sim_time:
        out.append(Parameter("use_sim_time", value=True))
    if args.reliable:
        out.append(Parameter("reliable", value=True))
    return out


def drain(executor: SingleThreadedExecutor, node: RecorderNode) -> None:
    """Write what is still queued: spin until no message for ``DRAIN_IDLE_S`` (at most ``DRAIN_MAX_S``)."""
    end = time.monotonic() + DRAIN_MAX_S
    while rclpy.ok() and time.monotonic() < end and not node.done:
        if time.monotonic_ns() - node.last_message_ns > DRAIN_IDLE_S * 1e9:
            break
        executor.spin_once(timeout_sec=0.05)


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``record``."""
    argv = list(sys.argv if argv is None else argv)
    args = build_parser().parse_args(remove_ros_args(argv)[1:])

    def run(node: RecorderNode, executor: Any, stop: threading.Event) -> int:
        while rclpy.ok() and not node.done and not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
        drain(executor, node)
        return 0

    def close(node: RecorderNode) -> None:
        counts = node.close()
        reason = node.stop_reason or "interrupted"
        print(f"record: {reason}; wrote {node.sink.path} ({node.storage}): "
              + ", ".join(f"{t} {n}" for t, n in counts.items()), flush=True)

    return run_node(NODE_NAME, argv, lambda: RecorderNode(parameter_overrides=_overrides(args)),
                    cleanup=close, body=run, fail_errors=(BagError, ValueError),
                    report_error=lambda exc: print(f"record: error: {exc}", file=sys.stderr))


if __name__ == "__main__":
    sys.exit(main())
