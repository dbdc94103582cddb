"""Closed-loop checks of a designed controller on the whole rig file it was designed for (no rclpy)."""
