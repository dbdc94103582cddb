"""Shared rclpy shell of every aeropend node (plant, excitation, bridge, controller, recorder, player).

Each node declares its parameters from its table of
:class:`~aeropend_sim.ros.node_usage.NodeParameter` (the same table its ``--help`` prints); every
node's ``main`` starts and stops through :func:`run_node` (``-h``/``--help`` answered before ROS
starts, init with a SIGINT/SIGTERM stop event, build, spin or run to completion, clean up,
destroy, shut down), so the shutdown path (motor off, :func:`wait_acknowledged` before a writer is
destroyed, bag closed) is the same everywhere.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

import rclpy
import yaml
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.duration import Duration
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.signals import SignalHandlerOptions

from aeropend_sim.files.safe_yaml import YamlRefusedError, load_yaml
from aeropend_sim.ros.node_usage import NodeParameter, NodeUsage, strip_ros_args

N = TypeVar("N", bound=Node)

#: How long a reliable writer waits at shutdown for its readers' acknowledgements [s]. A sample
#: the middleware lost on the way (a full socket buffer under load) is repaired only after the
#: writer's next heartbeat (Fast DDS: every 3 s by default), so the wait must outlast one period.
ACK_TIMEOUT_S = 10.0


def declare_parameter_table(node: Node, table: Iterable[NodeParameter]) -> dict[str, Any]:
    """Declare every parameter of ``table``; return the values by name.

    Parameters marked ``live`` may be set while the node runs (the node validates and applies
    them in its ``add_on_set_parameters_callback``); every other one is declared read-only, so
    ``ros2 param set`` is refused with "parameter is read-only" instead of reporting a success
    that changes nothing. Values given at start-up (``-p``, a params file, launch) apply to both.
    Types are dynamic: ``None`` defaults mean "unset" (e.g. a strategy's default pole pattern).
    The descriptor's description carries the unit and the type (``ros2 param describe``).
    """
    values = {}
    for p in table:
        desc = ParameterDescriptor(description=p.declared_description(), dynamic_typing=True,
                                   read_only=not p.live)
        values[p.name] = node.declare_parameter(p.name, p.default, desc).value
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


#: Values of a node's ``executor`` parameter: ``events`` (rclpy's C++ ``EventsExecutor``: waits and
#: dispatches in C++, holding the GIL only inside callbacks) or ``single`` (``SingleThreadedExecutor``).
EXECUTORS = ("events", "single")


def executor_kind(value: Any, error: type[Exception]) -> str:
    """Validate an ``executor`` parameter value.

    Parameters
    ----------
    value : Any
        The parameter value.
    error : type of Exception
        The node's configuration error, raised for a bad value.

    Returns
    -------
    str
        One of :data:`EXECUTORS`.

    Raises
    ------
    error
        If ``value`` is not one of :data:`EXECUTORS` (the message names the value).
    """
    kind = str(value)
    if kind not in EXECUTORS:
        raise error(f"executor = {kind!r}; expected one of {list(EXECUTORS)}")
    return kind


def make_executor(kind: str) -> Executor:
    """A new executor of kind ``kind`` (one of :data:`EXECUTORS`, see :func:`executor_kind`)."""
    return EventsExecutor() if kind == "events" else SingleThreadedExecutor()


def _single_threaded(node: Node) -> Executor:
    return SingleThreadedExecutor()


def refused_params_file(argv: Iterable[str]) -> str | None:
    """Why a ``--params-file`` of ``argv`` must not reach rclpy (None: every one may).

    Each parameters file named after ``--params-file`` goes through the project's YAML loader
    (:mod:`aeropend_sim.files.safe_yaml`) before ``rclpy.init``: an alias (a "billion laughs"
    file) or a file above the size limit is refused at once, with the file's name. A file that is
    missing or not valid YAML is left to rclpy, which reports it as before.

    Parameters
    ----------
    argv : iterable of str
        The process arguments (ROS arguments included).

    Returns
    -------
    str or None
        The refusal (names the file, the line of the alias and what was expected).
    """
    tokens = list(argv)
    for k, tok in enumerate(tokens[:-1]):
        if tok == "--params-file":
            try:
                load_yaml(tokens[k + 1], "a ROS 2 parameters file")
            except YamlRefusedError as exc:
                return str(exc)
            except (OSError, ValueError, yaml.YAMLError):  # rclpy's own message follows
                continue
    return None


def run_node(
    name: str,
    args: list[str] | None,
    make_node: Callable[[], N],
    config_errors: tuple[type[Exception], ...] = (),
    cleanup: Callable[[N], None] = lambda node: None,
    *,
    done: Callable[[N], bool] = lambda node: False,
    exit_status: Callable[[N], int] = lambda node: 0,
    period: float = 0.1,
    start_errors: tuple[type[Exception], ...] = (),
    make_executor: Callable[[N], Executor | None] = _single_threaded,
    body: Callable[[N, Executor | None, threading.Event], int] | None = None,
    fail_errors: tuple[type[Exception], ...] = (),
    report_error: Callable[[Exception], None] | None = None,
    interrupt_status: int = 0,
    rclpy_signals: bool = False,
    usage: NodeUsage | None = None,
) -> int:
    """The one lifecycle of every node's ``main``: init, build, run until stopped, clean up, shut down.

    With ``usage``, the arguments before ``--ros-args`` are parsed first: ``-h``/``--help`` prints
    the node's usage (topics, parameters, example) and returns 0, an unknown argument prints the
    reason and returns 2, both before ``rclpy.init`` (no participant, no port, no file opened).
    Then ``rclpy.init`` (SIGINT/SIGTERM set a stop event, :func:`init_with_stop_event`), the node from
    ``make_node``, its executor, then either the standard loop (spin until a signal, rclpy
    shutdown or ``done(node)``) or the node's own ``body``; finally ``cleanup(node)`` (motor
    off, acknowledgements awaited, summary logged, bag closed), ``destroy_node`` and
    ``rclpy.try_shutdown`` whatever happened.

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
        Stops the standard loop when it returns True (besides SIGINT/SIGTERM and rclpy shutdown).
    exit_status : callable
        Exit status after the standard loop stopped.
    period : float
        Spin timeout [s] of the standard loop between checks of the stop conditions.
    start_errors : tuple of exception types
        Raised by ``make_node`` when the node cannot start for another reason than a parameter
        (e.g. no firmware on the serial port); logged as ``cannot start: ...``, exit status 1.
    make_executor : callable
        The executor the node is added to (default a ``SingleThreadedExecutor``; None: the node
        is not spun, e.g. a pure publisher).
    body : callable, optional
        ``body(node, executor, stop_event) -> status`` replaces the standard loop (a node that
        runs to completion: the excitation, the recorder's drain, the player).
    fail_errors : tuple of exception types
        Errors of the run itself (a bag that cannot be written or read): passed to
        ``report_error``, exit status 1.
    report_error : callable, optional
        Reports a ``fail_errors`` exception (default: the node logger's error).
    interrupt_status : int
        Exit status on ``KeyboardInterrupt`` / external rclpy shutdown.
    rclpy_signals : bool
        Keep rclpy's own signal handlers (SIGINT shuts the context down, so ``rclpy.ok()`` turns
        False) instead of the stop event: for a node whose loop watches ``rclpy.ok()`` only.
    usage : NodeUsage, optional
        The node's usage, for a node without command-line flags of its own (a node with flags
        parses them with ``usage.parser()`` before calling this, so its ``--help`` is the same).

    Returns
    -------
    int
        Process exit status: ``exit_status(node)`` or the ``body``'s, 2 on an invalid parameter
        or argument or a refused parameters file (:func:`refused_params_file`), 1 on a start or run
        error, ``interrupt_status`` when interrupted, 0 after ``--help``.
    """
    if usage is not None:
        argv = list(sys.argv if args is None else args)
        parser = usage.parser(usage=f"{usage.command} [-h] [--ros-args -p NAME:=VALUE ...]")
        try:
            _, unknown = parser.parse_known_args(strip_ros_args(argv)[1:])
            if unknown:
                example = usage.parameters[0].name if usage.parameters else "NAME"
                parser.error(f"unrecognized arguments: {' '.join(unknown)} (node parameters go after "
                             f"--ros-args, e.g. --ros-args -p {example}:=VALUE; see {usage.command} --help)")
        except SystemExit as exc:  # --help printed (0) or an unknown argument reported (2)
            return int(exc.code or 0)
    if (refused := refused_params_file(sys.argv if args is None else args)) is not None:
        print(f"{name}: error: {refused}", file=sys.stderr)
        return 2
    if rclpy_signals:
        rclpy.init(args=args)
        stop = threading.Event()
    else:
        stop = init_with_stop_event(args)
    node: N | None = None
    status = 0
    try:
        node = make_node()
        executor = make_executor(node)
        if executor is not None:
            executor.add_node(node)
        if body is not None:
            status = body(node, executor, stop)
        else:
            assert executor is not None
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
        status = interrupt_status
    except fail_errors as exc:
        if report_error is not None:
            report_error(exc)
        else:
            rclpy.logging.get_logger(name).error(str(exc))
        status = 1
    finally:
        if node is not None:
            cleanup(node)
            node.destroy_node()
        rclpy.try_shutdown()
    return status
