"""Component ``gearbox``: ω₂ = ω₁/n between the rotor and the propeller (thesis Eq. 3.4).

n = ω₁/ω₂: the rotor turns n times faster than the propeller; a propeller on the motor shaft has
n = 1 (the value used when a rig file gives none).
"""

from __future__ import annotations

from aeropend_sim.components.base import Component, Param, Term

GEAR = Param("motor.gear_ratio", "1", "n = ω1/ω2 (rotor turns n times faster than the propeller)",
             sign="positive", absent=1.0, symbol="n",
             measure='count the teeth (1: direct drive); θ and thrust cannot tell it from K_q')


def propeller_speed(xp, omega, gear_ratio):
    """ω₂ = ω₁/n [rad/s]."""
    return omega / gear_ratio


def d_propeller_speed(xp, omega, gear_ratio):
    """∂ω₂/∂ω₁ [1]."""
    return 1.0 / gear_ratio


def rotor_speed(xp, y, gear_ratio):
    """ω₁ of a propeller speed y [rad/s]."""
    return gear_ratio * y


COMPONENT = Component(
    name="gearbox",
    part="rotor",
    label="gearbox",
    description="ω₂ = ω₁/n (Eq. 3.4; n = 1 without a gearbox)",
    order=35,
    params=(GEAR,),
    terms=(Term("gear", 10, propeller_speed, "ω₂ = ω₁/n", partials={"omega": d_propeller_speed},
                inverse=rotor_speed),),
)
