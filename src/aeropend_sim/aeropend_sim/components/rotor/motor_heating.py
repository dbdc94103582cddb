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

The gap diagnosis fits R_th and C_th (α_R: copper's unless the rig file states it). What a
recording determines depends on its length against R_th·C_th: the early warming rate
R_a·i_a²/C_th fixes C_th within seconds, the steady rise R_th·R_a·i_a² needs a few time constants
(12 s of APRBS at R_th·C_th = 30 s: C_th within 2 %, R_th 12 % off).
"""

from __future__ import annotations

from aeropend_sim.components.base import POSITIVE, Diagnosis, Effect, Param, Search, Term
from aeropend_sim.components.states import State

#: α_R of copper at 20 °C [1/K]: what the diagnosis assumes of a winding whose rig file states none
#: (brushed motors of lab rigs are wound with copper; the data show R_a's relative rise α_R·T_m,
#: which depends on α_R·R_th and α_R/C_th only, so α_R is not fitted beside them).
COPPER_ALPHA = 3.93e-3

ALPHA_R = Param("motor.alpha_R", "1/K", "temperature coefficient of the armature resistance",
                sign="positive", absent=0.0, symbol="α_R", typical=COPPER_ALPHA,
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


def _loss_scale(ctx):
    """The stall loss v_a²/R_a [W] at the largest recorded drive: the scale of the I²R loss."""
    return max(ctx.drive_max, 1e-9) ** 2 / ctx.rig.motor.R_a


def _alpha(rig):
    return rig.motor.alpha_R if rig.effects.motor_heating and rig.motor.alpha_R > 0.0 else COPPER_ALPHA


def thermal_resistance_range(ctx):
    """R_th whose steady rise at the stall loss v_a²/R_a of the largest recorded drive raises R_a by
    0.1 % … 300 % (α_R·R_th·v_a²/R_a from 1e-3 to 3; the running loss is a fraction of the stall
    loss), and 0.05 … 20 × a nominal R_th; absent at 0."""
    full = 1.0 / (_alpha(ctx.rig) * _loss_scale(ctx))
    m = ctx.rig.motor
    if ctx.rig.effects.motor_heating and m.R_th > 0.0:
        return min(0.05 * m.R_th, 1e-3 * full), max(20.0 * m.R_th, 3.0 * full), m.R_th, 1.3 * m.R_th
    return 1e-3 * full, 3.0 * full, 0.0, 0.3 * full


#: Heat capacity [J/K] the R_th search assumes until C_th is fitted: a small motor's winding
#: (about 2.6 g of copper at 0.385 J/(g·K)).
TYPICAL_HEAT_CAPACITY = 1.0


def heat_capacity_range(ctx):
    """Heat capacities of 1 mJ/K … 100 J/K (a micro-motor's winding holds tens of mg of copper at
    0.385 J/(g·K), a 20 W motor's tens of g), and 0.05 … 20 × a nominal C_th. The effect is absent
    at R_th = 0 whatever its heat capacity, so "off" here is a typical winding's
    (:data:`TYPICAL_HEAT_CAPACITY`): the screening's probe of R_th (the others at their off values)
    is then a winding warming over tens of seconds, not one following its loss at once (C_th at the
    range's end, which read like a constant change of R_a: the hypothesis was never fitted); its
    probe is a lighter winding (0.3 ×)."""
    m = ctx.rig.motor
    if ctx.rig.effects.motor_heating and m.C_th > 0.0:
        return min(1e-3, 0.05 * m.C_th), max(100.0, 20.0 * m.C_th), m.C_th, m.C_th
    return 1e-3, 100.0, TYPICAL_HEAT_CAPACITY, 0.3 * TYPICAL_HEAT_CAPACITY


def apply(rig, v):
    """The rig with a heated winding of thermal resistance R_th and heat capacity C_th (α_R: the rig
    file's, else copper's)."""
    return rig.with_params("motor", alpha_R=_alpha(rig), R_th=v["R_th"], C_th=v["C_th"]).with_effects(
        motor_heating=True)


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
    diagnoses=(Diagnosis("motor_heating", "electrical",
                         "the winding heats: R_a(T_m) = R_a·(1 + α_R·T_m), C_th·dT_m/dt = R_a(T_m)·i_a² − "
                         "T_m/R_th; the current and thrust sag over a run at a held duty", ("R_th", "C_th"),
                         ("i_a",),
                         sindy_terms={"theta_dot": ("L/J·Δf(R_a(T_m))",), "i_a": ("−R_a·α_R·T_m·i_a/L_a",)},
                         confusable_with=("armature_resistance",), order=65, apply=apply,
                         truth={"R_th": ((30.0, 80.0),), "C_th": ((0.1, 1.0),)},
                         search=(Search("R_th", "K/W", POSITIVE, "motor.R_th",
                                        "winding-to-ambient thermal resistance R_th",
                                        thermal_resistance_range,
                                        "α_R·R_th·v_a²/R_a from 1e-3 to 3 at the largest recorded drive "
                                        "(and 0.05 … 20 × a nominal R_th)", log=True),
                                 Search("C_th", "J/K", POSITIVE, "motor.C_th",
                                        "heat capacity of the winding C_th", heat_capacity_range,
                                        "1e-3 … 100 J/K (and 0.05 … 20 × a nominal C_th)", log=True))),),
)
