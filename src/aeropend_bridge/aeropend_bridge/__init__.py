"""Serial bridge to the Arduino Mega acquisition firmware.

Publishes the same topics as the simulated plant (:mod:`aeropend_sim.contract`).
"""
