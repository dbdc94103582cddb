"""Aeropendulum controllers (thesis chapter 6).

PID, small-signal linearisation, feedback linearisation and cascade control.
"""
