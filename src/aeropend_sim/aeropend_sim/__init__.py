"""Aeropendulum plant model library (thesis Eqs. 3.1-3.10), rig parameter files, topic contract, simulated plant node and excitation node."""
