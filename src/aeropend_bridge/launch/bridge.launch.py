"""Launch the hardware bridge (``aeropend_bridge`` node, console script ``bridge``).

Examples::

    ros2 launch aeropend_bridge bridge.launch.py port:=/dev/ttyACM0 theta_offset:=3.1416
    fake_mcu --link /tmp/aeropend_tty &   # no hardware: the pty fake firmware
    ros2 launch aeropend_bridge bridge.launch.py port:=/tmp/aeropend_tty
    ros2 launch aeropend_bridge bridge.launch.py autostart:=false   # managed: then
    ros2 lifecycle set /aeropend_bridge configure && ros2 lifecycle set /aeropend_bridge activate

Arguments mirror the node parameters (see ``aeropend_bridge.bridge_node``). The bridge is a
lifecycle node; ``autostart:=true`` (default) configures and activates it at start-up, so it
drives without a lifecycle manager; ``autostart:=false`` leaves it unconfigured for
``ros2 lifecycle set`` or a lifecycle manager (e.g. nav2_lifecycle_manager's ``node_names``).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from aeropend_sim.ros.launch_arguments import NAMESPACE, PARAMS_FILE, is_true, node_parameters

ARGUMENTS = (
    NAMESPACE,
    PARAMS_FILE,
    ("port", "/dev/ttyACM0", "serial device of the Arduino Mega"),
    ("rig", "thesis_rig", "rig name or YAML path (ADC LSBs, gear ratio)"),
    ("theta_offset", "0.0", "angle read with the rod hanging down [rad]"),
    ("command_timeout", "0.1", "duty 0 at most this long after the last valid command [s]"),
    ("frame_id", "aeropend", "header.frame_id of the sample messages"),
    ("autostart", "true", "configure + activate at start-up (false: wait for lifecycle transitions)"),
)


def _bridge(context, *args, **kwargs):
    value = {name: LaunchConfiguration(name).perform(context) for name, _, _ in ARGUMENTS}
    params = {
        "port": value["port"],
        "rig": value["rig"],
        "theta_offset": float(value["theta_offset"]),
        "command_timeout": float(value["command_timeout"]),
        "frame_id": value["frame_id"],
        "autostart": is_true(value["autostart"]),
    }
    return [Node(package="aeropend_bridge", executable="bridge", name="aeropend_bridge", output="screen",
                 parameters=node_parameters(params, value["params_file"]),
                 namespace=value["namespace"] or None)]


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=doc)
         for name, default, doc in ARGUMENTS]
        + [OpaqueFunction(function=_bridge)]
    )
