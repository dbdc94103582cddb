"""Simulated aeropendulum plant node ``aeropend_sim`` (console script ``sim_node``).

Publishes the contract sample topics (``/aeropend/joint_states`` + ``/aeropend/armature``, same
stamp, see :mod:`aeropend_sim.contract`) from a :class:`~aeropend_sim.simulation.PlantStepper`
and subscribes the duty-cycle command ``/aeropend/duty_cycle``. A drop-in replacement for the
hardware bridge.

Usage::

    sim_node --ros-args -p rig:=thesis_rig -p mode:=realtime
    sim_node --ros-args -p mode:=lockstep -p seed:=3 -p noise:=true \\
        -p "effects:=[dead_zone=true,armature_inductance=quasi_static]"

Parameters: :data:`PARAMETERS` (also printed by ``sim_node --help``).

Live parameters (``ros2 param set /aeropend_sim noise true``): ``effects`` and ``noise``; the
running plant continues from its state with the new rig (an input-delay change is refused: it
sizes the command delay line). The others are read-only (set them at start-up).

Invalid parameters log an error naming the value and exit with status 2. Invalid commands
(NaN, outside [0, 1]) are rejected, counted and logged (throttled); the plant keeps running.
All logic that is not rclpy lives in :mod:`aeropend_sim.sim_core`.
"""

from __future__ import annotations

import ctypes
import gc
import os
import sys
import threading
import time
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import BatteryState, JointState
from std_msgs.msg import Float64

from aeropend_sim.contract import REL_ARMATURE, REL_DUTY_CYCLE, REL_JOINT_STATES, TOPIC_CLOCK, Sample
from aeropend_sim.ros.node_shell import (
    declare_parameter_table,
    executor_kind,
    make_executor,
    run_node,
    wait_acknowledged,
)
from aeropend_sim.ros.node_usage import NodeParameter, NodeUsage, contract_topic
from aeropend_sim.ros.ros_contract import (
    CLOCK_QOS,
    CLOCK_QOS_LOCKSTEP,
    COMMAND_QOS,
    SAMPLE_QOS,
    SAMPLE_QOS_LOCKSTEP,
    sample_to_msgs,
    to_time,
)
from aeropend_sim.sim_core import (
    DEFAULT_COMMAND_TIMEOUT_S,
    DEFAULT_RIG,
    LOCKSTEP_REPUBLISH_S,
    CommandHold,
    CommandTiming,
    PlantClock,
    RealtimeSchedule,
    SimConfigError,
    make_settings,
)

NODE_NAME = "aeropend_sim"
#: Minimum interval [s] between two log lines of the same repeated warning.
LOG_THROTTLE_S = 1.0

