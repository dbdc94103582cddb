"""Position controller node ``aeropend_controller`` (console script ``controller``).

Subscribes the contract samples (``/aeropend/joint_states``: θ only is used), publishes one
duty-cycle command ``/aeropend/duty_cycle`` per new sample, so it runs at the sample rate of the
plant (simulated or hardware bridge) and, in lock-step, drives the simulated plant.

Usage::

    controller --ros-args -p strategy:=fl_pid -p "steps:=[0.0, 0.4, 3.0, 0.2]"
    controller --ros-args -p mode:=lockstep -p duration:=3.0 -p trace:=/tmp/run.csv

Parameters: :func:`parameter_table` (also printed by ``controller --help``).

Live parameters (``ros2 param set /aeropend_controller omega_n 6.0``): ``omega_n``, ``zeta``,
``rho`` (a new design, taken over bumpless), ``reference`` and ``steps``; a value the design
refuses is rejected with the reason. The others are read-only (set them at start-up). In real-time
mode a new pole pattern is designed in a background thread (up to ≈ 0.5 s on a rig file that
declares its drive; the loop keeps running on the old gains meanwhile, so the firmware's command
watchdog does not trip) and taken over at the next sample after it is ready; a design that fails
there is logged as an error and the loop keeps its gains. ``reference`` and ``steps`` changes reuse
the running design and take effect at once.

Publishes ``/aeropend/controller/signals`` (std_msgs/Float64MultiArray, one per sample, labelled
layout: :data:`~aeropend_control.controller_core.SIGNALS`: t, reference, θ, error, v, thrust, θ̂̇,
duty, saturated, stamp, receipt latency, publish latency (filled in the trace only), θ̂, d̂).
Invalid parameters log an error naming the value and exit with status 2.
On shutdown the node publishes duty 0.
"""

from __future__ import annotations

import ctypes
import gc
import math
import os
import sys
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import BatteryState, JointState
from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension

from aeropend_control.controller_core import (
    SIGNALS,
    ControllerConfigError,
    ControllerLoop,
    ControllerSettings,
    build_strategy,
    make_settings,
)
from aeropend_control.design import REACH_DUTY_MARGIN
from aeropend_control.strategies.registry import DEFAULT_STRATEGY, strategy_help
from aeropend_sim.contract import (
    REL_ARMATURE,
    REL_DUTY_CYCLE,
    REL_JOINT_STATES,
    REL_REFERENCE,
    ContractError,
    LockstepRepeats,
    stamp_to_ns,
)
from aeropend_sim.contract import (
    TOPIC_REFERENCE as TOPIC_REFERENCE,  # re-exported: the controller's reference topic
)
from aeropend_sim.ros.node_shell import (
    declare_parameter_table,
    executor_kind,
    make_executor,
    run_node,
    wait_acknowledged,
)
from aeropend_sim.ros.node_usage import NodeParameter, NodeUsage, TopicUse, contract_topic
from aeropend_sim.ros.ros_contract import (
    COMMAND_QOS,
    COMMAND_QOS_LOCKSTEP,
    SAMPLE_QOS_LOCKSTEP,
    SAMPLE_SUB_QOS,
    duty_msg,
)

NODE_NAME = "aeropend_controller"
#: Internal signals, relative to the node's namespace like the contract topics (the reference topic
#: ``REL_REFERENCE`` is the contract's); ``TOPIC_*`` are their names in the root namespace.
REL_SIGNALS = "aeropend/controller/signals"
TOPIC_SIGNALS = "/" + REL_SIGNALS
#: Unpaired joint_states / armature halves kept while waiting for the other half.
PAIR_BUFFER = 20
#: Real-time mode: wait this long after the command publisher first matched before answering
#: samples (the plant's side of the match may complete later; commands sent before it would be
#: delivered late by the reliable history).
MATCH_GRACE_NS = 250_000_000

