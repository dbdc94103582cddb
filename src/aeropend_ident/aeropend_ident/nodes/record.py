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

Parameters: :data:`PARAMETERS` (also printed by ``record --help``). An existing bag folder is
never replaced without ``--overwrite`` (``-p overwrite:=true``), and then only if it holds a bag
(:func:`aeropend_ident.io.bag_writer.claim_bag_folder`).

Crash safety: what was received is on disk at least every ``flush_interval`` seconds (the MCAP
chunk closed, the SQLite3 transaction committed, the file ``fsync``-ed; :class:`BagSink`), so a
recorder killed with SIGKILL, or a power cut, loses at most that much; ``reindex`` rebuilds the
``metadata.yaml`` it could not write. Loss: every message is counted by
:class:`aeropend_ident.io.integrity.loss.LossCounter` (publisher sequence numbers from the message
info, header stamps against the sample period); the per-topic loss is printed on exit and stored in
the bag's ``custom_data`` (``aeropend.loss``), where every reader finds it.

On SIGINT / SIGTERM the recorder first writes what is still queued (it spins until no message
has arrived for ``DRAIN_IDLE_S``, at most ``DRAIN_MAX_S``), then closes the bag.

Run as ``record --ros-args -p output:=/tmp/run -p duration:=2.0`` or with the friendly flags
``record -o /tmp/run --duration 2``. The bag is closed cleanly (valid ``metadata.yaml``) on
SIGINT, SIGTERM, duration or sample limit.
"""

from __future__ import annotations

import argparse
import json
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
from aeropend_ident.io.bag_writer import BagSink, claim_bag_folder
from aeropend_ident.io.bags import qos_for_topic
from aeropend_ident.io.integrity.loss import LOSS_KEY, RECORDER_KEY, LossCounter, loss_text
from aeropend_ident.nodes.qos import contract_qos, message_class, qos_from_rclpy
from aeropend_sim.contract import (
    CONTRACT_TOPICS,
    REL_ARMATURE,
    REL_DUTY_CYCLE,
    REL_JOINT_STATES,
    TOPIC_CLOCK,
    TOPIC_DUTY_CYCLE,
    TOPIC_JOINT_STATES,
    TYPE_ARMATURE,
    TYPE_CLOCK,
    TYPE_JOINT_STATES,
    namespaced,
)
from aeropend_sim.ros import ros_contract
from aeropend_sim.ros.node_shell import declare_parameter_table, run_node
from aeropend_sim.ros.node_usage import NodeParameter, NodeUsage, contract_topic

NODE_NAME = "aeropend_recorder"
#: The recorder's parameters (declared from this table, printed by ``--help``; the friendly flags
#: of :func:`build_parser` set them). All read-only: they fix the bag at start-up.
PARAMETERS: tuple[NodeParameter, ...] = (
    NodeParameter("output", "str", "", "",
                  "bag folder to create (empty: aeropend_<YYYYmmdd_HHMMSS> in the working folder)"),
    NodeParameter("overwrite", "bool", False, "",
                  "replace an existing bag folder (one that holds metadata.yaml, .mcap or .db3; never "
                  "another folder)"),
    NodeParameter("storage", "str", "mcap", "", "mcap | sqlite3"),
    NodeParameter("topics", "str[]", [""], "",
                  "topics to record; an empty string stands for the contract topics in the recorder's "
                  "namespace (the default: /aeropend/*, or /rig2/aeropend/* with -r __ns:=/rig2); add "
                  "/clock to record simulated time; types of other topics are discovered from the graph"),
    NodeParameter("duration", "float", 0.0, "s",
                  "stop after this much node-clock time; 0 = until SIGINT / SIGTERM"),
    NodeParameter("max_samples", "int", 0, "", "stop after this many joint_states messages; 0 = no limit"),
    NodeParameter("queue_depth", "int", 1000, "",
                  "subscription queue depth: the contract QoS policies with this deeper keep-last queue "
                  "(depth does not affect matching; at 490 Hz the contract's 5 would drop samples whenever "
                  "the recorder stalls for 10 ms)"),
    NodeParameter("flush_interval", "float", 0.5, "s",
                  "longest time a received message stays only in memory: the chunk is then closed and the "
                  "file fsync-ed, so a recorder killed (or a power cut) loses at most this much; > 0"),
    NodeParameter("reliable", "bool", False, "",
                  "subscribe to the sample topics with the lock-step QoS (reliable, keep all) instead of "
                  "best effort: for lock-step runs, whose plant publishes that way (nothing lost, a lagging "
                  "recorder slows the loop); does not match a best-effort (real-time) publisher"),
)

#: ``record --help`` (the flags are added by :func:`build_parser`).
USAGE = NodeUsage(
    command="record",
    node_name=NODE_NAME,
    summary="Record the aeropend contract topics (or any topics) into a rosbag2 bag, each with the QoS its "
            "publishers offer, so ros2 bag play and play replay it. Friendly flags or ROS parameters "
            "(--ros-args -p name:=value); the bag is closed cleanly (valid metadata.yaml) on SIGINT, "
            "SIGTERM, duration or sample limit.",
    topics=(*(contract_topic("subscribes", t) for t in (REL_JOINT_STATES, REL_ARMATURE, REL_DUTY_CYCLE)),
            contract_topic("subscribes", TOPIC_CLOCK, "with --clock (or topics)")),
    parameters=PARAMETERS,
    examples=("record -o /tmp/run --duration 2",
              "record --ros-args -p output:=/tmp/run -p duration:=2.0",
              "record -o rig2_run --ros-args -r __ns:=/rig2          # records /rig2/aeropend/*"),
    notes="An existing non-empty output folder is refused unless --overwrite is given. Exit status: 0 "
          "when the bag is closed, 1 when it cannot be written.",
)
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
        p = declare_parameter_table(self, PARAMETERS)
        output = p["output"] or time.strftime("aeropend_%Y%m%d_%H%M%S")
        self.storage = str(p["storage"])
        raw = [str(t) for t in p["topics"]] or [""]  # [""]: the contract topics in this node's namespace
        here = [namespaced(t, self.get_namespace()) for t in CONTRACT_TOPICS]  # what "" stands for
        self.topics = list(dict.fromkeys(x for t in raw for x in (here if t == "" else [t])))
        self.duration = float(p["duration"])
        self.max_samples = int(p["max_samples"])
        self.queue_depth = int(p["queue_depth"])
        self.reliable = bool(p["reliable"])
        self.flush_interval = float(p["flush_interval"])
        if self.duration < 0 or self.max_samples < 0:
            raise ValueError(f"duration {self.duration} s and max_samples {self.max_samples} must be >= 0")
        if not self.flush_interval > 0:
            raise ValueError(f"flush_interval {self.flush_interval} s must be > 0")
        claim_bag_folder(output, bool(p["overwrite"]), option="-o", flag="--overwrite").prepare(create=False)
        self.sink = BagSink(output, storage=self.storage,  # type: ignore[arg-type]
                            custom_data={RECORDER_KEY: NODE_NAME},
                            flush_interval_s=self.flush_interval)
        # messages may stop arriving: the timer flushes what the last ones left in memory
        self.create_timer(min(0.1, self.flush_interval / 4), self.sink.flush_if_due)
        self.done = False
        self.stop_reason = ""
        self.samples = 0
        self.last_message_ns = time.monotonic_ns()
        self._types: dict[str, str] = {}
        self._subs: dict[str, Any] = {}
        # what each topic should have carried: publisher sequence numbers, header stamps
        self.loss = LossCounter(stamped=lambda t: self._types.get(t) in (TYPE_JOINT_STATES, TYPE_ARMATURE))
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
            message_class(msgtype), topic, lambda data, info, t=topic: self._on_message(t, data, info), qos,
            raw=True)

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

    def _on_message(self, topic: str, data: bytes, info: Any = None) -> None:
        self.last_message_ns = time.monotonic_ns()
        if self.done:
            return
        stamp = self.get_clock().now().nanoseconds
        if not self.sink.has_topic(topic):
            self.sink.add_topic(topic, self._types[topic], self._offered_qos(topic))
        self.sink.write(topic, stamp, data)
        info = info or {}
        gid = info.get("publisher_gid")
        gid = bytes(gid.get("data", b"")) if isinstance(gid, dict) else bytes(gid or b"")
        self.loss.add(topic, stamp, data, info.get("publication_sequence_number"), gid)
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
            self.sink.set_custom_data(LOSS_KEY, json.dumps(self.loss.report()))
            self.sink.close()
        return dict(self.sink.counts)


def build_parser() -> argparse.ArgumentParser:
    """Friendly command-line flags (mapped onto the node parameters, :data:`PARAMETERS`)."""
    p = USAGE.parser()
    p.add_argument("-o", "--output", help="bag directory to create")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing bag folder at --output (only a folder that holds a bag)")
    p.add_argument("-s", "--storage", choices=["mcap", "sqlite3"])
    p.add_argument("--topics", nargs="+", help="topics to record (default: the contract topics)")
    p.add_argument("--clock", action="store_true", help="also record /clock")
    p.add_argument("--duration", type=float, help="seconds to record (0 = until Ctrl-C)")
    p.add_argument("--max-samples", type=int, help="stop after N joint_states messages")
    p.add_argument("--use-sim-time", action="store_true", help="use /clock time for stamps and duration")
    p.add_argument("--flush-interval", type=float, metavar="S",
                   help="put what was received on disk at least every S seconds (default 0.5): a killed "
                        "recorder loses at most that much")
    p.add_argument("--reliable", action="store_true",
                   help="reliable sample and /clock subscriptions (lock-step runs: nothing lost)")
    return p


def _overrides(args: argparse.Namespace) -> list[Parameter]:
    out = []
    if args.output:
        out.append(Parameter("output", value=args.output))
    if args.overwrite:
        out.append(Parameter("overwrite", value=True))
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
    if args.flush_interval is not None:
        out.append(Parameter("flush_interval", value=float(args.flush_interval)))
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
        report = node.loss.report()
        if report:
            print(f"record: loss: {loss_text(report)}", flush=True)

    return run_node(NODE_NAME, argv, lambda: RecorderNode(parameter_overrides=_overrides(args)),
                    cleanup=close, body=run, fail_errors=(BagError, ValueError),
                    report_error=lambda exc: print(f"record: error: {exc}", file=sys.stderr))


if __name__ == "__main__":
    sys.exit(main())
