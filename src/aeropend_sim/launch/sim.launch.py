"""Launch the simulated aeropendulum plant (``aeropend_sim`` node, console script ``sim_node``).

Examples::

    ros2 launch aeropend_sim sim.launch.py
    ros2 launch aeropend_sim sim.launch.py rig:=thesis_sim mode:=lockstep seed:=3 noise:=true
    ros2 launch aeropend_sim sim.launch.py effects:=dead_zone=true,armature_inductance=quasi_static
    ros2 launch aeropend_sim sim.launch.py namespace:=rig2 params_file:=my_sim.yaml

Arguments mirror the node parameters (see ``aeropend_sim.ros.sim_node``); ``effects`` is one
comma-separated string of ``name=value`` overrides, ``noise`` empty keeps the rig's switches.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from aeropend_sim.ros.launch_arguments import NAMESPACE, PARAMS_FILE, is_true, node_parameters

ARGUMENTS = (
    NAMESPACE,
    PARAMS_FILE,
    ("rig", "thesis_rig", "shipped rig name or path to a rig YAML file"),
    ("mode", "realtime", "realtime | lockstep"),
    ("seed", "0", "measurement-noise seed (int >= 0)"),
    ("noise", "", "true/false: sensor noise + quantisation on/off (empty: as in the rig file)"),
    ("effects", "", "comma-separated effect overrides name=value"),
    ("initial_theta", "0.0", "initial angle [rad]"),
    ("command_timeout", "0.25", "realtime: duty -> 0 after this long without command [s]"),
    ("rt_priority", "0", "realtime: SCHED_FIFO priority of the sampler thread (0 = off)"),
    ("executor", "events", "events (C++ EventsExecutor, lower latency) | single (SingleThreadedExecutor)"),
    ("frame_id", "aeropend", "header.frame_id of the sample messages"),
)


def _plant(context, *args, **kwargs):
    value = {name: LaunchConfiguration(name).perform(context) for name, _, _ in ARGUMENTS}
    params = {
        "rig": value["rig"],
        "mode": value["mode"],
        "seed": int(value["seed"]),
        "initial_theta": float(value["initial_theta"]),
        "command_timeout": float(value["command_timeout"]),
        "rt_priority": int(value["rt_priority"]),
        "executor": value["executor"],
        "frame_id": value["frame_id"],
    }
    if value["noise"]:
        params["noise"] = is_true(value["noise"])
    if value["effects"]:
        params["effects"] = [e.strip() for e in value["effects"].split(",") if e.strip()]
    return [
        Node(
            namespace=value["namespace"] or None, package="aeropend_sim",
            executable="sim_node",
            name="aeropend_sim",
            output="screen",
            parameters=node_parameters(params, value["params_file"]),
        )
    ]


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=doc)
         for name, default, doc in ARGUMENTS]
        + [OpaqueFunction(function=_plant)]
    )
