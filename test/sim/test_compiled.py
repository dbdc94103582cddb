"""The compiled simulator backend (aeropend_sim.compiled): agreement with the LSODA reference per
effect set, the batch against single replays, parameter vectors, the disk cache, stiff rigs.

The per-family, per-effect agreement is the LSODA column of ``test_components.py``; here the
thesis rig with every effect on over 60 s, the figures docs/model.md states.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from aeropend_sim.compiled import plant as plant_mod
from aeropend_sim.compiled import xp_numba
from aeropend_sim.compiled.plant import compiled_plant
from aeropend_sim.compiled.source import family_module, module_source, skipped_when_off, switched_by_value
from aeropend_sim.components import registry
from aeropend_sim.components.thrust.propeller import thrust
from aeropend_sim.components.xp import MATH, NUMPY, OPERATIONS
from aeropend_sim.excitation import aprbs
from aeropend_sim.model import I_A, TAU_F, PlantModel
from aeropend_sim.params import Rig, RigFileError, load_rig
from aeropend_sim.simulation import PlantStepper, SimulationError, simulate, simulate_batch
from bench.backends import study
from bench.fixtures.component_rigs import rig as family_rig


def all_effects(contact: bool = False) -> Rig:
    """The thesis rig with every dynamic effect on: the issue-37 study's rig
    (``bench/backends/study.py``, docs/findings/simulator_backends.md); ``contact`` moves the upper
    stop to 0.65 rad, touched 10-30 % of the time by the step and APRBS inputs."""
    return study.all_effects_rig(contact=contact)


def inputs(dt: float) -> dict[str, np.ndarray]:
    """The study's 60 s of Latin-hypercube steps and of APRBS, and 10 s of its duty that changes
    every sample (LSODA needs 5 s for 60 s of that)."""
    out = study.inputs(dt)
    out["per_sample"] = out["per_sample"][: round(10.0 / dt)]
    return out


@pytest.mark.parametrize("contact", [False, True], ids=["all_effects", "end_stop_contact"])
def test_agrees_with_lsoda_with_every_effect_on(contact):
    """θ within 1e-6 rad of LSODA (rtol 1e-8) with every effect on, stop contact included; θ̇ within
    1e-5 of its range. The fast states i_a and ω₁ deviate most at start-up from rest, where the
    lagged duty crosses the dead-zone edge and the H-bridge map's 0 V clip inside a sub-step
    (kinks RK4 integrates at lower order): there to 1e-3 of their range, on 99.9 % of the samples
    to 1e-5."""
    rig = all_effects(contact)
    for name, duty in inputs(rig.sample_period).items():
        ref = simulate(rig, duty, backend="lsoda")
        got = simulate(rig, duty)
        err = np.abs(got.x - ref.x)
        assert err[:, 0].max() < 1e-6, (name, err.max(axis=0))
        assert err[:, 1].max() <= 1e-5 * np.ptp(ref.theta_dot), (name, err.max(axis=0))
        for k, ch in ((I_A, "i_a"), (3, "omega_rotor"), (None, "thrust"), (None, "v_a")):
            e = np.abs(got.true[ch] - ref.true[ch]) if k is None else err[:, k]
            span = np.ptp(ref.true[ch])
            assert e.max() <= 1e-3 * span and np.percentile(e, 99.9) <= 1e-5 * span, (name, ch, e.max())
        if contact and name != "per_sample":
            assert np.mean(ref.theta > 0.65) > 0.05, "the input should press the rod on the stop"


def test_batch_rows_equal_single_replays_bit_for_bit():
    """Varied values include a fractional and a whole-sample delay, a lag switched off by T_a = 0 and
    a dead zone at 0 (flags that follow the values); each row has its own initial state."""
    rig = all_effects(contact=True)
    dt = rig.sample_period
    duty = aprbs(1.5, lo=0.3, hi=1.0, min_hold=0.05, max_hold=0.3, seed=4, dt=dt).duty
    keys = ("actuator.input_delay", "actuator.lag_time_constant", "actuator.dead_zone", "pendulum.c_over_J")
    values = np.array([[0.005, 0.01, 0.03, 2.0], [2 * dt, 0.0, 0.0, 2.5], [0.0, 0.03, 0.1, 1.5]])
    x0 = np.array([[0.1, 0.0, 0.0, 0.0, 0.0], [0.3, -0.2, 0.1, 50.0, 0.4], [0.0, 0.0, 0.0, 0.0, 0.0]])
    plant = compiled_plant(rig)
    channels = plant.channels
    batch = simulate_batch(plant, duty, plant.vectors(keys, values), x0=x0, tau_before=0.4, channels=channels)
    by_mapping = simulate_batch(rig, duty, dict(zip(keys, values.T, strict=True)), x0=x0, tau_before=0.4,
                                channels=("theta",), threads=1)
    assert np.array_equal(by_mapping["theta"], batch["theta"])
    for b in range(len(values)):
        actuator = {k.partition(".")[2]: v for k, v in zip(keys[:3], values[b, :3], strict=True)}
        one = rig.with_params("actuator", **actuator)
        one = one.with_params("pendulum", c_over_J=values[b, 3])
        single = simulate(one, duty, x0=x0[b], tau_before=0.4)
        for ch in single.true:
            assert np.array_equal(batch[ch][b], single.true[ch]), (b, ch)
        assert np.array_equal(batch["tau_f"][b][1:], single.x[1:, TAU_F]) or b == 1  # b = 1: no lag


def test_batches_from_two_threads_at_once_equal_sequential_ones():
    """Callers' threads (a threaded scheduler) may run batches at once; each batch also shares its
    rows out to threads of its own (the kernel releases the GIL)."""
    rig = all_effects()
    duty = aprbs(1.0, lo=0.3, hi=1.0, min_hold=0.05, max_hold=0.3, seed=5, dt=rig.sample_period).duty
    plant = compiled_plant(rig)
    p = plant.vectors(("pendulum.c_over_J",), np.linspace(1.5, 3.0, 8)[:, None])
    alone = simulate_batch(plant, duty, p, threads=1)["theta"]
    with ThreadPoolExecutor(max_workers=2) as pool:
        jobs = [pool.submit(simulate_batch, plant, duty, p, threads=3) for _ in range(4)]
        results = [j.result()["theta"] for j in jobs]
    assert all(np.array_equal(r, alone) for r in results)


def test_vectors_follow_the_rig_and_refuse_bad_values():
    rig = all_effects()
    plant = compiled_plant(rig)
    keys = ("actuator.lag_time_constant", "motor.K_d", "pendulum.theta_max")
    rows = np.array([[0.0, 1e-7, 1.0], [0.02, 2e-7, 1.2]])
    got = plant.vectors(keys, rows)
    for b, (ta, kd, thmax) in enumerate(rows):
        one = rig.with_params("actuator", lag_time_constant=ta).with_params("motor", K_d=kd)
        one = one.with_params("pendulum", theta_max=thmax)
        assert np.array_equal(got[b], plant.layout.vector(PlantModel(one).assembly)), b
    assert got[0, plant.layout.flag_index("actuator_lag")] == 0.0  # T_a = 0: the lag is off
    with pytest.raises(RigFileError, match=r"parameter set 1: motor.K_d = -1.0 must be >= 0"):
        plant.vectors(("motor.K_d",), [[1e-7], [-1.0]])
    with pytest.raises(RigFileError, match=r"parameter set 0: pendulum.theta_min .* must be < theta_max"):
        plant.vectors(("pendulum.theta_max",), [[-2.0]])
    with pytest.raises(RigFileError, match="sensor_noise effect is off"):
        plant.vectors(("sensors.snr_db",), [[30.0]])
    with pytest.raises(RigFileError, match="not a parameter of a dc_hbridge rig"):
        plant.vectors(("motor.T_m",), [[0.1]])
    with pytest.raises(RigFileError, match=r"expected \(B, 2\)"):
        plant.vectors(("motor.K_d", "motor.B_m"), [[1e-7, 1e-6, 0.0]])


@pytest.mark.parametrize("rig", [*(family_rig(f.name) for f in registry.families()),
                                 all_effects(contact=True)],
                         ids=[*(f.name for f in registry.families()), "all_effects"])
def test_derivatives_equal_the_model_rhs_row_by_row(rig):
    """The compiled loop of many states (a recording's equation-error terms) gives what the
    model's scalar right-hand side gives per row, bit for bit, and the drive quantity of the
    command past the lag; the end stops are crossed (|θ| up to 3 rad)."""
    rng = np.random.default_rng(7)
    n = 4000
    x = np.column_stack([rng.uniform(-3.0, 3.0, n), rng.normal(0.0, 5.0, n), rng.uniform(-1.0, 4.0, n),
                         rng.uniform(-50.0, 900.0, n), rng.uniform(0.0, 1.0, n)])
    x[:50, 1] = 0.0  # the dry frictions' regularised kink at rest
    u = rng.uniform(0.0, 1.0, n)
    model = PlantModel(rig)
    f, drive = plant_mod.derivatives(model, x, u)
    assert np.array_equal(f, np.array([model.rhs(0.0, xk, uk) for xk, uk in zip(x, u, strict=True)]))
    tau = x[:, TAU_F] if model.lag else u
    assert np.array_equal(drive, [model.drive(float(t)) for t in tau])
    with pytest.raises(ValueError, match=r"states of shape \(4000, 4\) and commands of shape \(4000,\)"):
        plant_mod.derivatives(model, x[:, :4], u)


def test_the_scalar_rhs_is_generated_on_first_use_and_then_called_directly():
    """A model (a fit builds hundreds) writes and compiles its scalar right-hand side only when it
    is first used; from then on ``model.rhs`` is the generated function itself (an ODE solver calls
    it without a property or method in between)."""
    model = PlantModel(load_rig("thesis_rig"))
    assert "rhs" not in vars(model) and "rhs" not in vars(model.assembly)
    f = model.rhs
    assert vars(model)["rhs"] is f is model.assembly.rhs and f.__name__ == "rhs"
    assert f(0.0, [0.3, 0.0, 0.5, 200.0, 0.4], 0.4)[0] == 0.0  # dθ/dt = θ̇


@pytest.mark.parametrize("family", [f.name for f in registry.families()])
def test_absent_values_switch_terms_off_exactly(family):
    """Effects kept in the compiled model (every term in a summed slot) add an exact 0.0 with their
    parameters at their absent values, on any input (where they also have a flag, it only saves
    evaluating them); the others have a flag."""
    lay = compiled_plant(family_rig(family)).layout
    rng = np.random.default_rng(0)
    names = ("theta", "theta_dot", "i_a", "omega", "omega_prop", "thrust", "u", "tau_f", "tau", "omega_sp")
    inputs_ = {name: [0.0, -0.0, 1e-300, -1e6, *rng.normal(0.0, 100.0, 20).tolist()] for name in names}
    for eff in registry.family_effects(family):
        assert (eff.name in lay.flags) == (not switched_by_value(eff) or skipped_when_off(eff))
        if not switched_by_value(eff):
            continue
        absent = {p.name: p.absent for p in eff.params}
        for term in eff.terms:
            for k in range(24):
                values = {**absent, **{n: inputs_[n][k] for n in term.inputs}}
                assert term(MATH, values) == 0.0, (eff.name, term.label, values)


def test_a_switched_off_coulomb_friction_is_skipped_and_changes_nothing():
    """The two Coulomb frictions (tanh, Stribeck exp) have a flag that skips their terms where they
    are off; the cheap summed terms keep being switched by their absent values. Skipped or
    evaluated at their absent values, the replay is the same bit for bit (θ and every channel)."""
    flagged = {e.name for e in registry.family_effects("dc_hbridge") if skipped_when_off(e)}
    assert flagged == {"rotor_coulomb_friction", "rod_coulomb_friction"}
    rig = load_rig("thesis_rig")
    assert not rig.effects.rod_coulomb_friction and not rig.effects.rotor_coulomb_friction
    plant = compiled_plant(rig)
    dt = rig.sample_period
    duty = aprbs(3.0, lo=0.3, hi=1.0, min_hold=0.05, max_hold=0.3, seed=7, dt=dt).duty
    p = plant.p[None, :].copy()
    evaluated = p.copy()
    for name in flagged:
        assert p[0, plant.layout.flag_index(name)] == 0.0
        evaluated[0, plant.layout.flag_index(name)] = 1.0  # the terms run, at their absent values
    x0 = np.array([[0.2, -0.1, 0.0, 30.0, 0.0]])
    names = plant.channels
    skipped, fail_s = plant.replay_batch(duty, p, x0, 0.4, names, threads=1)
    run, fail_r = plant.replay_batch(duty, evaluated, x0, 0.4, names, threads=1)
    assert fail_s[0] == fail_r[0] == -1
    assert np.array_equal(skipped, run)
    assert np.ptp(skipped[0, list(names).index("theta")]) > 0.1  # the rod moves


def test_generated_module_calls_the_registry_terms():
    """No second copy of an equation: the module imports each term function of the family."""
    for fam in registry.families():
        states = tuple(st.name for e in registry.family_effects(fam.name) for st in e.states)
        text = module_source(fam.name, states)  # a rig with every effect state: every term
        for part in (*registry.family_parts(fam.name), *registry.family_effects(fam.name)):
            for term in part.terms:
                assert f"from {term.fn.__module__} import {term.fn.__name__} as " in text, term.label


def test_disk_cache_serves_a_new_process():
    """A second process loads every kernel a simulation needs from numba's disk cache."""
    rig = all_effects()
    simulate(rig, np.full(50, 0.5))  # compiled (or loaded) here: the cache files exist
    module = family_module(rig.family).__name__
    code = ("import json, time; t0 = time.process_time(); import numpy as np\n"
            "from aeropend_sim.simulation import simulate\n"
            "from aeropend_sim.compiled.source import family_module\n"
            "from bench.backends.study import all_effects_rig\n"
            "simulate(all_effects_rig(), np.full(50, 0.5))\n"
            "m = family_module('dc_hbridge')\n"
            "count = lambda c: sum(c.values())\n"
            "stats = {k: [count(getattr(m, k).stats.cache_hits), count(getattr(m, k).stats.cache_misses)]"
            " for k in ('replay', 'outputs', 'jacobians')}\n"
            "print(json.dumps({'module': m.__name__, 'stats': stats, 'cpu_s': time.process_time() - t0}))\n")
    root = Path(__file__).resolve().parents[2]  # the repository: bench.backends imports from there
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=300,
                         env={**os.environ, "PYTHONPATH": str(root)})
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert report["module"] == module
    for kernel, (hits, misses) in report["stats"].items():
        assert hits >= 1 and misses == 0, (kernel, hits, misses)


