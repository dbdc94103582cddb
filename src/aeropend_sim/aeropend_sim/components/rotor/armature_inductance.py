"""Effect ``armature_inductance``: the armature current as a state (``dynamic``, thesis Eq. 3.5).

``dynamic``: L_a·di_a/dt = v_a − R_a·i_a + Σ; ``quasi_static``: the current follows the voltage at
once, i_a = (v_a + Σ)/R_a (thesis Eq. 3.6), the usual choice when L_a/R_a is far below the sample
period. A rig file that gives no L_a is quasi-static. The switch takes a mode, not true/false.
"""

from __future__ import annotations

from aeropend_sim.components.base import POSITIVE, Diagnosis, Effect, Param, Search, scaled

L_A = Param("motor.L_a", "H", "armature inductance", sign="positive", absent=0.0,
            relative_truth=((5.0, 15.0),), symbol="L_a", typical=0.001,
            measure='a current step at stall (thesis §4.4.2)')

def search_range(ctx):
    """0.01 … 100 × nominal L_a; a rig without one (quasi-static armature): electrical time
    constants L_a/R_a from 10 µs to 0.1 s, probe one sample period."""
    m = ctx.rig.motor
    if m.L_a > 0.0:
        return scaled(m.L_a, 0.01, 100.0, 3.0)
    return 1e-5 * m.R_a, 0.1 * m.R_a, 0.0, ctx.rig.sample_period * m.R_a


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
    families=("dc_hbridge", "voltage_amplifier"),
    why_not="an ESC drives a brushless motor from its own controller: no armature current to model",
    diagnoses=(Diagnosis("armature_inductance", "electrical",
                         "armature inductance L_a wrong (electrical time constant L_a/R_a)", ("L_a",),
                         ("i_a",),
                         sindy_terms={"theta_dot": ("L/J·Δf(L_a)",), "i_a": ("(L_a/L_a' − 1)·di_a/dt",),
                                      "omega_rotor": ("K_t·Δi_a(L_a)/J_m",)},
                         order=70, apply=apply,
                         search=(Search("L_a", "H", POSITIVE, "motor.L_a", "armature inductance L_a",
                                        search_range,
                                        "0.01 … 100 × nominal (without one: L_a/R_a 10 µs … 0.1 s)",
                                        log=True),)),),
)
