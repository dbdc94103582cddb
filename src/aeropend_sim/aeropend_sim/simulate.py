"""Deprecated: this module is :mod:`aeropend_sim.simulation` now; import from ``aeropend_sim``.

``from aeropend_sim.simulate import simulate`` keeps working, with a :class:`DeprecationWarning`,
for scripts written before the rename: ``from aeropend_sim import simulate, PlantStepper`` (or
``from aeropend_sim.simulation import ...``) is the path now. The module was renamed because the
package exports the *function* ``simulate``: a submodule of that name replaces the package
attribute when it is imported, so in a process that imports this module ``aeropend_sim.simulate``
is this module, not the function.
"""

import warnings

from aeropend_sim.simulation import (
    BACKENDS,
    DEFAULT_BACKEND,
    PlantStepper,
    SimulationError,
    Trajectory,
    measure,
    simulate,
    simulate_batch,
)

__all__ = ["BACKENDS", "DEFAULT_BACKEND", "PlantStepper", "SimulationError", "Trajectory", "measure",
           "simulate", "simulate_batch"]

warnings.warn("aeropend_sim.simulate is deprecated: import from aeropend_sim "
              "(or aeropend_sim.simulation)", DeprecationWarning, stacklevel=2)
