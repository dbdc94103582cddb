"""The state vector's one home (issue 64): a rig's layout, an effect with a state of its own.

``motor_heating`` declares the winding's temperature rise T_m: R_a(T_m) = R_a·(1 + α_R·T_m),
C_th·dT_m/dt = R_a(T_m)·i_a² − T_m/R_th. The checks below are worked out by hand from those two
equations and the recorded current, never by the model's own code.
"""

from __future__ import annotations

import numpy as np
import pytest

from aeropend_sim.components.states import CHAIN, N_CHAIN, StateLayout
from aeropend_sim.model import plant_model
from aeropend_sim.params import RigFileError, load_rig
from aeropend_sim.simulation import PlantStepper, SimulationError, simulate
from bench.fixtures.component_rigs import rig as family_rig

ALPHA, R_TH, C_TH = 3.93e-3, 20.0, 0.5  # copper; a small motor's 20 K/W; τ_th = 10 s


def _heated(name: str = "thesis_rig"):
    return load_rig(name).with_params("motor", alpha_R=ALPHA, R_th=R_TH, C_th=C_TH).with_effects(
        motor_heating=True)


def test_a_rig_without_effect_states_has_the_chain_and_a_heated_one_adds_t_m_after_it():
    plain = plant_model(load_rig("thesis_rig")).states
    heated = plant_model(_heated()).states
    assert plain.names == tuple(s.name for s in CHAIN) and plain.size == N_CHAIN
    assert heated.names[:N_CHAIN] == plain.names and heated.names[N_CHAIN:] == ("T_m",)
    assert heated.index("T_m") == 5 and heated.index("omega") == heated.index("omega_rotor") == 3
    with pytest.raises(KeyError, match=r"no state 'T_m' on this rig; its states are \['theta'"):
        plain.index("T_m")
    with pytest.raises(ValueError, match=r"state name\(s\) \['theta'\] declared twice"):
        StateLayout.of([CHAIN[0]])


def test_an_esc_rig_refuses_motor_heating_by_reason():
    with pytest.raises(RigFileError, match="armature"):
        family_rig("esc").with_effects(motor_heating=True)


def test_the_winding_warms_to_its_thermal_steady_state_and_the_rod_sags():
    """A held duty for 8 thermal time constants: T_m ends at R_th·R_a(T_m)·i_a², R_a(T_m)·i_a equals
    the voltage the back-EMF leaves (steady armature: i_a = (v_a − K_ω·ω₁)/R_a(T_m)), the early
    warming rate is (R_a(T_m)·i_a² − T_m/R_th)/C_th, and the rod settles lower than without heating."""
    rig = _heated()
    m = rig.motor
    n = round(8 * R_TH * C_TH / rig.sample_period)
    duty = np.full(n, 0.6)
    tr = simulate(rig, duty)
    cold = simulate(load_rig("thesis_rig"), duty)
    t_m = tr.x[:, plant_model(rig).states.index("T_m")]
    i_a = tr.true["i_a"]
    r_hot = m.R_a * (1.0 + ALPHA * t_m[-1])
    assert t_m[0] == 0.0 and t_m[-1] > 5.0
    assert t_m[-1] == pytest.approx(R_TH * r_hot * i_a[-1] ** 2, rel=1e-3)
    back_emf = m.K_omega * tr.x[-1, 3]
    assert r_hot * i_a[-1] == pytest.approx(tr.true["v_a"][-1] - back_emf, rel=1e-6)
    k = 10  # early on: the rate is R_a(T_m)·i_a²/C_th (the loss to ambient still negligible)
    rate = (t_m[k + 1] - t_m[k - 1]) / (2 * rig.sample_period)
    expected = (m.R_a * (1 + ALPHA * t_m[k]) * i_a[k] ** 2 - t_m[k] / R_TH) / C_TH
    assert rate == pytest.approx(expected, rel=1e-2)
    assert cold.theta[-1] - tr.theta[-1] > 0.005  # less current at the same voltage: less thrust
    assert tr.x[-1, 2] < cold.x[-1, 2]


