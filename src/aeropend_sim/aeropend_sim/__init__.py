"""Aeropendulum plant model library (thesis Eqs. 3.1-3.10), rig parameter files and topic contract.

Also the simulated plant node (``sim_node``) and the excitation node (``excitation``).
"""
