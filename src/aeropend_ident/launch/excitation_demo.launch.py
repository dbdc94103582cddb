"""Open-loop identification run: simulated plant + excitation signal + bag recorder.

Starts ``sim_node`` (plant), ``excitation`` (duty-cycle signal) and ``record`` from
``aeropend_ident`` (rosbag2 of the contract topics); when the excitation has sent its whole
signal the launch shuts down, which closes the bag cleanly.

Examples::

    ros2 launch aeropend_ident excitation_demo.launch.py                       # LHS, lock-step
    ros2 launch aeropend_ident excitation_demo.launch.py signal:=prbs mode:=realtime output:=/tmp/prbs
    ros2 launch aeropend_ident excitation_demo.launch.py rig:=thesis_sim seed:=4 noise:=true

In ``lockstep`` mode (default) plant and excitation ping-pong one sample per command, so the run
is deterministic and as fast as the machine allows; the recorder then runs on simulated time
(``use_sim_time``, ``/clock`` recorded). In ``realtime`` mode everything runs on wall time.
Signal arguments other than ``signal``/``seed`` take their defaults (see
``aeropend_sim.excitation``); use the ``excitation`` console script directly for full control.
"""

from launch import LaunchDescription
from launch.actions import (
    DeclareLaunchArgument,
    EmitEvent,
    OpaqueFunction,
    RegisterEventHandler,
    SetEnvironmentVariable,
)
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

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
    ("rig", "thesis_rig", "shipped rig name or path to a rig YAML file"),
    ("mode", "lockstep", "lockstep (deterministic ping-pong) | realtime"),
    ("signal", "lhs",
     "step | staircase | prbs | aprbs | density_prbs | lhs (thesis §5.1 Latin-hypercube steps)"),
    ("seed", "1", "seed of the signal and of the measurement noise"),
    ("noise", "", "true/false: sensor noise + quantisation on/off (empty: as in the rig file)"),
    ("output", "", "bag directory (empty: recorder default aeropend_<date>)"),
    ("storage", "mcap", "bag storage: mcap | sqlite3"),
    DISCOVERY_RANGE,
)


def _nodes(context, *args, **kwargs):
    value = {name: LaunchConfiguration(name).perform(context) for name, _, _ in ARGUMENTS}
    lockstep = value["mode"] == "lockstep"
    seed = int(value["seed"])
    plant_params = {"rig": value["rig"], "mode": value["mode"], "seed": seed}
    if lockstep:  # sample 0 waits for both sample consumers (excitation, recorder) and the recorder's /clock
        plant_params.update(min_subscribers=2, min_clock_subscribers=1)
    if value["noise"]:
        plant_params["noise"] = is_true(value["noise"])
    # wait for plant + recorder on the duty topic so the bag starts at sample 0
    signal_params = {"signal": value["signal"], "mode": value["mode"], "min_subscribers": 2}
    if value["signal"] in ("prbs", "aprbs", "density_prbs", "lhs"):
        signal_params["seed"] = seed
    if value["signal"] == "staircase":
        signal_params.update(levels=[0.3, 0.45, 0.6, 0.45], hold=[3.0])
    if value["signal"] in ("step", "aprbs", "density_prbs"):
        signal_params.setdefault("duration", 20.0)
    if value["signal"] == "step":
        signal_params["level"] = 0.4314  # thesis open-loop step (§4.5)
    topics = [""]  # the recorder's contract topics in its namespace
    record_params = {"storage": value["storage"], "topics": topics + (["/clock"] if lockstep else []),
                     "use_sim_time": lockstep}
    if value["output"]:
        record_params["output"] = value["output"]
    recorder = Node(package="aeropend_ident", executable="record", name="aeropend_recorder", output="screen",
                    parameters=node_parameters(record_params, value["params_file"]),
                    namespace=value["namespace"] or None)
    plant = Node(package="aeropend_sim", executable="sim_node", name="aeropend_sim", output="screen",
                 parameters=node_parameters(plant_params, value["params_file"]),
                 namespace=value["namespace"] or None)
    excitation = Node(package="aeropend_sim", executable="excitation", name="aeropend_excitation",
                      output="screen", parameters=node_parameters(signal_params, value["params_file"]),
                      namespace=value["namespace"] or None)
    done = RegisterEventHandler(
        OnProcessExit(target_action=excitation,
                      on_exit=[EmitEvent(event=Shutdown(reason="excitation signal finished"))])
    )
    return [recorder, plant, excitation, done]


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=doc)
         for name, default, doc in ARGUMENTS]
        + [SetEnvironmentVariable("ROS_AUTOMATIC_DISCOVERY_RANGE", LaunchConfiguration("discovery_range")),
           OpaqueFunction(function=_nodes)]
    )
