"""The recorder and player ROS 2 nodes."""
