"""Family ``dc_hbridge``: a brushed DC motor behind a PWM H-bridge (the thesis rig).

Ideal drive map v_a = v_supply·τ_e (PWM average); the thesis' measured map (Eq. 4.3) is the
``hbridge_map`` effect. The motor is :mod:`..rotor.dc_motor` (armature R_a, L_a, K_ω, K_t, J_m).
"""

from __future__ import annotations

import math

from aeropend_sim.components.base import DC_ROTOR, POSITIVE, Diagnosis, Family, Param, Search, Term, scaled

V_SUPPLY = Param("actuator.v_supply", "V", "H-bridge supply: ideal map v_a = v_supply·τ", sign="positive",
                 relative_truth=(), symbol="V_s", typical=12.0,
                 measure='the H-bridge supply voltage (a voltmeter)')


def voltage(xp, tau, v_supply):
    """Ideal PWM map v_a = v_supply·τ_e [V]."""
    return v_supply * tau


def d_voltage_d_tau(xp, tau, v_supply):
    """∂v_a/∂τ_e [V]."""
    return v_supply + 0.0 * tau


def duty_of_voltage(xp, y, v_supply):
    """τ_e of a voltage y [V] (inverse of the ideal map)."""
    return y / v_supply


#: Session-to-session drift of the supply V_s (σ of its log change, 8 %): a 3-cell LiPo runs from
#: 12.6 V to about 10.5 V under load over its charge (−17 %), a USB port 4.75–5.25 V, a bench supply
#: < 1 % (docs/gap.md, "Drift prior").
SUPPLY_DRIFT_SIGMA = 0.08


def drop_range(ctx):
    """−0.2 … 0.6 × v_a at the largest recorded duty; absent at 0 V."""
    v = max(ctx.drive_max, 1e-6)
    return -0.2 * v, 0.6 * v, 0.0, 0.06 * v


def apply_drop(rig, v):
    """The rig with a bridge drop V_d: the Eq. 4.3 map's k0 lowered by V_d; on the ideal map
    v_a = v_s·τ a drop V with the 0 V clip equals a dead zone V/v_s at a supply v_s − V."""
    drop = v["V_drop"]
    a = rig.actuator
    if rig.effects.hbridge_map:
        return rig.with_params("actuator", hbridge_k0=a.hbridge_k0 - drop)
    if drop <= 0.0:
        return rig.with_params("actuator", v_supply=a.v_supply - drop)
    if drop >= a.v_supply:
        raise ValueError(f"H-bridge drop {drop} V >= supply {a.v_supply} V")
    base_dz = a.dead_zone if rig.effects.dead_zone else 0.0
    te0 = drop / a.v_supply
    dz = base_dz + te0 * (1.0 - base_dz)
    return rig.with_params("actuator", v_supply=a.v_supply - drop, dead_zone=dz).with_effects(dead_zone=True)


def supply_range(ctx):
    """0.5 … 2 × the nominal supply."""
    return scaled(ctx.rig.actuator.v_supply, 0.5, 2.0, 1.1)


def apply_supply(rig, v):
    """Supply voltage V_s: the ideal map's v_supply; the Eq. 4.3 map's output k0 + k1·√(…) scales
    with V_s / v_supply (the bridge passes a fixed share of its supply)."""
    a = rig.actuator
    new = rig.with_params("actuator", v_supply=v["v_supply"])
    if rig.effects.hbridge_map:
        f = v["v_supply"] / a.v_supply
        new = new.with_params("actuator", hbridge_k0=a.hbridge_k0 * f, hbridge_k1=a.hbridge_k1 * f)
    return new


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
    usual_effects=("back_emf", "rotor_viscous_friction", "rod_viscous_friction"),
    diagnoses=(
        Diagnosis("hbridge_drop", "electrical",
                  "H-bridge voltage drop V_d: v_a = max(0, k0 − V_d + k1·sqrt(k2·τ + k3)) (Eq. 4.3 map) or "
                  "max(0, v_supply·τ − V_d) (ideal map)",
                  ("V_drop",), ("theta",),
                  sindy_terms={"theta_dot": ("L/J·Δf(V_d)",), "i_a": ("Δv_a(V_d)/L_a",),
                               "v_a": ("Δv_a(V_d)",)},
                  confusable_with=("dead_zone",), truth={"V_drop": ((0.12, 0.25),)}, order=20,
                  apply=apply_drop,
                  search=(Search("V_drop", "V", (-math.inf, math.inf), "actuator.hbridge_k0",
                                 "voltage lost across the bridge switches V_d", drop_range,
                                 "−0.2 … 0.6 × v_a at the largest recorded duty"),)),
        Diagnosis("supply_voltage", "electrical",
                  "supply voltage V_s of the H-bridge changed (battery charge, another supply): the whole "
                  "drive map scales, v_a = (V_s/V_s,nominal)·v_a,nominal(τ). With the angle alone it acts "
                  "as a thrust-gain change (thrust ∝ ω₁² ∝ v_a²); the recorded v_a separates the two",
                  ("v_supply",), ("v_a",), sindy_terms={"v_a": ("ΔV_s·τ",)},
                  confusable_with=("thrust_coefficient", "hbridge_drop"), kind="drift", order=5,
                  drift_sigma=SUPPLY_DRIFT_SIGMA,
                  apply=apply_supply,
                  search=(Search("v_supply", "V", POSITIVE, "actuator.v_supply", "supply voltage V_s",
                                 supply_range, "0.5 … 2 × nominal", log=True),)),
    ),
)
