"""A stand-in for a lab's own bridge node (e.g. a Quanser rig's), for ``test_bridge_check.py``.

Written from the contract alone (docs/hardware.md), with none of ``aeropend_bridge``'s code: a
rig that measures θ and ω₁ only, published at 200 Hz, duty commands validated and applied, τ 0
after 0.1 s without a command. ``--fault`` breaks one clause the way lab nodes do:

* ``unit``: θ in degrees;
* ``stamp``: the armature message stamped with its own ``now()`` instead of the sample's stamp;
* ``zeros``: the unmeasured channels (θ̇, ω₂, i_a, v_a) published as 0.0 instead of NaN;
* ``none``: conforms.

Run: ``python lab_bridge_node.py --fault unit`` (node name ``/lab_bridge``).
"""

from __future__ import annotations

import argparse
import math
import random
import time

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import BatteryState, JointState
from std_msgs.msg import Float64


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--fault", choices=("none", "unit", "stamp", "zeros"), default="none")
    fault = ap.parse_args().fault
    rclpy.init()
    node = rclpy.create_node("lab_bridge")
    state = {"duty": 0.0, "last": 0.0, "theta": 0.0}
    cmd_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)

    def on_cmd(msg: Float64) -> None:
        if math.isfinite(msg.data) and 0.0 <= msg.data <= 1.0:
            state["duty"], state["last"] = msg.data, time.monotonic()

    node.create_subscription(Float64, "aeropend/duty_cycle", on_cmd, cmd_qos)
    pub_js = node.create_publisher(JointState, "aeropend/joint_states", qos_profile_sensor_data)
    pub_arm = node.create_publisher(BatteryState, "aeropend/armature", qos_profile_sensor_data)
    nan = math.nan
    unmeasured = 0.0 if fault == "zeros" else nan

    def tick() -> None:
        if time.monotonic() - state["last"] > 0.1:
            state["duty"] = 0.0
        tau = state["duty"]
        state["theta"] += 0.05 * (0.8 * tau - state["theta"])  # a slow first-order rod
        theta = state["theta"] + random.gauss(0.0, 1e-3)
        stamp = node.get_clock().now().to_msg()
        js = JointState()
        js.header.stamp = stamp
        js.header.frame_id = "lab"
        js.name = ["pendulum", "motor", "propeller"]
        js.position = [math.degrees(theta) if fault == "unit" else theta, nan, nan]
        js.velocity = [unmeasured, 600.0 * tau + random.gauss(0.0, 0.5), unmeasured]
        js.effort = [nan, tau, nan]
        arm = BatteryState()
        arm.header.stamp = node.get_clock().now().to_msg() if fault == "stamp" else stamp
        arm.voltage = unmeasured
        arm.current = unmeasured
        pub_js.publish(js)
        pub_arm.publish(arm)

    node.create_timer(0.005, tick)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