#: The node parameters after ``strategy`` (declared from this table by :func:`parameter_table`, printed
#: by ``--help``), validated by :func:`aeropend_control.controller_core.make_settings`. Live
#: (``ros2 param set``): the pole pattern (a new design taken over bumpless) and the reference (initial
#: value and step sequence); the
#: others fix the rig, the structure or the process set-up of a run and are read-only.
_PARAMETERS: tuple[NodeParameter, ...] = (
    NodeParameter("mode", "str", "realtime", "",
                  "realtime: best-effort samples (keep last 100); lockstep: reliable samples, exactly one "
                  "command per new sample stamp (a re-published sample is answered again only if a duty "
                  "subscriber matched after the first answer)"),
    NodeParameter("steps", "float[]", None, "",
                  "reference step sequence [t0, theta0, t1, theta1, ...] (t in s from the first sample, "
                  "theta in rad)", live=True),
    NodeParameter("reference", "float", 0.0, "rad",
                  "reference before the first step; messages on aeropend/reference override the sequence "
                  "from their arrival on", live=True),
    NodeParameter("allocator", "str", "model", "", "model | thesis (aeropend_control.allocation)"),
    NodeParameter("omega_n", "float", None, "rad/s",
                  "closed-loop natural frequency (unset: the strategy's default, 9.5 for FL and "
                  "small-signal, 9 for the cascades; on a rig file that declares a drive lag or delay, "
                  "the robust design)",
                  live=True),
    NodeParameter("zeta", "float", None, "", "closed-loop damping ratio (unset: per strategy and rig file, "
                  "0.7 nominal)", live=True),
    NodeParameter("rho", "float", None, "", "real closed-loop pole / omega_n (unset: 1)", live=True),
    NodeParameter("tf", "float", 0.01, "s", "theta_dot / derivative filter time constant of the difference "
                  "estimator"),
    NodeParameter("theta_op", "float", None, "rad", "operating point of small_signal_fixed"),
    NodeParameter("duration", "float", 0.0, "s",
                  "stop (duty 0, exit 0) after this much sample time; 0 = run until SIGINT/SIGTERM"),
    NodeParameter("trace", "str", "", "",
                  "CSV path for the internal signals, written on exit (empty = none)"),
    NodeParameter("estimator", "str", "observer", "",
                  "theta_dot estimate: observer (stationary Kalman filter with the model thrust as known "
                  "input) | difference (filtered difference, time constant tf)"),
    NodeParameter("rt_priority", "int", 0, "",
                  "SCHED_FIFO priority 1-99 of the executor thread (needs CAP_SYS_NICE or an rtprio limit, "
                  "else a warning); also switches the cyclic garbage collector off after start-up and locks "
                  "memory; 0 = normal scheduling"),
    NodeParameter("executor", "str", "events", "",
                  "events (rclpy's C++ EventsExecutor, lower latency) | single (SingleThreadedExecutor)"),
    NodeParameter("min_subscribers", "int", 1, "",
                  "send the first command only once this many subscriptions are matched on duty_cycle (the "
                  "plant, plus a recorder: 2), so a recorder started alongside records every command"),
)


def parameter_table() -> tuple[NodeParameter, ...]:
    """The node's parameters; the ``strategy`` description lists the strategies registered when the
    node is built (:func:`~aeropend_control.strategies.registry.strategy_help`), so a lab's strategy
    registered before start-up is listed and accepted."""
    return (NodeParameter("rig", "str", "thesis_rig", "", "rig name or YAML path whose model the design and "
                          "the allocation use"),
            NodeParameter("strategy", "str", DEFAULT_STRATEGY, "", strategy_help()), *_PARAMETERS)

#: ``controller --help``.
USAGE = NodeUsage(
    command="controller",
    node_name=NODE_NAME,
    summary="Position controller of the aeropendulum: one duty-cycle command per new sample of the plant "
            "(simulated or the hardware bridge), so it runs at the plant's sample rate and, in lock-step, "
            "drives the simulated plant. On shutdown it publishes duty 0.",
    topics=(contract_topic("subscribes", REL_JOINT_STATES, "theta (omega_1 for the cascades)"),
            contract_topic("subscribes", REL_ARMATURE, "i_a, cascades only"),
            TopicUse("subscribes", REL_REFERENCE, "std_msgs/msg/Float64", "reference [rad], latest wins"),
            contract_topic("publishes", REL_DUTY_CYCLE, "one command per sample"),
            TopicUse("publishes", REL_SIGNALS, "std_msgs/msg/Float64MultiArray",
                     "internal signals, one per sample: " + ", ".join(SIGNALS))),
    parameters=parameter_table(),
    examples=('controller --ros-args -p strategy:=fl_pid -p "steps:=[0.0, 0.4, 3.0, 0.2]"',
              "controller --ros-args -p mode:=lockstep -p duration:=3.0 -p trace:=/tmp/run.csv",
              "ros2 param set /aeropend_controller omega_n 6.0      # a live parameter"),
    notes="Exit status: 0 on SIGINT/SIGTERM or after duration, 2 on an invalid parameter (the message "
          "names the value).",
)


