"""Launch arguments shared by the packages' launch files, as ``(name, default, description)``.

Plain data (no ``launch`` import), so the launch files and their test read the same tuples.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: ROS namespace of a rig's nodes and topics (:data:`aeropend_sim.contract.REL_JOINT_STATES`).
NAMESPACE = ("namespace", "",
             "ROS namespace of the rig's nodes and topics (rig2: /rig2/aeropend/*; empty: root)")
#: Jazzy's discovery range for the demos' nodes.
DISCOVERY_RANGE = ("discovery_range", "LOCALHOST",
                   "ROS_AUTOMATIC_DISCOVERY_RANGE of the demo's nodes: LOCALHOST keeps its DDS traffic on "
                   "this host; SUBNET / SYSTEM_DEFAULT for a lab network")
#: A ROS parameters file (``config/*.yaml`` of the packages is the template) for the nodes.
PARAMS_FILE = ("params_file", "",
               "ROS parameters file (YAML, /**/<node>: ros__parameters: ...) for the nodes; applied "
               "after the other arguments, so its values win (empty: none)")

#: Launch-argument spellings read as true (as ``sim_core`` reads boolean node parameters).
TRUE_WORDS = ("true", "1", "yes", "on")


def is_true(text: str) -> bool:
    """A boolean launch argument: ``true``/``1``/``yes``/``on`` (any case, spaces ignored)."""
    return text.strip().lower() in TRUE_WORDS


def node_parameters(values: dict[str, Any], params_file: str) -> list[Any]:
    """``parameters=`` of a ``launch_ros`` node: the argument values, then the params file.

    Parameters
    ----------
    values : dict
        Parameter values from the launch arguments.
    params_file : str
        Path of a ROS parameters file, or "" for none. launch_ros applies the entries in order,
        so the file's values override the arguments' for the parameters it sets.

    Returns
    -------
    list
        ``[values]`` or ``[values, params_file]``.

    Raises
    ------
    FileNotFoundError
        If ``params_file`` is given and is not a file (named in the message).
    """
    if not params_file:
        return [values]
    if not Path(params_file).is_file():
        raise FileNotFoundError(f"params_file:={params_file!r} is not a file")
    return [values, params_file]
