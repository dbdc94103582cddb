"""Offline identification and sim-to-real gap diagnosis on rosbag2 files.

Reads bags with ``rosbags`` (no ROS installation needed); also the recorder and player nodes and
the CSV import of third-party rig logs.
"""
