"""Effect ``armature_inductance``: the armature current as a state (``dynamic``, thesis Eq. 3.5).

``dynamic``: L_a·di_a/dt = v_a − R_a·i_a + Σ; ``quasi_static``: the current follows the voltage at
once, i_a = (v_a + Σ)/R_a (thesis Eq. 3.6), the usual choice when L_a/R_a is far below the sample
period. A rig file that gives no L_a is quasi-static, and so is one whose L_a/R_a is below
:data:`QUASI_STATIC_FRACTION` of its sample period unless its ``effects:`` section names the mode
(the load report says so). The switch takes a mode, not true/false.
"""

from __future__ import annotations

from aeropend_sim.components.base import POSITIVE, Diagnosis, Effect, Param, Search, scaled

L_A = Param("motor.L_a", "H", "armature inductance", sign="positive", absent=0.0,
            relative_truth=((5.0, 15.0),), symbol="L_a", typical=0.001,
            measure='a current step at stall (thesis §4.4.2)')

#: Largest electrical time constant L_a/R_a, as a fraction of the sample period, that is treated as
#: quasi-static: within one sample the current settles to e^-10 of i_a = (v_a + Σ)/R_a, and the torque
#: it makes lags by under a tenth of a sample, below what a sampled recording resolves (singular
#: perturbation; a dynamic armature that fast also costs an explicit integrator L_a/R_a-sized steps).
QUASI_STATIC_FRACTION = 0.1


def negligible(values, sample_period):
    """Why a rig file's L_a is quasi-static at its sample period [s] (None if it is not)."""
    tau_e = values["motor.L_a"] / values["motor.R_a"]
    if tau_e < QUASI_STATIC_FRACTION * sample_period:
        return (f"armature quasi-static (Eq. 3.6): L_a/R_a = {tau_e * 1e3:.3g} ms is below "
                f"{QUASI_STATIC_FRACTION:g} × the sample period {sample_period * 1e3:.3g} ms; write "
                f"effects.armature_inductance: dynamic to integrate it anyway")
    return None


def search_range(ctx):
    """0.01 … 100 × nominal L_a of a dynamic armature; a quasi-static one (no L_a, or one too fast
    for the sample period): electrical time constants L_a/R_a from :data:`QUASI_STATIC_FRACTION` of
    a sample period to 0.1 s, probe one sample period."""
    m, period = ctx.rig.motor, ctx.rig.sample_period
    if m.L_a > 0.0 and ctx.rig.effects.armature_inductance == "dynamic":
        return scaled(m.L_a, 0.01, 100.0, 3.0)
    return QUASI_STATIC_FRACTION * period * m.R_a, 0.1 * m.R_a, 0.0, period * m.R_a


def apply(rig, v):
    """The rig with the armature current a state of inductance L_a."""
    return rig.with_params("motor", L_a=v["L_a"]).with_effects(armature_inductance="dynamic")


EFFECT = Effect(
    name="armature_inductance",
    part="rotor",
    label="armature inductance",
    description="`dynamic`: L_a di_a/dt = v_a − R_a i_a − K_ω ω₁ (Eq. 3.5); `quasi_static`: "
                "i_a = (v_a − K_ω ω₁)/R_a (Eq. 3.6)",
    order=40,
    params=(L_A,),
    modes=("dynamic", "quasi_static"),
    legacy_default="dynamic",
    negligible=negligible,
    needs=("armature",),
    diagnoses=(Diagnosis("armature_inductance", "electrical",
                         "armature inductance L_a wrong (electrical time constant L_a/R_a)", ("L_a",),
                         ("i_a",),
                         sindy_terms={"theta_dot": ("L/J·Δf(L_a)",), "i_a": ("(L_a/L_a' − 1)·di_a/dt",),
                                      "omega_rotor": ("K_t·Δi_a(L_a)/J_m",)},
                         order=70, apply=apply,
                         search=(Search("L_a", "H", POSITIVE, "motor.L_a", "armature inductance L_a",
                                        search_range,
                                        "0.01 … 100 × nominal (quasi-static: L_a/R_a 0.1 sample … 0.1 s)",
                                        log=True),)),),
)