class ControllerNode(Node):
    """rclpy shell around :class:`~aeropend_control.controller_core.ControllerLoop`."""

    def __init__(self, **node_options: Any) -> None:
        """``node_options`` go to :class:`rclpy.node.Node` (e.g. ``context``, ``parameter_overrides``)."""
        super().__init__(NODE_NAME, **node_options)
        raw = declare_parameter_table(self, parameter_table())
        try:
            self.rt_priority = _rt_priority(raw.pop("rt_priority"))
            self.executor_kind = executor_kind(raw.pop("executor"), ControllerConfigError)
            self.min_subscribers = _min_subscribers(raw.pop("min_subscribers"))
            self.settings = make_settings(**raw)
            self._raw = raw
            self.loop = ControllerLoop(self.settings)
            if self.settings.mode == "realtime":
                _warm_up(self.settings)
        except ControllerConfigError:
            self.destroy_node()
            raise
        s = self.settings
        qos = SAMPLE_QOS_LOCKSTEP if s.mode == "lockstep" else SAMPLE_SUB_QOS
        self._pub_duty = self.create_publisher(Float64, REL_DUTY_CYCLE,
                                               COMMAND_QOS_LOCKSTEP if s.mode == "lockstep" else COMMAND_QOS)
        self._pub_sig = self.create_publisher(Float64MultiArray, REL_SIGNALS, 10)
        self.create_subscription(JointState, REL_JOINT_STATES, self._on_sample, qos)
        # cascades also need i_a: pair joint_states and armature by their common stamp
        self._pending_js: dict[int, tuple[float, float]] = {}
        self._pending_arm: dict[int, float] = {}
        if "i_a" in self.loop.needs:
            self.create_subscription(BatteryState, REL_ARMATURE, self._on_armature, qos)
        self.create_subscription(Float64, REL_REFERENCE, self._on_reference, 10)
        # a new pole pattern in real-time mode is designed here, off the executor (up to ≈ 0.5 s on a
        # rig file that declares its drive), and taken over at the first sample after it is ready
        self._designer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="redesign")
        self._redesign: tuple[ControllerSettings, Future] | None = None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.finished = threading.Event()
        self._matched_ns: int | None = None
        #: Which lock-step repeats are answered again (:meth:`_control`).
        self._repeats = LockstepRepeats()
        self.published = 0
        self.bad_samples = 0
        self._layout = [MultiArrayDimension(label=",".join(SIGNALS), size=len(SIGNALS), stride=len(SIGNALS))]
        self.get_logger().info(
            f"rig {s.rig.name!r}, strategy {s.strategy}, mode {s.mode}, steps {s.steps}, "
            f"poles {s.spec}, allocator {s.allocator}, estimator {s.estimator}, duration {s.duration:g} s, "
            f"executor {self.executor_kind}"
        )

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Validate and apply live parameters (``live`` in :func:`parameter_table`) between two samples (the
        executor runs this and the sample callbacks in one thread); a bad value is refused with the
        reason and the loop keeps its settings. Read-only ones never get here (rclpy refuses them)."""
        changes = {p.name: p.value for p in params}
        try:
            settings = make_settings(previous=self.settings, **{**self._raw, **changes})
            self._apply(settings)
        except ControllerConfigError as exc:
            self.get_logger().warn(f"parameter change {changes} refused: {exc}")
            return SetParametersResult(successful=False, reason=str(exc))
        self._raw.update(changes)
        self.settings = settings
        self.get_logger().info(f"parameters set {changes}: poles {settings.spec}, reference "
                               f"{settings.reference}, steps {settings.steps}")
        return SetParametersResult(successful=True)

    def destroy_node(self) -> None:
        """Stop the background designer (a pending design is dropped), then destroy the node."""
        designer = getattr(self, "_designer", None)  # absent when the constructor failed early
        if designer is not None:
            designer.shutdown(wait=False, cancel_futures=True)
        super().destroy_node()

    def _apply(self, settings: ControllerSettings) -> None:
        """Take validated settings over: at once when the pole pattern is the running one or in
        lock-step mode (the plant waits for the command); in real-time mode a new pole pattern is
        designed in the background (:meth:`take_over_redesign` applies it) and the rest at once."""
        if settings.spec == self.loop.settings.spec or settings.mode == "lockstep":
            self.loop.retune(settings)
            self._redesign = None  # a pending design of another pole pattern is superseded
            return
        self.loop.retune(replace(settings, spec=self.loop.settings.spec))  # reference and steps at once
        pending = self._redesign
        if pending is not None and pending[0].spec == settings.spec:
            future = pending[1]
        else:
            future = self._designer.submit(build_strategy, settings)
        self._redesign = (settings, future)
        self.get_logger().info(f"designing for poles {settings.spec} in the background; the loop keeps "
                               f"poles {self.loop.settings.spec} until the design is ready")

    def take_over_redesign(self) -> bool:
        """Apply a finished background design (between two samples); True if the loop was retuned.

        A design that failed is logged as an error and the loop keeps its running pole pattern.
        """
        if self._redesign is None or not self._redesign[1].done():
            return False
        settings, future = self._redesign
        self._redesign = None
        try:
            self.loop.retune(settings, future.result())
        except ControllerConfigError as exc:
            self.get_logger().error(f"design for poles {settings.spec} failed, the loop keeps poles "
                                    f"{self.loop.settings.spec}: {exc}")
            return False
        self.get_logger().info(f"poles {settings.spec} taken over")
        return True

    def _on_reference(self, msg: Float64) -> None:
        t = self.loop.time_of(self.loop.last_stamp) if self.loop.last_stamp is not None else 0.0
        if not math.isfinite(msg.data):
            self.get_logger().warn(f"ignored non-finite reference {msg.data!r}")
            return
        self.loop.reference.set_topic(msg.data, t)

    def _on_sample(self, msg: JointState) -> None:
        if self.finished.is_set():
            return
        try:
            idx = list(msg.name).index("pendulum")
            theta = float(msg.position[idx])
        except (ValueError, IndexError, ContractError):
            self.bad_samples += 1
            self.get_logger().warn(f"sample without pendulum position: names {list(msg.name)}",
                                   throttle_duration_sec=1.0)
            return
        stamp = stamp_to_ns(msg.header.stamp.sec, msg.header.stamp.nanosec)
        needs = self.loop.needs
        omega = math.nan
        if "omega" in needs:
            try:
                omega = float(msg.velocity[list(msg.name).index("motor")])
            except (ValueError, IndexError):
                pass
        if "i_a" not in needs:
            self._control(stamp, theta, omega)
            return
        self._pending_js[stamp] = (theta, omega)
        self._pair(stamp)

    def _on_armature(self, msg: BatteryState) -> None:
        stamp = stamp_to_ns(msg.header.stamp.sec, msg.header.stamp.nanosec)
        self._pending_arm[stamp] = float(msg.current)
        self._pair(stamp)

    def _pair(self, stamp: int) -> None:
        if stamp in self._pending_js and stamp in self._pending_arm:
            theta, omega = self._pending_js.pop(stamp)
            self._control(stamp, theta, omega, self._pending_arm.pop(stamp))
        for d in (self._pending_js, self._pending_arm):  # forget unpaired halves of old samples
            while len(d) > PAIR_BUFFER:
                d.pop(min(d))

    def _control(self, stamp: int, theta: float, omega: float = math.nan, i_a: float = math.nan) -> None:
        realtime = self.settings.mode == "realtime"
        if self._matched_ns is None:
            if self._pub_duty.get_subscription_count() < self.min_subscribers:
                return  # not every reader would hear the command; the lock-step plant re-publishes while idle
            self._matched_ns = time.monotonic_ns()
        if realtime and time.monotonic_ns() - self._matched_ns < MATCH_GRACE_NS:
            return
        recv = self.get_clock().now().nanoseconds if realtime else None
        if self._redesign is not None:
            self.take_over_redesign()
        repeat = stamp == self.loop.last_stamp
        if (repeat and not realtime
                and not self._repeats.answer_again(self._pub_duty.get_subscription_count())):
            # the answer reached every reader matched then; a second one would advance the plant twice
            self.loop.repeats += 1
            return
        duty = self.loop.on_sample(stamp, theta, omega, i_a, recv)
        if duty is None:
            return
        if self.loop.clamp_event is not None:
            req, used = self.loop.clamp_event
            self.get_logger().warn(
                f"reference {req:.4g} rad is outside the rig's reach [0, {self.loop.reach:.4g}] rad (holding "
                f"it would need a duty cycle above {1.0 - REACH_DUTY_MARGIN:g}): clamped to {used:.4g} rad, "
                "flagged in the signals (reference_clamped)")
        if self.loop.detune_event is not None:
            before, after = self.loop.detune_event
            self.get_logger().warn(
                "the duty cycle limit-cycles (a drive lag or delay the rig file does not know?): motor "
                + (f"speed loop detuned from {before:.3g} to {after:.3g} rad/s" if after < before else
                   f"speed loop already at its floor of {after:.3g} rad/s, not detuned further"))
        if not realtime:  # read before publishing: a reader matched after this read is served again
            self._repeats.published(self._pub_duty.get_subscription_count())
        self._pub_duty.publish(duty_msg(duty))
        if realtime and not repeat:
            self.loop.mark_published(self.get_clock().now().nanoseconds)
        self.published += 1
        self._pub_sig.publish(Float64MultiArray(data=[float(x) for x in self.loop.last_signals]))
        if self.loop.done():
            self.finished.set()

    def shutdown(self) -> None:
        """Publish duty 0 and write the trace (if configured)."""
        try:
            self._pub_duty.publish(duty_msg(0.0))
            wait_acknowledged(self, [self._pub_duty])
        except Exception as exc:  # context may already be gone
            self.get_logger().warn(f"could not publish duty 0 on shutdown: {exc}")
        if self.settings.trace:
            self.loop.write_trace(self.settings.trace)
        self.get_logger().info(
            f"summary: commands={self.published} samples={len(self.loop.rows)} repeats={self.loop.repeats} "
            f"stale={self.loop.stale} bad_samples={self.bad_samples} "
            f"nan_inputs={self.loop.strategy.nan_count}"
        )


def _warm_up(settings: Any, n: int = 200) -> None:
    """Run a throw-away copy of the loop on synthetic samples so the first real samples do not pay
    first-call costs (lazy imports, caches); the node's own loop is untouched."""
    loop = ControllerLoop(settings)
    for k in range(n):
        loop.on_sample(k * 2_048_000, 0.001 * k, 100.0, 0.3, k * 2_048_000 + 100_000)
        loop.mark_published(k * 2_048_000 + 200_000)
    Float64MultiArray(data=[float(x) for x in loop.last_signals])
    duty_msg(0.0)


