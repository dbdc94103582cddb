"""Partial state: the pendulum equation from θ and τ only (static thrust map, thesis Eqs. 4.3/4.4)."""

from __future__ import annotations

import pytest

from aeropend_ident.partial import angle_only_data, static_thrust_library
from aeropend_ident.sindy import IdentificationError, fit
from aeropend_sim.excitation import lhs_steps
from aeropend_sim.model import PlantModel
from aeropend_sim.params import load_rig
from aeropend_sim.simulate import simulate


def test_thesis_rig_pendulum_from_angle_only_at_50db() -> None:
    rig = load_rig("thesis_rig")
    noisy = rig.with_effects(sensor_noise=True).with_params("sensors", snr_db=50)
    duty = lhs_steps(20, tau_min=0.35, tau_max=0.65, hold_min=1.0, hold_max=5.0, seed=0).duty
    tr = simulate(noisy, duty, seed=5)
    data = angle_only_data(tr.t, tr.theta, tr.duty, PlantModel(rig).armature_voltage)
    assert set(data.variables) == {"theta", "theta_dot", "v_a", "duty"}
    lib = static_thrust_library()
    m = fit(data, lib, targets=["theta_dot"], threshold=0.05, method="weak", K=300, H_xt=0.5)
    p = m.derived_parameters()
    # measured: c/J −2.1 %, mgd/J −4.5 % (the static thrust map ignores the rotor lag)
    assert p["c_over_J"][0] == pytest.approx(rig.pendulum.c_over_J, rel=0.05)
    assert p["mgd_over_J"][0] == pytest.approx(rig.pendulum.mgd_over_J, rel=0.08)
    assert m.coefficient("theta_dot", "v_a²") > 0
    # the current equation is refused: no i_a in an angle-only log
    with pytest.raises(IdentificationError, match="armature-current equation di_a/dt needs the state i_a"):
        fit(data, static_thrust_library(), targets=["i_a"], method="weak")
    with pytest.raises(IdentificationError, match="duty must be finite"):
        angle_only_data(tr.t, tr.theta, tr.duty * 2.0)