#: The node parameters (declared from this table, printed by ``--help``); all dynamically typed and
#: validated by :func:`aeropend_sim.sim_core.make_settings` so errors name the value and what was
#: expected. Live: the effect switches and the sensor noise (the plant continues from its state with
#: the new rig; an input-delay change is refused: it sizes the command delay line); the others fix
#: the rig, the run and the process set-up and are read-only.
PARAMETERS: tuple[NodeParameter, ...] = (
    NodeParameter("rig", "str", DEFAULT_RIG, "", "shipped rig name or path to a rig YAML file"),
    NodeParameter("effects", "str[]", None, "",
                  "effect-switch overrides name=value, e.g. "
                  "[dead_zone=true,armature_inductance=quasi_static]",
                  live=True),
    NodeParameter("mode", "str", "realtime", "",
                  "realtime: one sample every rig.sample_period of wall time (dedicated thread, absolute "
                  "deadlines), stamps start + k*T_s in ROS time, latest command zero-order held, duty -> 0 "
                  "after command_timeout without command, best-effort samples; lockstep: sample 0 once "
                  "min_subscribers subscriptions are matched on joint_states (re-published every 0.5 s "
                  "while idle), then exactly one sample per valid command, stamped with simulated time "
                  "k*T_s, /clock published, reliable keep-all samples"),
    NodeParameter("seed", "int", 0, "", "seed of the measurement noise (>= 0)"),
    NodeParameter("initial_theta", "float", None, "rad", "initial angle (unset: hanging down)"),
    NodeParameter("initial_state", "float[]", None, "",
                  "initial state [theta rad, theta_dot rad/s, i_a A, omega_rotor rad/s, tau_f]; wins over "
                  "initial_theta"),
    NodeParameter("noise", "bool", None, "",
                  "sensor noise and quantisation on/off (unset: as in the rig file)", live=True),
    NodeParameter("command_timeout", "float", DEFAULT_COMMAND_TIMEOUT_S, "s",
                  "realtime: duty -> 0 after this long without command"),
    NodeParameter("publish_clock", "bool", None, "",
                  "publish /clock (unset: true in lockstep, false in realtime)"),
    NodeParameter("frame_id", "str", "aeropend", "", "header.frame_id of the sample messages"),
    NodeParameter("min_subscribers", "int", 1, "",
                  "lockstep: subscriptions matched on joint_states before sample 0 is published (besides "
                  "every subscriber of either sample topic the graph already shows); a subscriber that "
                  "matches later misses the samples before it, so a lock-step graph names its consumers "
                  "here (the main job: excitation and recorder, 2); a command that arrives earlier starts "
                  "the run anyway"),
    NodeParameter("min_clock_subscribers", "int", 0, "",
                  "lockstep: subscriptions matched on /clock before sample 0 is published (besides every "
                  "/clock subscriber the graph already shows); a recorder of /clock whose reader is "
                  "announced after its sample readers would otherwise miss the first ticks (the main "
                  "job: 1)"),
    NodeParameter("rt_priority", "int", 0, "",
                  "realtime: SCHED_FIFO priority 1-99 of the sampler thread (needs CAP_SYS_NICE or an "
                  "rtprio limit, else a warning); the executor thread then runs at rt_priority - 1, the "
                  "cyclic garbage collector is switched off after start-up and memory is locked; 0 = "
                  "normal scheduling"),
    NodeParameter("timing_log", "str", "", "",
                  "realtime: .npz path for every sample instant and command receipt (the summary line adds "
                  "the sample -> command-receipt latency); empty = off"),
    NodeParameter("timing_capacity", "int", 1 << 18, "",
                  "realtime: samples (and commands) the timing log keeps (2^18 = 9 min at 488 Hz; 32 bytes "
                  "per entry)"),
    NodeParameter("executor", "str", "events", "",
                  "events: rclpy's C++ EventsExecutor (the executor thread holds the GIL only inside "
                  "callbacks, commands are received sooner, docs/data_plane.md); single: "
                  "SingleThreadedExecutor"),
)

#: ``sim_node --help``.
USAGE = NodeUsage(
    command="sim_node",
    node_name=NODE_NAME,
    summary="Simulated aeropendulum plant: publishes the contract samples (joint_states + armature, one "
            "stamp per sample) of a rig file's model and applies the duty-cycle commands it receives; a "
            "drop-in replacement for the hardware bridge.",
    topics=(contract_topic("publishes", REL_JOINT_STATES, "theta, theta_dot, omega_1, omega_2, applied duty"),
            contract_topic("publishes", REL_ARMATURE, "v_a [V], i_a [A], same stamp"),
            contract_topic("publishes", TOPIC_CLOCK, "simulated time (publish_clock)"),
            contract_topic("subscribes", REL_DUTY_CYCLE,
                           "duty cycle in [0, 1]; NaN / out of range rejected")),
    parameters=PARAMETERS,
    examples=("sim_node --ros-args -p rig:=thesis_rig -p mode:=realtime",
              "sim_node --ros-args -p mode:=lockstep -p seed:=3 -p noise:=true "
              "-p \"effects:=[dead_zone=true]\"",
              "ros2 param set /aeropend_sim noise false      # a live parameter"),
    notes="Exit status: 0 on SIGINT/SIGTERM, 2 on an invalid parameter (the message names the value), "
          "1 if the sampler fails.",
)


