"""Record the aeropend contract topics into a rosbag2 bag (``aeropend_recorder``).

Examples::

    ros2 launch aeropend_ident record.launch.py output:=/data/run1
    ros2 launch aeropend_ident record.launch.py output:=/data/run2 storage:=sqlite3 duration:=60
    ros2 launch aeropend_ident record.launch.py clock:=true use_sim_time:=true   # simulated runs
    ros2 launch aeropend_ident record.launch.py topics:="/aeropend/joint_states /aeropend/armature"

Stop with Ctrl-C (the bag is closed cleanly), or let ``duration`` / ``max_samples`` end it; the
launch shuts down when the recorder exits.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from aeropend_sim.ros.launch_arguments import NAMESPACE, PARAMS_FILE, is_true, node_parameters

CONTRACT_TOPICS = ["/aeropend/duty_cycle", "/aeropend/joint_states", "/aeropend/armature"]

ARGUMENTS = (
    NAMESPACE,
    PARAMS_FILE,
    ("output", "", "bag directory to create (empty: aeropend_<date>_<time> in the working directory)"),
    ("storage", "mcap", "bag storage: mcap | sqlite3"),
    ("topics", "", "space-separated topics (empty: the contract topics)"),
    ("clock", "false", "also record /clock (simulated runs)"),
    ("duration", "0.0", "seconds to record, 0 = until Ctrl-C"),
    ("max_samples", "0", "stop after N joint_states messages, 0 = no limit"),
    ("use_sim_time", "false", "stamp and time the recording with /clock"),
)


def _recorder(context, *args, **kwargs):
    value = {name: LaunchConfiguration(name).perform(context) for name, _, _ in ARGUMENTS}
    topics = value["topics"].split() or [""]  # "": the contract topics in the recorder's namespace
    if is_true(value["clock"]) and "/clock" not in topics:
        topics.append("/clock")
    params = {
        "storage": value["storage"],
        "topics": topics,
        "duration": float(value["duration"]),
        "max_samples": int(value["max_samples"]),
        "use_sim_time": is_true(value["use_sim_time"]),
    }
    if value["output"]:
        params["output"] = value["output"]
    recorder = Node(package="aeropend_ident", executable="record", name="aeropend_recorder",
                    output="screen", parameters=node_parameters(params, value["params_file"]),
                    namespace=value["namespace"] or None)
    shutdown = EmitEvent(event=Shutdown(reason="recorder finished"))
    stop_with_recorder = RegisterEventHandler(OnProcessExit(target_action=recorder, on_exit=[shutdown]))
    return [recorder, stop_with_recorder]


def generate_launch_description() -> LaunchDescription:
    """Launch description: the arguments above and the recorder node."""
    args = [DeclareLaunchArgument(name, default_value=default, description=doc)
            for name, default, doc in ARGUMENTS]
    return LaunchDescription([*args, OpaqueFunction(function=_recorder)])
