"""Reading the project's input files safely (no rclpy, nothing else of aeropend_sim).

:mod:`aeropend_sim.files.safe_yaml` is the one YAML loader of every package: rig files, CSV
presets, parameter values, bag ``metadata.yaml``, archive manifests.
"""
