"""Shared rclpy shell pieces of the aeropend nodes (plant, bridge, controller).

Each node declares its parameters from a table of ``(name, default, description)`` and runs its
own spin loop until SIGINT/SIGTERM; these two helpers keep that identical across nodes.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterable
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions


def declare_parameter_table(node: Node, table: Iterable[tuple[str, Any, str]]) -> dict[str, Any]:
    """Declare every ``(name, default, description)`` parameter (dynamic typing); return the values."""
    values = {}
    for name, default, doc in table:
        desc = ParameterDescriptor(description=doc, dynamic_typing=True)
        values[name] = node.declare_parameter(name, default, desc).value
    return values


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
