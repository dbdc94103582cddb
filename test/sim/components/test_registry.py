"""The component registry: every effect acts, is documented, is absent when absent, linearises, and
simulates alike on the compiled backend and the LSODA reference.

Adding an effect is one module under ``aeropend_sim/components`` plus ONE row in :data:`ROWS`
(the parameter values at which the effect clearly acts); every test here then covers it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_sim.components import registry
from aeropend_sim.components.base import INPUTS, SECTIONS, SLOT_INPUTS, SLOTS, Effect
from aeropend_sim.components.xp import MATH, NUMPY, OPERATIONS
from aeropend_sim.model import PlantModel
from aeropend_sim.params import Rig, RigFileError
from aeropend_sim.simulation import simulate
from bench.fixtures.component_rigs import rig as family_rig

#: One row per effect: parameter values at which switching it on clearly changes the response.
ROWS: dict[str, dict[str, float]] = {
    "input_delay": {"actuator.input_delay": 0.03},
    "actuator_lag": {"actuator.lag_time_constant": 0.05},
    "dead_zone": {"actuator.dead_zone": 0.1},
    "hbridge_map": {"actuator.hbridge_k0": -0.2914, "actuator.hbridge_k1": 6.8e-4,
                    "actuator.hbridge_k2": 1.469e7, "actuator.hbridge_k3": 4.3629e4},
    "armature_inductance": {"motor.L_a": 0.05},
    "back_emf": {"motor.K_omega": 0.03},
    "rotor_viscous_friction": {"motor.B_m": 2e-5},
    "propeller_drag": {"motor.K_d": 5e-7},
    "thrust_exponent": {"thrust.exponent": 1.8},
    "rod_viscous_friction": {"pendulum.c_over_J": 3.0},
    "rod_coulomb_friction": {"pendulum.coulomb_over_J": 0.8, "pendulum.stribeck_over_J": 0.5},
    "end_stops": {"pendulum.theta_max": 0.25, "pendulum.stop_stiffness": 3000.0,
                  "pendulum.stop_damping": 60.0},
    "sensor_noise": {"sensors.snr_db": 30.0},
    "quantisation": {"sensors.theta_quantum": 0.01},
    "rotor_coulomb_friction": {"motor.T_c": 4e-4},
    "motor_heating": {"motor.alpha_R": 3.93e-3, "motor.R_th": 20.0, "motor.C_th": 0.2},
}

CASES = [(f.name, e.name) for f in registry.families() for e in registry.family_effects(f.name)]


def _duty(rig: Rig, seconds: float = 1.5) -> np.ndarray:
    """Rest, a step to the duty holding 0.5 rad, then one holding 0.2 rad."""
    m = PlantModel(rig)
    n = round(seconds / rig.sample_period)
    d = np.full(n, m.equilibrium(0.5)[1])
    d[: n // 10] = 0.0
    d[n // 2:] = m.equilibrium(0.2)[1]
    return d


def _set(rig: Rig, values: dict[str, float]) -> Rig:
    for key, v in values.items():
        section, _, name = key.partition(".")
        rig = rig.with_params(section, **{name: v})
    return rig


def _without(rig: Rig, effect: Effect) -> Rig:
    """The rig with the effect off and its parameters at their absent values."""
    rig = rig.with_effects(**{effect.name: effect.off})
    return _set(rig, {p.key: p.absent for p in effect.params if p.absent is not None})


def _run(rig: Rig, duty: np.ndarray) -> dict[str, np.ndarray]:
    tr = simulate(rig, duty, seed=5)
    return {"x": tr.x, **tr.channels()}


def test_every_effect_has_a_row():
    assert set(ROWS) == {e.name for e in registry.effects()}, "add one row per effect to ROWS"


def test_registry_is_consistent():
    registry.owners()  # raises on a key or a name declared twice
    for p in registry.params().values():
        assert p.unit and p.doc and p.section in SECTIONS, p.key
    for part in registry.parts():
        assert part.label and part.description, part.name
        for term in part.terms:
            assert term.slot in SLOTS, term.label
            assert set(term.inputs) - set(term.states) <= set(SLOT_INPUTS[term.slot]), term.label
            for a in term.param_names:
                names = {p.partition(".")[2] for p in registry.params()}
                assert a in names, f"{term.label}: unknown parameter {a}"
            if term.slot in ("duty", "drive", "thrust", "gear", "rotor_response"):
                assert term.inverse is not None, f"{term.label} needs an inverse"
    for ns in (MATH, NUMPY):
        assert all(callable(getattr(ns, op)) for op in OPERATIONS)
    assert set(INPUTS) >= {i for ins in SLOT_INPUTS.values() for i in ins}
    # each family has exactly one drive map of its own and a rotor
    for fam in registry.families():
        parts = registry.family_parts(fam.name)
        assert [t.slot for p in parts for t in p.terms].count("drive") == 1, fam.name
        assert {p.part for p in parts} >= {"actuator", "rotor", "thrust", "pendulum", "sensors"}


@pytest.mark.parametrize("family,effect", CASES, ids=[f"{f}-{e}" for f, e in CASES])
def test_effect_acts_is_absent_when_absent_and_linearises(family, effect):
    eff = registry.effect(effect)
    base = family_rig(family)
    off = _without(base, eff)
    duty = _duty(off)
    ref = _run(off, duty)
    # switched on with every parameter absent: the same trajectory bit for bit, or refused by name
    try:
        absent_on = off.with_effects(**{effect: eff.on})
    except RigFileError as exc:
        assert any(p.key in str(exc) for p in eff.params), str(exc)
    else:
        got = _run(absent_on, duty)
        assert set(got) == set(ref)
        for k in ref:
            assert np.array_equal(got[k], ref[k]), f"{effect} on with absent parameters changed {k}"
    # switched on at the row's values: the response changes
    row = {k: v for k, v in ROWS[effect].items() if k in registry.family_params(family)}
    on = _set(off, row).with_effects(**{effect: eff.on})
    got = _run(on, duty)
    change = max(float(np.max(np.abs(got[k] - ref[k]))) for k in ("theta", "omega_rotor"))
    assert change > 1e-3, f"{effect} at {row} changes θ/ω₁ by only {change:g}"
    # the compiled backend (the default) agrees with the LSODA reference (docs/model.md)
    lsoda = simulate(on, duty, seed=5, backend="lsoda").x
    err = np.abs(got["x"] - lsoda).max(axis=0)
    assert err[0] < 1e-6 and np.all(err[1:4] <= 1e-5 * np.ptp(lsoda[:, 1:4], axis=0)), err
    # the Jacobian (chain rule over the terms' partials) matches finite differences of rhs
    m = PlantModel(on)
    rng = np.random.default_rng(1)
    for _ in range(4):
        x = np.array([rng.uniform(0.05, 0.45), rng.uniform(-1.0, 1.0), rng.uniform(0.05, 0.5),
                      rng.uniform(50.0, 300.0), rng.uniform(0.2, 0.8),
                      *(rng.uniform(0.0, st.typical) for st in m.states.extra)])
        u = float(rng.uniform(0.2, 0.8))
        A, B = m.jacobian(x, u)
        A_fd, B_fd = _fd(m, x, u)
        assert np.allclose(A, A_fd, rtol=1e-5, atol=1e-6 * max(np.abs(A_fd).max(), 1.0)), (A, A_fd)
        assert np.allclose(B, B_fd, rtol=1e-5, atol=1e-6 * max(np.abs(B_fd).max(), 1.0)), (B, B_fd)


def _fd(m: PlantModel, x: np.ndarray, u: float, h: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    n = m.states.size
    A = np.zeros((n, n))
    for j in range(n):
        d = np.zeros(n)
        d[j] = h * max(1.0, abs(x[j]))
        A[:, j] = (np.array(m.rhs(0, x + d, u)) - np.array(m.rhs(0, x - d, u))) / (2 * d[j])
    B = ((np.array(m.rhs(0, x, u + h)) - np.array(m.rhs(0, x, u - h))) / (2 * h))[:, None]
    return A, B


@pytest.mark.parametrize("family", [f.name for f in registry.families()])
def test_each_family_settles_where_its_equilibrium_says(family):
    """From rest at the equilibrium duty of 0.3 rad the rod settles at 0.3 rad and the rotor at the
    equilibrium speed; for an ESC that speed is the static throttle map's."""
    rig = family_rig(family).with_effects(input_delay=False)
    m = PlantModel(rig)
    x_eq, tau = m.equilibrium(0.3)
    assert np.allclose(m.rhs(0.0, x_eq, tau), 0.0, atol=1e-9)
    tr = simulate(rig, np.full(round(30.0 / rig.sample_period), tau))
    assert tr.theta[-1] == pytest.approx(0.3, abs=2e-4)
    assert tr.omega_rotor[-1] == pytest.approx(x_eq[3], rel=1e-4)
    if family == "esc":
        a = rig.actuator
        w_map = a.omega_max * max(0.0, (tau - a.idle_duty) / (1.0 - a.idle_duty)) ** a.curve_exponent
        assert tr.omega_rotor[-1] == pytest.approx(w_map, rel=1e-4)
        assert "i_a" not in tr.channels() and "v_a" not in tr.channels()  # absent, not zeros
        assert x_eq[2] == 0.0
    else:
        assert {"i_a", "v_a"} <= set(tr.channels())
    # the thrust at the rotor speed balances gravity: (L/J)·f = (mgd/J)·sin θ
    assert m.thrust(x_eq[3]) * rig.pendulum.L_over_J == pytest.approx(rig.pendulum.mgd_over_J * math.sin(0.3))