def test_stiff_rig_gets_more_substeps_and_divergence_is_reported(monkeypatch):
    """L_a/R_a = 10 µs (|λ| ≈ 1e5/s): the plan adds sub-steps and the replay stays on LSODA's; with
    the sub-steps capped the replay diverges and says so."""
    rig = load_rig("thesis_rig").with_params("motor", L_a=1.08e-5)
    plant = compiled_plant(rig)
    assert plant.plan.substeps[0] > 400
    duty = np.r_[np.zeros(20), np.full(200, 0.7)]
    ref = simulate(rig, duty, backend="lsoda")
    assert np.abs(simulate(rig, duty).theta - ref.theta).max() < 1e-8
    monkeypatch.setattr(plant_mod, "MAX_SUBSTEPS", 6)
    with pytest.raises(SimulationError, match=r"diverged at sample \d+ \(t = .* s\): a state is not finite"):
        simulate(rig, duty)
    stiff_row = {"motor.L_a": [2.2e-3, 1.08e-5]}  # set 0: the thesis rig's L_a, set 1: the stiff one
    with pytest.raises(SimulationError, match=r"parameter set 1: the compiled replay diverged .* than 6 RK4"):
        simulate_batch(load_rig("thesis_rig"), duty, stiff_row)


def test_stepper_equals_simulate_bit_for_bit():
    rig = all_effects(contact=True).with_effects(armature_inductance="quasi_static")
    duty = np.repeat(np.random.default_rng(1).uniform(0.2, 0.9, 25), 20)
    batch = simulate(rig, duty)
    stepper = PlantStepper(rig)
    states = [stepper.x.copy()]
    for u in duty[:-1]:
        stepper.step(float(u))
        states.append(stepper.x.copy())
    assert np.array_equal(np.array(states)[1:], batch.x[1:])  # x[0]: the initial state as given
    for traj in (batch, simulate(rig, duty, backend="lsoda")):  # quasi-static: the algebraic current
        assert np.array_equal(traj.x[:, I_A], traj.true["i_a"])


