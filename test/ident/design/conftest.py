"""Shared fixtures of the experiment-design tests."""

from __future__ import annotations

import pytest

from aeropend_ident.design.candidates import Candidate
from aeropend_ident.gap.effects import apply_effects
from aeropend_sim.params import load_rig


@pytest.fixture(scope="module")
def pair() -> list[Candidate]:
    """Two candidates that differ in one effect: thesis_sim, and thesis_sim with a 20 ms actuator lag."""
    rig = load_rig("thesis_sim")
    lagged, meas = apply_effects(rig, {"actuator_lag": {"lag_time_constant": 0.02}})
    return [Candidate("nominal", (), rig), Candidate("actuator_lag", ("actuator_lag",), lagged, meas)]
