"""Launch arguments shared by the packages' launch files, as ``(name, default, description)``.

Plain data (no ``launch`` import), so the launch files and their test read the same tuples.
"""

from __future__ import annotations

#: ROS namespace of a rig's nodes and topics (:data:`aeropend_sim.contract.REL_JOINT_STATES`).
NAMESPACE = ("namespace", "",
             "ROS namespace of the rig's nodes and topics (rig2: /rig2/aeropend/*; empty: root)")
#: Jazzy's discovery range for the demos' nodes.
DISCOVERY_RANGE = ("discovery_range", "LOCALHOST",
                   "ROS_AUTOMATIC_DISCOVERY_RANGE of the demo's nodes: LOCALHOST keeps its DDS traffic on "
                   "this host; SUBNET / SYSTEM_DEFAULT for a lab network")
