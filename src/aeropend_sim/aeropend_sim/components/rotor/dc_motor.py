"""Component ``dc_motor``: a brushed DC motor's armature circuit and rotor (thesis Eqs. 3.5, 3.8).

    L_a·di_a/dt = v_a − R_a·i_a + Σ(armature terms, e.g. −K_ω·ω₁)
    J_m·ω̇₁    = K_t·i_a + Σ(rotor-torque terms, e.g. −B_m·ω₁)

With the ``armature_inductance`` effect off the current is algebraic (thesis Eq. 3.6),
i_a = (v_a + Σ armature terms)/R_a. The armature closure is part of the model's skeleton
(:mod:`aeropend_sim.components.assembly`); this module declares the parameters and the motor
torque K_t·i_a.
"""

from __future__ import annotations

from aeropend_sim.components.base import POSITIVE, Component, Diagnosis, Param, Search, Term, scaled

R_A = Param("motor.R_a", "ohm", "armature resistance", sign="positive",
            relative_truth=((0.6, 0.8), (1.25, 1.6)), symbol="R_a", typical=2.0,
            measure='the armature voltage over the current at stall (thesis §4.4.1), or an ohmmeter')
K_T = Param("motor.K_t", "N*m/A", "torque constant K_t", sign="positive",
            relative_truth=((0.6, 0.8), (1.25, 1.6)), symbol="K_t", typical=0.01,
            measure="the motor's data sheet (K_t = K_ω in SI units)")
J_M = Param("motor.J_m", "kg*m^2", "rotor-side inertia (rotor + gear + propeller reflected)", sign="positive",
            relative_truth=((0.2, 0.4), (3.0, 6.0)), symbol="J_m", typical=1e-05,
            measure="steps or PRBS with holds near the motor's time constant, "
                    "or the data sheet's rotor inertia")


def torque(xp, i_a, K_t):
    """Motor torque K_t·i_a [N·m]."""
    return K_t * i_a


def d_torque_d_i_a(xp, i_a, K_t):
    """∂(K_t·i_a)/∂i_a [N·m/A]."""
    return K_t + 0.0 * i_a


def resistance(xp, R_a):
    """Armature resistance R_a [Ω] (a heated winding's replaces it: ``motor_heating``)."""
    return R_a


def resistance_range(ctx):
    """0.2 … 5 × nominal R_a."""
    return scaled(ctx.rig.motor.R_a, 0.2, 5.0, 1.2)


def torque_constant_range(ctx):
    """0.2 … 5 × nominal K_t."""
    return scaled(ctx.rig.motor.K_t, 0.2, 5.0, 1.2)


def inertia_range(ctx):
    """0.05 … 20 × nominal J_m."""
    return scaled(ctx.rig.motor.J_m, 0.05, 20.0, 2.0)


def _setter(name):
    def apply(rig, v):
        return rig.with_params("motor", **{name: v[name]})

    apply.__doc__ = f"The rig with motor.{name} replaced."
    return apply


_MOTOR = ("back_emf", "armature_resistance", "torque_constant", "rotor_friction", "propeller_drag")

COMPONENT = Component(
    name="dc_motor",
    part="rotor",
    label="DC motor",
    description="armature L_a·di_a/dt = v_a − R_a·i_a − K_ω·ω₁ (Eq. 3.5); rotor J_m·ω̇₁ = K_t·i_a − ... "
                "(Eq. 3.8)",
    order=30,
    params=(R_A, K_T, J_M),
    terms=(Term("rotor_torque", 0, torque, "K_t·i_a", partials={"i_a": d_torque_d_i_a}),
           Term("resistance", 0, resistance, "R_a")),
    needs=("armature",),
    diagnoses=(
        Diagnosis("armature_resistance", "electrical",
                  "armature resistance R_a wrong: L_a·di_a/dt = v_a − R_a·i_a − K_ω·ω₁", ("R_a",), ("i_a",),
                  sindy_terms={"theta_dot": ("L/J·Δf(R_a)",), "i_a": ("−ΔR_a·i_a/L_a",),
                               "omega_rotor": ("K_t·Δi_a(R_a)/J_m",)},
                  confusable_with=tuple(x for x in _MOTOR if x != "armature_resistance"), order=60,
                  apply=_setter("R_a"),
                  search=(Search("R_a", "ohm", POSITIVE, "motor.R_a", "armature resistance R_a",
                                 resistance_range,
                                 "0.2 … 5 × nominal", log=True),)),
        Diagnosis("torque_constant", "motor",
                  "motor torque constant K_t wrong: J_m·ω̇₁ = K_t·i_a − B_m·ω₁ − …",
                  ("K_t",), ("i_a", "omega_rotor"),
                  sindy_terms={"theta_dot": ("L/J·Δf(K_t)",), "omega_rotor": ("ΔK_t·i_a/J_m",)},
                  confusable_with=tuple(x for x in _MOTOR if x != "torque_constant"), order=80,
                  apply=_setter("K_t"),
                  search=(Search("K_t", "N*m/A", POSITIVE, "motor.K_t", "torque constant K_t",
                                 torque_constant_range,
                                 "0.2 … 5 × nominal", log=True),)),
        Diagnosis("motor_time_constant", "motor",
                  "rotor-side inertia J_m wrong (rotor + gear + propeller): the motor's mechanical time "
                  "constant J_m/(B_m + 2·K_d·ω₁ + K_t·K_ω/R_a) scales with it, the thrust follows the duty "
                  "cycle more slowly or faster", ("J_m",), ("theta",),
                  sindy_terms={"theta_dot": ("L/J·Δf(J_m)",), "omega_rotor": ("−ΔJ_m·ω̇₁/J_m",)},
                  confusable_with=("actuator_lag", "input_delay"), screened=False, order=100, timing=True,
                  apply=_setter("J_m"),
                  search=(Search("J_m", "kg*m^2", POSITIVE, "motor.J_m", "rotor-side inertia J_m",
                                 inertia_range,
                                 "0.05 … 20 × nominal", log=True),)),
    ),
)
