"""Hardware bridge node ``aeropend_bridge`` (console script ``bridge``).

Connects to the acquisition firmware over a serial port (``firmware/PROTOCOL.md``) and makes
the real rig look exactly like the simulated plant (:mod:`aeropend_sim.ros.sim_node`): publishes
``/aeropend/joint_states`` + ``/aeropend/armature`` (same stamp per sample, SI units, sensor
data QoS) and, while active, subscribes ``/aeropend/duty_cycle`` (reliable). Stamps come from
the MCU clock mapped to ROS time (:class:`~aeropend_bridge.bridge_core.ClockMapper`).

A managed (lifecycle) node: ``configure`` opens the port and recognises the firmware,
``activate`` enables the duty output, ``deactivate`` drives 0 and stops, ``cleanup`` closes the
port (see :class:`BridgeNode`). With ``autostart`` (default true) the plain command configures
and activates itself, so a lab without a lifecycle manager runs it as before.

Usage::

    bridge --ros-args -p port:=/dev/ttyACM0 -p rig:=thesis_rig -p theta_offset:=3.1416
    bridge --ros-args -p port:=/dev/ttyACM0 -p autostart:=false   # then:
    ros2 lifecycle set /aeropend_bridge configure
    ros2 lifecycle set /aeropend_bridge activate

Parameters: :data:`PARAMETERS` (also printed by ``bridge --help``).

Every parameter but ``autostart`` may be set while the node is *unconfigured* and applies at the
next ``configure``; while configured ``ros2 param set`` is refused with that reason.
Invalid parameters fail ``configure`` with a message naming the value (plain command: exit
status 2); no firmware on the port fails it too (exit status 1). NaN / out-of-range duty
commands are rejected, counted and logged (throttled). On deactivate and on shutdown the motor
is switched off (duty 0 sent, output disabled) before anything else.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from sensor_msgs.msg import BatteryState, JointState
from std_msgs.msg import Float64

from aeropend_bridge.bridge_core import (
    Backoff,
    BridgeConfigError,
    BridgeStats,
    Calibration,
    ClockMapper,
    CommandWatchdog,
    FirmwareError,
    FirmwareHandshake,
    RateMeter,
    SequenceTracker,
    firmware_trips_since,
)
from aeropend_bridge.family import CommandMap, check_firmware, legacy_hello, read_rig_hardware
from aeropend_bridge.protocol import (
    BAUD,
    CH_INDEX,
    Enable,
    HelloFrame,
    HelloRequest,
    Rate,
    SampleFrame,
    StatusFrame,
)
from aeropend_bridge.serial_link import SerialLink
from aeropend_sim.contract import REL_ARMATURE, REL_DUTY_CYCLE, REL_JOINT_STATES
from aeropend_sim.params import RigFileError, load_rig
from aeropend_sim.ros.node_shell import declare_parameter_table, run_node
from aeropend_sim.ros.node_usage import NodeParameter, NodeUsage, TopicUse, contract_topic
from aeropend_sim.ros.ros_contract import COMMAND_QOS, SAMPLE_QOS, sample_to_msgs

NODE_NAME = "aeropend_bridge"
TOPIC_DIAGNOSTICS = "/diagnostics"
LOG_THROTTLE_S = 1.0
#: While inactive: how often [s] the bridge looks for (and warns about) duty-command publishers
IDLE_WARN_PERIOD_S = 5.0
#: Nominal firmware sample rate [Hz]: 16 MHz / 64 / 510.
NOMINAL_RATE_HZ = 16e6 / 64 / 510
#: How long configure waits for the firmware's HELLO after recognising its samples [s]: more than
#: the 0.52 s between the HELLO frames the firmware sends unasked (after every STATUS frame).
HELLO_WAIT_S = 0.6

#: The node parameters (declared from this table, printed by ``--help``). Every one but
#: ``autostart`` may be set while the node is *unconfigured* and applies at the next ``configure``
#: (``live``; while configured, ``ros2 param set`` is refused with that reason).
PARAMETERS: tuple[NodeParameter, ...] = (
    NodeParameter("autostart", "bool", True, "",
                  "configure and activate at start-up (plain command, no lifecycle manager); false leaves "
                  "the node unconfigured for `ros2 lifecycle set` or a lifecycle manager"),
    NodeParameter("port", "str", "/dev/ttyACM0", "",
                  "serial device (a /dev/serial/by-id/... link survives re-enumeration)", live=True),
    NodeParameter("baud", "int", BAUD, "bit/s", "line rate", live=True),
    NodeParameter("rig", "str", "thesis_rig", "",
                  "rig name or YAML path: ADC LSBs from its sensors, motor.gear_ratio", live=True),
    NodeParameter("theta_offset", "float", 0.0, "rad", "angle read with the rod hanging down (theta = 0 "
                  "there)", live=True),
    NodeParameter("command_timeout", "float", 0.1, "s",
                  "duty 0 is on the wire at most this long after the last valid command", live=True),
    NodeParameter("keepalive_period", "float", 0.02, "s",
                  "re-send period of the current duty (duty 0 while configured but inactive; feeds the "
                  "firmware's 250 ms watchdog); must be < command_timeout / 2", live=True),
    NodeParameter("rate_divider", "int", 1, "",
                  "the firmware sends a sample every rate_divider PWM periods (1 = 490 Hz)", live=True),
    NodeParameter("diagnostics_period", "float", 1.0, "s", "period of /diagnostics", live=True),
    NodeParameter("backoff_initial", "float", 0.05, "s",
                  "first reconnection delay after the port vanished (doubling)", live=True),
    NodeParameter("backoff_max", "float", 2.0, "s", "largest reconnection delay", live=True),
    NodeParameter("frame_id", "str", "aeropend", "", "header.frame_id of the sample messages", live=True),
    NodeParameter("handshake_timeout", "float", 3.0, "s",
                  "configure fails unless the port opens and the protocol-1 firmware is recognised within "
                  "this time (opening the port resets a Mega: its boot loader runs first)", live=True),
)

#: Parameters read by ``configure`` (settable while unconfigured).
CONFIGURE_PARAMETERS = frozenset(p.name for p in PARAMETERS if p.live)

#: ``bridge --help``.
USAGE = NodeUsage(
    command="bridge",
    node_name=NODE_NAME,
    summary="Hardware bridge: talks to the acquisition firmware over a serial port and makes the real rig "
            "look exactly like the simulated plant (same topics, types, units, stamps). A managed "
            "(lifecycle) node: configure opens the port and recognises the firmware, activate enables "
            "the duty output; with autostart (default) it does both at start-up.",
    topics=(contract_topic("publishes", REL_JOINT_STATES, "theta, omega_1, omega_2, applied duty; MCU "
                           "clock mapped to ROS time"),
            contract_topic("publishes", REL_ARMATURE, "v_a [V], i_a [A], same stamp"),
            TopicUse("publishes", TOPIC_DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray",
                     "serial link: rate, lost frames, CRC errors, watchdog trips"),
            contract_topic("subscribes", REL_DUTY_CYCLE, "duty cycle in [0, 1]; NaN / out of range "
                           "rejected")),
    parameters=PARAMETERS,
    examples=("bridge --ros-args -p port:=/dev/ttyACM0 -p rig:=thesis_rig -p theta_offset:=3.1416",
              "bridge --ros-args -p port:=/dev/ttyACM0 -p autostart:=false   # then:",
              "ros2 lifecycle set /aeropend_bridge configure",
              "ros2 lifecycle set /aeropend_bridge activate"),
    notes="Parameters marked live may be set while the node is unconfigured and apply at the next "
          "configure. Exit status: 0 on SIGINT/SIGTERM, 2 on an invalid parameter, 1 when no "
          "protocol-1 firmware answers on the port. The motor is switched off on deactivate and on "
          "shutdown before anything else.",
)


def _positive(name: str, value: Any) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise BridgeConfigError(f"parameter {name} = {value!r} is not a number") from None
    if not (math.isfinite(v) and v > 0):
        raise BridgeConfigError(f"parameter {name} = {value!r} must be a finite positive number")
    return v


class BridgeNode(LifecycleNode):
    """rclpy shell of the hardware bridge, a managed (lifecycle) node (see module docstring).

    Transitions (``ros2 lifecycle set /aeropend_bridge <transition>``):

    * ``configure``: validate the parameters, open the port and recognise the firmware from its
      sample stream (:class:`~aeropend_bridge.bridge_core.FirmwareHandshake`) within
      ``handshake_timeout``, read its HELLO and refuse a firmware of another family or sensor
      than the rig file's (:func:`~aeropend_bridge.family.check_firmware`); the output is switched
      off (ENABLE 0, duty 0 or the ESC's zero-throttle pulse).
      ``/diagnostics`` runs from here on. Fails (state stays *unconfigured*, port closed) with
      the reason logged.
    * ``activate``: ENABLE 1, the duty-command subscription is created and its commands forwarded
      (duty 0 until the first one), keep-alives feed the firmware watchdog, samples are published.
    * ``deactivate``: duty 0 on the wire, ENABLE 0, the subscription destroyed (while inactive
      a duty-command publisher is warned about every 5 s), samples no longer
      published (the port stays open, diagnostics continue).
    * ``cleanup``: close the port and drop publishers, subscription and timers.
    * ``shutdown`` (from any state, also on SIGINT/SIGTERM): motor off, port closed.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.autostart = bool(declare_parameter_table(self, PARAMETERS)["autostart"])
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()  # duty sends from the executor and the link thread
        self._last_send_ns = 0
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._active = False
        #: the duty-command subscription: it exists only while active (:meth:`on_activate`)
        self._command_sub: Any = None
        self._idle_publishers_checked_ns = 0
        self._finalized = False
        self.link: SerialLink | None = None
        self._pub_js: Any = None
        self._pub_arm: Any = None
        self._pub_diag: Any = None
        self._entities: list[Any] = []
        self._transition_error: Exception | None = None
        self._recognised = threading.Event()
        self._hello_seen = threading.Event()
        self.hello: HelloFrame | None = None
        self._last_sample: SampleFrame | None = None

    # ------------------------------------------------------------------ parameters
    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        configured = [p.name for p in params if p.name in CONFIGURE_PARAMETERS]
        if self.link is not None and configured:
            names = ", ".join(configured)
            return SetParametersResult(
                successful=False,
                reason=f"{names} apply at configure: the bridge is configured; run the cleanup "
                       "transition first, set the parameter, then configure again")
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Configure and activate (``autostart``); raise the reason if either fails.

        Raises
        ------
        BridgeConfigError
            A parameter is invalid.
        FirmwareError
            The port cannot be opened or carries no protocol-1 firmware.
        """
        for step in (self.trigger_configure, self.trigger_activate):
            if step() != TransitionCallbackReturn.SUCCESS:
                exc = self._transition_error or FirmwareError("lifecycle transition failed")
                self.destroy_node()
                raise exc

    def _transition(self, name: str, action: Callable[[], None]) -> TransitionCallbackReturn:
        self._transition_error = None
        try:
            action()
        except (BridgeConfigError, RigFileError, FirmwareError) as exc:
            self._transition_error = exc if not isinstance(exc, RigFileError) else BridgeConfigError(str(exc))
            self.get_logger().error(f"{name} failed: {exc}")
            self._release()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Validate parameters, open the port, recognise the firmware; output off."""
        return self._transition("configure", self._do_configure)

    def _do_configure(self) -> None:
        p = {name: self.get_parameter(name).value for name in CONFIGURE_PARAMETERS}
        self._configure(p)
        self._pub_js = self.create_lifecycle_publisher(JointState, REL_JOINT_STATES, SAMPLE_QOS)
        self._pub_arm = self.create_lifecycle_publisher(BatteryState, REL_ARMATURE, SAMPLE_QOS)
        self._pub_diag = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self._entities = [
            self.create_timer(self.keepalive_s, self._keepalive, clock=self._steady),
            self.create_timer(self.diag_period_s, self._publish_diagnostics, clock=self._steady),
        ]
        self._recognised.clear()
        self.link = SerialLink(self.port, self._on_frame, baud=self.baud,
                               clock_ns=lambda: self.get_clock().now().nanoseconds,
                               on_event=self._on_link_event, on_connect=self._on_connect,
                               backoff=self.backoff)
        self._decoder = self.link.decoder
        self.link.start()
        if not self.link.wait_connected(self.handshake_timeout_s):
            raise FirmwareError(f"cannot open {self.port} within {self.handshake_timeout_s:g} s "
                                f"({self._last_link_event or 'no reply'})")
        if not self._recognised.wait(self.handshake_timeout_s):
            s = self.link.decoder.stats
            h = self.handshake
            raise FirmwareError(
                f"no aeropend protocol-1 firmware on {self.port} within {self.handshake_timeout_s:g} s: "
                f"{h.frames} sample frames, longest consistent run {h.longest} of {h.needed}; "
                f"{s.bytes} bytes read, {s.crc_errors} CRC errors, {s.errors} framing errors "
                "(wrong baud rate, another sketch, or the board still booting?)")
        self._check_family()
        self.get_logger().info(
            f"configured: port {self.port} at {self.baud} baud, aeropend firmware recognised "
            f"({self.handshake.longest} consistent sample frames), rig {self.rig_name!r}, theta_offset "
            f"{self.cal.theta_offset:g} rad, command_timeout {self.command_timeout_s:g} s; output off")

    def _check_family(self) -> None:
        """Wait for the firmware's HELLO (a protocol-1 firmware has none: H-bridge, ADC or SSI angle)
        and refuse a firmware that does not drive or measure what the rig file says; nothing has
        been armed yet (output off since the connection)."""
        if self._hello_seen.wait(HELLO_WAIT_S):
            hello, how = self.hello, "announced"
        else:
            hello, how = legacy_hello(self._last_sample), "protocol 1, no HELLO"  # type: ignore[arg-type]
        assert hello is not None
        check_firmware(self.hw, hello, self.theta_quantum or None)
        if not self.theta_quantum:
            if hello.sensor_name == "pot":
                raise BridgeConfigError(f"rig {self.rig_name!r} states no sensors.theta_quantum: the "
                                        "potentiometer's angle per ADC count must be stated [rad]")
            self.cal = dataclasses.replace(self.cal, theta_lsb=2 * math.pi / hello.counts_per_rev)
        if 2 * self.keepalive_s * 1e3 >= hello.silence_ms:
            raise BridgeConfigError(
                f"keepalive_period {self.keepalive_s:g} s is too slow for the firmware's "
                f"{hello.silence_ms} ms command watchdog (must be below half of it)")
        self.firmware = hello
        self.cal = dataclasses.replace(self.cal, homing=hello.has(CH_INDEX))
        esc = (f", ESC {hello.frame_hz} Hz {hello.pulse_min_us}-{hello.pulse_max_us} µs, arming "
               f"{hello.arm_ms} ms" if hello.actuator_name == "esc" else "")
        self.get_logger().info(
            f"firmware ({how}): actuator {hello.actuator_name}, angle {hello.sensor_name} "
            f"({hello.counts_per_rev} counts/rev), channels 0x{hello.channels:02x}, watchdog "
            f"{hello.silence_ms} ms{esc}")

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Enable the H-bridge output and subscribe to duty commands (duty 0 until the first one).

        The subscription is created here and destroyed on deactivate, so no command published while
        the bridge was inactive can be applied: a new volatile reader receives only what is
        published after it matched. Filtering an always-on subscription in its callback did not
        hold: rclpy's executor takes one message per subscription per wait and serves a ready
        subscription before a ready service, so commands queued beside the activate request were
        taken after it; and a reliable command lost by a loaded host comes again at the writer's
        next heartbeat, seconds later (``bench/repro/bridge_queued_command.py``).
        """
        def action() -> None:
            self.watchdog.disarm()  # no command from before the activation is applied
            self._active = True
            self._command_sub = self.create_subscription(Float64, REL_DUTY_CYCLE, self._on_command,
                                                         COMMAND_QOS)
            self.link.send(Enable(True))  # type: ignore[union-attr]
            self._send_duty(0.0)
            self.get_logger().info("active: duty output enabled")
        ret = self._transition("activate", action)
        return super().on_activate(state) if ret == TransitionCallbackReturn.SUCCESS else ret

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Duty 0 on the wire, output disabled, the duty-command subscription destroyed."""
        self._motor_off()
        self._unsubscribe()
        self._idle_publishers_checked_ns = 0  # warn at once if a controller still publishes
        self.get_logger().info("inactive: duty 0 sent, output disabled")
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Close the port; drop publishers, subscription and timers."""
        self._release()
        self.get_logger().info(f"unconfigured: {self.port} closed")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Motor off (if active), port closed."""
        self._release()
        self._finalized = True
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """An unexpected error in a transition: motor off, port closed, back to unconfigured."""
        self.get_logger().error("error in a lifecycle transition: motor off, port closed")
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def _motor_off(self) -> None:
        """Duty 0 (three times, in case one frame is lost), then ENABLE 0; stop forwarding."""
        self._active = False
        if self.link is None:
            return
        for _ in range(3):
            self.link.send(self.cmap.off())
            time.sleep(0.005)
        self.link.send(Enable(False))

    def _unsubscribe(self) -> None:
        """Destroy the duty-command subscription, if there is one."""
        sub, self._command_sub = self._command_sub, None
        if sub is not None:
            self.destroy_subscription(sub)

    def _release(self) -> None:
        """Motor off if the port is open, close it, destroy the configured entities."""
        link, was_active = self.link, self._active
        if link is not None and was_active:
            self._motor_off()
        self._active = False
        self._unsubscribe()
        if link is not None:
            link.stop()
            self.link = None
        for entity in self._entities:
            if hasattr(entity, "cancel"):
                entity.cancel()
                self.destroy_timer(entity)
            else:
                self.destroy_subscription(entity)
        self._entities = []
        for name in ("_pub_js", "_pub_arm"):
            pub = getattr(self, name, None)
            if pub is not None:
                self.destroy_lifecycle_publisher(pub)
                setattr(self, name, None)
        pub = getattr(self, "_pub_diag", None)
        if pub is not None:
            self.destroy_publisher(pub)
            self._pub_diag = None

    def finish(self) -> None:
        """Shut down from any state (motor off, port closed) and log the run summary."""
        summary = self.summary() if getattr(self, "stats", None) is not None else "summary: not configured"
        if not self._finalized:
            self.trigger_shutdown()
        self.get_logger().info("motor off (duty 0 sent), port closed; " + summary)

    def _configure(self, p: dict[str, Any]) -> None:
        self.port = str(p["port"])
        if not self.port:
            raise BridgeConfigError("parameter port is empty; expected a serial device path")
        baud = p["baud"]
        if not isinstance(baud, int) or baud <= 0:
            raise BridgeConfigError(f"parameter baud = {baud!r} must be a positive integer")
        self.baud = baud
        self.rig_name = str(p["rig"])
        rig = load_rig(self.rig_name)
        offset = p["theta_offset"]
        if not isinstance(offset, (int, float)) or not math.isfinite(float(offset)):
            raise BridgeConfigError(f"parameter theta_offset = {offset!r} must be a finite angle [rad]")
        self.theta_quantum = float(rig.sensors.theta_quantum)
        if self.theta_quantum == 0:  # not stated: 2π / the firmware's counts (checked at configure)
            rig = rig.with_params("sensors", theta_quantum=2 * math.pi / 1024)
        self.cal = Calibration.from_rig(rig, theta_offset=float(offset))
        self.hw = read_rig_hardware(self.rig_name, rig.family, rig.name)
        self.cmap = CommandMap.for_rig(self.hw)  # the one τ -> DUTY / PULSE map; no firmware: refused
        self._hello_seen.clear()
        self.hello = None
        self.command_timeout_s = _positive("command_timeout", p["command_timeout"])
        self.keepalive_s = _positive("keepalive_period", p["keepalive_period"])
        if 2 * self.keepalive_s >= self.command_timeout_s:
            raise BridgeConfigError(
                f"keepalive_period {self.keepalive_s:g} s must be shorter than half the "
                f"command_timeout {self.command_timeout_s:g} s")
        div = p["rate_divider"]
        if not isinstance(div, int) or not 1 <= div <= 255:
            raise BridgeConfigError(f"parameter rate_divider = {div!r} must be an integer in 1..255")
        self.rate_divider = div
        self.diag_period_s = _positive("diagnostics_period", p["diagnostics_period"])
        self.backoff = Backoff(_positive("backoff_initial", p["backoff_initial"]),
                               _positive("backoff_max", p["backoff_max"]))
        self.frame_id = str(p["frame_id"])
        self.handshake_timeout_s = _positive("handshake_timeout", p["handshake_timeout"])
        self.handshake = FirmwareHandshake()
        self._last_link_event = ""
        # The watchdog is checked on every keep-alive tick, so trip two ticks early: duty 0 is on
        # the wire at most command_timeout − keepalive_period after the last valid command, which
        # leaves one tick of margin for timer jitter on a loaded machine.
        self.watchdog = CommandWatchdog(round((self.command_timeout_s - 2 * self.keepalive_s) * 1e9))
        self.seq = SequenceTracker()
        self.clock_map = ClockMapper()
        self.rate = RateMeter()
        self.stats = BridgeStats()
        self._was_tripped = True
        self._last_sent: float | None = None

    # ------------------------------------------------------------------ serial side
    def _on_connect(self) -> None:
        with self._lock:
            self.seq.restart()
            self.clock_map.reset()
            self.stats.connected = True
        link = self.link
        if link is None:
            return
        link.send(HelloRequest())
        link.send(Rate(self.rate_divider))
        if self._active:
            link.send(Enable(True))
            self._send_duty(self.watchdog.duty(time.monotonic_ns()))
        else:  # the firmware starts with its output enabled: off until activated
            link.send(Enable(False))
            self._send_duty(0.0)  # noted as sent: the link thread keeps it alive during configure

    def _on_link_event(self, msg: str) -> None:
        self._last_link_event = msg
        if msg.startswith("lost"):
            with self._lock:
                self.stats.connected = False
                self.stats.reconnects += 1
            self.get_logger().warn(msg)
        elif msg.startswith("cannot open"):
            self.get_logger().warn(msg, throttle_duration_sec=5.0)
        else:
            self.get_logger().info(msg)

    def _on_frame(self, frame: object, host_ns: int) -> None:
        if isinstance(frame, HelloFrame):
            self.hello = frame
            self._hello_seen.set()
            return
        if isinstance(frame, SampleFrame):
            self._last_sample = frame
            self._link_keepalive()
            with self._lock:
                resets = self.seq.resets
                gap = self.seq.update(frame.seq)
                if self.seq.resets != resets:
                    self.clock_map.reset()  # MCU restarted: its clock restarted too
                stamp = self.clock_map.update(frame.t_us, host_ns)
                self.stats.count_sample(frame, self.cal.homed(frame))
                self.rate.tick(time.monotonic_ns())
                if not self._recognised.is_set() and self.handshake.update(frame.seq, frame.t_us):
                    self._recognised.set()
            if gap:
                self.get_logger().warn(
                    f"{gap} sample frame(s) lost before seq {frame.seq} (total {self.seq.lost})",
                    throttle_duration_sec=LOG_THROTTLE_S)
            pub_js, pub_arm = self._pub_js, self._pub_arm
            if not self._active or pub_js is None or pub_arm is None:
                return  # inactive: no samples published (lifecycle convention)
            sample = self.cal.to_sample(frame, stamp, self.cmap.applied(frame))
            js, arm = sample_to_msgs(sample, self.frame_id)
            try:
                pub_js.publish(js)
                pub_arm.publish(arm)
            except Exception as exc:  # publishers gone during shutdown; keep the reader alive
                if self.context.ok():
                    self.get_logger().error(f"publishing sample {frame.seq} failed: {exc}",
                                            throttle_duration_sec=LOG_THROTTLE_S)
        elif isinstance(frame, StatusFrame):
            with self._lock:
                self.stats.status_frames += 1
                before = self.stats.mcu_status.get("watchdog_trips")
                self.stats.mcu_status = {
                    "rx_frames": frame.rx_frames, "rx_errors": frame.rx_errors,
                    "tx_overflows": frame.tx_overflows, "watchdog_trips": frame.watchdog_trips,
                    "speed_spikes": frame.spikes, "angle_errors": frame.angle_errors,
                }
            new = firmware_trips_since(before, frame.watchdog_trips)
            if new and self._active:
                silence = f"{self.hello.silence_ms} ms" if self.hello is not None else "its silence limit"
                self.get_logger().warn(
                    f"the firmware's own watchdog cut the output {new} time(s) since its last status: no "
                    f"frame reached it for {silence}, the host was late (duty 0 until the next frame)",
                    throttle_duration_sec=LOG_THROTTLE_S)

    # ------------------------------------------------------------------ commands
    def _on_command(self, msg: Float64) -> None:
        """A duty command (the subscription exists only while active: :meth:`on_activate`)."""
        if not self._active:
            return
        reason = self.watchdog.offer(msg.data, time.monotonic_ns())
        if reason is not None:
            self.get_logger().warn(
                f"rejected duty command {msg.data!r}: {reason} (rejected so far: {self.watchdog.rejected})",
                throttle_duration_sec=LOG_THROTTLE_S)
            return
        self._send_duty(self.watchdog.duty(time.monotonic_ns()))

    def _send_duty(self, duty: float) -> None:
        with self._send_lock:
            self._send_locked(duty)

    def _send_locked(self, duty: float) -> None:
        """Send ``duty`` (fraction) and note it and the time; the caller holds ``_send_lock``. Duty 0
        while an index-homing encoder has not seen its index: the rod's angle is unknown."""
        link = self.link
        if duty != 0.0 and not self.stats.angle_homed:
            self.get_logger().warn(
                f"duty {duty:g} held at 0: the encoder has not seen its index since the MCU started, so "
                "the rod's angle is unknown; turn the rod by hand through the index",
                throttle_duration_sec=LOG_THROTTLE_S)
            duty = 0.0
        if link is not None:
            link.send(self.cmap.command(duty))
            self._last_sent = duty
            self._last_send_ns = time.monotonic_ns()

    def _link_keepalive(self) -> None:
        """Duty 0 from the link thread when the last duty sent was 0 and nothing was sent for two
        keep-alive periods: the executor's keep-alive timer cannot run before the node spins, and
        with ``autostart`` configure and activate run before it does (the firmware's 250 ms
        watchdog tripped between activation and the first timer keep-alive on a loaded machine,
        CI of stop 29). Never a non-zero duty: keeping the motor running stays the executor's job
        (bridge watchdog), so a stalled executor still ends in the firmware's duty 0."""
        with self._send_lock:
            stale = time.monotonic_ns() - self._last_send_ns > 2 * self.keepalive_s * 1e9
            if stale and self._last_sent == 0.0:
                self._send_locked(0.0)

    def _keepalive(self) -> None:
        """Every keep-alive period: the current duty (active), or duty 0 while configured but
        inactive, so the firmware's 250 ms command watchdog stays quiet as long as the bridge lives
        (it tripped between the duty 0 sent on connect and activation when configure → activate
        took longer than 250 ms: ``bench/repro/firmware_watchdog_trip.py``).

        While active it fills silence only: when that duty went out within the last period (the
        controller's commands are flowing), nothing is sent. A repeat between two commands tells
        the firmware nothing new, and an emulated MCU that waits for the host's answer to each
        sample (simavr harness ``-H``) would take it for the answer."""
        if not self._active:
            self._send_duty(0.0)
            self._warn_idle_publishers()
            return
        now = time.monotonic_ns()
        trips = self.watchdog.trips
        duty = self.watchdog.duty(now)
        if self.watchdog.trips != trips:
            self.get_logger().warn(
                f"no valid duty command for {self.command_timeout_s:g} s: duty -> 0 "
                f"(watchdog trips so far: {self.watchdog.trips})")
        elif duty == self._last_sent and now - self._last_send_ns < self.keepalive_s * 1e9:
            return
        self._send_duty(duty)

    def _warn_idle_publishers(self) -> None:
        """While inactive, every :data:`IDLE_WARN_PERIOD_S`: warn when something publishes duty
        commands, which the bridge does not subscribe to until it is activated."""
        now = time.monotonic_ns()
        if now - self._idle_publishers_checked_ns < IDLE_WARN_PERIOD_S * 1e9:
            return
        self._idle_publishers_checked_ns = now
        n = self.count_publishers(REL_DUTY_CYCLE)
        if n:
            self.get_logger().warn(
                f"{n} publisher(s) on {self.resolve_topic_name(REL_DUTY_CYCLE)}: their duty commands "
                "are not applied while the bridge is inactive (activate it: ros2 lifecycle set "
                f"{self.get_fully_qualified_name()} activate)")

    # ------------------------------------------------------------------ diagnostics
    def diagnostics(self) -> DiagnosticStatus:
        """Current diagnostic status of the bridge."""
        with self._lock:
            rate = self.rate.rate(time.monotonic_ns())
            kv = self.stats.diagnostics(rate, self.seq, self._decoder_errors(), self.watchdog,
                                        self.clock_map)
            connected = self.stats.connected and self.link is not None and self.link.connected
            angle_valid = self.stats.angle_valid
            homed = self.stats.angle_homed
        expected = NOMINAL_RATE_HZ / self.rate_divider
        if not connected:
            level, message = DiagnosticStatus.ERROR, f"not connected to {self.port}"
        elif abs(rate - expected) > 0.05 * expected:
            level, message = DiagnosticStatus.WARN, f"sample rate {rate:.1f} Hz, expected {expected:.1f} Hz"
        elif not homed:
            level, message = DiagnosticStatus.WARN, ("encoder index not seen since the MCU started: angle "
                                                     "unknown (NaN), output held off; turn the rod "
                                                     "through the index")
        elif not angle_valid:
            level, message = DiagnosticStatus.WARN, "AS5040 read-out rejected by the firmware: angle held"
        else:
            level, message = DiagnosticStatus.OK, f"{rate:.1f} Hz"
        if not self._active:
            message += "; inactive: output off"
        kv.append(("active", str(self._active)))
        return DiagnosticStatus(level=level, name=f"{NODE_NAME}: serial link", message=message,
                                hardware_id=self.port, values=[KeyValue(key=k, value=v) for k, v in kv])

    def _decoder_errors(self) -> dict[str, int]:
        s = self._decoder.stats
        return {"crc_errors": s.crc_errors, "cobs_errors": s.cobs_errors, "length_errors": s.length_errors,
                "type_errors": s.type_errors, "oversize": s.oversize, "bytes": s.bytes}

    def _publish_diagnostics(self) -> None:
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [self.diagnostics()]
        self._pub_diag.publish(arr)

    # ------------------------------------------------------------------ summary
    def summary(self) -> str:
        """One-line run summary (``key=value`` pairs)."""
        s = self._decoder.stats
        return (f"summary: samples={self.stats.samples} lost={self.seq.lost} crc_errors={s.crc_errors} "
                f"decoder_errors={s.errors} reconnects={self.stats.reconnects} "
                f"commands={self.watchdog.accepted} rejected={self.watchdog.rejected} "
                f"watchdog_trips={self.watchdog.trips} "
                f"firmware_trips={self.stats.mcu_status.get('watchdog_trips', 'unknown')}")


def main(args: list[str] | None = None) -> int:
    """Entry point of ``bridge``; returns the exit status (2 = bad parameter, 1 = no firmware).

    With ``autostart`` (default) the node configures and activates itself, so the plain command
    drives the rig without a lifecycle manager; ``-p autostart:=false`` leaves it unconfigured
    for ``ros2 lifecycle set`` or a lifecycle manager.
    """

    def make() -> BridgeNode:
        node = BridgeNode()
        if node.autostart:
            node.start()
        return node

    return run_node(NODE_NAME, args, make, (BridgeConfigError,), BridgeNode.finish, period=0.05,
                    start_errors=(FirmwareError,), usage=USAGE)


if __name__ == "__main__":
    sys.exit(main())