def test_bad_backend_and_channel_are_refused():
    rig = load_rig("thesis_rig")
    with pytest.raises(SimulationError, match=r"backend 'jax': expected one of \['compiled', 'lsoda'\]"):
        simulate(rig, np.full(5, 0.5), backend="jax")
    with pytest.raises(SimulationError, match=r"channel\(s\) \['v_a'\] do not exist for a esc rig"):
        simulate_batch(family_rig("esc"), np.full(5, 0.5), {}, channels=("theta", "v_a"))
    with pytest.raises(SimulationError, match=r"initial states of shape \(2, 4\)"):
        simulate_batch(rig, np.full(5, 0.5), {"motor.K_d": [1e-7, 2e-7]}, x0=np.zeros((2, 4)))


def test_numba_namespace_gives_the_values_of_math():
    special = [0.0, -0.0, 1.5, -2.5, math.inf, -math.inf, math.nan]
    assert all(hasattr(xp_numba, op) for op in OPERATIONS)
    for a in special:
        assert repr(xp_numba.sign(a)) == repr(MATH.sign(a))
        for b in special:
            for op in ("maximum", "minimum"):
                assert repr(getattr(xp_numba, op)(a, b)) == repr(getattr(MATH, op)(a, b)), (op, a, b)


def test_numba_tanh_is_libms_bit_for_bit_across_its_saturation():
    """xp_numba.tanh skips the libm call where tanh is ±1.0; it must give math.tanh's values there
    and on both sides of the cut-off, signed zeros, infinities and NaN included."""
    cut = xp_numba.TANH_SATURATED
    near = [np.nextafter(cut, 0.0), cut, np.nextafter(cut, 50.0), 18.0, 19.0615, 19.07, 20.0, 21.5, 30.0,
            1e300, 0.005, 1e-310, 0.0, -0.0, math.inf, math.nan]
    grid = np.linspace(-40.0, 40.0, 16001).tolist()
    for a in (*near, *(-x for x in near), *grid):
        assert repr(xp_numba.tanh(a)) == repr(math.tanh(a)), a
    assert math.tanh(np.nextafter(cut, 0.0)) == 1.0  # libm is already 1.0 just below: the cut is safe


