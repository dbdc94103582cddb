"""Aeropendulum controllers: PID, small-signal linearisation, feedback linearisation, cascade (thesis chapter 6)."""
