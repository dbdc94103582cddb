"""Fit replays (aeropend_ident.greybox.batch): their sub-step plan against the LSODA reference.

The fits replay at least one RK4 sub-step per 2.048 ms sample and keep |h·λ| ≤ FIT_STEP_BOUND
(RK4 stays stable; the stiff modes are faster than a sample and only their slow manifold is
seen), the reference simulator 6 sub-steps and |h·λ| ≤ 0.5: the agreement the module doc states.
"""

from __future__ import annotations

import numpy as np
import pytest

from aeropend_ident.greybox.batch import FIT_STEP_BOUND, RigReplays
from aeropend_sim.compiled.plant import STEP_BOUND, CompiledPlant
from aeropend_sim.simulation import simulate
from bench.backends import study

SPAN_S = 10.0


def _fit_replay(rig, duty, x0):
    rr = RigReplays(duty, rig.sample_period, tau_before=0.0)
    out, ok = rr.run([rig], x0[None, :], ("theta",))
    assert ok[0]
    plant, _ = rr.plant(rig)
    return out["theta"][0], int(plant.plans(plant.p[None, :]).substeps[0])


def test_fit_replays_of_the_thesis_rig_with_every_effect_on_agree_with_lsoda():
    """One sub-step per sample: θ within 3e-5 rad of LSODA (the study's K = 1 column: 1.9e-5 on
    steps, 1.6e-5 on APRBS, 2.5e-6 on a duty changing every sample), far below a recorded angle's
    noise (a 12-bit encoder's rounding alone is 4.4e-4 rad RMS)."""
    rig = study.all_effects_rig()
    for name, duty in study.inputs(rig.sample_period).items():
        duty = duty[: round(SPAN_S / rig.sample_period)]
        ref = simulate(rig, duty, backend="lsoda")
        theta, k = _fit_replay(rig, duty, ref.x[0])
        assert k == 1, name
        assert np.abs(theta - ref.x[:, 0]).max() < 3e-5, name


@pytest.mark.parametrize("coulomb_over_J", [5.0, 20.0, 60.0])
def test_a_stiff_dry_friction_needs_fewer_fit_sub_steps_and_stays_accurate(coulomb_over_J):
    """The regularised Coulomb law's slope at rest, (T_c/J)/v_ε up to 6000 s⁻¹, sets the stiffness:
    the fit bound takes a quarter of the reference bound's sub-steps, and θ stays within 1e-5 rad of
    LSODA while the rod sticks (62-100 % of the time) and slips."""
    rig = study.all_effects_rig().with_params("pendulum", coulomb_over_J=coulomb_over_J)
    duty = study.inputs(rig.sample_period)["aprbs"][: round(SPAN_S / rig.sample_period)]
    ref = simulate(rig, duty, backend="lsoda")
    theta, k = _fit_replay(rig, duty, ref.x[0])
    k_ref = int(CompiledPlant(rig, substeps=1, step_bound=STEP_BOUND).plan.substeps[0])
    assert k <= max(1, int(np.ceil(k_ref * STEP_BOUND / FIT_STEP_BOUND)))
    assert np.abs(theta - ref.x[:, 0]).max() < 1e-5


def test_a_step_bound_beyond_rk4_stability_is_refused():
    with pytest.raises(ValueError, match="step_bound"):
        CompiledPlant(study.all_effects_rig(), step_bound=3.0)