def test_initial_states_of_the_chain_or_the_layout_and_nothing_else():
    rig = _heated()
    duty = np.full(50, 0.5)
    five = simulate(rig, duty, x0=[0.1, 0.0, 0.0, 0.0, 0.0])
    six = simulate(rig, duty, x0=[0.1, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert np.array_equal(five.x, six.x)  # the chain's five: T_m starts at ambient
    warm = simulate(rig, duty, x0=[0.1, 0.0, 0.0, 0.0, 0.0, 20.0])
    assert warm.x[0, 5] == 20.0 and warm.true["i_a"][-1] < six.true["i_a"][-1]
    with pytest.raises(SimulationError, match=r"initial state of shape \(4,\): expected 6 states"):
        simulate(rig, duty, x0=[0.0] * 4)
    layout = plant_model(rig).states
    np.testing.assert_array_equal(layout.with_values([0.1, 0.0, 0.0, 0.0, 0.0], {"T_m": 20.0}),
                                  [0.1, 0.0, 0.0, 0.0, 0.0, 20.0])
    np.testing.assert_array_equal(layout.with_values([0.1, 0.0, 0.0, 0.0, 0.0], None), [0.1] + [0.0] * 5)
    with pytest.raises(KeyError, match="no state 'T_w'"):
        layout.with_values([0.0] * 5, {"T_w": 1.0})


def test_a_stepper_switched_to_a_heated_rig_keeps_the_chain_and_starts_t_m_at_ambient():
    plain = load_rig("thesis_rig")
    st = PlantStepper(plain)
    for _ in range(200):
        st.step(0.5)
    before = st.x.copy()
    st.set_rig(_heated())
    assert st.x.shape == (6,) and np.array_equal(st.x[:N_CHAIN], before) and st.x[5] == 0.0
    st.step(0.5)
    assert st.x[5] > 0.0
    st.set_rig(plain)
    assert st.x.shape == (N_CHAIN,)


def test_the_compiled_replay_completes_a_chain_state_and_refuses_other_lengths():
    """The kernels read x0 without bounds checks: a chain-only x0 (what a fit's start gives) on a
    heated rig is completed with T_m = 0 before it reaches them (it read memory past the row before:
    gap fits of a heated rig differed from run to run), any other length is refused."""
    from aeropend_sim.compiled.plant import compiled_plant

    plant = compiled_plant(_heated())
    duty = np.full(200, 0.5)
    p = np.repeat(plant.p[None, :], 2, axis=0)
    chain = np.array([[0.1, 0.0, 0.0, 0.0, 0.0]] * 2)
    whole = np.array([[0.1, 0.0, 0.0, 0.0, 0.0, 0.0]] * 2)
    a, fa = plant.replay_batch(duty, p, chain, 0.0, ("theta", "T_m"), threads=1)
    b, fb = plant.replay_batch(duty, p, whole, 0.0, ("theta", "T_m"), threads=1)
    assert (fa < 0).all() and (fb < 0).all() and np.array_equal(a, b)
    assert a[0, 1, 0] == 0.0 and a[0, 1, -1] > 0.0  # T_m from ambient, warming
    states, _u, failed = plant.replay(duty, chain[0])
    assert failed < 0 and np.array_equal(states[:, :5], plant.replay(duty, whole[0])[0][:, :5])
    with pytest.raises(ValueError, match=r"initial state of shape \(2, 4\): expected 6 states"):
        plant.replay_batch(duty, p, np.zeros((2, 4)), 0.0, ("theta",), threads=1)


def test_effect_states_that_do_not_fit_are_refused_when_declared():
    from aeropend_sim.components.base import Effect, Term
    from aeropend_sim.components.states import State

    def rate(xp, i_a, T_x, k_x):
        return k_x * i_a - T_x

    t_x = State("T_x", "T_x", "K", "a test state")
    with pytest.raises(ValueError, match=r"state\(s\) \['T_x'\] have no rate term"):
        Effect(name="x", part="rotor", label="x", description="x", order=1, states=(t_x,))
    with pytest.raises(ValueError, match="reads or drives a state it does not declare"):
        Effect(name="x", part="rotor", label="x", description="x", order=1,
               terms=(Term("rate", 0, rate, "k·i_a − T_x", state="T_x", states=("T_x",)),))
    with pytest.raises(ValueError, match="a rate term names the state it drives"):
        Term("rate", 0, rate, "k·i_a − T_x", states=("T_x",))
