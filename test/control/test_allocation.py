"""Control allocation (aeropend_control.allocation): round trips against the forward model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_control.allocation import EQ44, AllocationError, ModelAllocator, ThesisAllocator
from aeropend_sim.model import PlantModel
from aeropend_sim.params import load_rig
from aeropend_sim.simulation import simulate

RIG = load_rig("thesis_rig")


@pytest.mark.parametrize("theta", [0.1, 0.2, 0.4, 0.7, 1.0])
def test_model_allocation_matches_equilibrium(theta: float) -> None:
    model = PlantModel(RIG)
    _, tau_eq = model.equilibrium(theta)
    f = model.a_g * math.sin(theta) / model.b_f
    a = ModelAllocator(RIG).allocate(f)
    assert not a.is_saturated and a.achieved == f
    assert a.duty == pytest.approx(tau_eq, rel=1e-12)
    assert a.v_a == pytest.approx(model.armature_voltage(a.duty), rel=1e-10)


@pytest.mark.parametrize("f", [0.02, 0.1, 0.25])
def test_model_allocation_round_trip_through_simulation(f: float) -> None:
    """Hold the allocated duty on the full dynamic model: the steady thrust is the request."""
    a = ModelAllocator(RIG).allocate(f)
    traj = simulate(RIG, np.full(200, a.duty))  # 0.41 s, motor time constant ≈ 20 ms
    assert traj.thrust[-1] == pytest.approx(f, rel=1e-6)


def test_model_forward_inverse_consistent() -> None:
    alloc = ModelAllocator(RIG)
    for v in np.linspace(0.1, alloc.v_max, 7):
        f = alloc.thrust_for_voltage(float(v))
        assert alloc.voltage_for_thrust(f) == pytest.approx(v, rel=1e-9)


def test_model_saturation_reported() -> None:
    alloc = ModelAllocator(RIG)
    hi = alloc.allocate(1.0)
    assert hi.saturated == 1 and hi.duty == 1.0 and hi.achieved == pytest.approx(alloc.f_max)
    assert alloc.f_max == pytest.approx(0.3697, abs=1e-4)
    lo = alloc.allocate(-0.1)
    assert lo.saturated == -1 and lo.duty == 0.0 and lo.achieved == 0.0
    zero = alloc.allocate(0.0)
    assert zero.saturated == 0 and zero.duty == 0.0
    with pytest.raises(AllocationError, match="nan"):
        alloc.allocate(math.nan)


@pytest.mark.parametrize("f", [0.01, 0.1, 0.2, 0.35])
def test_thesis_allocation_round_trip(f: float) -> None:
    alloc = ThesisAllocator(RIG)
    a = alloc.allocate(f)
    a2, a1, a0 = EQ44
    k0, k1, k2, k3 = (RIG.actuator.hbridge_k0, RIG.actuator.hbridge_k1, RIG.actuator.hbridge_k2,
                      RIG.actuator.hbridge_k3)
    v = k0 + k1 * math.sqrt(k2 * a.duty + k3)  # Eq. 4.3 forward
    assert a2 * v * v + a1 * v + a0 == pytest.approx(f, rel=1e-10)  # Eq. 4.4 forward


def test_thesis_allocation_limits_and_agreement_with_model() -> None:
    th, mo = ThesisAllocator(RIG), ModelAllocator(RIG)
    # Eq. 4.3 at τ = 1 gives 2.3187 V; Eq. 4.4 there 0.394 N
    assert th.v_max == pytest.approx(2.3187, abs=1e-4) and th.f_max == pytest.approx(0.3941, abs=1e-4)
    assert th.allocate(0.001).saturated == -1 and th.allocate(0.001).duty == 0.0
    assert th.allocate(0.5).saturated == 1 and th.allocate(0.5).duty == 1.0
    # the rig's K_q was fitted to Eq. 4.4: the two chains agree within 4 % of duty for 0.1-0.3 N
    for f in (0.1, 0.2, 0.3):
        assert th.allocate(f).duty == pytest.approx(mo.allocate(f).duty, rel=0.04)
