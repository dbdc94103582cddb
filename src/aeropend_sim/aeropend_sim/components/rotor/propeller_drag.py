"""Effect ``propeller_drag``: the propeller's drag torque on the rotor, J_m·ω̇₁ −= K_d·ω₁|ω₁|."""

from __future__ import annotations

from aeropend_sim.components.base import POSITIVE, Diagnosis, Effect, Param, Search, Term, load_range

K_D = Param("motor.K_d", "N*m*s^2/rad^2", "propeller drag torque on the rotor: K_d·ω1·|ω1|", sign="nonneg",
            absent=0.0, relative_truth=((0.4, 0.6), (1.6, 2.5)), symbol="K_d", typical=1e-07,
            measure="the propeller's torque coefficient C_Q·ρ·D⁵/(2π)² (data sheet), "
                    "or the rotor speed recorded")


def torque(xp, omega, K_d):
    """−K_d·ω₁·|ω₁| [N·m]."""
    return -K_d * omega * xp.abs(omega)


def d_torque_d_omega(xp, omega, K_d):
    """∂(−K_d·ω₁|ω₁|)/∂ω₁ [N·m·s/rad]."""
    return -2.0 * K_d * xp.abs(omega)


def search_range(ctx):
    """Up to 3 × the K_d that halves the steady rotor speed at the largest recorded duty (and
    0.05 … 20 × a nominal K_d): K_d = (net torque without K_d at ω_max/2)/(ω_max/2)²."""
    w = 0.5 * max(ctx.omega_max, 1e-9)
    halving = max(ctx.rotor_torque(w, without=NAME) / w**2, 1e-30)
    return load_range(ctx.rig.motor.K_d, ctx.rig.effects.propeller_drag, halving, 0.1)


def apply(rig, v):
    """The rig with propeller drag K_d."""
    return rig.with_params("motor", K_d=v["K_d"]).with_effects(propeller_drag=True)


NAME = "propeller_drag"

EFFECT = Effect(
    name=NAME,
    part="rotor",
    label="propeller drag",
    description="−K_d ω₁|ω₁| on the rotor",
    order=43,
    params=(K_D,),
    terms=(Term("rotor_torque", 20, torque, "−K_d·ω₁|ω₁|", partials={"omega": d_torque_d_omega}),),
    legacy_default=True,
    diagnoses=(Diagnosis("propeller_drag", "aerodynamic",
                         "propeller drag torque wrong or omitted: J_m·ω̇₁ = … − K_d·ω₁|ω₁|", ("K_d",),
                         ("omega_rotor",),
                         sindy_terms={"theta_dot": ("L/J·Δf(K_d)",), "omega_rotor": ("−ΔK_d·ω₁|ω₁|/J_m",)},
                         confusable_with=("thrust_law", "back_emf", "armature_resistance", "torque_constant",
                                          "rotor_friction"), order=110, apply=apply,
                         search=(Search("K_d", "N*m*s^2/rad^2", POSITIVE, "motor.K_d",
                                        "drag torque coefficient K_d",
                                        search_range, "1e-3 … 3 × the K_d that halves the steady rotor speed "
                                        "(and "
                                        "0.05 … 20 × a nominal K_d)", log=True),)),),
)
