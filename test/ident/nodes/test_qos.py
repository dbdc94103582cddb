"""The recorder's and player's QoS conversions (``aeropend_ident.nodes.qos``), without processes.

Every enum value a bag can hold (rosbags' ``QosHistory`` / ``QosReliability`` / ``QosDurability``
/ ``QosLiveliness``, ``UNKNOWN`` and ``SYSTEM_DEFAULT`` included) is mapped to a profile, and
each mapped profile is checked to create an rclpy publisher in this process (rcl rejects
``UNKNOWN`` policies with "failed setting topic QoS", the error of issue 34).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

pytest.importorskip("rclpy")

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from aeropend_ident.io import bags
from aeropend_ident.nodes.qos import (
    DEFAULT_DEPTH,
    INFINITE_TIME,
    contract_qos,
    playback_qos,
    qos_from_rclpy,
    qos_to_rclpy,
)
from aeropend_sim.contract import COMMAND_QOS_DEPTH, SAMPLE_QOS_DEPTH
from aeropend_sim.ros.harness import private_node, random_domain

#: What rosbag2 Jazzy writes for a publisher found by discovery (rmw_fastrtps): history unknown,
#: depth 0, infinite durations (ros2/rosbag2#1237 shows the Humble form: ``history: 3, depth: 0``).
ROSBAG2_DISCOVERED = Qos(
    history=QosHistory.UNKNOWN, depth=0, reliability=QosReliability.RELIABLE,
    durability=QosDurability.VOLATILE, deadline=INFINITE_TIME, lifespan=INFINITE_TIME,
    liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=INFINITE_TIME,
    avoid_ros_namespace_conventions=False,
)
_ZERO = QosTime(0, 0)


@pytest.fixture(scope="module")
def node() -> Iterator[Any]:
    """One rclpy node on a private domain, to prove that a mapped profile creates a publisher."""
    with private_node("test_nodes_qos", random_domain()) as (n, _):
        yield n


def _publishes(node: Any, profile: QoSProfile) -> None:
    from std_msgs.msg import Float64

    pub = node.create_publisher(Float64, "/qos_probe", profile)
    try:
        pub.publish(Float64(data=1.0))
    finally:
        node.destroy_publisher(pub)


# -- out of the bag: every enum value -----------------------------------------------------------

HISTORY_CASES = [  # recorded (history, depth) -> offered (history, depth)
    (QosHistory.KEEP_LAST, 7, HistoryPolicy.KEEP_LAST, 7),
    (QosHistory.KEEP_LAST, 0, HistoryPolicy.KEEP_LAST, DEFAULT_DEPTH),
    (QosHistory.KEEP_ALL, 0, HistoryPolicy.KEEP_ALL, DEFAULT_DEPTH),
    (QosHistory.SYSTEM_DEFAULT, 0, HistoryPolicy.KEEP_LAST, DEFAULT_DEPTH),
    (QosHistory.SYSTEM_DEFAULT, 3, HistoryPolicy.KEEP_LAST, 3),
    (QosHistory.UNKNOWN, 0, HistoryPolicy.KEEP_LAST, DEFAULT_DEPTH),
    (QosHistory.UNKNOWN, 5, HistoryPolicy.KEEP_LAST, 5),
]


def test_every_history_value_is_covered() -> None:
    assert {c[0] for c in HISTORY_CASES} == set(QosHistory)


@pytest.mark.parametrize(("history", "depth", "want", "want_depth"), HISTORY_CASES)
def test_history_becomes_a_concrete_one(node: Any, history: QosHistory, depth: int,
                                        want: HistoryPolicy, want_depth: int) -> None:
    p = qos_to_rclpy(ROSBAG2_DISCOVERED._replace(history=history, depth=depth))
    assert (p.history, p.depth) == (want, want_depth)
    _publishes(node, p)


@pytest.mark.parametrize("history", [QosHistory.UNKNOWN, QosHistory.SYSTEM_DEFAULT])
def test_untold_history_comes_from_the_fallback(history: QosHistory) -> None:
    recorded = ROSBAG2_DISCOVERED._replace(history=history, depth=0)
    assert qos_to_rclpy(recorded, bags.SAMPLE_QOS_RELIABLE).history == HistoryPolicy.KEEP_ALL
    p = qos_to_rclpy(recorded, bags.COMMAND_QOS)
    assert (p.history, p.depth) == (HistoryPolicy.KEEP_LAST, COMMAND_QOS_DEPTH)
    # a history the bag tells is never overridden
    told = qos_to_rclpy(recorded._replace(history=QosHistory.KEEP_LAST, depth=3), bags.SAMPLE_QOS_RELIABLE)
    assert (told.history, told.depth) == (HistoryPolicy.KEEP_LAST, 3)


@pytest.mark.parametrize(("value", "want"), [
    (QosReliability.SYSTEM_DEFAULT, ReliabilityPolicy.SYSTEM_DEFAULT),
    (QosReliability.RELIABLE, ReliabilityPolicy.RELIABLE),
    (QosReliability.BEST_EFFORT, ReliabilityPolicy.BEST_EFFORT),
    (QosReliability.UNKNOWN, ReliabilityPolicy.RELIABLE),  # rclpy's default
    (QosReliability.BEST_AVAILABLE, ReliabilityPolicy.BEST_AVAILABLE),
])
def test_reliability(node: Any, value: QosReliability, want: ReliabilityPolicy) -> None:
    p = qos_to_rclpy(ROSBAG2_DISCOVERED._replace(reliability=value))
    assert p.reliability == want
    _publishes(node, p)


@pytest.mark.parametrize(("value", "want"), [
    (QosDurability.SYSTEM_DEFAULT, DurabilityPolicy.SYSTEM_DEFAULT),
    (QosDurability.TRANSIENT_LOCAL, DurabilityPolicy.TRANSIENT_LOCAL),
    (QosDurability.VOLATILE, DurabilityPolicy.VOLATILE),
    (QosDurability.UNKNOWN, DurabilityPolicy.VOLATILE),  # rclpy's default
    (QosDurability.BEST_AVAILABLE, DurabilityPolicy.BEST_AVAILABLE),
])
def test_durability(node: Any, value: QosDurability, want: DurabilityPolicy) -> None:
    p = qos_to_rclpy(ROSBAG2_DISCOVERED._replace(durability=value))
    assert p.durability == want
    _publishes(node, p)


@pytest.mark.parametrize(("value", "want"), [
    (QosLiveliness.SYSTEM_DEFAULT, LivelinessPolicy.SYSTEM_DEFAULT),
    (QosLiveliness.AUTOMATIC, LivelinessPolicy.AUTOMATIC),
    (QosLiveliness.MANUAL_BY_NODE, LivelinessPolicy.MANUAL_BY_TOPIC),  # deprecated, not in rclpy
    (QosLiveliness.MANUAL_BY_TOPIC, LivelinessPolicy.MANUAL_BY_TOPIC),
    (QosLiveliness.UNKNOWN, LivelinessPolicy.SYSTEM_DEFAULT),  # rclpy's default
    (QosLiveliness.BEST_AVAILABLE, LivelinessPolicy.BEST_AVAILABLE),
])
def test_liveliness(node: Any, value: QosLiveliness, want: LivelinessPolicy) -> None:
    p = qos_to_rclpy(ROSBAG2_DISCOVERED._replace(liveliness=value))
    assert p.liveliness == want
    _publishes(node, p)


def test_every_policy_value_is_covered() -> None:
    """The parametrised tables above name every member of every enum (a new rosbags value fails)."""
    from aeropend_ident.nodes import qos

    assert set(qos.RELIABILITY) == set(QosReliability)
    assert set(qos.DURABILITY) == set(QosDurability)
    assert set(qos.LIVELINESS) == set(QosLiveliness)


@pytest.mark.parametrize(("t", "ns"), [
    (_ZERO, 0),                                 # unspecified
    (INFINITE_TIME, 0),                         # RMW_DURATION_INFINITE as rosbag2 writes it
    (QosTime(0x7FFFFFFF, 0xFFFFFFFF), 0),       # Foxy rmw_fastrtps "infinite"
    (QosTime(0x7FFFFFFF, 0x7FFFFFFF), 0),       # Foxy rmw_connext "infinite"
    (QosTime(2, 500_000_000), 2_500_000_000),   # a real deadline
])
def test_durations(node: Any, t: QosTime, ns: int) -> None:
    p = qos_to_rclpy(ROSBAG2_DISCOVERED._replace(deadline=t, lifespan=t, liveliness_lease_duration=t))
    got = (p.deadline.nanoseconds, p.lifespan.nanoseconds, p.liveliness_lease_duration.nanoseconds)
    assert got == (ns,) * 3
    _publishes(node, p)


def test_the_rosbag2_profile_of_a_discovered_publisher_publishes(node: Any) -> None:
    """The exact profile of issue 34 (``history: unknown``, depth 0) now creates a publisher."""
    p = qos_to_rclpy(ROSBAG2_DISCOVERED)
    assert (p.history, p.depth, p.reliability, p.durability) == (
        HistoryPolicy.KEEP_LAST, DEFAULT_DEPTH, ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE)
    _publishes(node, p)


# -- out of the bag: several publishers (rosbag2's adapt_offer_to_recorded_offers) --------------


def test_playback_of_agreeing_publishers_takes_their_policies_and_the_contract_history() -> None:
    best_effort = ROSBAG2_DISCOVERED._replace(reliability=QosReliability.BEST_EFFORT)
    # two publishers that differ only in history, depth and lifespan (not compatibility-relevant)
    other = best_effort._replace(history=QosHistory.KEEP_ALL, lifespan=QosTime(1, 0))
    p, warning = playback_qos("/aeropend/joint_states", [best_effort, other])
    assert warning is None
    assert (p.reliability, p.history, p.depth) == (ReliabilityPolicy.BEST_EFFORT, HistoryPolicy.KEEP_LAST,
                                                   SAMPLE_QOS_DEPTH)
    # reliable samples: the lock-step plant's keep-all, in any namespace
    p, _ = playback_qos("/rig2/aeropend/joint_states", [ROSBAG2_DISCOVERED])
    assert (p.reliability, p.history) == (ReliabilityPolicy.RELIABLE, HistoryPolicy.KEEP_ALL)
    p, _ = playback_qos("/aeropend/duty_cycle", [ROSBAG2_DISCOVERED])
    assert (p.history, p.depth) == (HistoryPolicy.KEEP_LAST, COMMAND_QOS_DEPTH)
    # a foreign topic: keep last DEFAULT_DEPTH, as rosbag2's player
    p, _ = playback_qos("/tf", [ROSBAG2_DISCOVERED])
    assert (p.history, p.depth) == (HistoryPolicy.KEEP_LAST, DEFAULT_DEPTH)


def test_playback_of_disagreeing_publishers_offers_the_default_with_a_warning() -> None:
    best_effort = ROSBAG2_DISCOVERED._replace(reliability=QosReliability.BEST_EFFORT)
    p, warning = playback_qos("/aeropend/armature", [ROSBAG2_DISCOVERED, best_effort])
    assert (p.reliability, p.durability, p.history, p.depth) == (
        ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE, HistoryPolicy.KEEP_LAST, DEFAULT_DEPTH)
    assert warning is not None and "/aeropend/armature" in warning and "2 recorded publishers" in warning


def test_playback_without_recorded_profiles() -> None:
    p, warning = playback_qos("/aeropend/duty_cycle", [])
    assert warning is None and (p.reliability, p.depth) == (ReliabilityPolicy.RELIABLE, COMMAND_QOS_DEPTH)
    p, _ = playback_qos("/aeropend/joint_states", [])
    assert (p.reliability, p.depth) == (ReliabilityPolicy.BEST_EFFORT, SAMPLE_QOS_DEPTH)
    p, _ = playback_qos("/chatter", [])
    assert (p.reliability, p.history, p.depth) == (ReliabilityPolicy.RELIABLE, HistoryPolicy.KEEP_LAST,
                                                   DEFAULT_DEPTH)


# -- into the bag ------------------------------------------------------------------------------


def _discovered(reliability: ReliabilityPolicy) -> QoSProfile:
    """A profile as ``get_publishers_info_by_topic`` reports it (history unknown, depth 0)."""
    inf = Duration(nanoseconds=2**63 - 1)
    return QoSProfile(history=HistoryPolicy.UNKNOWN, depth=0, reliability=reliability,
                      durability=DurabilityPolicy.VOLATILE, deadline=inf, lifespan=inf,
                      liveliness=LivelinessPolicy.AUTOMATIC, liveliness_lease_duration=inf)


def test_recorded_profile_has_the_contract_history() -> None:
    reliable = _discovered(ReliabilityPolicy.RELIABLE)
    best_effort = _discovered(ReliabilityPolicy.BEST_EFFORT)
    # best effort, keep last 5, infinite durations: the contract's offer of the real-time plant
    assert qos_from_rclpy(best_effort, contract_qos("/aeropend/joint_states", False)) == bags.SAMPLE_QOS
    assert qos_from_rclpy(reliable, contract_qos("/aeropend/armature", True)) == bags.SAMPLE_QOS_RELIABLE
    assert qos_from_rclpy(reliable, contract_qos("/aeropend/duty_cycle", True)) == bags.COMMAND_QOS
    assert qos_from_rclpy(reliable, contract_qos("/clock", True)) == bags.CLOCK_QOS_RELIABLE  # lock-step
    assert contract_qos("/tf") is None
    q = qos_from_rclpy(best_effort)
    assert (q.history, q.depth) == (QosHistory.KEEP_LAST, DEFAULT_DEPTH)
    assert q.reliability == QosReliability.BEST_EFFORT


def test_recorded_profile_keeps_a_history_the_writer_tells() -> None:
    told = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=3, reliability=ReliabilityPolicy.RELIABLE)
    q = qos_from_rclpy(told, bags.SAMPLE_QOS_RELIABLE)
    assert (q.history, q.depth) == (QosHistory.KEEP_LAST, 3)
    assert (q.deadline, q.lifespan) == (_ZERO, _ZERO)  # unspecified stays unspecified
    q = qos_from_rclpy(QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE))
    assert q.history == QosHistory.KEEP_ALL


@pytest.mark.parametrize("reliability", [ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT])
def test_recorded_then_played_offers_the_same_policies(node: Any, reliability: ReliabilityPolicy) -> None:
    """Round trip through the bag entry: the player offers what the recorded publisher offered."""
    for topic in ("/aeropend/joint_states", "/aeropend/duty_cycle", "/clock", "/tf"):
        offered = _discovered(reliability)
        bag_entry = qos_from_rclpy(offered, contract_qos(topic, reliability == ReliabilityPolicy.RELIABLE))
        p, warning = playback_qos(topic, [bag_entry])
        assert warning is None
        assert (p.reliability, p.durability, p.liveliness) == (offered.reliability, offered.durability,
                                                               offered.liveliness)
        assert (p.deadline.nanoseconds, p.lifespan.nanoseconds) == (0, 0)  # infinite -> unset
        assert (p.history, p.depth) == (qos_to_rclpy(bag_entry).history, qos_to_rclpy(bag_entry).depth)
        _publishes(node, p)


# -- watching a topic (the ``topics`` command) ----------------------------------------------------


def test_watch_qos_matches_every_publisher_and_never_slows_one() -> None:
    from aeropend_ident.nodes.qos import watch_qos

    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    best_effort = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    p = watch_qos([], 100)
    assert (p.history, p.depth, p.reliability, p.durability) == (
        HistoryPolicy.KEEP_LAST, 100, ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE)
    assert watch_qos([reliable], 100).reliability == ReliabilityPolicy.BEST_EFFORT  # the default
    assert watch_qos([reliable, latched], 100, reliable=True).reliability == ReliabilityPolicy.RELIABLE
    assert watch_qos([reliable, best_effort], 100, reliable=True).reliability == ReliabilityPolicy.BEST_EFFORT
    assert watch_qos([latched], 100).durability == DurabilityPolicy.TRANSIENT_LOCAL  # latched message shown
    assert watch_qos([latched, reliable], 100).durability == DurabilityPolicy.VOLATILE
    assert watch_qos([], 0).depth == 1
