"""Minimal rig files of the three actuator families, shared by the component-registry tests.

Each is what a lab would write: the family's required parameters and a few effects, nothing else.
The numbers are plausible for the kind of rig (sources say so); they are test fixtures, not rigs
aeropend ships.
"""

from __future__ import annotations

import copy
from typing import Any

from aeropend_sim.params import Rig, rig_from_dict

_SRC = "test fixture (test/component_rigs.py)"


def q(value: float, unit: str, source: str = _SRC) -> dict[str, Any]:
    """A rig-file quantity."""
    return {"value": value, "unit": unit, "source": source}


#: DC motor behind an H-bridge with an ideal map: the thesis rig's motor, gearbox and rod.
DC_HBRIDGE: dict[str, Any] = {
    "name": "dc_minimal",
    "sample_period": q(2.048e-3, "s"),
    "actuator": {"family": "dc_hbridge", "v_supply": q(2.3187, "V")},
    "motor": {"R_a": q(1.08, "ohm"), "K_t": q(6.3085e-3, "N*m/A"), "J_m": q(1.3959e-6, "kg*m^2"),
              "gear_ratio": q(6.1111111, "1"), "K_omega": q(6.3085e-3, "V*s/rad"),
              "B_m": q(2.8981e-6, "N*m*s/rad"), "K_d": q(9.9561e-8, "N*m*s^2/rad^2")},
    "thrust": {"K_q": q(2.8585e-4, "N*s^2/rad^2")},
    "pendulum": {"mgd_over_J": q(15.472, "1/s^2"), "L_over_J": q(45.072, "1/(kg*m)"),
                 "c_over_J": q(2.2343, "1/s")},
}

#: DC motor on a voltage amplifier (Quanser-Aero-like numbers: 24 V full scale, 8.4 Ω, K = 0.042).
VOLTAGE_AMPLIFIER: dict[str, Any] = {
    "name": "amplifier_minimal",
    "sample_period": q(2e-3, "s"),
    "actuator": {"family": "voltage_amplifier", "v_max": q(24.0, "V")},
    "motor": {"R_a": q(8.4, "ohm"), "K_t": q(0.042, "N*m/A"), "J_m": q(2e-5, "kg*m^2"),
              "K_omega": q(0.042, "V*s/rad"), "K_d": q(1e-7, "N*m*s^2/rad^2")},
    "thrust": {"K_q": q(2e-6, "N*s^2/rad^2")},
    "pendulum": {"mgd_over_J": q(20.0, "1/s^2"), "L_over_J": q(60.0, "1/(kg*m)"), "c_over_J": q(0.8, "1/s")},
}

#: Brushless motor behind an ESC: the minimal file of issue 35 (family, geometry, c/J, the static
#: throttle map, response time, dead time) plus the propeller's thrust coefficient.
ESC: dict[str, Any] = {
    "name": "esc_minimal",
    "sample_period": q(0.01, "s"),
    "actuator": {"family": "esc", "omega_max": q(600.0, "rad/s"), "idle_duty": q(0.1, "1"),
                 "input_delay": q(0.05, "s")},
    "motor": {"T_m": q(0.08, "s")},
    "thrust": {"K_q": q(3.45e-6, "N*s^2/rad^2")},
    "pendulum": {"mass": q(0.05, "kg"), "com_distance": q(0.25, "m"), "thrust_arm": q(0.25, "m"),
                 "c_over_J": q(0.5, "1/s")},
}

FAMILY_DOCS = {"dc_hbridge": DC_HBRIDGE, "voltage_amplifier": VOLTAGE_AMPLIFIER, "esc": ESC}


def doc(family: str) -> dict[str, Any]:
    """A fresh copy of the minimal rig-file structure of ``family``."""
    return copy.deepcopy(FAMILY_DOCS[family])


def rig(family: str) -> Rig:
    """The minimal rig of ``family``."""
    return rig_from_dict(doc(family), f"{family}_minimal.yaml")
