"""Offline identification and sim-to-real gap diagnosis on rosbag2 files (rosbags, no ROS install needed); recorder, player and CSV import."""