def _rt_priority(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 99:
        raise ControllerConfigError(f"rt_priority = {value!r}; expected an integer in 0..99 (0 = off)")
    return value


def _min_subscribers(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ControllerConfigError(f"min_subscribers = {value!r}; expected an integer >= 1")
    return value


def _lock_memory(node: Node) -> None:
    """``mlockall(MCL_CURRENT | MCL_FUTURE)``: no page faults on code or data evicted by memory reclaim."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.mlockall(3) != 0:
            node.get_logger().warn(f"mlockall failed (errno {ctypes.get_errno()}); memory not locked")
    except (OSError, AttributeError) as exc:  # pragma: no cover - non-Linux
        node.get_logger().warn(f"mlockall unavailable: {exc}")


def _set_rt_priority(node: ControllerNode) -> None:
    if node.rt_priority <= 0:
        return
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(node.rt_priority))
        node.get_logger().info(f"executor thread runs with SCHED_FIFO priority {node.rt_priority}")
        gc.collect()
        gc.freeze()
        gc.disable()
        _lock_memory(node)
    except (OSError, AttributeError) as exc:
        node.get_logger().warn(f"rt_priority = {node.rt_priority}: cannot set SCHED_FIFO ({exc})")


def main(args: list[str] | None = None) -> int:
    """Entry point of ``controller``; returns the exit status (2 = bad parameter).

    Started and stopped by :func:`aeropend_sim.ros.node_shell.run_node` (SIGINT/SIGTERM stop, duty 0
    and trace on exit), with the executor chosen by the ``executor`` parameter.
    """
    def make() -> ControllerNode:
        node = ControllerNode()
        _set_rt_priority(node)
        return node

    return run_node(NODE_NAME, args, make, (ControllerConfigError,), ControllerNode.shutdown,
                    done=lambda node: node.finished.is_set(),
                    make_executor=lambda node: make_executor(node.executor_kind), usage=USAGE)

if __name__ == "__main__":
    sys.exit(main())
