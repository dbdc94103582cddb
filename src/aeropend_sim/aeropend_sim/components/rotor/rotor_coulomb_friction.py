"""Effect ``rotor_coulomb_friction``: brush (Coulomb) friction of the rotor, J_m·ω̇₁ −= T_c·sgn(ω₁).

A constant torque against the rotation of a brushed motor (brushes on the commutator, bearing
preload). sgn(ω₁) is regularised as tanh(ω₁/ω_ε) (ω_ε = ``rotor_friction_velocity``) so the ODE
stays Lipschitz. Split from the pre-issue-35 ``coulomb_friction`` switch, which also turned on
the rod's dry friction; that switch is still read as both.
"""

from __future__ import annotations

import math

from aeropend_sim.components.base import POSITIVE, Diagnosis, Effect, Param, Search, Term, load_range

T_C = Param("motor.T_c", "N*m", "rotor Coulomb (brush) friction torque", sign="nonneg", absent=0.0,
            symbol="T_c")
OMEGA_EPS = Param("motor.rotor_friction_velocity", "rad/s", "tanh regularisation width of sign(ω₁)",
                  sign="positive", absent=1.0, setting=True, symbol="ω_ε")


def torque(xp, omega, T_c, rotor_friction_velocity):
    """−T_c·tanh(ω₁/ω_ε) [N·m]."""
    return -T_c * xp.tanh(omega / rotor_friction_velocity)


def d_torque_d_omega(xp, omega, T_c, rotor_friction_velocity):
    """∂/∂ω₁ [N·m·s/rad] (written with 1 − tanh², which cannot overflow)."""
    th = xp.tanh(omega / rotor_friction_velocity)
    return -T_c / rotor_friction_velocity * (1.0 - th * th)


def search_range(ctx):
    """Up to 3 × the T_c that halves the steady rotor speed at the largest recorded duty (and
    0.05 … 20 × a nominal T_c): T_c = (net torque without T_c at ω_max/2)/tanh(ω_max/2/ω_ε)."""
    w = 0.5 * max(ctx.omega_max, 1e-9)
    m = ctx.rig.motor
    halving = max(ctx.rotor_torque(w, without=NAME) / math.tanh(w / m.rotor_friction_velocity), 1e-30)
    return load_range(m.T_c, ctx.rig.effects.rotor_coulomb_friction, halving, 0.1)


def apply(rig, v):
    """The rig with rotor brush friction T_c."""
    return rig.with_params("motor", T_c=v["T_c"]).with_effects(rotor_coulomb_friction=True)


NAME = "rotor_coulomb_friction"

EFFECT = Effect(
    name=NAME,
    part="rotor",
    label="rotor brush friction",
    description="−T_c sgn(ω₁) on the rotor (brush friction)",
    order=44,
    params=(T_C, OMEGA_EPS),
    terms=(Term("rotor_torque", 30, torque, "−T_c·tanh(ω₁/ω_ε)", partials={"omega": d_torque_d_omega}),),
    legacy_switch="coulomb_friction",
    diagnoses=(Diagnosis("rotor_brush_friction", "motor",
                         "rotor brush friction T_c wrong or omitted: J_m·ω̇₁ = … − T_c·sgn(ω₁)", ("T_c",),
                         ("omega_rotor",),
                         sindy_terms={"theta_dot": ("L/J·Δf(T_c)",), "omega_rotor": ("−ΔT_c·sgn(ω₁)/J_m",)},
                         confusable_with=("rotor_friction", "propeller_drag"), order=115, apply=apply,
                         truth={"T_c": ((1e-3, 3e-3),)},
                         search=(Search("T_c", "N*m", POSITIVE, "motor.T_c",
                                        "rotor brush friction torque T_c",
                                        search_range, "1e-3 … 3 × the T_c that halves the steady rotor speed "
                                        "(and "
                                        "0.05 … 20 × a nominal T_c)", log=True),)),),
)
