"""``topics``: see the ROS 2 graph's topics on a machine without the ``ros2`` CLI (thin rclpy shell).

``topics list`` waits ``--spin-time`` seconds for discovery, then prints every topic with its
type(s), the rate measured over ``--window`` seconds (as ``ros2 topic hz``: messages received,
so a best-effort topic that loses messages on the way shows the received rate) and its numbers
of publishers and subscribers (this command's own subscriptions not counted), like
``ros2 topic list -t`` plus ``ros2 topic hz``. ``topics echo TOPIC`` prints the topic's messages
as YAML separated by ``---`` lines, as ``ros2 topic echo`` does (``-n N``: stop after N).

The graph is the one of ``ROS_DOMAIN_ID`` (and ``ROS_AUTOMATIC_DISCOVERY_RANGE``), as for every
node. In a namespace (``-N /rig2`` or ``--ros-args -r __ns:=/rig2``), ``list`` shows the topics
under it and a relative ``echo`` topic (``aeropend/joint_states``) is resolved in it. The
subscriptions are best effort (they match every publisher and never slow a lock-step plant down;
``echo --reliable`` asks for reliable delivery when every publisher offers it) and transient-local
when every publisher is (latched messages). Ctrl-C stops either command with exit status 0; an
unknown topic (after ``--timeout`` seconds of discovery) or a type not installed here is a
one-line error with exit status 1.

Examples::

    topics list
    topics list --window 5 -N /rig2
    topics echo /aeropend/joint_states -n 1
    ROS_DOMAIN_ID=7 topics echo aeropend/duty_cycle --ros-args -r __ns:=/rig2
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from rclpy.node import Node
from rclpy.utilities import remove_ros_args

from aeropend_ident.nodes.qos import message_class, watch_qos
from aeropend_ident.nodes.topic_view import (
    DEFAULT_TRUNCATE,
    TopicRow,
    message_to_yaml,
    rate_stats,
    topic_table,
)
from aeropend_sim.ros.node_shell import run_node

#: Node name prefix (hidden: a leading underscore keeps it out of ``ros2 node list``).
NODE_NAME = "_aeropend_topics"
#: Queue depth of the command's subscriptions (≈ 0.2 s at the 488 Hz sample rate).
QUEUE_DEPTH = 100


class TopicsError(ValueError):
    """A topic the command cannot show (not in the graph, several types, type not installed)."""


def _spin_for(executor: Any, seconds: float, stop: threading.Event,
              until: Callable[[], bool] = lambda: False) -> None:
    """Spin ``executor`` for ``seconds`` or until ``stop`` is set or ``until()`` is true."""
    end = time.monotonic() + max(seconds, 0.0)
    while not stop.is_set() and not until() and time.monotonic() < end:
        executor.spin_once(timeout_sec=min(0.05, max(end - time.monotonic(), 0.0)))


def _in_namespace(name: str, namespace: str) -> bool:
    return namespace in ("", "/") or name.startswith(namespace.rstrip("/") + "/")


def _hidden(name: str) -> bool:
    return any(part.startswith("_") for part in name.split("/"))


def _others(infos: Sequence[Any], node: Node) -> list[Any]:
    """Endpoints of other nodes than this command's."""
    return [i for i in infos if (i.node_name, i.node_namespace) != (node.get_name(), node.get_namespace())]


def _message_class(topic: str, msgtype: str) -> Any:
    try:
        return message_class(msgtype)
    except (ImportError, AttributeError, ValueError) as exc:
        raise TopicsError(f"type {msgtype} of {topic} is not installed in this environment ({exc})") from exc


