"""rclpy <-> rosbags conversions shared by the recorder and the player nodes.

:func:`qos_from_rclpy` stores a publisher's offered QoS in the bag; :func:`qos_to_rclpy` gives
the player that QoS back; :func:`message_class` imports a message type by its ROS name.
"""

from __future__ import annotations

import importlib
from typing import Any

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

_INFINITE_NS = 2**63 - 1


def message_class(msgtype: str) -> Any:
    """Python class of a ROS 2 message type name such as ``sensor_msgs/msg/JointState``."""
    pkg, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def _qtime(d: Duration) -> QosTime:
    ns = d.nanoseconds
    if ns <= 0 or ns >= _INFINITE_NS:
        return QosTime(sec=9223372036, nsec=854775807) if ns >= _INFINITE_NS else QosTime(0, 0)
    sec, nsec = divmod(ns, 1_000_000_000)
    return QosTime(sec=sec, nsec=nsec)


def qos_from_rclpy(profile: QoSProfile, default_depth: int) -> Qos:
    """rosbags :class:`Qos` of an rclpy profile (a depth of 0 from graph discovery -> ``default_depth``)."""
    return Qos(
        history=QosHistory[profile.history.name],
        depth=int(profile.depth) or default_depth,
        reliability=QosReliability[profile.reliability.name],
        durability=QosDurability[profile.durability.name],
        deadline=_qtime(profile.deadline),
        lifespan=_qtime(profile.lifespan),
        liveliness=QosLiveliness[profile.liveliness.name],
        liveliness_lease_duration=_qtime(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


def qos_to_rclpy(qos: Qos) -> QoSProfile:
    """rclpy profile of a rosbags :class:`Qos` (infinite / unset durations keep rclpy defaults)."""
    kwargs: dict[str, Any] = {
        "history": HistoryPolicy[qos.history.name],
        "depth": int(qos.depth) or 10,
        "reliability": ReliabilityPolicy[qos.reliability.name],
        "durability": DurabilityPolicy[qos.durability.name],
        "liveliness": LivelinessPolicy[qos.liveliness.name],
        "avoid_ros_namespace_conventions": bool(qos.avoid_ros_namespace_conventions),
    }
    for key in ("deadline", "lifespan", "liveliness_lease_duration"):
        t: QosTime = getattr(qos, key)
        ns = int(t.sec) * 1_000_000_000 + int(t.nsec)
        if 0 < ns < _INFINITE_NS:
            kwargs[key] = Duration(nanoseconds=ns)
    return QoSProfile(**kwargs)