def test_esc_map_equilibrium_and_limits():
    rig = family_rig("esc")
    m = PlantModel(rig)
    a = rig.actuator
    assert m.drive(a.idle_duty) == 0.0 and m.drive(0.05) == 0.0
    assert m.drive(1.0) == pytest.approx(a.omega_max)
    for tau in (0.2, 0.55, 0.9):
        assert m.duty_for_drive(m.drive(tau)) == pytest.approx(tau, rel=1e-12)
    with pytest.raises(ValueError, match="armature voltage"):
        m.armature_voltage(0.5)
    assert m.current([0.1, 0.0, 0.0, 200.0, 0.5], 0.5) == 0.0
    with pytest.raises(ValueError, match=r"duty cycle .* > 1"):
        m.duty_for_drive(2.0 * a.omega_max)


def test_docs_tables_are_generated_from_the_registry():
    """docs/model.md's families, slots, components, effects and parameters tables and docs/gap.md's
    catalog table are current (rewrite them with ``python tools/gen_model_tables.py``)."""
    from pathlib import Path

    from tools.gen_model_tables import FILES, render

    root = Path(__file__).resolve().parents[3]
    for name, tables in FILES.items():
        _, stale = render((root / "docs" / name).read_text(encoding="utf-8"), tables)
        assert not stale, f"docs/{name}: stale table(s) {stale}; run tools/gen_model_tables.py"
