"""Hardware bridge node ``aeropend_bridge`` (console script ``bridge``).

Connects to the acquisition firmware over a serial port (``firmware/PROTOCOL.md``) and makes
the real rig look exactly like the simulated plant (:mod:`aeropend_sim.sim_node`): publishes
``/aeropend/joint_states`` + ``/aeropend/armature`` (same stamp per sample, SI units, sensor
data QoS) and subscribes ``/aeropend/duty_cycle`` (reliable). Stamps come from the MCU clock
mapped to ROS time (:class:`~aeropend_bridge.bridge_core.ClockMapper`).

Usage::

    bridge --ros-args -p port:=/dev/ttyACM0 -p rig:=thesis_rig -p theta_offset:=3.1416

Parameters
----------
port : str, default ``/dev/ttyACM0``
    Serial device (a ``/dev/serial/by-id/...`` link survives re-enumeration).
baud : int, default 500000
rig : str, default ``thesis_rig``
    Rig name or YAML path: ADC LSBs from ``sensors``, ``motor.gear_ratio``.
theta_offset : float [rad], default 0.0
    Angle read with the rod hanging down (θ = 0 there).
command_timeout : float [s], default 0.1
    Duty 0 is on the wire at most this long after the last valid command.
keepalive_period : float [s], default 0.02
    The current duty is re-sent this often (feeds the firmware's 250 ms watchdog); must be
    < command_timeout / 2 (the watchdog trips at command_timeout − 2·keepalive_period and is
    checked every keepalive_period).
rate_divider : int, default 1
    Firmware sends a sample every ``rate_divider`` PWM periods (1 = 490 Hz).
diagnostics_period : float [s], default 1.0
backoff_initial, backoff_max : float [s], default 0.05, 2.0
    Reconnection delays after the port vanished (doubling).
frame_id : str, default ``aeropend``

Invalid parameters exit with status 2 and a message naming the value. NaN / out-of-range
duty commands are rejected, counted and logged (throttled). On shutdown the motor is switched
off (duty 0 sent) before the port is closed.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from sensor_msgs.msg import BatteryState, JointState
from std_msgs.msg import Float64

from aeropend_bridge.bridge_core import (
    Backoff,
    BridgeConfigError,
    BridgeStats,
    Calibration,
    ClockMapper,
    CommandWatchdog,
    RateMeter,
    SequenceTracker,
)
from aeropend_bridge.protocol import BAUD, Duty, Rate, SampleFrame, StatusFrame
from aeropend_bridge.serial_link import SerialLink
from aeropend_sim.contract import REL_ARMATURE, REL_DUTY_CYCLE, REL_JOINT_STATES
from aeropend_sim.node_shell import declare_parameter_table, run_node
from aeropend_sim.params import RigFileError, load_rig
from aeropend_sim.ros_contract import COMMAND_QOS, SAMPLE_QOS, sample_to_msgs

NODE_NAME = "aeropend_bridge"
TOPIC_DIAGNOSTICS = "/diagnostics"
LOG_THROTTLE_S = 1.0
#: Nominal firmware sample rate [Hz]: 16 MHz / 64 / 510.
NOMINAL_RATE_HZ = 16e6 / 64 / 510

PARAMETERS: tuple[tuple[str, Any, str], ...] = (
    ("port", "/dev/ttyACM0", "serial device"),
    ("baud", BAUD, "line rate [bit/s]"),
    ("rig", "thesis_rig", "rig name or YAML path (ADC LSBs, gear ratio)"),
    ("theta_offset", 0.0, "angle read with the rod hanging down [rad]"),
    ("command_timeout", 0.1, "duty 0 at most this long after the last valid command [s]"),
    ("keepalive_period", 0.02, "re-send period of the current duty [s]"),
    ("rate_divider", 1, "firmware sample divider (1 = every PWM period)"),
    ("diagnostics_period", 1.0, "period of /diagnostics [s]"),
    ("backoff_initial", 0.05, "first reconnection delay [s]"),
    ("backoff_max", 2.0, "largest reconnection delay [s]"),
    ("frame_id", "aeropend", "header.frame_id of the sample messages"),
)


def _positive(name: str, value: Any) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise BridgeConfigError(f"parameter {name} = {value!r} is not a number") from None
    if not (math.isfinite(v) and v > 0):
        raise BridgeConfigError(f"parameter {name} = {value!r} must be a finite positive number")
    return v


class BridgeNode(Node):
    """rclpy shell of the hardware bridge (see module docstring).

    Raises
    ------
    BridgeConfigError
        From the constructor if a parameter is invalid (the node is destroyed first).
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = declare_parameter_table(self, PARAMETERS)
        try:
            self._configure(p)
        except (BridgeConfigError, RigFileError) as exc:
            self.destroy_node()
            raise BridgeConfigError(str(exc)) from None
        self._pub_js = self.create_publisher(JointState, REL_JOINT_STATES, SAMPLE_QOS)
        self._pub_arm = self.create_publisher(BatteryState, REL_ARMATURE, SAMPLE_QOS)
        self._pub_diag = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self.create_subscription(Float64, REL_DUTY_CYCLE, self._on_command, COMMAND_QOS)
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(self.keepalive_s, self._keepalive, clock=self._steady)
        self.create_timer(self.diag_period_s, self._publish_diagnostics, clock=self._steady)
        self._lock = threading.Lock()
        self.link = SerialLink(self.port, self._on_frame, baud=self.baud,
                               clock_ns=lambda: self.get_clock().now().nanoseconds,
                               on_event=self._on_link_event, on_connect=self._on_connect,
                               backoff=self.backoff)
        self.get_logger().info(
            f"port {self.port} at {self.baud} baud, rig {self.rig_name!r}, theta_offset "
            f"{self.cal.theta_offset:g} rad, command_timeout {self.command_timeout_s:g} s")

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
        self.cal = Calibration.from_rig(rig, theta_offset=float(offset))
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
    def start(self) -> None:
        """Start the serial reader thread."""
        self.link.start()

    def _on_connect(self) -> None:
        with self._lock:
            self.seq.restart()
            self.clock_map.reset()
            self.stats.connected = True
        self.link.send(Rate(self.rate_divider))
        self.link.send(Duty.from_fraction(self.watchdog.duty(time.monotonic_ns())))

    def _on_link_event(self, msg: str) -> None:
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
        if isinstance(frame, SampleFrame):
            with self._lock:
                resets = self.seq.resets
                gap = self.seq.update(frame.seq)
                if self.seq.resets != resets:
                    self.clock_map.reset()  # MCU restarted: its clock restarted too
                stamp = self.clock_map.update(frame.t_us, host_ns)
                self.stats.count_sample(frame)
                self.rate.tick(time.monotonic_ns())
            if gap:
                self.get_logger().warn(
                    f"{gap} sample frame(s) lost before seq {frame.seq} (total {self.seq.lost})",
                    throttle_duration_sec=LOG_THROTTLE_S)
            js, arm = sample_to_msgs(self.cal.to_sample(frame, stamp), self.frame_id)
            try:
                self._pub_js.publish(js)
                self._pub_arm.publish(arm)
            except Exception as exc:  # publishers gone during shutdown; keep the reader alive
                if self.context.ok():
                    self.get_logger().error(f"publishing sample {frame.seq} failed: {exc}",
                                            throttle_duration_sec=LOG_THROTTLE_S)
        elif isinstance(frame, StatusFrame):
            with self._lock:
                self.stats.status_frames += 1
                self.stats.mcu_status = {
                    "rx_frames": frame.rx_frames, "rx_errors": frame.rx_errors,
                    "tx_overflows": frame.tx_overflows, "watchdog_trips": frame.watchdog_trips,
                    "speed_spikes": frame.spikes, "angle_errors": frame.angle_errors,
                }

    # ------------------------------------------------------------------ commands
    def _on_command(self, msg: Float64) -> None:
        reason = self.watchdog.offer(msg.data, time.monotonic_ns())
        if reason is not None:
            self.get_logger().warn(
                f"rejected duty command {msg.data!r}: {reason} (rejected so far: {self.watchdog.rejected})",
                throttle_duration_sec=LOG_THROTTLE_S)
            return
        self._send_duty(self.watchdog.duty(time.monotonic_ns()))

    def _send_duty(self, duty: float) -> None:
        self.link.send(Duty.from_fraction(duty))
        self._last_sent = duty

    def _keepalive(self) -> None:
        now = time.monotonic_ns()
        trips = self.watchdog.trips
        duty = self.watchdog.duty(now)
        if self.watchdog.trips != trips:
            self.get_logger().warn(
                f"no valid duty command for {self.command_timeout_s:g} s: duty -> 0 "
                f"(watchdog trips so far: {self.watchdog.trips})")
        self._send_duty(duty)

    # ------------------------------------------------------------------ diagnostics
    def diagnostics(self) -> DiagnosticStatus:
        """Current diagnostic status of the bridge."""
        with self._lock:
            rate = self.rate.rate(time.monotonic_ns())
            kv = self.stats.diagnostics(rate, self.seq, self._decoder_errors(), self.watchdog,
                                        self.clock_map)
            connected = self.stats.connected and self.link.connected
            angle_valid = self.stats.angle_valid
        expected = NOMINAL_RATE_HZ / self.rate_divider
        if not connected:
            level, message = DiagnosticStatus.ERROR, f"not connected to {self.port}"
        elif abs(rate - expected) > 0.05 * expected:
            level, message = DiagnosticStatus.WARN, f"sample rate {rate:.1f} Hz, expected {expected:.1f} Hz"
        elif not angle_valid:
            level, message = DiagnosticStatus.WARN, "AS5040 read-out rejected by the firmware: angle held"
        else:
            level, message = DiagnosticStatus.OK, f"{rate:.1f} Hz"
        return DiagnosticStatus(level=level, name=f"{NODE_NAME}: serial link", message=message,
                                hardware_id=self.port, values=[KeyValue(key=k, value=v) for k, v in kv])

    def _decoder_errors(self) -> dict[str, int]:
        s = self.link.decoder.stats
        return {"crc_errors": s.crc_errors, "cobs_errors": s.cobs_errors, "length_errors": s.length_errors,
                "type_errors": s.type_errors, "oversize": s.oversize, "bytes": s.bytes}

    def _publish_diagnostics(self) -> None:
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [self.diagnostics()]
        self._pub_diag.publish(arr)

    # ------------------------------------------------------------------ shutdown
    def shutdown_motor(self) -> None:
        """Send duty 0 (three times, in case one frame is lost), then close the port."""
        for _ in range(3):
            self.link.send(Duty(0))
            time.sleep(0.005)
        self.link.stop()

    def summary(self) -> str:
        """One-line run summary (``key=value`` pairs)."""
        s = self.link.decoder.stats
        return (f"summary: samples={self.stats.samples} lost={self.seq.lost} crc_errors={s.crc_errors} "
                f"decoder_errors={s.errors} reconnects={self.stats.reconnects} "
                f"commands={self.watchdog.accepted} rejected={self.watchdog.rejected} "
                f"watchdog_trips={self.watchdog.trips}")


def main(args: list[str] | None = None) -> int:
    """Entry point of ``bridge``; returns the exit status (2 = bad parameter)."""

    def make() -> BridgeNode:
        node = BridgeNode()
        node.start()
        return node

    def cleanup(node: BridgeNode) -> None:
        node.shutdown_motor()
        node.get_logger().info("motor off (duty 0 sent), port closed; " + node.summary())

    return run_node(NODE_NAME, args, make, (BridgeConfigError,), cleanup, period=0.05)

if __name__ == "__main__":
    sys.exit(main())
