"""Topic contract shared by the simulated plant, the hardware bridge, controllers and tools.

This module is the single source of truth for topic names, message types, channel layout,
units and QoS of the aeropend node graph. It imports no ROS package, so the offline tools
(bag reading with ``rosbags``) use the same definitions as the nodes (``rclpy``); the rclpy
message conversions live in :mod:`aeropend_sim.ros.ros_contract`.

Topics (all SI units; duty cycle as a fraction in [0, 1]; angles in rad; the names below are in
the root namespace: a node's namespace prefixes them, see :data:`REL_JOINT_STATES`)

==============================  ===========================  =====  ==========================
topic                           type                         dir.   content
==============================  ===========================  =====  ==========================
``/aeropend/duty_cycle``        ``std_msgs/msg/Float64``     in     duty-cycle command τ
``/aeropend/joint_states``      ``sensor_msgs/msg/JointState``  out  θ, θ̇, ω₁, ω₂, applied τ
``/aeropend/armature``          ``sensor_msgs/msg/BatteryState`` out armature v_a [V], i_a [A]
``/clock``                      ``rosgraph_msgs/msg/Clock``  out    simulated time (sim only)
``/aeropend/reference``         ``std_msgs/msg/Float64``     in     reference θ_ref [rad] of a
                                                                    controller; a closed-loop
                                                                    log's θ_ref in a bag
``/aeropend/extra_channels``    ``std_msgs/msg/``            bag    a recording's extra
                                ``Float64MultiArray``               channels (see
                                                                    :data:`EXTRA_CHANNELS`)
==============================  ===========================  =====  ==========================

``joint_states`` carries three joints in this order:

* ``pendulum``: position θ [rad] (0 = rod hanging down), velocity θ̇ [rad/s] or NaN when the
  source does not measure it, effort NaN.
* ``motor``: position NaN, velocity ω₁ rotor speed [rad/s] or NaN, effort = the duty cycle τ
  that was applied to the H-bridge over the sample interval that *ends* at this stamp
  (ros2_control convention: a PWM-driven joint's effort command is its duty cycle).
* ``propeller``: position NaN, velocity ω₂ propeller speed [rad/s] or NaN, effort NaN.

A 2-DOF rig's recording adds a fourth joint ``phi`` (:data:`SECOND_AXIS_JOINT`: position φ, velocity
φ̇, effort NaN); readers look joints up by name, so the three contract joints are read as always.

``armature`` uses ``sensor_msgs/BatteryState`` because it is the standard message that carries
a stamped voltage/current pair: ``voltage`` = armature voltage v_a [V] over the interval that
ends at the stamp (like the applied duty), ``current`` = armature current i_a [A] at the stamp
(NaN when not measured); every other field is NaN / unknown.

θ, θ̇, ω₁, ω₂ and i_a are instantaneous values at the stamp. Offline, the bag reader shifts the
applied duty and v_a back by one sample into the batch convention of
:class:`aeropend_sim.recording.Recording` (``duty[k]`` held over [t_k, t_{k+1})).

Both sample messages of one acquisition sample carry the **same header stamp**: the sample
instant. A recording therefore aligns exactly at the sample rate (490 Hz on the thesis rig).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, fields

#: Nominal sample period of the thesis rig: Timer1 phase-correct 8-bit PWM overflow (thesis §4.3.2).
SAMPLE_PERIOD_S: float = 2.048e-3
#: Nominal sample rate [Hz] (1 / 2.048 ms ≈ 488.28 Hz, "490 Hz" in the thesis).
SAMPLE_RATE_HZ: float = 1.0 / SAMPLE_PERIOD_S

#: Contract topics relative to a node's namespace: every node uses these, so a rig started with
#: ``--ros-args -r __ns:=/rig2`` (or a launch ``namespace``) publishes ``/rig2/aeropend/joint_states``
#: and a second rig or simulator runs beside it. In the root namespace (the default) they resolve to
#: the absolute ``TOPIC_*`` names below, today's names.
REL_DUTY_CYCLE = "aeropend/duty_cycle"
REL_JOINT_STATES = "aeropend/joint_states"
REL_ARMATURE = "aeropend/armature"

TOPIC_DUTY_CYCLE = "/" + REL_DUTY_CYCLE
TOPIC_JOINT_STATES = "/" + REL_JOINT_STATES
TOPIC_ARMATURE = "/" + REL_ARMATURE
#: Simulated time stays global (ROS convention): a second lock-step plant runs with
#: ``publish_clock:=false``.
TOPIC_CLOCK = "/clock"


def namespaced(topic: str, namespace: str) -> str:
    """Absolute name of a contract topic (``TOPIC_*`` or ``REL_*``) in ``namespace`` ("" or "/" =
    root): ``namespaced(TOPIC_JOINT_STATES, "/rig2") == "/rig2/aeropend/joint_states"``."""
    rel = topic.lstrip("/")
    ns = namespace.strip("/")
    return f"/{ns}/{rel}" if ns else f"/{rel}"

#: Reference θ_ref [rad] of a closed loop (``std_msgs/Float64``, latest wins): what the controller node
#: subscribes to and where a bag keeps a recording's :data:`REFERENCE_CHANNEL`.
REL_REFERENCE = "aeropend/reference"
TOPIC_REFERENCE = "/" + REL_REFERENCE
#: A recording's other extra channels (:data:`EXTRA_CHANNELS` and lab-named ones), one
#: ``std_msgs/Float64MultiArray`` per sample (see :data:`EXTRA_CHANNELS`).
REL_EXTRA_CHANNELS = "aeropend/extra_channels"
TOPIC_EXTRA_CHANNELS = "/" + REL_EXTRA_CHANNELS

TYPE_DUTY_CYCLE = "std_msgs/msg/Float64"
TYPE_JOINT_STATES = "sensor_msgs/msg/JointState"
TYPE_ARMATURE = "sensor_msgs/msg/BatteryState"
TYPE_CLOCK = "rosgraph_msgs/msg/Clock"
TYPE_REFERENCE = "std_msgs/msg/Float64"
TYPE_EXTRA_CHANNELS = "std_msgs/msg/Float64MultiArray"

#: Topic -> message type of every contract topic (what the recorder records by default).
CONTRACT_TOPICS: dict[str, str] = {
    TOPIC_DUTY_CYCLE: TYPE_DUTY_CYCLE,
    TOPIC_JOINT_STATES: TYPE_JOINT_STATES,
    TOPIC_ARMATURE: TYPE_ARMATURE,
}

#: Joint names of ``joint_states`` in their fixed order.
JOINT_NAMES: tuple[str, str, str] = ("pendulum", "motor", "propeller")

#: Sample channels, their unit and meaning (column names used by every array API).
CHANNELS: dict[str, tuple[str, str]] = {
    "theta": ("rad", "pendulum angle θ, 0 = hanging down"),
    "theta_dot": ("rad/s", "pendulum angular velocity θ̇"),
    "omega_rotor": ("rad/s", "rotor speed ω₁"),
    "omega_prop": ("rad/s", "propeller speed ω₂"),
    "i_a": ("A", "armature current i_a"),
    "v_a": ("V", "armature voltage v_a"),
    "duty": ("1", "applied duty cycle τ in [0, 1]"),
}

#: Named channels a recording may carry beyond :data:`CHANNELS` (they are no part of the 1-DOF plant):
#: name -> (unit, meaning). A lab may add channels under its own names (:func:`check_extra_channel`:
#: lower-case snake case, with a stated unit). In a bag, ``phi`` / ``phi_dot`` are the position /
#: velocity of a fourth ``joint_states`` joint :data:`SECOND_AXIS_JOINT` (after the contract's three, so
#: a 2-DOF rig's state is one JointState), ``theta_ref`` is published on :data:`TOPIC_REFERENCE` (the
#: controller's reference topic: ``play`` replays a closed-loop log's reference to a controller) and every
#: other extra channel goes into one ``std_msgs/Float64MultiArray`` per sample on
#: :data:`TOPIC_EXTRA_CHANNELS`, its layout's single dimension labelled with the channel names and
#: units joined by commas (``thrust [N],x_acc [m/s^2]``; as ``/aeropend/controller/signals``).
EXTRA_CHANNELS: dict[str, tuple[str, str]] = {
    "phi": ("rad", "second-axis angle φ of a 2-DOF rig (e.g. a Quanser Aero's yaw)"),
    "phi_dot": ("rad/s", "second-axis angular velocity φ̇"),
    "theta_ref": ("rad", "reference θ_ref of a closed-loop run: the angle the controller was asked to reach "
                         "(not an input: the duty cycle it applied is)"),
    "thrust": ("N", "measured thrust f (load cell)"),
}
#: The fourth ``joint_states`` joint of a 2-DOF rig and the extra channel of each of its fields.
SECOND_AXIS_JOINT = "phi"
SECOND_AXIS_FIELDS: dict[str, str] = {"phi": "position", "phi_dot": "velocity"}
#: The extra channel kept on :data:`TOPIC_REFERENCE`; a set point: it holds between samples.
REFERENCE_CHANNEL = "theta_ref"
_EXTRA_NAME = re.compile(r"[a-z][a-z0-9_]*")


def check_extra_channel(name: str, unit: str | None = None) -> str:
    """Validate an extra channel's name and unit; return its unit.

    Parameters
    ----------
    name : str
        :data:`EXTRA_CHANNELS` name or a lab's own (lower-case letters, digits, ``_``; starting with a
        letter; not a :data:`CHANNELS` name, which has its own place in the contract).
    unit : str, optional
        Its unit (SI, e.g. ``"m/s^2"``); None for an :data:`EXTRA_CHANNELS` name (its unit).

    Returns
    -------
    str
        The unit.

    Raises
    ------
    ContractError
        A contract channel's name, a malformed name, a lab channel without unit, or a unit that
        differs from an :data:`EXTRA_CHANNELS` name's.
    """
    if name in CHANNELS or name in ("t", "time"):
        raise ContractError(f"extra channel {name!r} is a contract channel; it has its own place "
                            f"(contract channels: {list(CHANNELS)})")
    if not isinstance(name, str) or not _EXTRA_NAME.fullmatch(name):
        raise ContractError(f"extra channel name {name!r}: expected lower-case letters, digits and '_', "
                            "starting with a letter (e.g. 'phi', 'thrust', 'x_acc')")
    known = EXTRA_CHANNELS.get(name)
    if known is not None:
        if unit not in (None, "", known[0]):
            raise ContractError(f"extra channel {name!r} is in {known[0]} ({known[1]}), not {unit!r}; "
                                f"scale the column to {known[0]}")
        return known[0]
    if not unit or not isinstance(unit, str):
        raise ContractError(f"extra channel {name!r}: its unit is needed (e.g. 'N', 'm/s^2', 'rad'); the "
                            f"channels with a known unit are {list(EXTRA_CHANNELS)}")
    return unit


#: QoS of sample topics: ROS 2 ``qos_profile_sensor_data`` (best effort, keep last 5, volatile).
SAMPLE_QOS_DEPTH = 5
#: Queue depth of the contract's sample *subscriptions* (≈ 0.2 s at 488 Hz): a Python subscriber
#: that is not scheduled for a few tens of milliseconds on a loaded machine keeps every sample
#: (with depth 5 it lost every sample older than 10 ms; docs/data_plane.md). Depth is local to
#: the subscriber and does not affect QoS matching.
SAMPLE_SUB_DEPTH = 100
#: QoS of the command topic: reliable, keep last 10, volatile.
COMMAND_QOS_DEPTH = 10
#: QoS of /clock as the simulated plant and ``play --clock`` publish it: reliable, keep last 10.
CLOCK_QOS_DEPTH = 10


class ContractError(ValueError):
    """A message or value violates the topic contract."""


@dataclass(frozen=True)
class Sample:
    """One acquisition sample of the plant (simulated or real).

    Attributes
    ----------
    stamp_ns : int
        Sample instant [ns] (ROS time; simulated time in lock-step mode).
    theta, theta_dot, omega_rotor, omega_prop, i_a, v_a : float
        Channels in SI units (see :data:`CHANNELS`); NaN where the source does not measure it.
    duty : float
        Duty cycle τ in [0, 1] applied over the sample interval that ends at this stamp
        (wire convention; see the module doc and :mod:`aeropend_sim.recording`).
    """

    stamp_ns: int
    theta: float
    theta_dot: float = math.nan
    omega_rotor: float = math.nan
    omega_prop: float = math.nan
    i_a: float = math.nan
    v_a: float = math.nan
    duty: float = math.nan

    def joint_state_fields(self) -> dict[str, list[float] | list[str]]:
        """Field values of the ``joint_states`` message for this sample (see module doc)."""
        nan = math.nan
        return {
            "name": list(JOINT_NAMES),
            "position": [self.theta, nan, nan],
            "velocity": [self.theta_dot, self.omega_rotor, self.omega_prop],
            "effort": [nan, self.duty, nan],
        }

    def armature_fields(self) -> dict[str, float]:
        """Field values of the ``armature`` message for this sample (see module doc)."""
        return {"voltage": self.v_a, "current": self.i_a}


CHANNEL_NAMES: tuple[str, ...] = tuple(f.name for f in fields(Sample) if f.name != "stamp_ns")


def sample_from_fields(
    stamp_ns: int,
    names: list[str],
    position: list[float],
    velocity: list[float],
    effort: list[float],
    voltage: float = math.nan,
    current: float = math.nan,
) -> Sample:
    """Rebuild a :class:`Sample` from the fields of a ``joint_states`` (+ ``armature``) message.

    Parameters
    ----------
    stamp_ns : int
        Header stamp [ns].
    names, position, velocity, effort : list
        JointState arrays; joints are looked up by name, so their order may differ.
    voltage, current : float
        ``armature`` message fields [V], [A]; NaN when absent.

    Raises
    ------
    ContractError
        If a contract joint is missing or the arrays are shorter than ``names``.
    """
    names = list(names)
    missing = [j for j in JOINT_NAMES if j not in names]
    if missing:
        raise ContractError(
            f"joint_states lacks joint(s) {missing}; expected names {list(JOINT_NAMES)}, "
            f"got {names}"
        )
    n = len(names)

    def pick(arr: list[float], joint: str, what: str) -> float:
        if len(arr) == 0:
            return math.nan
        if len(arr) != n:
            raise ContractError(
                f"joint_states.{what} has {len(arr)} entries, expected {n} (one per name)"
            )
        return float(arr[names.index(joint)])

    return Sample(
        stamp_ns=int(stamp_ns),
        theta=pick(position, "pendulum", "position"),
        theta_dot=pick(velocity, "pendulum", "velocity"),
        omega_rotor=pick(velocity, "motor", "velocity"),
        omega_prop=pick(velocity, "propeller", "velocity"),
        duty=pick(effort, "motor", "effort"),
        v_a=float(voltage),
        i_a=float(current),
    )


def validate_duty(value: float) -> float:
    """Check a duty-cycle command against the contract.

    Parameters
    ----------
    value : float
        Commanded duty cycle τ (fraction).

    Returns
    -------
    float
        ``value`` unchanged.

    Raises
    ------
    ContractError
        If ``value`` is NaN/inf or outside [0, 1].
    """
    v = float(value)
    if not math.isfinite(v):
        raise ContractError(f"duty cycle {value!r} is not finite; expected a fraction in [0, 1]")
    if v < 0.0 or v > 1.0:
        raise ContractError(f"duty cycle {v:g} is outside [0, 1] (a fraction, not percent)")
    return v


def stamp_to_ns(sec: int, nanosec: int) -> int:
    """Convert a ``builtin_interfaces/Time`` (sec, nanosec) to integer nanoseconds."""
    return int(sec) * 1_000_000_000 + int(nanosec)


def ns_to_stamp(ns: int) -> tuple[int, int]:
    """Convert integer nanoseconds to ``builtin_interfaces/Time`` (sec, nanosec)."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return sec, nanosec


class LockstepRepeats:
    """Whether a lock-step command writer answers a re-published sample again.

    The lock-step plant re-publishes its last sample while it waits for a command
    (``sim_core.LOCKSTEP_REPUBLISH_S``) and advances once per command it receives; commands carry no
    stamp. A repeat that crossed a slow answer on the wire, if answered too, makes the plant advance
    twice on one command (one duty applied for two periods, the trajectory one sample late). Every
    duty reader matched when the answer went out got it (reliable, keep-all), so a repeat is answered
    again only when more readers are matched now than then: a plant matched late may have missed it.
    Used by the controller node and the excitation's ``LockstepFeeder``
    (``bench/repro/lockstep_double_answer.py``).
    """

    def __init__(self) -> None:
        self._matched = 0

    def published(self, matched: int) -> None:
        """Record that an answer goes out now to ``matched`` duty readers (count read before
        publishing, so a reader matched afterwards counts as new)."""
        self._matched = int(matched)

    def answer_again(self, matched: int) -> bool:
        """True if a repeat of the last answered sample is to be answered again, ``matched`` being
        the duty readers matched now."""
        return matched > self._matched
