"""``aeropend_player``: replay a bag's raw messages with their original timing (thin rclpy shell).

``play BAG [--rate 1.0] [--loop] [--topics T ...]`` reads the bag with ``rosbags``
(:class:`aeropend_ident.io.bag_reader.RawBagReader`) and publishes each message's serialised bytes
unchanged (header stamps included) on its topic, with a publisher per topic offering the QoS the
bag recorded for it, adapted as rosbag2's player adapts it
(:func:`aeropend_ident.nodes.qos.playback_qos`: any tool's profile, ``history: unknown``
included, becomes one rclpy accepts; publishers that offered different QoS -> the default
profile; the contract QoS when the bag has none). Message k is published at
``start + (log_k − log_0) / rate`` on the monotonic clock (absolute deadlines, so sleep
overshoot does not accumulate). The command exits when the bag is done, once every reliable
subscriber has acknowledged every message (at most ``node_shell.ACK_TIMEOUT_S``) and after
``--linger`` seconds.

``--clock [HZ]`` publishes the bag's time on ``/clock`` (``rosgraph_msgs/Clock``, HZ default 40,
as ``ros2 bag play --clock``): log_0 + (now − start)·rate, so nodes with ``use_sim_time`` run on
the recording's time base (a bag recorded with simulated time, the main job's, replays in
simulated time); a ``/clock`` recorded in the bag is then not replayed.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import rclpy
from rclpy.node import Node
from rclpy.utilities import remove_ros_args
from rosgraph_msgs.msg import Clock as ClockMsg

from aeropend_ident.errors import BagError, BagLossWarning, print_warnings_as_lines
from aeropend_ident.io.bag_reader import RawBagReader
from aeropend_ident.io.integrity.loss import loss_warning, stored_loss
from aeropend_ident.nodes.qos import message_class, playback_qos
from aeropend_sim.contract import TOPIC_CLOCK
from aeropend_sim.ros.node_shell import run_node, wait_acknowledged
from aeropend_sim.ros.node_usage import NodeUsage, TopicUse, contract_topic
from aeropend_sim.ros.ros_contract import CLOCK_QOS, to_time

NODE_NAME = "aeropend_player"

#: ``play --help`` (the flags are added by :func:`build_parser`; the player has no ROS parameters).
USAGE = NodeUsage(
    command="play",
    node_name=NODE_NAME,
    summary="Replay a rosbag2 bag's messages with their original timing: each message's serialised bytes "
            "unchanged (header stamps included) on its topic, with the QoS the bag recorded for it; exits "
            "when the bag is done.",
    topics=(TopicUse("publishes", "every topic of the bag (or --topics)", "its recorded type",
                     "the QoS the bag recorded (the contract QoS when it has none)"),
            contract_topic("publishes", TOPIC_CLOCK,
                           "with --clock: the bag's time, as ros2 bag play --clock")),
    parameters=(),
    examples=("play reports/main/run_bag",
              "play my_run --rate 2 --topics /aeropend/joint_states",
              "play my_run --clock --wait-for-subscribers 10"),
    notes="Exit status: 0 when the bag was played, 1 when it cannot be read, 2 on a bad option.",
)


class PlayerNode(Node):
    """Publishers for the topics of one bag (raw bytes)."""

    def __init__(self, reader: RawBagReader, clock: bool = False, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.pubs: dict[str, Any] = {}
        self.clock_pub = self.create_publisher(ClockMsg, TOPIC_CLOCK, CLOCK_QOS) if clock else None
        for topic, info in reader.topics.items():
            if clock and topic == TOPIC_CLOCK:
                continue  # the bag's own /clock gives way to the one published from the bag's time
            qos, warning = playback_qos(topic, info.qos)
            if warning is not None:
                self.get_logger().warning(warning)
            self.pubs[topic] = self.create_publisher(message_class(info.msgtype), topic, qos)

    def wait_for_subscribers(self, timeout_s: float, settle_s: float = 0.5) -> bool:
        """Wait until every publisher has at least one matched subscription (or the timeout).

        Matching is seen on the publisher's side first; the subscriber side may still be
        completing discovery, so the method waits another ``settle_s`` seconds after the match
        (otherwise the first messages can be lost, even with reliable QoS).
        """
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if all(p.get_subscription_count() > 0 for p in self.pubs.values()):
                time.sleep(settle_s)
                return True
            time.sleep(0.02)
        return False


def play(node: PlayerNode, reader: RawBagReader, rate: float, clock_hz: float = 40.0) -> tuple[int, float]:
    """Publish every message of ``reader`` on schedule (streamed, constant memory).

    Message k is due at ``start + (log_k − log_0) / rate`` (as
    :func:`aeropend_ident.io.bag_reader.playback_deadlines` computes); stops early when rclpy shuts down.
    With the node's ``/clock`` publisher, the bag time log_0 + (now − start)·rate is published
    every 1/``clock_hz`` s of wall time in between.

    Returns
    -------
    (int, float)
        Messages published and the largest lateness [s] of a publication versus its deadline.
    """
    pubs = node.pubs
    context = node.context
    worst = 0
    count = 0
    start = log0 = 0
    tick_ns = round(1e9 / clock_hz)
    next_tick = 0
    for topic, logtime, raw in reader.messages():
        if topic not in pubs:
            continue
        if count == 0:
            start, log0 = time.monotonic_ns() + 1_000_000, logtime  # 1 ms to get going
            next_tick = start
        due = start + round((logtime - log0) / rate)  # = playback_deadlines(...)[k]
        while node.clock_pub is not None and next_tick <= due and context.ok():
            wait = next_tick - time.monotonic_ns()
            if wait > 0:
                time.sleep(wait / 1e9)
            node.clock_pub.publish(ClockMsg(clock=to_time(log0 + round((next_tick - start) * rate))))
            next_tick += tick_ns
        wait = due - time.monotonic_ns()
        if wait > 0:
            time.sleep(wait / 1e9)
        if not context.ok():  # SIGINT/SIGTERM: rclpy shut the context down
            break
        try:
            pubs[topic].publish(raw)
        except Exception:  # rclpy raises RCLError ("context is invalid") once shut down
            if context.ok():
                raise
            break  # shut down between the check and the publish
        worst = max(worst, time.monotonic_ns() - due)
        count += 1
    return count, worst / 1e9


def build_parser() -> argparse.ArgumentParser:
    """Command-line flags of ``play``."""
    p = USAGE.parser()
    p.add_argument("bag", type=Path, help="bag directory or .mcap/.db3 file")
    p.add_argument("-r", "--rate", type=float, default=1.0, help="speed factor (default 1.0)")
    p.add_argument("-l", "--loop", action="store_true", help="play again and again until Ctrl-C")
    p.add_argument("--topics", nargs="+", help="only these topics")
    p.add_argument("--delay", type=float, default=0.0, help="seconds to wait before playing")
    p.add_argument("--wait-for-subscribers", type=float, default=0.0, metavar="TIMEOUT",
                   help="wait up to TIMEOUT s until every topic has a subscriber")
    p.add_argument("--linger", type=float, default=0.5, help="seconds to stay up after the last message")
    p.add_argument("--clock", type=float, nargs="?", const=40.0, default=None, metavar="HZ",
                   help="publish the bag's time on /clock at HZ (default 40), as ros2 bag play --clock")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``play``."""
    argv = list(sys.argv if argv is None else argv)
    args = build_parser().parse_args(remove_ros_args(argv)[1:])
    print_warnings_as_lines("play")
    if not args.rate > 0:
        print(f"play: error: --rate {args.rate} must be > 0", file=sys.stderr)
        return 2
    if args.clock is not None and not args.clock > 0:
        print(f"play: error: --clock {args.clock} Hz must be > 0", file=sys.stderr)
        return 2
    try:
        reader = RawBagReader(args.bag, args.topics)
    except BagError as exc:
        print(f"play: error: {exc}", file=sys.stderr)
        return 1
    loss = stored_loss(reader.custom_data)  # what record counted as lost (replayed as recorded)
    text = loss_warning(f"bag '{args.bag}'", loss) if loss else None
    if text is not None:
        warnings.warn(text, BagLossWarning, stacklevel=1)
    def run(node: PlayerNode, executor: Any, stop: threading.Event) -> int:
        if args.wait_for_subscribers > 0 and not node.wait_for_subscribers(args.wait_for_subscribers):
            missing = [t for t, p in node.pubs.items() if p.get_subscription_count() == 0]
            node.get_logger().warning(f"no subscriber on {missing} after {args.wait_for_subscribers:g} s; "
                                      "playing anyway")
        if args.delay > 0:
            time.sleep(args.delay)
        while True:
            count, late = play(node, reader, args.rate, args.clock or 40.0)
            stopped = "" if rclpy.ok() else " (interrupted)"
            print(f"play: published {count} messages from {args.bag} at rate {args.rate:g} "
                  f"(worst lateness {late * 1e3:.2f} ms){stopped}", flush=True)
            if not args.loop or not rclpy.ok():
                break
        if rclpy.ok():
            # a writer destroyed before its reliable readers acknowledged drops what they lack
            wait_acknowledged(node, [*node.pubs.values(), *([node.clock_pub] if node.clock_pub else [])])
            time.sleep(max(args.linger, 0.0))
        return 0

    # rclpy's own SIGINT handling: play() stops when rclpy.ok() turns False; the node is not spun
    try:
        return run_node(NODE_NAME, argv, lambda: PlayerNode(reader, clock=args.clock is not None), body=run,
                        make_executor=lambda node: None, fail_errors=(BagError,), rclpy_signals=True,
                        report_error=lambda exc: print(f"play: error: {exc}", file=sys.stderr))
    finally:
        reader.close()


if __name__ == "__main__":
    sys.exit(main())
