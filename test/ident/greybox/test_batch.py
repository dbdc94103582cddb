"""Fit replays (aeropend_ident.greybox.batch): their sub-step plan against the LSODA reference.

The fits replay at least one RK4 sub-step per 2.048 ms sample and keep |h·λ| ≤ FIT_STEP_BOUND
(RK4 stays stable; the stiff modes are faster than a sample and only their slow manifold is
seen), the reference simulator 6 sub-steps and |h·λ| ≤ 0.5: the agreement the module doc states.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from aeropend_ident.greybox.batch import (
    FIT_STEP_BOUND,
    THREADS_ENV,
    RigReplays,
    one_replay_thread,
    replay_threads,
)
from aeropend_sim.compiled.plant import STEP_BOUND, CompiledPlant, compiled_plant
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
    k_ref = int(compiled_plant(rig, substeps=1, step_bound=STEP_BOUND).plan.substeps[0])
    assert k <= max(1, int(np.ceil(k_ref * STEP_BOUND / FIT_STEP_BOUND)))
    assert np.abs(theta - ref.x[:, 0]).max() < 1e-5


def test_a_step_bound_beyond_rk4_stability_is_refused():
    with pytest.raises(ValueError, match="step_bound"):
        compiled_plant(study.all_effects_rig(), step_bound=3.0)


def test_one_replay_thread_holds_for_the_calling_thread_only(monkeypatch):
    """Inside the block this thread's batch replays run on it alone; another thread keeps the
    default (one per core), and the block restores what was before, nested or not."""
    monkeypatch.delenv(THREADS_ENV, raising=False)
    assert replay_threads() is None
    seen = {}
    with one_replay_thread():
        seen["inside"] = replay_threads()
        other = threading.Thread(target=lambda: seen.setdefault("other thread", replay_threads()))
        other.start()
        other.join()
        with one_replay_thread():
            pass
        seen["after a nested block"] = replay_threads()
    assert seen == {"inside": 1, "other thread": None, "after a nested block": 1}
    assert replay_threads() is None
    monkeypatch.setenv(THREADS_ENV, "3")
    assert replay_threads() == 3
    with one_replay_thread():
        assert replay_threads() == 1
    assert replay_threads() == 3


def test_a_batch_inside_one_replay_thread_is_not_split_and_gives_the_same_replays(monkeypatch):
    monkeypatch.delenv(THREADS_ENV, raising=False)
    rig = study.all_effects_rig()
    duty = study.inputs(rig.sample_period)["aprbs"][:500]
    rigs = [rig.with_params("pendulum", c_over_J=rig.pendulum.c_over_J * f) for f in (0.5, 1.0, 1.5, 2.0)]
    x0 = np.zeros((4, 5))
    asked = []
    split = CompiledPlant.replay_batch

    def spy(self, *args, **kwargs):
        asked.append(args[5] if len(args) > 5 else kwargs.get("threads"))
        return split(self, *args, **kwargs)

    monkeypatch.setattr(CompiledPlant, "replay_batch", spy)
    rr = RigReplays(duty, rig.sample_period, tau_before=0.0)
    shared, ok_shared = rr.run(rigs, x0, ("theta",))
    with one_replay_thread():
        alone, ok_alone = rr.run(rigs, x0, ("theta",))
    assert asked == [None, 1]
    assert ok_shared.all() and ok_alone.all()
    assert np.array_equal(shared["theta"], alone["theta"])
    assert len({float(th[-1]) for th in alone["theta"]}) == 4
