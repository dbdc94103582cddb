"""Closed loop: the simulated plant or the hardware bridge, plus the controller node.

The controller is the same in both cases; only the plant process changes (the topic contract
is the interface). Examples::

    ros2 launch aeropend_control closed_loop.launch.py strategy:=fl_pid steps:=0.5,0.4
    ros2 launch aeropend_control closed_loop.launch.py mode:=lockstep effects:=dead_zone=true
    ros2 launch aeropend_control closed_loop.launch.py plant:=bridge port:=/dev/ttyACM0 \\
        strategy:=fl_cascade steps:=1.0,0.2,6.0,0.7

``steps`` is ``t0,θ0,t1,θ1,...`` (s, rad); the set point can also be published on
``/aeropend/reference`` (std_msgs/Float64). ``strategy`` takes the names of the strategy registry
(:mod:`aeropend_control.strategies.registry`; ``--show-args`` lists them with a description).
Plain-command equivalent: ``sim_node`` (or ``bridge``) and ``controller`` with the same
``--ros-args -p name:=value`` parameters.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, SetEnvironmentVariable
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from aeropend_control.strategies.registry import DEFAULT_STRATEGY, strategy_help, strategy_names
from aeropend_sim.ros.launch_arguments import (
    DISCOVERY_RANGE,
    NAMESPACE,
    PARAMS_FILE,
    is_true,
    node_parameters,
)

ARGUMENTS = (
    NAMESPACE,
    PARAMS_FILE,
    ("plant", "sim", "sim (simulated plant) | bridge (hardware through the serial bridge)"),
    ("rig", "thesis_rig", "rig name or YAML path, used by the plant/bridge and the controller"),
    ("mode", "realtime", "realtime | lockstep (lockstep: sim plant only)"),
    ("strategy", DEFAULT_STRATEGY, strategy_help()),
    ("estimator", "observer", "θ̇ estimate: observer | difference"),
    ("steps", "", "reference steps t0,theta0,t1,theta1,... (s, rad); empty: /aeropend/reference only"),
    ("effects", "", "sim plant: comma-separated effect overrides name=value"),
    ("noise", "", "sim plant: true/false sensor noise (empty: as in the rig file)"),
    ("port", "/dev/ttyACM0", "bridge: serial device of the Arduino Mega"),
    ("rt_priority", "0", "SCHED_FIFO priority of the plant sampler and controller (0 = off)"),
    DISCOVERY_RANGE,
)
#: Arguments whose value launch checks against a list (an unknown strategy fails before any node starts).
CHOICES = {"strategy": strategy_names()}


def _nodes(context, *args, **kwargs):
    v = {name: LaunchConfiguration(name).perform(context) for name, _, _ in ARGUMENTS}
    if v["plant"] not in ("sim", "bridge"):
        raise RuntimeError(f"plant:={v['plant']!r}; expected 'sim' or 'bridge'")
    if v["plant"] == "bridge" and v["mode"] != "realtime":
        raise RuntimeError("plant:=bridge runs in real time only; use mode:=realtime")
    rt = int(v["rt_priority"])
    if v["plant"] == "sim":
        plant_params = {"rig": v["rig"], "mode": v["mode"], "rt_priority": rt}
        if v["noise"]:
            plant_params["noise"] = is_true(v["noise"])
        if v["effects"]:
            plant_params["effects"] = [e.strip() for e in v["effects"].split(",") if e.strip()]
        plant = Node(package="aeropend_sim", executable="sim_node", name="aeropend_sim", output="screen",
                     parameters=node_parameters(plant_params, v["params_file"]),
                     namespace=v["namespace"] or None)
    else:
        plant = Node(package="aeropend_bridge", executable="bridge", name="aeropend_bridge", output="screen",
                     parameters=node_parameters({"port": v["port"], "rig": v["rig"]}, v["params_file"]),
                     namespace=v["namespace"] or None)
    ctrl_params = {"rig": v["rig"], "strategy": v["strategy"], "mode": v["mode"], "estimator": v["estimator"],
                   "rt_priority": rt}
    if v["steps"]:
        ctrl_params["steps"] = [float(x) for x in v["steps"].split(",") if x.strip()]
    controller = Node(package="aeropend_control", executable="controller", name="aeropend_controller",
                      output="screen", parameters=node_parameters(ctrl_params, v["params_file"]),
                      namespace=v["namespace"] or None)
    return [plant, controller]


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=doc,
                               **({"choices": list(CHOICES[name])} if name in CHOICES else {}))
         for name, default, doc in ARGUMENTS]
        + [SetEnvironmentVariable("ROS_AUTOMATIC_DISCOVERY_RANGE", LaunchConfiguration("discovery_range")),
           OpaqueFunction(function=_nodes)]
    )
