"""rclpy <-> rosbags QoS conversions shared by the recorder and the player nodes (one home).

What goes into a bag
    :func:`qos_from_rclpy` turns the QoS a publisher offers, as graph discovery reports it
    (``Node.get_publishers_info_by_topic``), into the ``offered_qos_profiles`` entry of the bag.
    DDS discovery carries reliability, durability, deadline, lifespan and liveliness but not the
    writer's history: rmw reports history ``UNKNOWN`` and depth 0. rosbag2 (Humble to Rolling,
    ``RecorderImpl::offered_qos_profiles_for_topic``) stores that profile unchanged, so its bags
    say ``history: unknown`` / ``depth: 0`` and only its player's adaptation makes them playable.
    aeropend's recorder writes a concrete history and depth instead: the writer's own when
    discovery reports one, else the ones the topic contract prescribes for that topic and
    reliability (:func:`contract_qos`), else keep-last :data:`DEFAULT_DEPTH`. Every policy it
    writes is one rclpy accepts, so ``play`` and ``ros2 bag play`` replay the bag as recorded.

What comes out of a bag
    :func:`playback_qos` is the offer the player makes for a topic from the profiles its bag lists
    (any tool's bag: ``unknown`` / ``system_default`` values, depth 0, Foxy-era "infinite"
    durations). It follows rosbag2's player (``Rosbag2QoS::adapt_offer_to_recorded_offers``):
    when every recorded publisher offered the same compatibility-relevant policies (reliability,
    durability, deadline, liveliness and its lease) that profile is offered, otherwise rclpy's
    default profile (reliable, volatile, keep last 10), with a warning. :func:`qos_to_rclpy` makes
    one recorded profile valid for ``create_publisher``: a concrete history is kept (keep-last with
    depth 0 gets :data:`DEFAULT_DEPTH`); a history the bag does not tell (``unknown``,
    ``system_default``) is the contract's for an aeropend topic, by the same rule as the
    recorder's (a reliable sample topic is the lock-step plant's keep-all, so a lagging reliable
    reader is not overrun), else keep-last (the recorded depth, else :data:`DEFAULT_DEPTH`, the
    depth rosbag2's player uses); an ``unknown`` reliability, durability or liveliness takes
    rclpy's default; the deprecated ``manual_by_node`` liveliness (no longer in rclpy) becomes
    ``manual_by_topic``, the offer that still satisfies every request ``manual_by_node`` satisfied.

:func:`watch_qos` is the subscription QoS of the ``topics`` command; :func:`message_class` imports a
message type by its ROS name.
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from typing import Any

from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_default,
)
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from aeropend_ident.io.bags import INFINITE_TIME, qos_for_topic
from aeropend_sim.contract import CONTRACT_TOPICS, TOPIC_CLOCK

#: Keep-last depth for a history the bag does not tell: rmw's default profile depth (10), the one
#: rosbag2's player offers for every recorded topic (``Rosbag2QoS::default_history``).
DEFAULT_DEPTH: int = qos_profile_default.depth

_INFINITE_NS = 2**63 - 1  # RMW_DURATION_INFINITE [ns] (INFINITE_TIME in a bag)
#: "Infinite" durations of Foxy-era bags (rosbag2 ``qos.cpp``: rmw_fastrtps' and rmw_connext's
#: before ``RMW_DURATION_INFINITE``; rmw_cyclonedds' was 2^63 − 1 ns already), read as infinite
#: like rosbag2 does.
_FOXY_INFINITE = {(0x7FFFFFFF, 0xFFFFFFFF), (0x7FFFFFFF, 0x7FFFFFFF)}


def message_class(msgtype: str) -> Any:
    """Python class of a ROS 2 message type name such as ``sensor_msgs/msg/JointState``.

    Raises
    ------
    ValueError
        If ``msgtype`` is not of the form ``package/msg/Name``.
    ImportError, AttributeError
        If the package or the message is not installed.
    """
    parts = msgtype.split("/")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"message type {msgtype!r} is not of the form 'package/msg/Name'")
    pkg, kind, name = parts
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def contract_qos(topic: str, reliable: bool = False) -> Qos | None:
    """The QoS the topic contract prescribes for an aeropend topic offered with this reliability.

    Parameters
    ----------
    topic : str
        Topic name: a contract topic in any namespace (``/rig2/aeropend/joint_states``) or
        ``/clock``; any other topic has no contract QoS.
    reliable : bool
        Whether the publisher offers reliable delivery: a reliable sample writer is the lock-step
        plant's (keep all), a best-effort one the real-time plant's or a driver's (keep last 5).

    Returns
    -------
    rosbags.interfaces.Qos or None
        :func:`aeropend_ident.io.bags.qos_for_topic` of the topic, None for a non-contract topic.
    """
    if topic != TOPIC_CLOCK and not any(topic.endswith(name) for name in CONTRACT_TOPICS):
        return None
    return qos_for_topic(topic, lockstep=reliable)


def _has_history(history: QosHistory, depth: int) -> bool:
    """Whether a profile says what its history is (keep-all, or keep-last with a depth)."""
    return history == QosHistory.KEEP_ALL or (history == QosHistory.KEEP_LAST and depth > 0)


# -- into the bag -----------------------------------------------------------------------------


def _qtime(d: Duration) -> QosTime:
    ns = d.nanoseconds
    if ns >= _INFINITE_NS:
        return INFINITE_TIME
    if ns <= 0:
        return QosTime(0, 0)
    sec, nsec = divmod(ns, 1_000_000_000)
    return QosTime(sec=sec, nsec=nsec)


def qos_from_rclpy(profile: QoSProfile, fallback: Qos | None = None) -> Qos:
    """Bag entry (rosbags :class:`Qos`) of a publisher's offered QoS, with a concrete history.

    Parameters
    ----------
    profile : rclpy.qos.QoSProfile
        The offered profile, usually ``TopicEndpointInfo.qos_profile`` from graph discovery
        (history ``UNKNOWN``, depth 0: discovery does not carry the writer's history).
    fallback : rosbags.interfaces.Qos, optional
        Where history and depth come from when ``profile`` has none (history unknown or system
        default, or keep-last with depth 0): the contract QoS of the topic. Without it keep-last
        :data:`DEFAULT_DEPTH`.

    Returns
    -------
    rosbags.interfaces.Qos
        The profile's reliability, durability, liveliness and durations (infinite durations as
        :data:`INFINITE_TIME`, as rosbag2 writes them) with history ``KEEP_LAST`` (depth > 0) or
        ``KEEP_ALL``.
    """
    history, depth = QosHistory[profile.history.name], int(profile.depth)
    if not _has_history(history, depth):
        if fallback is not None:
            history, depth = fallback.history, int(fallback.depth)
        else:
            history, depth = QosHistory.KEEP_LAST, DEFAULT_DEPTH
    return Qos(
        history=history,
        depth=depth,
        reliability=QosReliability[profile.reliability.name],
        durability=QosDurability[profile.durability.name],
        deadline=_qtime(profile.deadline),
        lifespan=_qtime(profile.lifespan),
        liveliness=QosLiveliness[profile.liveliness.name],
        liveliness_lease_duration=_qtime(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


# -- out of the bag ---------------------------------------------------------------------------

#: Recorded reliability -> offered one (``UNKNOWN``, which rcl rejects, -> rclpy's default).
RELIABILITY: dict[QosReliability, ReliabilityPolicy] = {
    QosReliability.SYSTEM_DEFAULT: ReliabilityPolicy.SYSTEM_DEFAULT,
    QosReliability.RELIABLE: ReliabilityPolicy.RELIABLE,
    QosReliability.BEST_EFFORT: ReliabilityPolicy.BEST_EFFORT,
    QosReliability.UNKNOWN: qos_profile_default.reliability,
    QosReliability.BEST_AVAILABLE: ReliabilityPolicy.BEST_AVAILABLE,
}
#: Recorded durability -> offered one (``UNKNOWN`` -> rclpy's default).
DURABILITY: dict[QosDurability, DurabilityPolicy] = {
    QosDurability.SYSTEM_DEFAULT: DurabilityPolicy.SYSTEM_DEFAULT,
    QosDurability.TRANSIENT_LOCAL: DurabilityPolicy.TRANSIENT_LOCAL,
    QosDurability.VOLATILE: DurabilityPolicy.VOLATILE,
    QosDurability.UNKNOWN: qos_profile_default.durability,
    QosDurability.BEST_AVAILABLE: DurabilityPolicy.BEST_AVAILABLE,
}
#: Recorded liveliness -> offered one (``UNKNOWN`` -> rclpy's default; the deprecated
#: ``MANUAL_BY_NODE``, absent from rclpy, -> ``MANUAL_BY_TOPIC``, which satisfies the same requests).
LIVELINESS: dict[QosLiveliness, LivelinessPolicy] = {
    QosLiveliness.SYSTEM_DEFAULT: LivelinessPolicy.SYSTEM_DEFAULT,
    QosLiveliness.AUTOMATIC: LivelinessPolicy.AUTOMATIC,
    QosLiveliness.MANUAL_BY_NODE: LivelinessPolicy.MANUAL_BY_TOPIC,
    QosLiveliness.MANUAL_BY_TOPIC: LivelinessPolicy.MANUAL_BY_TOPIC,
    QosLiveliness.UNKNOWN: qos_profile_default.liveliness,
    QosLiveliness.BEST_AVAILABLE: LivelinessPolicy.BEST_AVAILABLE,
}


def _duration(t: QosTime) -> Duration | None:
    """A finite, positive recorded duration; None for unspecified (0) or any "infinite" value."""
    sec, nsec = int(t.sec), int(t.nsec)
    ns = sec * 1_000_000_000 + nsec
    if (sec, nsec) in _FOXY_INFINITE or ns <= 0 or ns >= _INFINITE_NS:
        return None
    return Duration(nanoseconds=ns)


def qos_to_rclpy(qos: Qos, fallback: Qos | None = None) -> QoSProfile:
    """rclpy profile that offers what one recorded profile offered, valid for ``create_publisher``.

    Parameters
    ----------
    qos : rosbags.interfaces.Qos
        A profile from a bag's ``offered_qos_profiles`` (any tool's: every enum value allowed).
    fallback : rosbags.interfaces.Qos, optional
        History and depth to use when ``qos`` does not tell its history (``UNKNOWN`` or
        ``SYSTEM_DEFAULT``): the topic's contract QoS (:func:`contract_qos`).

    Returns
    -------
    rclpy.qos.QoSProfile
        History ``KEEP_ALL`` kept; ``KEEP_LAST`` with the recorded depth (0 ->
        :data:`DEFAULT_DEPTH`); ``UNKNOWN`` / ``SYSTEM_DEFAULT`` history -> ``fallback``'s, else
        ``KEEP_LAST`` with the recorded depth or :data:`DEFAULT_DEPTH`. Reliability, durability and
        liveliness through :data:`RELIABILITY`, :data:`DURABILITY`, :data:`LIVELINESS`. Deadline,
        lifespan and liveliness lease: finite positive values kept, unspecified or infinite ones
        (including the Foxy-era encodings) left unset (= infinite).
    """
    history, depth = QosHistory(qos.history), int(qos.depth)
    if history not in (QosHistory.KEEP_ALL, QosHistory.KEEP_LAST) and fallback is not None:
        history, depth = QosHistory(fallback.history), int(fallback.depth)
    kwargs: dict[str, Any] = {
        "history": HistoryPolicy.KEEP_ALL if history == QosHistory.KEEP_ALL else HistoryPolicy.KEEP_LAST,
        "depth": depth if depth > 0 else DEFAULT_DEPTH,
        "reliability": RELIABILITY[QosReliability(qos.reliability)],
        "durability": DURABILITY[QosDurability(qos.durability)],
        "liveliness": LIVELINESS[QosLiveliness(qos.liveliness)],
        "avoid_ros_namespace_conventions": bool(qos.avoid_ros_namespace_conventions),
    }
    for key in ("deadline", "lifespan", "liveliness_lease_duration"):
        d = _duration(getattr(qos, key))
        if d is not None:
            kwargs[key] = d
    return QoSProfile(**kwargs)


def _compatibility_key(qos: Qos) -> tuple[Any, ...]:
    """The policies that decide matching (history and lifespan excluded, as rosbag2 does)."""
    p = qos_to_rclpy(qos)
    return (p.reliability, p.durability, p.deadline.nanoseconds, p.liveliness,
            p.liveliness_lease_duration.nanoseconds)


def playback_qos(topic: str, profiles: Sequence[Qos]) -> tuple[QoSProfile, str | None]:
    """The QoS the player offers on ``topic``, from the profiles its bag recorded.

    Parameters
    ----------
    topic : str
        Topic name (its contract QoS fills what the bag does not tell; named in the warning).
    profiles : sequence of rosbags.interfaces.Qos
        The topic's ``offered_qos_profiles`` (one per recorded publisher; may be empty).

    Returns
    -------
    (rclpy.qos.QoSProfile, str or None)
        When all profiles agree on the compatibility-relevant policies: :func:`qos_to_rclpy` of
        the first, a history it does not tell taken from :func:`contract_qos`. Without profiles:
        the contract QoS of an aeropend topic, rclpy's default profile for any other. When they
        disagree: rclpy's default profile (reliable, volatile, keep last :data:`DEFAULT_DEPTH`),
        which matches reliable and best-effort subscribers alike, and a warning naming the topic.
    """
    default = QoSProfile(depth=DEFAULT_DEPTH)
    if not profiles:
        contract = contract_qos(topic)
        return (qos_to_rclpy(contract) if contract is not None else default), None
    keys = {_compatibility_key(q) for q in profiles}
    if len(keys) == 1:
        first = profiles[0]
        reliable = QosReliability(first.reliability) == QosReliability.RELIABLE
        return qos_to_rclpy(first, contract_qos(topic, reliable)), None
    return (default,
            f"the {len(profiles)} recorded publishers of {topic} offered different QoS "
            f"({len(keys)} kinds); offering the default (reliable, volatile, keep last {DEFAULT_DEPTH})")


# -- watching a topic --------------------------------------------------------------------------


def watch_qos(offers: Sequence[QoSProfile], depth: int, reliable: bool = False) -> QoSProfile:
    """Subscription QoS of a monitoring tool (``topics``) that matches every publisher of a topic.

    Follows rosbag2's recorder (``Rosbag2QoS::adapt_request_to_offers``) for durability:
    transient-local (latched messages delivered) when every publisher offers it, else volatile.
    Reliability is best effort unless ``reliable`` (and every publisher offers reliable): a
    best-effort reader matches every writer and never slows one down (a lock-step plant's
    keep-all writer waits for its reliable readers).

    Parameters
    ----------
    offers : sequence of rclpy.qos.QoSProfile
        The publishers' offered profiles (``TopicEndpointInfo.qos_profile``); may be empty.
    depth : int
        Keep-last depth of the subscription queue (>= 1).
    reliable : bool
        Ask for reliable delivery when every publisher offers it.

    Returns
    -------
    rclpy.qos.QoSProfile
    """
    every = bool(offers)
    all_reliable = every and all(o.reliability == ReliabilityPolicy.RELIABLE for o in offers)
    latched = every and all(o.durability == DurabilityPolicy.TRANSIENT_LOCAL for o in offers)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=max(int(depth), 1),
        reliability=(ReliabilityPolicy.RELIABLE if reliable and all_reliable
                     else ReliabilityPolicy.BEST_EFFORT),
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )
