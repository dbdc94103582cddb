"""``python -m aeropend_sim.compiled.warm`` (run by scripts/setup_env.sh) prepares the compiled module
of every registered family with and without its stateful effects: the modules the suite's parallel
workers would otherwise each compile on an empty cache."""

from __future__ import annotations

import numpy as np

from aeropend_sim.compiled import warm
from aeropend_sim.compiled.plant import compiled_plant
from aeropend_sim.components import registry
from aeropend_sim.model import PlantModel


def test_warm_prepares_every_family_with_and_without_its_effect_states() -> None:
    families = [f.name for f in registry.families()]
    assert [family for family, _ in warm.warm()] == families
    for family in families:
        rigs = warm._variants(family)
        extra = [tuple(st.name for st in PlantModel(r).states.extra) for r in rigs]
        stateful = [st.name for e in registry.family_effects(family) for st in e.states]
        assert extra == ([(), tuple(stateful)] if stateful else [()]), family
        for rig in rigs:  # each variant simulates: its module's kernels are the ones loaded
            plant = compiled_plant(rig)
            states, _, failed = plant.replay(np.full(50, 0.4), np.zeros(plant.states.size))
            assert failed == -1 and np.all(np.isfinite(states))
    assert any(len(warm._variants(f)) == 2 for f in families)  # motor heating's temperature state
