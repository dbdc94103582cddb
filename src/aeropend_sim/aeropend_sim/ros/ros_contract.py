"""rclpy side of the topic contract: QoS profiles and message <-> :class:`Sample` conversion.

Every node (simulated plant, bridge, controllers, recorder, player) builds and parses contract
messages through these functions, so the simulated plant and the hardware bridge are
interchangeable. See :mod:`aeropend_sim.contract` for the topic table.
"""

from __future__ import annotations

import math

from builtin_interfaces.msg import Time
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from sensor_msgs.msg import BatteryState, JointState
from std_msgs.msg import Float64

from aeropend_sim.contract import (
    CLOCK_QOS_DEPTH,
    COMMAND_QOS_DEPTH,
    SAMPLE_SUB_DEPTH,
    ContractError,
    Sample,
    ns_to_stamp,
    sample_from_fields,
    stamp_to_ns,
)

#: QoS of the duty-cycle command topic (reliable: a lost command would stall lock-step runs).
COMMAND_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=COMMAND_QOS_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

#: QoS for *publishing* samples in real time: ``qos_profile_sensor_data`` (best effort, keep
#: last 5, volatile), what a hardware driver offers.
SAMPLE_QOS = qos_profile_sensor_data

#: QoS for *subscribing* to samples: the policies of :data:`SAMPLE_QOS` (best effort, volatile;
#: matches best-effort and reliable publishers) with a keep-last queue of ``SAMPLE_SUB_DEPTH``
#: (100 ≈ 0.2 s) instead of 5, so a subscriber that is not scheduled for a while on a loaded
#: machine does not lose the samples that arrived meanwhile (docs/data_plane.md).
SAMPLE_SUB_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=SAMPLE_SUB_DEPTH,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)

#: QoS of the samples in lock-step mode, publishers and subscribers: reliable, **keep all**,
#: volatile. With keep-all the plant's writer holds every sample until each matched reader has
#: acknowledged it, and a reader never evicts a sample the application has not taken, so a
#: subscriber that falls behind slows the lock-step loop down instead of losing samples (with
#: keep-last 50 a recorder lagging 50 samples lost them; docs/data_plane.md). Still matched by
#: :data:`SAMPLE_SUB_QOS` (best-effort) subscribers.
SAMPLE_QOS_LOCKSTEP = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

#: QoS of the duty-cycle commands in lock-step mode (the excitation's and the controller's writer,
#: the recorder's reader with ``--reliable``): reliable, **keep all**, volatile, for the reason of
#: :data:`SAMPLE_QOS_LOCKSTEP`. The plant takes each command at once (it answers it with the next
#: sample), but a recorder that falls behind the loop lost commands from the keep-last-10 writer of
#: :data:`COMMAND_QOS` (264 of 2448 in one main-job run under load; docs/data_plane.md). Matched by
#: :data:`COMMAND_QOS` readers (history is not part of QoS compatibility).
COMMAND_QOS_LOCKSTEP = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)


#: QoS of /clock (the simulated plant, ``play --clock``): reliable so that lock-step consumers see
#: every tick; best-effort subscribers (rclpy's time source) match.
CLOCK_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=CLOCK_QOS_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

#: QoS of the lock-step plant's /clock (one tick per sample): reliable, **keep all**, volatile, for
#: the reason of :data:`SAMPLE_QOS_LOCKSTEP`: a recorder that falls behind lost ticks from the
#: keep-last-10 writer of :data:`CLOCK_QOS` (305 of 9901 in one main-job run, in bursts of 15-99).
#: Best-effort subscribers (rclpy's time source) still match.
CLOCK_QOS_LOCKSTEP = QoSProfile(
    history=HistoryPolicy.KEEP_ALL,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)


def to_time(ns: int) -> Time:
    """``builtin_interfaces/Time`` for an integer-nanosecond instant."""
    sec, nanosec = ns_to_stamp(ns)
    return Time(sec=sec, nanosec=nanosec)


def sample_to_msgs(sample: Sample, frame_id: str = "aeropend") -> tuple[JointState, BatteryState]:
    """Build the ``joint_states`` and ``armature`` messages of one sample (same stamp).

    Parameters
    ----------
    sample : Sample
        The acquisition sample.
    frame_id : str
        ``header.frame_id`` of both messages.

    Returns
    -------
    (JointState, BatteryState)
    """
    stamp = to_time(sample.stamp_ns)
    js = JointState()
    js.header.stamp = stamp
    js.header.frame_id = frame_id
    for key, value in sample.joint_state_fields().items():
        setattr(js, key, value)
    arm = BatteryState()
    arm.header.stamp = stamp
    arm.header.frame_id = frame_id
    nan = math.nan
    arm.voltage = float(sample.v_a)
    arm.current = float(sample.i_a)
    arm.temperature = nan
    arm.charge = nan
    arm.capacity = nan
    arm.design_capacity = nan
    arm.percentage = nan
    arm.present = True
    return js, arm


def sample_from_msgs(js: JointState, arm: BatteryState | None = None) -> Sample:
    """Rebuild a :class:`Sample` from a ``joint_states`` message and optionally its ``armature``.

    Raises
    ------
    aeropend_sim.contract.ContractError
        If the messages violate the contract or their stamps differ.
    """
    ns = stamp_to_ns(js.header.stamp.sec, js.header.stamp.nanosec)
    voltage = current = math.nan
    if arm is not None:
        arm_ns = stamp_to_ns(arm.header.stamp.sec, arm.header.stamp.nanosec)
        if arm_ns != ns:
            raise ContractError(
                f"armature stamp {arm_ns} ns differs from joint_states stamp {ns} ns; "
                "both channels of one sample must carry the same stamp"
            )
        voltage, current = arm.voltage, arm.current
    return sample_from_fields(
        ns, list(js.name), list(js.position), list(js.velocity), list(js.effort), voltage, current
    )


def duty_msg(duty: float) -> Float64:
    """``std_msgs/Float64`` duty-cycle command (fraction in [0, 1])."""
    return Float64(data=float(duty))
