"""The ROS 2 shell of the simulated plant: nodes, their lifecycle helper, QoS and domain."""