#: Bases whose libm ``pow(a, 2.0)`` is one ulp off the correctly rounded square a·a (glibc).
_POW_OFF_BY_ONE_ULP = (2846.831024813296, 1400.1116057980619, 790.7557591791938)


def test_an_exponent_of_two_is_the_square_in_every_namespace():
    """power(a, 2) = a·a exactly, the same in the math, NumPy and numba namespaces (the xp module
    doc, "Squares"); any other exponent is still a**b."""
    bases = np.array([0.0, 1e-300, 0.5, 3.0, 217.25, *_POW_OFF_BY_ONE_ULP])
    assert any(pow(float(a), 2.0) != a * a for a in bases)  # the cases the change is about
    for a in bases.tolist():
        assert MATH.power(a, 2.0) == a * a
        assert xp_numba.power(a, 2.0) == a * a
        assert MATH.power(a, 1.9) == xp_numba.power(a, 1.9) == a**1.9
    assert np.array_equal(NUMPY.power(bases, 2.0), bases * bases)
    alphas = np.where(np.arange(bases.size) % 2 == 0, 2.0, 1.9)
    assert np.array_equal(NUMPY.power(bases, alphas), np.where(alphas == 2.0, bases * bases, bases**1.9))
    assert NUMPY.power(3.0, 1.5) == 3.0**1.5


class _SpyXP:
    """MATH that records the bases ``power`` is called with."""

    def __init__(self) -> None:
        self.bases: list[float] = []

    def __getattr__(self, name):
        return getattr(MATH, name)

    def power(self, a, b):
        self.bases.append(a)
        return MATH.power(a, b)


def test_thrust_law_never_raises_zero_to_a_power():
    """At rest the thrust is 0 without 0^α, whose ∂/∂α = 0^α·ln 0 is NaN under automatic
    differentiation; elsewhere the values are K_q·sign(ω₂)·|ω₂|^α, bit for bit."""
    spy = _SpyXP()
    for w in (0.0, -0.0):
        for alpha in (1.0, 1.9, 2.0, 2.3):
            assert thrust(spy, w, 2.8585e-4, alpha) == 0.0
    assert all(b > 0.0 for b in spy.bases)
    for w in np.linspace(-300.0, 300.0, 61):
        expected = 2.8585e-4 * MATH.sign(float(w)) * MATH.power(abs(float(w)), 1.9)
        assert thrust(MATH, float(w), 2.8585e-4, 1.9) == expected
