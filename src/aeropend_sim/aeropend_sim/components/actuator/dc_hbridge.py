"""Family ``dc_hbridge``: a brushed DC motor behind a PWM H-bridge (the thesis rig).

Ideal drive map v_a = v_supply·τ_e (PWM average); the thesis' measured map (Eq. 4.3) is the
``hbridge_map`` effect. The motor is :mod:`..rotor.dc_motor` (armature R_a, L_a, K_ω, K_t, J_m).
"""

from __future__ import annotations

from aeropend_sim.components.base import DC_ROTOR, Diagnosis, Family, Param, Term

V_SUPPLY = Param("actuator.v_supply", "V", "H-bridge supply: ideal map v_a = v_supply·τ", sign="positive",
                 relative_truth=(), symbol="V_s")


def voltage(xp, tau, v_supply):
    """Ideal PWM map v_a = v_supply·τ_e [V]."""
    return v_supply * tau


def d_voltage_d_tau(xp, tau, v_supply):
    """∂v_a/∂τ_e [V]."""
    return v_supply + 0.0 * tau


def duty_of_voltage(xp, y, v_supply):
    """τ_e of a voltage y [V] (inverse of the ideal map)."""
    return y / v_supply


FAMILY = Family(
    name="dc_hbridge",
    part="actuator",
    label="DC motor behind an H-bridge",
    description="duty cycle τ → armature voltage v_a through a PWM H-bridge (ideal v_supply·τ or the "
                "thesis Eq. 4.3 map); brushed DC motor with armature R_a, L_a, K_ω, K_t, rotor J_m, gear",
    order=10,
    params=(V_SUPPLY,),
    terms=(Term("drive", 10, voltage, "v_a = v_supply·τ_e", partials={"tau": d_voltage_d_tau},
                inverse=duty_of_voltage),),
    families=("dc_hbridge",),
    why_not="a parameter of the dc_hbridge family: its rig file says actuator.family: dc_hbridge",
    drive="v_a",
    lacks={"rotor_response": DC_ROTOR},
    diagnoses=(
        Diagnosis("hbridge_drop", "electrical",
                  "H-bridge voltage drop V_d: v_a = max(0, k0 − V_d + k1·sqrt(k2·τ + k3)) (Eq. 4.3 map) or "
                  "max(0, v_supply·τ − V_d) (ideal map)",
                  ("V_drop",), ("theta",),
                  sindy_terms={"theta_dot": ("L/J·Δf(V_d)",), "i_a": ("Δv_a(V_d)/L_a",),
                               "v_a": ("Δv_a(V_d)",)},
                  confusable_with=("dead_zone",), truth={"V_drop": ((0.12, 0.25),)}),
        Diagnosis("supply_voltage", "electrical",
                  "supply voltage V_s of the H-bridge changed (battery charge, another supply): the whole "
                  "drive map scales, v_a = (V_s/V_s,nominal)·v_a,nominal(τ). With the angle alone it acts "
                  "as a thrust-gain change (thrust ∝ ω₁² ∝ v_a²); the recorded v_a separates the two",
                  ("v_supply",), ("v_a",), sindy_terms={"v_a": ("ΔV_s·τ",)},
                  confusable_with=("thrust_coefficient", "hbridge_drop"), kind="drift"),
    ),
)
