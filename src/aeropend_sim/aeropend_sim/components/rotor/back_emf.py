"""Effect ``back_emf``: the back-EMF e_a = K_ω·ω₁ in the armature equation (thesis Eq. 3.5)."""

from __future__ import annotations

from aeropend_sim.components.base import POSITIVE, Diagnosis, Effect, Param, Search, Term

K_OMEGA = Param("motor.K_omega", "V*s/rad", "back-EMF constant K_ω", sign="nonneg", absent=0.0,
                relative_truth=((0.5, 0.7), (1.4, 2.0)), symbol="K_ω", typical=0.01,
                measure='the armature voltage, current and speed at steady state (thesis §4.4.3), '
                        'or the data sheet')


def voltage(xp, omega, K_omega):
    """−K_ω·ω₁ [V]."""
    return -K_omega * omega


def d_voltage_d_omega(xp, omega, K_omega):
    """∂(−K_ω·ω₁)/∂ω₁ [V·s/rad]."""
    return -K_omega + 0.0 * omega


def search_range(ctx):
    """0.1 … 10 × nominal K_ω (K_t when the rig has no back-EMF); absent at the rig's K_ω (0 when off)."""
    m, on = ctx.rig.motor, ctx.rig.effects.back_emf
    base = m.K_omega if (on and m.K_omega > 0.0) else m.K_t
    off = m.K_omega if on else 0.0
    return 0.1 * base, 10.0 * base, off, (1.3 if on else 0.5) * base


def apply(rig, v):
    """The rig with back-EMF constant K_ω."""
    return rig.with_params("motor", K_omega=v["K_omega"]).with_effects(back_emf=True)


EFFECT = Effect(
    name="back_emf",
    part="rotor",
    label="back-EMF",
    description="e_a = K_ω ω₁ in the armature equation (off: e_a = 0)",
    order=41,
    params=(K_OMEGA,),
    terms=(Term("armature", 10, voltage, "−K_ω·ω₁", partials={"omega": d_voltage_d_omega}),),
    legacy_default=True,
    diagnoses=(Diagnosis("back_emf", "motor",
                         "back-EMF constant K_ω wrong or omitted: L_a·di_a/dt = v_a − R_a·i_a − K_ω·ω₁",
                         ("K_omega",), ("i_a",),
                         sindy_terms={"theta_dot": ("L/J·Δf(K_ω)",), "i_a": ("−ΔK_ω·ω₁/L_a",),
                                      "omega_rotor": ("K_t·Δi_a(K_ω)/J_m",)},
                         confusable_with=("armature_resistance", "torque_constant", "rotor_friction",
                                          "propeller_drag"), order=50, apply=apply,
                         search=(Search("K_omega", "V*s/rad", POSITIVE, "motor.K_omega",
                                        "back-EMF constant K_ω",
                                        search_range, "0.1 … 10 × nominal (K_t when the rig has no back-EMF)",
                                        log=True),)),),
)