def run_list(node: Node, executor: Any, stop: threading.Event, args: argparse.Namespace) -> int:
    """``topics list``: discover, measure the rates, print the table."""
    _spin_for(executor, args.spin_time, stop)
    namespace = node.get_namespace()
    topics: dict[str, tuple[str, ...]] = {}
    arrivals: dict[str, list[int]] = {}
    tried: set[str] = set()

    def discover() -> None:
        """Take in the topics the graph shows now; subscribe to each new one to measure its rate."""
        for name, types in node.get_topic_names_and_types():
            if name in topics or not _in_namespace(name, namespace):
                continue
            if _hidden(name) and not args.include_hidden_topics:
                continue
            topics[name] = tuple(types)
            if args.window > 0 and name not in tried:
                tried.add(name)
                try:
                    cls = message_class(types[0])
                except (ImportError, AttributeError, ValueError):
                    continue  # type not installed here: no rate ("-")
                times: list[int] = []
                arrivals[name] = times
                node.create_subscription(cls, name, lambda _raw, t=times: t.append(time.monotonic_ns()),
                                         watch_qos([], QUEUE_DEPTH), raw=True)

    discover()
    end = time.monotonic() + args.window
    while args.window > 0 and not stop.is_set() and time.monotonic() < end:
        _spin_for(executor, min(0.25, end - time.monotonic()), stop)
        discover()  # a topic that appears during the window is measured from then on
    if stop.is_set():
        return 0
    rows = [TopicRow(name, types, len(_others(node.get_publishers_info_by_topic(name), node)),
                     len(_others(node.get_subscriptions_info_by_topic(name), node)),
                     rate_stats(arrivals[name]) if name in arrivals else None)
            for name, types in sorted(topics.items())]
    rows = [r for r in rows if r.publishers or r.subscribers]  # not /rosout etc. of this command alone
    if not rows:
        where = f" under {namespace}" if namespace != "/" else ""
        print(f"no topics{where} on ROS_DOMAIN_ID {node.context.get_domain_id()} after {args.spin_time:g} s",
              flush=True)
        return 0
    print(topic_table(rows, with_rate=args.window > 0), end="", flush=True)
    if args.window > 0 and len(arrivals) < len(rows):
        print("rate '-': message type not installed here", flush=True)
    return 0


def _find_topic(node: Node, executor: Any, stop: threading.Event, topic: str, timeout: float) -> str | None:
    """The topic's type once the graph shows it (None if stopped meanwhile)."""
    found: dict[str, list[str]] = {}

    def seen() -> bool:
        found.update(node.get_topic_names_and_types())
        return topic in found

    _spin_for(executor, timeout, stop, seen)
    if stop.is_set():
        return None
    if topic not in found:
        near = sorted(t for t in found if not _hidden(t))
        shown = ", ".join(near[:8]) + (f", ... ({len(near)} in all)" if len(near) > 8 else "")
        raise TopicsError(f"topic {topic} not found after {timeout:g} s on ROS_DOMAIN_ID "
                          f"{node.context.get_domain_id()} (topics seen: {shown or 'none'}); "
                          "check the name, the namespace (-N) and ROS_DOMAIN_ID")
    types = found[topic]
    if len(types) != 1:
        raise TopicsError(f"topic {topic} has {len(types)} types {types}; cannot echo it")
    return types[0]


def run_echo(node: Node, executor: Any, stop: threading.Event, args: argparse.Namespace) -> int:
    """``topics echo TOPIC``: print messages as YAML until ``-n`` messages or Ctrl-C."""
    topic = node.resolve_topic_name(args.topic)
    msgtype = _find_topic(node, executor, stop, topic, args.timeout)
    if msgtype is None:
        return 0
    cls = _message_class(topic, msgtype)
    truncate = None if args.full_length else args.truncate_length
    printed = [0]

    def on_message(msg: Any) -> None:
        if args.count and printed[0] >= args.count:
            return
        text = message_to_yaml(msg, truncate, args.no_arr, args.no_str, args.flow_style)
        sys.stdout.write(text + "---\n")
        sys.stdout.flush()
        printed[0] += 1

    offers = [i.qos_profile for i in _others(node.get_publishers_info_by_topic(topic), node)]
    node.create_subscription(cls, topic, on_message, watch_qos(offers, QUEUE_DEPTH, args.reliable))
    while not stop.is_set() and not (args.count and printed[0] >= args.count):
        executor.spin_once(timeout_sec=0.1)
    return 0


