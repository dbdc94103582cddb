"""Text of the ``topics`` command (no rclpy): messages as YAML, arrival rates, the topic table.

:func:`message_to_yaml` prints a ROS 2 message the way ``ros2 topic echo`` does
(``rosidl_runtime_py.convert.message_to_yaml``, which the PyPI wheels aeropend installs do not
ship): one ``field: value`` line per field in declaration order, nested messages indented,
sequences as YAML lists, strings and sequences longer than ``truncate_length`` cut with ``...``.
It works on any generated message class (it reads ``get_fields_and_field_types()``).

:func:`rate_stats` is ``ros2 topic hz``'s statistics of arrival times: average rate
(n − 1) / (t_last − t_first) and the minimum, maximum and standard deviation of the intervals.
:func:`topic_table` lays out ``topics list``.
"""

from __future__ import annotations

import array
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import yaml

#: ``ros2 topic echo``'s default cut of long strings and sequences.
DEFAULT_TRUNCATE = 128


def _is_message(value: Any) -> bool:
    return hasattr(type(value), "get_fields_and_field_types")


def _element_type(field_type: str) -> str:
    """Element type of a sequence or array field type (``sequence<double>``, ``double[9]``)."""
    if field_type.startswith("sequence<"):
        return field_type[len("sequence<"):-1].split(",")[0]
    return field_type.split("[")[0]


def _sequence_summary(value: Any, field_type: str) -> str:
    """``--no-arr`` text of a sequence field: its element type and length."""
    return f"<sequence type: {_element_type(field_type)}, length: {len(value)}>"


def _plain(value: Any, field_type: str, truncate: int | None, no_arr: bool, no_str: bool) -> Any:
    """``value`` as YAML-ready Python data (dicts, lists, str, int, float, bool)."""
    if _is_message(value):
        return message_to_dict(value, truncate, no_arr, no_str)
    if isinstance(value, (bytes, bytearray)):
        value = list(value)
    if isinstance(value, (array.array, np.ndarray, list, tuple)):
        if no_arr:
            return _sequence_summary(value, field_type)
        items = list(value)
        cut = truncate is not None and len(items) > truncate
        element = _element_type(field_type)
        out = [_plain(v, element, truncate, no_arr, no_str) for v in (items[:truncate] if cut else items)]
        return [*out, "..."] if cut else out
    if isinstance(value, str):
        if no_str:
            return f"<string length: {len(value)}>"
        return value[:truncate] + "..." if truncate is not None and len(value) > truncate else value
    if isinstance(value, np.generic):
        return value.item()
    return value


def message_to_dict(msg: Any, truncate: int | None = DEFAULT_TRUNCATE, no_arr: bool = False,
                    no_str: bool = False) -> dict[str, Any]:
    """A ROS 2 message as an ordered ``dict`` of plain Python values (what :func:`message_to_yaml` prints).

    Parameters
    ----------
    msg : ROS 2 message
        Instance of a generated message class (``sensor_msgs.msg.JointState()``, ...).
    truncate : int or None
        Strings and sequences longer than this are cut and end with ``"..."`` (None: never).
    no_arr, no_str : bool
        Replace sequences / strings by ``<sequence type: T, length: N>`` / ``<string length: N>``.

    Returns
    -------
    dict
        Field name -> value, in the message's field order; nested messages as nested dicts,
        sequences (``array.array``, NumPy arrays, lists) as lists, NumPy scalars as Python ones.

    Raises
    ------
    TypeError
        If ``msg`` is not a generated ROS 2 message.
    """
    if not _is_message(msg):
        raise TypeError(f"{type(msg).__name__} is not a ROS 2 message (no get_fields_and_field_types)")
    fields = msg.get_fields_and_field_types()
    return {name: _plain(getattr(msg, name), ftype, truncate, no_arr, no_str)
            for name, ftype in fields.items()}


def message_to_yaml(msg: Any, truncate: int | None = DEFAULT_TRUNCATE, no_arr: bool = False,
                    no_str: bool = False, flow_style: bool = False) -> str:
    """A ROS 2 message as YAML text, as ``ros2 topic echo`` prints it (without the ``---`` line).

    Parameters
    ----------
    msg : ROS 2 message
    truncate, no_arr, no_str
        See :func:`message_to_dict`.
    flow_style : bool
        Inline lists and mappings (``{a: 1, b: [1, 2]}``) instead of block style.

    Returns
    -------
    str
        YAML text ending with a newline; ``yaml.safe_load`` gives :func:`message_to_dict` back
        (floats NaN/inf as ``.nan`` / ``.inf``).
    """
    return yaml.safe_dump(message_to_dict(msg, truncate, no_arr, no_str), sort_keys=False, allow_unicode=True,
                          width=sys.maxsize, default_flow_style=flow_style)


@dataclass(frozen=True)
class RateStats:
    """Arrival statistics of one topic over a measurement window.

    Attributes
    ----------
    count : int
        Messages received.
    rate_hz : float or None
        Average rate (count − 1) / (t_last − t_first) [Hz]; None with fewer than two messages.
    min_s, max_s, std_s : float or None
        Shortest, longest interval and the intervals' standard deviation [s].
    """

    count: int
    rate_hz: float | None
    min_s: float | None = None
    max_s: float | None = None
    std_s: float | None = None


def rate_stats(times_ns: Sequence[int]) -> RateStats:
    """``ros2 topic hz`` statistics of arrival times.

    Parameters
    ----------
    times_ns : sequence of int
        Arrival times [ns] of the messages, in arrival order (a monotonic clock).

    Returns
    -------
    RateStats

    Raises
    ------
    ValueError
        If the times decrease.
    """
    t = np.asarray(times_ns, dtype=np.int64)
    if t.size < 2:
        return RateStats(int(t.size), None)
    dt = np.diff(t) / 1e9
    if np.any(dt < 0):
        raise ValueError("arrival times must not decrease")
    span = (t[-1] - t[0]) / 1e9
    rate = (t.size - 1) / span if span > 0 else math.inf
    return RateStats(int(t.size), float(rate), float(dt.min()), float(dt.max()), float(dt.std()))


def format_rate(stats: RateStats | None) -> str:
    """Short rate text of :func:`topic_table`: ``488.3 Hz``, ``1 msg``, ``no messages`` or ``-``."""
    if stats is None:
        return "-"
    if stats.rate_hz is None:
        return "no messages" if stats.count == 0 else "1 msg"
    return f"{stats.rate_hz:.4g} Hz"


@dataclass(frozen=True)
class TopicRow:
    """One line of ``topics list``: a topic, its types, endpoint counts and measured rate."""

    name: str
    types: tuple[str, ...]
    publishers: int
    subscribers: int
    rate: RateStats | None = None


def topic_table(rows: Sequence[TopicRow], with_rate: bool = True) -> str:
    """The ``topics list`` table: name, type(s), rate (optional), publishers and subscribers.

    Columns are padded to their widest entry; rows keep the order given. Returns "" for no rows.
    """
    if not rows:
        return ""
    header = ["topic", "type", *(["rate"] if with_rate else []), "pub", "sub"]
    lines = [[r.name, ", ".join(r.types), *([format_rate(r.rate)] if with_rate else []), str(r.publishers),
              str(r.subscribers)] for r in rows]
    widths = [max(len(x) for x in col) for col in zip(header, *lines, strict=True)]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(line, widths, strict=True)).rstrip()
                     for line in [header, *lines]) + "\n"
