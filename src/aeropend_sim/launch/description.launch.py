"""Robot description of a rig: robot_state_publisher (tf from ``aeropend/joint_states``) + RViz.

Examples::

    ros2 launch aeropend_sim sim.launch.py &                 # or the bridge / a bag: play ...
    ros2 launch aeropend_sim description.launch.py           # robot_state_publisher + RViz
    ros2 launch aeropend_sim description.launch.py rviz:=false    # e.g. for Foxglove
    ros2 launch aeropend_sim description.launch.py namespace:=rig2   # frames rig2/base_link, ...

``robot_description`` is the URDF of ``rig`` (:func:`aeropend_sim.description.urdf_for_rig`;
``share/aeropend_sim/urdf/aeropend.urdf`` is the thesis rig's). robot_state_publisher reads the
contract's ``aeropend/joint_states`` in the same namespace; only the ``pendulum`` joint moves.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from aeropend_sim.contract import REL_JOINT_STATES
from aeropend_sim.description import urdf_for_rig
from aeropend_sim.ros.launch_arguments import NAMESPACE, PARAMS_FILE, is_true, node_parameters

ARGUMENTS = (
    NAMESPACE,
    PARAMS_FILE,
    ("rig", "thesis_rig", "rig name or YAML path whose URDF is published"),
    ("rviz", "true", "also start RViz with share/aeropend_sim/rviz/aeropend.rviz"),
    ("rviz_config", "", "RViz configuration file (empty: the package's)"),
)


def _nodes(context, *args, **kwargs):
    v = {name: LaunchConfiguration(name).perform(context) for name, _, _ in ARGUMENTS}
    ns = v["namespace"].strip("/")
    params = {"robot_description": urdf_for_rig(v["rig"]), "frame_prefix": f"{ns}/" if ns else ""}
    nodes = [Node(package="robot_state_publisher", executable="robot_state_publisher",
                  name="robot_state_publisher", output="screen", namespace=v["namespace"] or None,
                  parameters=node_parameters(params, v["params_file"]),
                  remappings=[("joint_states", REL_JOINT_STATES)])]
    if is_true(v["rviz"]):
        config = v["rviz_config"]
        if not config:
            from ament_index_python.packages import get_package_share_directory

            config = f"{get_package_share_directory('aeropend_sim')}/rviz/aeropend.rviz"
        nodes.append(Node(package="rviz2", executable="rviz2", name="rviz2", output="screen",
                          namespace=v["namespace"] or None, arguments=["-d", config]))
    return nodes


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=doc)
         for name, default, doc in ARGUMENTS]
        + [OpaqueFunction(function=_nodes)]
    )
