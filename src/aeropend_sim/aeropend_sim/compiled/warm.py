"""Compile the simulator's kernels for every actuator family once, before many processes need them.

The generated modules (:mod:`aeropend_sim.compiled.source`) compile on their first call in a
machine's first process and load from numba's disk cache afterwards. Processes that start together
on an empty cache (the test suite's parallel workers and the commands its tests start, the workers
of a local Dask cluster) each compile the same kernels at once, seconds of CPU per family each.
:func:`warm` compiles them in one process first: every registered family, its module without effect
states and its module with every effect that has a state of its own (``motor_heating``), through
the calls the simulator, the replays and the fits make (a replay and its outputs, a batch replay
with its sub-step plan, one step, the right-hand side at many states).

``python -m aeropend_sim.compiled.warm`` runs it (``scripts/setup_env.sh`` does after installing).
"""

from __future__ import annotations

import sys
import time

import numpy as np
import yaml

from aeropend_sim.compiled.plant import CompiledPlant, derivatives
from aeropend_sim.components import registry
from aeropend_sim.model import PlantModel
from aeropend_sim.params import Rig, rig_from_dict
from aeropend_sim.rigfile.template import new_rig_text


def _variants(family: str) -> list[Rig]:
    """The family's ``rig new`` rig, and the same with every effect that has a state switched on."""
    rig = rig_from_dict(yaml.safe_load(new_rig_text(family, {})), f"rig new --actuator {family}")
    stateful = [e for e in registry.family_effects(family) if e.states]
    if not stateful:
        return [rig]
    heated = rig
    for effect in stateful:  # the effect's parameters at their typical values (``rig new``'s starting values)
        for p in effect.params:
            if p.typical is not None:
                heated = heated.with_params(p.section, **{p.name: p.typical})
    return [rig, heated.with_effects(**{e.name: e.on for e in stateful})]


def _exercise(rig: Rig) -> None:
    """One call of each kernel of ``rig``'s compiled module (loaded from the disk cache, or compiled)."""
    model = PlantModel(rig)
    plant = CompiledPlant(model)
    n = plant.states.size
    duty = np.full(8, 0.3)
    states, u, _ = plant.replay(duty, np.zeros(n))
    plant.outputs(states, u)
    plant.replay_batch(duty, plant.p[None, :], np.zeros((1, n)), 0.0, plant.channels, threads=1)
    plant.step(np.zeros(n), 0.3, 0.3)
    derivatives(model, states, duty)


def warm(families: list[str] | None = None) -> list[tuple[str, float]]:
    """Load or compile the kernels of ``families`` (default: every registered one).

    Returns
    -------
    list of (str, float)
        Each family and the seconds its modules took (about 0.2 s once cached).
    """
    out = []
    for family in families or [f.name for f in registry.families()]:
        t0 = time.perf_counter()
        for rig in _variants(family):
            _exercise(rig)
        out.append((family, time.perf_counter() - t0))
    return out


def main(argv: list[str] | None = None) -> int:
    """Warm every family's kernels and say how long each took."""
    del argv
    for family, seconds in warm():
        print(f"compiled simulator of the {family} family ready ({seconds:.1f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