def build_parser() -> argparse.ArgumentParser:
    """Command-line flags of ``topics`` (``--ros-args ...`` is passed to rclpy)."""
    p = argparse.ArgumentParser(
        prog="topics", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="See the ROS 2 graph's topics without the ros2 CLI: list them with their types and "
                    "measured rates, or print a topic's messages as YAML.",
        epilog="The graph is the one of ROS_DOMAIN_ID. Examples:\n"
               "  topics list\n"
               "  topics list --window 5 -N /rig2\n"
               "  topics echo /aeropend/joint_states -n 1\n"
               "  topics echo aeropend/duty_cycle --ros-args -r __ns:=/rig2")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-N", "--namespace", default=None,
                        help="namespace: list the topics under it, resolve relative topic names in it")
    common.add_argument("--spin-time", type=float, default=1.0, metavar="S",
                        help="seconds to wait for discovery (default 1)")
    sub = p.add_subparsers(dest="command", required=True, metavar="{list,echo}")
    lst = sub.add_parser("list", parents=[common], help="topics, types, rates, publishers and subscribers",
                         description="List the graph's topics with their types, measured rates and "
                                     "numbers of publishers and subscribers.")
    lst.add_argument("-w", "--window", type=float, default=2.0, metavar="S",
                     help="seconds to measure the rates (default 2; 0 = types only)")
    lst.add_argument("-a", "--include-hidden-topics", action="store_true",
                     help="also topics with a '_' segment")
    echo = sub.add_parser("echo", parents=[common], help="print a topic's messages as YAML",
                          description="Print a topic's messages as YAML, '---' after each "
                                      "(as ros2 topic echo).")
    echo.add_argument("topic", help="topic name (relative names are resolved in the namespace)")
    echo.add_argument("-n", "--count", type=int, default=0, metavar="N",
                      help="stop after N messages (0 = never)")
    echo.add_argument("--once", dest="count", action="store_const", const=1, help="stop after one message")
    echo.add_argument("--timeout", type=float, default=5.0, metavar="S",
                      help="seconds to wait for the topic to appear (default 5)")
    echo.add_argument("--truncate-length", type=int, default=DEFAULT_TRUNCATE, metavar="L",
                      help=f"cut strings and sequences longer than L (default {DEFAULT_TRUNCATE})")
    echo.add_argument("--full-length", action="store_true", help="never cut strings and sequences")
    echo.add_argument("--no-arr", action="store_true", help="show sequences as their type and length")
    echo.add_argument("--no-str", action="store_true", help="show strings as their length")
    echo.add_argument("--flow-style", action="store_true", help="inline YAML lists and mappings")
    echo.add_argument("--reliable", action="store_true",
                      help="reliable subscription when every publisher is reliable "
                           "(may slow a lock-step plant)")
    return p


def _check(args: argparse.Namespace) -> str | None:
    """A one-line usage error, or None."""
    if args.spin_time < 0:
        return f"--spin-time {args.spin_time:g} must be >= 0"
    if args.command == "list" and args.window < 0:
        return f"--window {args.window:g} must be >= 0"
    if args.command == "echo":
        if args.count < 0:
            return f"-n {args.count} must be >= 0"
        if args.timeout < 0:
            return f"--timeout {args.timeout:g} must be >= 0"
        if args.truncate_length < 1:
            return f"--truncate-length {args.truncate_length} must be >= 1"
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``topics``."""
    argv = list(sys.argv if argv is None else argv)
    args = build_parser().parse_args(remove_ros_args(argv)[1:])
    problem = _check(args)
    if problem is not None:
        print(f"topics: error: {problem}", file=sys.stderr)
        return 2
    body = run_list if args.command == "list" else run_echo
    try:
        return run_node(NODE_NAME, argv,
                        lambda: Node(f"{NODE_NAME}_{os.getpid()}", namespace=args.namespace),
                        body=lambda node, executor, stop: body(node, executor, stop, args),
                        fail_errors=(TopicsError,),
                        report_error=lambda exc: print(f"topics: error: {exc}", file=sys.stderr))
    except BrokenPipeError:  # `topics echo ... | head`: the reader left; not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
