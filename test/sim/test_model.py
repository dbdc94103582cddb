"""Plant model invariants: equilibrium, energy, linearisation, thesis Table 4.2, effects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_sim.model import I_A, OMEGA, TAU_F, THETA, THETA_DOT, ModelError, PlantModel
from aeropend_sim.params import load_rig
from aeropend_sim.simulation import PlantStepper, SimulationError, simulate

RIG = load_rig("thesis_rig")
SIM = load_rig("thesis_sim")

# thesis Table 4.2: v_a [V], i_a [A], rotor speed [RPM]
TABLE_4_2 = np.array([
    [1.08, 0.29, 1158], [1.182, 0.33, 1235], [1.272, 0.35, 1306], [1.377, 0.40, 1402],
    [1.483, 0.45, 1485], [1.561, 0.50, 1561], [1.666, 0.55, 1638], [1.781, 0.61, 1734],
    [1.864, 0.65, 1805], [1.974, 0.70, 1885],
])


@pytest.mark.parametrize("rig", [RIG, SIM], ids=["thesis_rig", "thesis_sim"])
@pytest.mark.parametrize("theta", [0.2, 0.4, 0.7])
def test_equilibrium_balances_thrust_and_gravity(rig, theta):
    m = PlantModel(rig)
    x, tau = m.equilibrium(theta)
    assert np.allclose(m.rhs(0.0, x, tau), 0.0, atol=1e-9)
    # L·f = m·g·d·sin θ, per unit inertia
    assert m.b_f * m.thrust(x[OMEGA]) == pytest.approx(m.a_g * math.sin(theta), rel=1e-12)
    # the simulated plant started at rest with the equilibrium duty settles there
    traj = simulate(rig, np.full(int(25.0 / rig.sample_period), tau))
    assert traj.theta[-1] == pytest.approx(theta, abs=2e-4)
    assert traj.omega_rotor[-1] == pytest.approx(x[OMEGA], rel=1e-4)


def test_equilibrium_out_of_range_is_refused():
    m = PlantModel(RIG)
    with pytest.raises(ModelError, match="outside"):
        m.equilibrium(3.2)  # past π the thrust would have to pull
    with pytest.raises(ModelError, match="outside"):
        m.equilibrium(-0.1)
    # past π/2 the rod leans over its pivot: the holding thrust falls again with sin θ
    x, tau = m.equilibrium(2.0)
    assert m.thrust(x[OMEGA]) == pytest.approx(m.a_g * math.sin(2.0) / m.b_f, rel=1e-9)
    assert tau < m.equilibrium(math.pi / 2)[1]
    with pytest.raises(ModelError, match="duty cycle"):
        PlantModel(SIM).equilibrium(1.2)  # needs more than τ = 1 on the thesis simulation


def test_motor_off_energy_decays():
    """τ = 0 ⇒ rod energy and stored motor energy are non-increasing and decay."""
    m = PlantModel(RIG)
    x0 = np.array([1.0, 0.0, 0.0, 0.0, 0.0])
    traj = simulate(RIG, np.zeros(int(15.0 / RIG.sample_period)), x0=x0)
    e = np.array([m.pendulum_energy(x) for x in traj.x])
    assert np.all(np.diff(e) <= 1e-12)
    assert e[-1] < 0.01 * e[0]
    # spinning motor, rod at rest, switched off: armature + rotor energy decays monotonically
    x1 = np.array([0.0, 0.0, 0.5, 180.0, 0.0])
    traj = simulate(RIG, np.zeros(200), x0=x1)
    em = np.array([m.motor_energy(x) for x in traj.x])
    assert np.all(np.diff(em) <= 1e-15)
    assert em[-1] < 1e-3 * em[0]


def _fd_jacobian(m: PlantModel, x: np.ndarray, u: float, h: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    A = np.zeros((5, 5))
    for j in range(5):
        d = np.zeros(5)
        d[j] = h * max(1.0, abs(x[j]))
        A[:, j] = (np.array(m.rhs(0, x + d, u)) - np.array(m.rhs(0, x - d, u))) / (2 * d[j])
    hu = h
    B = ((np.array(m.rhs(0, x, u + hu)) - np.array(m.rhs(0, x, u - hu))) / (2 * hu))[:, None]
    return A, B


@pytest.mark.parametrize(
    "switches",
    [
        {},
        {"hbridge_map": False},
        {"armature_inductance": "quasi_static"},
        {"actuator_lag": True, "dead_zone": True, "coulomb_friction": True},
        {"thrust_exponent": True},
    ],
    ids=["nominal", "ideal_map", "quasi_static", "lag_deadzone_coulomb", "thrust_exponent"],
)
def test_linearisation_matches_finite_differences(switches):
    rig = RIG.with_effects(**switches)
    rig = rig.with_params("actuator", lag_time_constant=0.03, dead_zone=0.05)
    rig = rig.with_params("motor", T_c=2e-5)
    rig = rig.with_params("pendulum", coulomb_over_J=0.3, stribeck_over_J=0.4, stribeck_velocity=0.3)
    rig = rig.with_params("thrust", exponent=1.8)
    m = PlantModel(rig)
    rng = np.random.default_rng(3)
    for _ in range(5):
        x = np.array([rng.uniform(0.1, 1.0), rng.uniform(-1, 1), rng.uniform(0.1, 0.6),
                      rng.uniform(50, 200), rng.uniform(0.2, 0.9)])
        u = rng.uniform(0.2, 0.9)
        A, B = m.jacobian(x, u)
        A_fd, B_fd = _fd_jacobian(m, x, u)
        assert np.allclose(A, A_fd, rtol=1e-5, atol=1e-6 * np.abs(A_fd).max())
        assert np.allclose(B, B_fd, rtol=1e-5, atol=1e-6 * max(np.abs(B_fd).max(), 1.0))


def test_steady_back_emf_reproduces_thesis_table_4_2():
    """Steady motor states at the Table 4.2 voltages match the strobe speeds within its scatter."""
    v, i_meas, rpm = TABLE_4_2.T
    rig = RIG.with_effects(hbridge_map=False)
    k_hat = []
    for vk, rpm_k in zip(v, rpm, strict=True):
        r = rig.with_params("actuator", v_supply=vk)
        traj = simulate(r, np.ones(int(0.3 / r.sample_period)))  # ≈15 mechanical time constants
        w = traj.omega_rotor[-1]
        i = traj.i_a[-1]
        assert traj.v_a[-1] == pytest.approx(vk, rel=1e-12)
        # within 3σ of the table's K_ω scatter (σ/K = 2.1 %)
        assert w * 60 / (2 * math.pi) == pytest.approx(rpm_k, rel=3 * 0.0207)
        k_hat.append((vk - r.motor.R_a * i) / (w * 60 / (2 * math.pi)))
    k_hat = np.array(k_hat)
    # the thesis' estimator applied to the model's steady states gives Table 4.2's K̂ω
    assert k_hat.mean() == pytest.approx(6.606e-4, abs=1.38e-5)
    # and the simulated currents match the measured ones within the same scatter
    for vk, ik in zip(v, i_meas, strict=True):
        r = rig.with_params("actuator", v_supply=vk)
        traj = simulate(r, np.ones(int(0.3 / r.sample_period)))
        assert traj.i_a[-1] == pytest.approx(ik, rel=0.08)


def test_hbridge_map_is_thesis_eq_4_3():
    m = PlantModel(RIG)
    assert m.armature_voltage(0.4314) == pytest.approx(1.4263, abs=1e-4)
    assert m.armature_voltage(1.0) == pytest.approx(2.3187, abs=1e-4)
    assert m.armature_voltage(0.0) == 0.0  # Eq. 4.3 is negative below τ ≈ 0.95 %: clipped
    for tau in (0.05, 0.3, 0.8):
        assert m.duty_for_voltage(m.armature_voltage(tau)) == pytest.approx(tau, rel=1e-10)


def test_dead_zone_blocks_small_duty():
    rig = RIG.with_effects(dead_zone=True).with_params("actuator", dead_zone=0.2)
    m = PlantModel(rig)
    assert m.armature_voltage(0.19) == 0.0
    traj = simulate(rig, np.full(500, 0.19))
    assert np.all(traj.omega_rotor == 0.0) and np.all(traj.theta == 0.0)
    # full scale is preserved
    assert m.armature_voltage(1.0) == pytest.approx(PlantModel(RIG).armature_voltage(1.0))


@pytest.mark.parametrize("backend", ["lsoda", "compiled"])
def test_input_delay_shifts_response_exactly(backend):
    dt = RIG.sample_period
    duty = np.r_[np.zeros(20), np.full(300, 0.6)]
    base = simulate(RIG, duty, backend=backend)
    rig = RIG.with_effects(input_delay=True).with_params("actuator", input_delay=3 * dt)
    delayed = simulate(rig, duty, backend=backend)
    assert np.allclose(delayed.x[3:], base.x[:-3], atol=1e-7)
    # a fractional delay (1.5 samples) equals the undelayed plant sampled twice as fast with
    # the input shifted by three half-samples; the compiled backend integrates the two with RK4
    # sub-steps of dt/6 and dt/12, so they agree to its accuracy, not LSODA's: the armature's
    # 2 ms transient after the step to 1e-5 of i_a's and ω₁'s ranges, θ to 1e-9 rad
    rig_frac = RIG.with_effects(input_delay=True).with_params("actuator", input_delay=1.5 * dt)
    frac = simulate(rig_frac, duty, backend=backend)
    fine = simulate(RIG, np.r_[np.zeros(3), np.repeat(duty, 2)[:-3]], dt=dt / 2, backend=backend)
    if backend == "lsoda":
        assert np.allclose(frac.x, fine.x[::2], atol=1e-7)
    else:
        assert np.all(np.abs(frac.x - fine.x[::2]) <= 1e-5 * np.ptp(fine.x, axis=0) + 1e-9)
        assert np.abs(frac.theta - fine.theta[::2]).max() < 1e-9


def test_actuator_lag_is_first_order():
    T_a = 0.05
    rig = RIG.with_effects(actuator_lag=True).with_params("actuator", lag_time_constant=T_a)
    traj = simulate(rig, np.full(200, 0.5))
    k = round(T_a / rig.sample_period)
    t = traj.t[k]
    assert traj.x[k, TAU_F] == pytest.approx(0.5 * (1 - math.exp(-t / T_a)), rel=1e-6)


def test_quasi_static_inductance_has_same_steady_state():
    dyn = simulate(RIG, np.full(1500, 0.6))
    qs = simulate(RIG.with_effects(armature_inductance="quasi_static"), np.full(1500, 0.6))
    assert qs.i_a[-1] == pytest.approx(dyn.i_a[-1], rel=1e-4)
    assert qs.theta[-1] == pytest.approx(dyn.theta[-1], rel=1e-3)
    # but the dynamic current needs time to rise (τ_e = L/R ≈ 2 ms) while the algebraic one jumps
    assert dyn.i_a[1] < 0.7 * qs.i_a[1]


@pytest.mark.parametrize("backend", ["compiled", "lsoda"])
def test_quasi_static_current_is_the_fast_dynamic_current_at_the_sample_instants(backend):
    """Sample k is the state before τ_k acts: a quasi-static current there is the algebraic current
    of the command held until then, the limit of a dynamic one as L_a/R_a → 0 (not a sample early)."""
    dt = RIG.sample_period
    duty = np.repeat(np.random.default_rng(5).uniform(0.3, 0.9, 40), 10)
    fast = RIG.with_params("motor", L_a=RIG.motor.R_a * dt / 200.0)
    dyn = simulate(fast, duty, backend=backend)
    qs = simulate(fast.with_effects(armature_inductance="quasi_static"), duty, backend=backend)
    assert np.max(np.abs(qs.i_a - dyn.i_a)) < 0.02 * np.ptp(dyn.i_a)


def test_end_stops_hold_the_rod():
    rig = RIG.with_effects(end_stops=True).with_params("pendulum", theta_max=0.3)
    traj = simulate(rig, np.full(3000, 1.0))
    assert traj.theta.max() < 0.3 + 0.05
    assert traj.theta[-1] == pytest.approx(0.3, abs=0.03)


def test_coulomb_friction_gives_linear_decay():
    """Pure Coulomb friction: successive peak amplitudes drop by a constant step."""
    rig = RIG.with_effects(coulomb_friction=True, viscous_friction=False)
    rig = rig.with_params("pendulum", coulomb_over_J=0.5)
    traj = simulate(rig, np.zeros(int(8.0 / rig.sample_period)), x0=np.array([0.6, 0, 0, 0, 0]))
    th = traj.theta
    peaks = [th[k] for k in range(1, th.size - 1)
             if th[k] > th[k - 1] and th[k] >= th[k + 1] and th[k] > 0.05]
    drops = np.diff(peaks)
    assert len(drops) >= 3
    assert np.std(drops) < 0.05 * abs(np.mean(drops))


def test_stribeck_friction_exceeds_coulomb_at_low_rate_and_decays_to_it():
    """Dry friction level T_f/J + ((T_s − T_f)/J)·exp(−(θ̇/v_s)²): static level at θ̇ ≈ 0, sliding
    level well above v_s; off without the Coulomb switch; a rig file may omit the Stribeck keys."""
    rig = RIG.with_effects(coulomb_friction=True).with_params(
        "pendulum", coulomb_over_J=0.5, stribeck_over_J=0.8, stribeck_velocity=0.2)
    m = PlantModel(rig)
    eps = rig.pendulum.friction_velocity  # 0.01 rad/s: sgn(θ̇) saturated from ~5·v_ε on
    slow = 5 * eps
    assert m.dry_friction(slow) == pytest.approx(
        (0.5 + 0.8 * math.exp(-((slow / 0.2) ** 2))) * math.tanh(slow / eps), rel=1e-12)
    assert m.dry_friction(slow) > 1.2  # near the static level 1.3
    assert m.dry_friction(2.0) == pytest.approx(0.5, rel=1e-6)  # 10·v_s: the sliding level only
    assert m.dry_friction(-2.0) == pytest.approx(-0.5, rel=1e-6)
    assert PlantModel(rig.with_effects(coulomb_friction=False)).a_s == 0.0
    # thesis_rig.yaml predates the Stribeck keys: it loads with the defaults, and says so
    assert RIG.pendulum.stribeck_over_J == 0.0
    assert RIG.status("pendulum.stribeck_over_J") == "not modelled"
    assert RIG.status("pendulum.stribeck_velocity") == "default"  # a setting, not a physical absence


def test_sensor_noise_snr_and_quantisation():
    rig = RIG.with_effects(sensor_noise=True).with_params("sensors", snr_db=30.0)
    duty = np.repeat(np.random.default_rng(0).uniform(0.3, 0.9, 20), 200)
    noisy = simulate(rig, duty, seed=7)
    again = simulate(rig, duty, seed=7)
    other = simulate(rig, duty, seed=8)
    assert np.array_equal(noisy.theta, again.theta)
    assert not np.array_equal(noisy.theta, other.theta)
    sig = noisy.true["theta"]
    snr = 10 * np.log10(np.mean(sig**2) / np.mean((noisy.theta - sig) ** 2))
    assert snr == pytest.approx(30.0, abs=0.5)
    q = RIG.with_effects(quantisation=True)
    quant = simulate(q, duty)
    lsb = q.sensors.theta_quantum
    assert np.allclose(quant.theta / lsb, np.round(quant.theta / lsb))
    assert np.max(np.abs(quant.theta - quant.true["theta"])) <= lsb / 2 + 1e-12


def test_invalid_duty_is_rejected_with_index():
    duty = np.full(10, 0.5)
    duty[4] = np.nan
    with pytest.raises(SimulationError, match=r"duty\[4\]"):
        simulate(RIG, duty)
    with pytest.raises(SimulationError, match=r"1\.2"):
        simulate(RIG, np.array([0.1, 1.2]))
    with pytest.raises(SimulationError, match="initial state"):
        simulate(RIG, duty[:3], x0=np.array([0.0, 1.0]))


@pytest.mark.parametrize("delay_samples", [0.0, 2.0, 1.5])
def test_stepper_matches_batch(delay_samples):
    rig = RIG.with_effects(input_delay=delay_samples > 0, actuator_lag=True)
    rig = rig.with_params("actuator", input_delay=delay_samples * rig.sample_period, lag_time_constant=0.01)
    duty = np.repeat(np.random.default_rng(1).uniform(0.2, 0.9, 25), 20)
    batch = simulate(rig, duty)
    stepper = PlantStepper(rig)
    states = [stepper.x.copy()]
    for u in duty[:-1]:
        stepper.step(float(u))
        states.append(stepper.x.copy())
    assert np.allclose(np.array(states)[:, [THETA, THETA_DOT, I_A, OMEGA]],
                       batch.x[:, [THETA, THETA_DOT, I_A, OMEGA]], rtol=1e-6, atol=1e-8)


def test_stepper_rejects_bad_duty_without_changing_state():
    s = PlantStepper(RIG)
    s.step(0.5)
    x = s.x.copy()
    for bad in (math.nan, -0.1, 1.01, math.inf):
        with pytest.raises(SimulationError):
            s.step(bad)
    assert np.array_equal(s.x, x) and s.k == 1


def test_holding_duty_is_the_equilibrium_duty_and_passes_one_beyond_the_reach():
    """The unclipped holding duty: equilibrium's τ where that holds; past the actuator's reach (the
    thesis simulation holds at most 0.76 rad with τ ≤ 1) the τ > 1 it would take, smooth in θ."""
    m = PlantModel(SIM)
    for theta in (0.0, 0.3, 0.7):
        assert m.holding_duty(theta) == m.equilibrium(theta)[1]
    with pytest.raises(ModelError, match="duty cycle"):
        m.equilibrium(1.2)
    beyond = [m.holding_duty(t) for t in (1.2, 1.3, 1.4)]
    assert 1.0 < beyond[0] < beyond[1] < beyond[2]
    with pytest.raises(ModelError, match="outside"):
        m.holding_duty(-0.1)
