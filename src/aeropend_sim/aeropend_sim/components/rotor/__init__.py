"""rotor components and effects: one declaration per module, found by
:mod:`aeropend_sim.components.registry`."""
