"""The compiled simulator backend (issue 37): the plant's component functions compiled by numba
into a fixed-step RK4 replay whose cost does not depend on how often the input changes.

``source`` writes one module per actuator family from the registry (:mod:`.source`), ``kernels``
is the integrator text those modules end with, ``xp_numba`` the ``xp`` namespace numba compiles
the terms against, and ``plant`` the object the simulator and the fits use
(:class:`.plant.CompiledPlant`). The public entry points are
:func:`aeropend_sim.simulation.simulate` (``backend="compiled"``) and
:func:`aeropend_sim.simulation.simulate_batch`.
"""
