"""Shared rclpy shell pieces of the aeropend nodes (plant, bridge, controller).

Each node declares its parameters from a table of ``(name, default, description)`` and runs its
own spin loop until SIGINT/SIGTERM; these helpers keep that identical across nodes.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.signals import SignalHandlerOptions

N = TypeVar("N", bound=Node)

#: How long a reliable writer waits at shutdown for its readers' acknowledgements [s]. A sample
#: the middleware lost on the way (a full socket buffer under load) is repaired only after the
#: writer's next heartbeat (Fast DDS: every 3 s by default), so the wait must outlast one period.
ACK_TIMEOUT_S = 10.0


def declare_parameter_table(node: Node, table: Iterable[tuple[str, Any, str]],
                            live: Iterable[str] = ()) -> dict[str, Any]:
    """Declare every ``(name, default, description)`` parameter; return the values.

    Parameters named in ``live`` may be set while the node runs (the node validates and applies
    them in its ``add_on_set_parameters_callback``); every other one is declared read-only, so
    ``ros2 param set`` is refused with "parameter is read-only" instead of reporting a success
    that changes nothing. Values given at start-up (``-p``, a params file, launch) apply to both.
    Types are dynamic: ``None`` defaults mean "unset" (e.g. a strategy's default pole pattern).
    """
    live = set(live)
    values = {}
    for name, default, doc in table:
        what = doc if name in live else f"{doc} (read-only: fixed at start-up)"
        desc = ParameterDescriptor(description=what, dynamic_typing=True, read_only=name not in live)
        values[name] = node.declare_parameter(name, default, desc).value
    return values


def wait_acknowledged(node: Node, publishers: Iterable[Publisher],
                      timeout_s: float = ACK_TIMEOUT_S) -> bool:
    """Block until every reliable reader acknowledged every sample of ``publishers``.

    A DDS writer that is destroyed drops what its reliable readers have not acknowledged yet:
    a lock-step publisher that exits right after its last message loses the tail a lagging
    recorder has not received (docs/data_plane.md). Call this before destroying the node.

    Parameters
    ----------
    node : rclpy.node.Node
        Owner of the publishers (its logger reports what was not acknowledged).
    publishers : iterable of rclpy.publisher.Publisher
        Writers to wait for (best-effort ones return at once).
    timeout_s : float
        Total time budget [s] for all of them.

    Returns
    -------
    bool
        True if everything was acknowledged in time; otherwise False and a warning naming the
        topics whose readers may miss samples.
    """
    deadline = time.monotonic() + timeout_s
    late = []
    for pub in publishers:
        left = max(deadline - time.monotonic(), 0.0)
        if not pub.wait_for_all_acked(Duration(nanoseconds=round(left * 1e9))):
            late.append(pub.topic_name)
    if late:
        node.get_logger().warn(f"not acknowledged within {timeout_s:g} s by every reliable reader: "
                               f"{', '.join(late)} (a reader may miss the last samples)")
    return not late


def init_with_stop_event(args: list[str] | None) -> threading.Event:
    """``rclpy.init`` without rclpy's signal handlers; SIGINT/SIGTERM set the returned event.

    The node then shuts down in its own loop (motor off, summary logged, bag closed) instead of
    being interrupted inside a callback.
    """
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()

    def _on_signal(signum: int, frame: Any) -> None:
        stop.set()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    return stop


def run_node(
    name: str,
    args: list[str] | None,
    make_node: Callable[[], N],
    config_errors: tuple[type[Exception], ...],
    cleanup: Callable[[N], None],
    *,
    done: Callable[[N], bool] = lambda node: False,
    exit_status: Callable[[N], int] = lambda node: 0,
    period: float = 0.1,
    start_errors: tuple[type[Exception], ...] = (),
) -> int:
    """Lifecycle shared by the nodes' ``main``: build, spin until stopped, clean up.

    Parameters
    ----------
    name : str
        Node name, used for the logger of a parameter error (raised before the node exists).
    args : list of str or None
        Command-line arguments for ``rclpy.init`` (``--ros-args ...``).
    make_node : callable
        Builds (and starts) the node; raises one of ``config_errors`` on a bad parameter.
    config_errors : tuple of exception types
        Logged as ``invalid parameter: ...``; the process then exits with status 2.
    cleanup : callable
        Run on the node before it is destroyed (motor off, summary logged, ...).
    done : callable
        Stops the spin loop when it returns True (besides SIGINT/SIGTERM and rclpy shutdown).
    exit_status : callable
        Exit status after a normal stop.
    period : float
        Spin timeout [s] between checks of the stop conditions.
    start_errors : tuple of exception types
        Raised by ``make_node`` when the node cannot start for another reason than a parameter
        (e.g. no firmware on the serial port); logged as ``cannot start: ...``, exit status 1.

    Returns
    -------
    int
        Process exit status: ``exit_status(node)``, 2 on an invalid parameter, 1 on a start error.
    """
    stop = init_with_stop_event(args)
    node: N | None = None
    status = 0
    try:
        node = make_node()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while not stop.is_set() and rclpy.ok() and not done(node):
            executor.spin_once(timeout_sec=period)
        status = exit_status(node)
    except config_errors as exc:
        rclpy.logging.get_logger(name).error(f"invalid parameter: {exc}")
        status = 2
    except start_errors as exc:
        rclpy.logging.get_logger(name).error(f"cannot start: {exc}")
        status = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            cleanup(node)
            node.destroy_node()
        rclpy.try_shutdown()
    return status
