"""Effect ``rotor_coulomb_friction``: brush (Coulomb) friction of the rotor, J_m·ω̇₁ −= T_c·sgn(ω₁).

A constant torque against the rotation of a brushed motor (brushes on the commutator, bearing
preload). sgn(ω₁) is regularised as tanh(ω₁/ω_ε) (ω_ε = ``rotor_friction_velocity``) so the ODE
stays Lipschitz. Split from the pre-issue-35 ``coulomb_friction`` switch, which also turned on
the rod's dry friction; that switch is still read as both.
"""

from __future__ import annotations

from aeropend_sim.components.base import Diagnosis, Effect, Param, Term

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


EFFECT = Effect(
    name="rotor_coulomb_friction",
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
                         confusable_with=("rotor_friction", "propeller_drag")),),
)