def _reduce_timer_slack() -> None:
    """Ask Linux for 1 µs timer slack on the calling thread (default 50 µs) to cut sleep jitter."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(29, 1000, 0, 0, 0)  # PR_SET_TIMERSLACK
    except (OSError, AttributeError):  # pragma: no cover - non-Linux
        pass


class SimPlantNode(Node):
    """rclpy shell of the simulated plant (see module docstring).

    Raises
    ------
    SimConfigError
        From the constructor if a parameter is invalid (the node is destroyed first).
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        raw = declare_parameter_table(self, PARAMETERS)
        self.timing_log = str(raw.pop("timing_log") or "")
        timing_capacity = raw.pop("timing_capacity")
        try:
            self.executor_kind = executor_kind(raw.pop("executor"), SimConfigError)
        except SimConfigError:
            self.destroy_node()
            raise
        try:
            self.settings = make_settings(**raw)
        except SimConfigError:
            self.destroy_node()
            raise
        self._raw = raw
        s = self.settings
        # the plant is built and its kernels loaded (0.5-1 s) before the node offers its topics: built
        # in the sampler thread, sample 0 was 0.5-0.7 s late (the stamps lagged wall time by that for
        # good) and the executor thread, starved meanwhile, applied a checker's first command up to
        # 0.5 s late (bench/repro/sim_start_stall.py)
        self.plant = PlantClock(s, origin_ns=0)
        self.plant.stepper.warm()
        lockstep = s.mode == "lockstep"
        sample_qos = SAMPLE_QOS_LOCKSTEP if lockstep else SAMPLE_QOS
        self._pub_js = self.create_publisher(JointState, REL_JOINT_STATES, sample_qos)
        self._pub_arm = self.create_publisher(BatteryState, REL_ARMATURE, sample_qos)
        clock_qos = CLOCK_QOS_LOCKSTEP if lockstep else CLOCK_QOS
        self._pub_clock = self.create_publisher(ClockMsg, TOPIC_CLOCK, clock_qos) if s.publish_clock else None
        timeout_ns = None if lockstep else round(s.command_timeout * 1e9)
        self.hold = CommandHold(timeout_ns)
        try:
            self.timing = CommandTiming(int(timing_capacity)) if self.timing_log and not lockstep else None
        except (SimConfigError, TypeError, ValueError) as exc:
            self.destroy_node()
            raise SimConfigError(
                f"timing_capacity = {timing_capacity!r}: expected an int >= 1 ({exc})") from exc
        self.published = 0
        self.republished = 0
        self.error: BaseException | None = None
        self.schedule: RealtimeSchedule | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._wait_timer: Any = None
        self._last_overrun = (0, 0)  # (sample, lateness [ns]) of the sampler's latest overrun
        self._reported = (0, 0)  # overruns and command timeouts already logged
        self._last_activity_ns = 0
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_subscription(Float64, REL_DUTY_CYCLE, self._on_command, COMMAND_QOS)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        over = ", ".join(f"{k}={v}" for k, v in s.effect_overrides.items()) or "none"
        self.get_logger().info(
            f"rig {s.rig.name!r}, mode {s.mode}, T_s = {s.period_s * 1e3:.3f} ms, seed {s.seed}, "
            f"x0 = {s.x0.tolist()}, effect overrides: {over}, publish_clock {s.publish_clock}"
        )

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Apply live parameters (``live`` in :data:`PARAMETERS`): the running plant continues from its
        state with the new rig (:meth:`PlantStepper.set_rig`); refused with the reason otherwise."""
        changes = {p.name: p.value for p in params}
        try:
            settings = make_settings(**{**self._raw, **changes})
            self.plant.stepper.set_rig(settings.rig)
        except (SimConfigError, ValueError) as exc:
            self.get_logger().warn(f"parameter change {changes} refused: {exc}")
            return SetParametersResult(successful=False, reason=str(exc))
        self._raw.update(changes)
        self.settings = settings
        over = ", ".join(f"{k}={v}" for k, v in settings.effect_overrides.items()) or "none"
        self.get_logger().info(f"parameters set {changes}: effect overrides {over}")
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ publishing
    def _publish(self, msgs: tuple[JointState, BatteryState], stamp_ns: int) -> None:
        if self._pub_clock is not None:
            self._pub_clock.publish(ClockMsg(clock=to_time(stamp_ns)))
        self._pub_js.publish(msgs[0])
        self._pub_arm.publish(msgs[1])

    def _msgs(self, sample: Sample) -> tuple[JointState, BatteryState]:
        return sample_to_msgs(sample, self.settings.frame_id)

    # ------------------------------------------------------------------ start / stop
    def start(self) -> None:
        """Publish sample 0 (lock-step) or start the real-time sampler thread."""
        if self.settings.mode == "lockstep":
            self._last_msgs = self._msgs(self.plant.last)
            self._waiting_since_ns = time.monotonic_ns()
            self._wait_timer = self.create_timer(0.005, self._start_when_matched, clock=self._steady)
        else:
            if self.settings.rt_priority > 0:  # the calling thread spins the executor (command receipt)
                self._set_priority(max(self.settings.rt_priority - 1, 1), "executor thread")
                gc.collect()  # no cyclic-GC pauses (milliseconds) in the real-time threads
                gc.freeze()
                gc.disable()
                self._lock_memory()
            self._thread = threading.Thread(target=self._run_realtime, name="aeropend_sampler", daemon=True)
            self._thread.start()
            self.create_timer(LOG_THROTTLE_S, self._report_sampler, clock=self._steady)

    def _report_sampler(self) -> None:
        """Log the sampler's new overruns and command timeouts, at most once a second.

        Runs on the executor thread, so the sampler's loop holds no logging code. It does not make
        the plant immune to a console nobody reads: rclpy's log call keeps the GIL while it writes,
        so a full stderr pipe freezes every thread of the process (docs/data_plane.md,
        ``bench/repro/unread_stderr.py``). Whoever starts the node must read its output (launch,
        a terminal, the main job's log files).
        """
        sched = self.schedule
        if sched is not None and sched.overruns != self._reported[0]:
            k, late = self._last_overrun
            self.get_logger().warn(
                f"sampler overruns: {sched.overruns - self._reported[0]} in the last {LOG_THROTTLE_S:g} s "
                f"(last: sample {k} {late / 1e6:.2f} ms late, > 1 period "
                f"{sched.period_ns / 1e6:.3f} ms; schedule re-anchored); overruns so far "
                f"{sched.overruns}, stamps now lag wall time by {sched.dropped_ns / 1e6:.1f} ms")
        if self.hold.timeouts != self._reported[1]:
            self.get_logger().warn(
                f"no duty command for {self.settings.command_timeout:g} s: duty -> 0 "
                f"(timeouts so far: {self.hold.timeouts})")
        self._reported = (sched.overruns if sched is not None else 0, self.hold.timeouts)

    def lockstep_publishers(self) -> list[Publisher]:
        """The writers a lock-step run must deliver whole, all reliable keep-all: the sample topics
        (joint_states, armature) and ``/clock`` when it is published (a ``/clock`` tick lost on the
        way and not yet repaired when the plant exited cut the main job's bag at tick 188 of 1101:
        docs/findings/data_plane.md)."""
        return [self._pub_js, self._pub_arm, *([self._pub_clock] if self._pub_clock is not None else [])]

    def _matched(self) -> tuple[int, int]:
        return self._pub_js.get_subscription_count(), self._pub_arm.get_subscription_count()

    def _start_when_matched(self) -> None:
        """Lock-step: publish sample 0 once the sample topics' subscribers are matched.

        ``joint_states`` needs ``min_subscribers`` matched subscriptions, and each sample topic and
        ``/clock`` at least as many as the ROS graph shows (a subscriber discovered but not yet
        matched would miss sample 0 and what follows until it matches: a recorder's /clock reader
        matched a moment after its sample reader lost the first ticks), ``/clock`` also
        ``min_clock_subscribers`` (a reader the graph does not show yet is not waited for: the main
        job's recorder announces its /clock reader after its sample readers, so a plant that matched
        the sample readers first would start without it and its bag would lose the first ticks; the
        one path found for a CI failure of the main job's /clock check, docs/findings/data_plane.md).
        """
        matched = self._matched()
        known = (self.count_subscribers(self._pub_js.topic_name),
                 self.count_subscribers(self._pub_arm.topic_name))
        need = (max(self.settings.min_subscribers, known[0]), known[1])
        clock = self._clock_matched()
        if matched[0] < need[0] or matched[1] < need[1] or clock[0] < clock[1]:
            self.get_logger().info(
                f"lock-step: waiting for subscriptions to match (joint_states {matched[0]} of {need[0]}, "
                f"armature {matched[1]} of {need[1]}, /clock {clock[0]} of {clock[1]}; "
                f"min_subscribers {self.settings.min_subscribers}, "
                f"min_clock_subscribers {self.settings.min_clock_subscribers})",
                throttle_duration_sec=2.0,
            )
            return
        self._publish_first_sample()

    def _clock_matched(self) -> tuple[int, int]:
        """(matched, needed) ``/clock`` subscriptions: at least ``min_clock_subscribers`` and every
        one the graph shows; (0, 0) when ``/clock`` is not published."""
        if self._pub_clock is None:
            return 0, 0
        return (self._pub_clock.get_subscription_count(),
                max(self.settings.min_clock_subscribers, self.count_subscribers(self._pub_clock.topic_name)))

    def _publish_first_sample(self) -> None:
        self._wait_timer.cancel()
        self._wait_timer = None
        self.get_logger().info("lock-step: sample 0 published (matched subscriptions: joint_states, "
                               f"armature {self._matched()}, /clock {self._clock_matched()[0]})")
        self._publish(self._last_msgs, self.plant.last.stamp_ns)
        self.published += 1
        self._last_activity_ns = time.monotonic_ns()
        self.create_timer(0.1, self._republish_if_idle, clock=self._steady)

    def stop(self) -> None:
        """Stop the sampler thread (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    # ------------------------------------------------------------------ commands
    def _on_command(self, msg: Float64) -> None:
        now = time.monotonic_ns()
        reason = self.hold.offer(msg.data, now)
        if reason is not None:
            self.get_logger().warn(
                f"rejected duty command {msg.data!r}: {reason} (rejected so far: {self.hold.rejected})",
                throttle_duration_sec=LOG_THROTTLE_S,
            )
            return
        if self.timing is not None:
            self.timing.on_command(now, float(msg.data))
        if self.settings.mode == "lockstep":
            if self._wait_timer is not None:
                self.get_logger().warn(f"lock-step: command before sample 0 (matched {self._matched()}); "
                                       "starting the run")
                self._publish_first_sample()
            sample = self.plant.advance(self.hold.value(now))
            self._last_msgs = self._msgs(sample)
            self._publish(self._last_msgs, sample.stamp_ns)
            self.published += 1
            self._last_activity_ns = time.monotonic_ns()

    def _republish_if_idle(self) -> None:
        now = time.monotonic_ns()
        if now - self._last_activity_ns >= LOCKSTEP_REPUBLISH_S * 1e9:
            self._publish(self._last_msgs, self.plant.last.stamp_ns)
            self.republished += 1
            self._last_activity_ns = now

    # ------------------------------------------------------------------ real-time sampler
    def _set_priority(self, prio: int | None = None, what: str = "sampler thread") -> None:
        prio = self.settings.rt_priority if prio is None else prio
        if prio <= 0:
            return
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))  # 0 = this thread
            self.get_logger().info(f"{what} runs with SCHED_FIFO priority {prio}")
        except (OSError, AttributeError) as exc:
            self.get_logger().warn(
                f"rt_priority = {prio}: cannot set SCHED_FIFO ({exc}); {what} uses normal scheduling"
            )

    def _lock_memory(self) -> None:
        """``mlockall(MCL_CURRENT | MCL_FUTURE)``: no page faults on memory evicted by reclaim."""
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.mlockall(3) != 0:
                self.get_logger().warn(f"mlockall failed (errno {ctypes.get_errno()}); memory not locked")
        except (OSError, AttributeError) as exc:  # pragma: no cover - non-Linux
            self.get_logger().warn(f"mlockall unavailable: {exc}")

    def _run_realtime(self) -> None:
        _reduce_timer_slack()
        self._set_priority()
        period_ns = round(self.settings.period_s * 1e9)
        lead_ns = 10 * period_ns
        mono0 = time.monotonic_ns()
        ros0 = self.get_clock().now().nanoseconds
        # ROS time of sample 0 = ROS time now + lead (mapped once, here).
        plant = self.plant
        plant.start_at(ros0 + lead_ns)
        sched = RealtimeSchedule(period_ns, mono0 + lead_ns)
        self.schedule = sched
        msgs = self._msgs(plant.last)
        stamp = plant.last.stamp_ns
        k = 0
        log = self.get_logger()
        try:
            while not self._stop.is_set():
                deadline = sched.deadline_ns(k)
                while (rem := deadline - time.monotonic_ns()) > 0:
                    time.sleep(rem * 1e-9)
                now = time.monotonic_ns()
                overruns = sched.overruns
                late = sched.on_wake(k, now)
                if sched.overruns != overruns:
                    self._last_overrun = (k, late)  # logged by _report_sampler, never from here
                if self.timing is not None:
                    self.timing.on_sample(stamp, now)
                self._publish(msgs, stamp)
                self.published += 1
                sample = plant.advance(self.hold.value(now))
                msgs, stamp = self._msgs(sample), sample.stamp_ns
                k += 1
        except Exception as exc:
            if self._stop.is_set() or not self.context.ok():
                return  # shutting down: publishers may already be gone
            self.error = exc
            log.error(f"real-time sampler stopped at sample {k}: {type(exc).__name__}: {exc}")

    # ------------------------------------------------------------------ report
    def summary(self) -> str:
        """One-line run summary (``key=value`` pairs, parsed by the benchmark)."""
        parts = [
            f"mode={self.settings.mode}", f"samples={self.published}",
            f"republished={self.republished}", f"commands={self.hold.accepted}",
            f"rejected={self.hold.rejected}", f"timeouts={self.hold.timeouts}",
        ]
        if self.schedule is not None:
            sch = self.schedule
            parts += [f"overruns={sch.overruns}", f"max_late_ms={sch.max_lateness_ns / 1e6:.3f}",
                      f"dropped_ms={sch.dropped_ns / 1e6:.3f}"]
        if self.timing is not None:
            parts += [f"{k}={v:.3f}" if k.endswith("_ms") else f"{k}={v:.0f}"
                      for k, v in self.timing.summary().items()]
        return "summary: " + " ".join(parts)


def main(args: list[str] | None = None) -> int:
    """Entry point of ``sim_node``; returns the process exit status (2 = bad parameter)."""
    # Let the sampler thread take the GIL within 0.5 ms of its deadline (default 5 ms).
    sys.setswitchinterval(5e-4)

    def make() -> SimPlantNode:
        node = SimPlantNode()
        node.start()
        return node

    def cleanup(node: SimPlantNode) -> None:
        node.stop()
        if node.settings.mode == "lockstep":  # reliable samples: the recorder must have them all
            wait_acknowledged(node, node.lockstep_publishers())
        node.get_logger().info(node.summary())
        if node.timing is not None:
            node.timing.write(node.timing_log)

    return run_node(NODE_NAME, args, make, (SimConfigError,), cleanup,
                    make_executor=lambda node: make_executor(node.executor_kind),
                    done=lambda node: node.error is not None,
                    exit_status=lambda node: 1 if node.error is not None else 0, usage=USAGE)

if __name__ == "__main__":
    sys.exit(main())
