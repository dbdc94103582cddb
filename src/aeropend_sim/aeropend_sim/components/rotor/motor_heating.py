"""Effect ``motor_heating``: the armature winding warms with its I²R loss and its resistance rises.

    R_a(T_m) = R_a·(1 + α_R·T_m)
    C_th·dT_m/dt = R_a(T_m)·i_a² − T_m/R_th

T_m is the winding's temperature rise above ambient [K], a state of its own (declared here, after
the chain's in the rig's state layout, :mod:`aeropend_sim.components.states`); a recording starts
with the motor at ambient (T_m = 0). α_R is the resistance's temperature coefficient (copper:
3.93e-3 1/K at 20 °C), R_th the winding-to-ambient thermal resistance [K/W] and C_th the winding's
heat capacity [J/K]; the thermal time constant is R_th·C_th. A small brushed motor (R_th ≈ 10-30 K/W,
R_th·C_th ≈ 10-100 s) held at 1 A through 2 Ω warms by tens of K within a minute: R_a rises by
10-20 %, so at a held duty cycle the current, the torque and the thrust sag and the rod settles
lower over the run, which a model with a constant R_a cannot follow (a lab meets it as a rig that
"droops" during long recordings and recovers after a pause).

R_a(T_m) replaces the armature resistance wherever the chain uses it (the ``resistance`` slot:
the armature equation, dynamic or quasi-static), so the effect is this one module.
"""

from __future__ import annotations

from aeropend_sim.components.base import Effect, Param, Term
from aeropend_sim.components.states import State

ALPHA_R = Param("motor.alpha_R", "1/K", "temperature coefficient of the armature resistance",
                sign="positive", absent=0.0, symbol="α_R", typical=3.93e-3,
                measure="the winding's material (copper: 3.93e-3 1/K at 20 °C)")
R_TH = Param("motor.R_th", "K/W", "winding-to-ambient thermal resistance", sign="positive", absent=0.0,
             symbol="R_th", typical=20.0,
             measure="the steady winding temperature rise (from R_a's rise) over the I²R loss at a held "
                     "current, or the data sheet's thermal resistance")
C_TH = Param("motor.C_th", "J/K", "heat capacity of the armature winding", sign="positive", absent=0.0,
             symbol="C_th", typical=2.0,
             measure="the thermal time constant R_th·C_th of R_a's rise after a current step, over R_th")

T_M = State("T_m", "T_m", "K", "armature winding temperature rise above ambient (motor_heating)",
            typical=30.0)


def heated_resistance(xp, T_m, R_a, alpha_R):
    """R_a(T_m) = R_a·(1 + α_R·T_m) [Ω]."""
    return R_a * (1.0 + alpha_R * T_m)


def winding_heating(xp, i_a, T_m, R_a, alpha_R, R_th, C_th):
    """dT_m/dt = (R_a(T_m)·i_a² − T_m/R_th)/C_th [K/s]."""
    return (R_a * (1.0 + alpha_R * T_m) * i_a * i_a - T_m / R_th) / C_th


EFFECT = Effect(
    name="motor_heating",
    part="rotor",
    label="motor heating",
    description="R_a(T_m) = R_a·(1 + α_R·T_m), C_th·dT_m/dt = R_a(T_m)·i_a² − T_m/R_th (winding temperature "
                "rise T_m a state)",
    order=45,
    params=(ALPHA_R, R_TH, C_TH),
    states=(T_M,),
    terms=(Term("resistance", 10, heated_resistance, "R_a·(1 + α_R·T_m)", states=("T_m",)),
           Term("rate", 0, winding_heating, "(R_a(T_m)·i_a² − T_m/R_th)/C_th", state="T_m", states=("T_m",))),
    needs=("armature",),
)
