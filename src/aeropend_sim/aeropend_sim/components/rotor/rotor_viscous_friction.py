"""Effect ``rotor_viscous_friction``: viscous friction B_m of the rotor, J_m·ω̇₁ −= B_m·ω₁.

Split from the pre-issue-35 ``viscous_friction`` switch, which also turned on the rod's c/J
(``rod_viscous_friction``); that switch is still read as both.
"""

from __future__ import annotations

from aeropend_sim.components.base import POSITIVE, Diagnosis, Effect, Param, Search, Term, load_range

B_M = Param("motor.B_m", "N*m*s/rad", "rotor viscous friction", sign="nonneg", absent=0.0,
            relative_truth=((4.0, 10.0),), symbol="B_m", typical=1e-06,
            measure="the data sheet's no-load current × K_t over the no-load speed")


def torque(xp, omega, B_m):
    """−B_m·ω₁ [N·m]."""
    return -B_m * omega


def d_torque_d_omega(xp, omega, B_m):
    """∂(−B_m·ω₁)/∂ω₁ [N·m·s/rad]."""
    return -B_m + 0.0 * omega


def search_range(ctx):
    """Up to 3 × the B_m that halves the steady rotor speed at the largest recorded duty (and
    0.05 … 20 × a nominal B_m): B_m = (net torque without B_m at ω_max/2)/(ω_max/2)."""
    w = 0.5 * max(ctx.omega_max, 1e-9)
    halving = max(ctx.rotor_torque(w, without=NAME) / w, 1e-30)
    return load_range(ctx.rig.motor.B_m, ctx.rig.effects.rotor_viscous_friction, halving, 0.2)


def apply(rig, v):
    """The rig with rotor viscous friction B_m."""
    return rig.with_params("motor", B_m=v["B_m"]).with_effects(rotor_viscous_friction=True)


NAME = "rotor_viscous_friction"

EFFECT = Effect(
    name=NAME,
    part="rotor",
    label="rotor viscous friction",
    description="−B_m ω₁ on the rotor",
    order=42,
    params=(B_M,),
    terms=(Term("rotor_torque", 10, torque, "−B_m·ω₁", partials={"omega": d_torque_d_omega}),),
    legacy_switch="viscous_friction",
    legacy_default=True,
    diagnoses=(Diagnosis("rotor_friction", "motor",
                         "rotor viscous friction B_m wrong or omitted: J_m·ω̇₁ = … − B_m·ω₁",
                         ("B_m",), ("omega_rotor",),
                         sindy_terms={"theta_dot": ("L/J·Δf(B_m)",), "omega_rotor": ("−ΔB_m·ω₁/J_m",)},
                         confusable_with=("back_emf", "armature_resistance", "torque_constant",
                                          "propeller_drag"), order=90, apply=apply,
                         search=(Search("B_m", "N*m*s/rad", POSITIVE, "motor.B_m",
                                        "rotor viscous friction B_m",
                                        search_range, "1e-3 … 3 × the B_m that halves the steady rotor "
                                        "speed at the largest recorded duty (and 0.05 … 20 × a nominal "
                                        "B_m)", log=True),)),),
)
