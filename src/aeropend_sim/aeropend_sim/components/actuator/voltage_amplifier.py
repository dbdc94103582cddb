"""Family ``voltage_amplifier``: a DC motor driven by a voltage amplifier (e.g. the Quanser Aero).

The command τ is a fraction of the amplifier's full scale: v_a = v_offset + v_max·τ_e, no H-bridge
map. The motor is :mod:`..rotor.dc_motor` (armature electrics R_a, L_a, K_ω, K_t, J_m).
"""

from __future__ import annotations

import math

from aeropend_sim.components.base import DC_ROTOR, Diagnosis, Family, Param, Search, Term

V_MAX = Param("actuator.v_max", "V", "amplifier full scale: v_a = v_offset + v_max·τ", sign="positive",
              symbol="V_max", typical=10.0,
              measure="the amplifier gain × the command's full scale (data sheet)")
V_OFFSET = Param("actuator.v_offset", "V", "amplifier output at zero command (offset)", absent=0.0,
                 symbol="v_0", typical=0.0,
                 measure='the amplifier output at zero command (a voltmeter), or a balance table')


def voltage(xp, tau, v_max, v_offset):
    """Amplifier output v_a = v_offset + v_max·τ_e [V]."""
    return v_offset + v_max * tau


def d_voltage_d_tau(xp, tau, v_max, v_offset):
    """∂v_a/∂τ_e [V]."""
    return v_max + 0.0 * tau


def duty_of_voltage(xp, y, v_max, v_offset):
    """τ_e of a voltage y [V]."""
    return (y - v_offset) / v_max


def offset_range(ctx):
    """±0.2 × v_a at the largest recorded duty around the nominal offset."""
    v = max(abs(ctx.drive_max), 1e-6)
    off = ctx.rig.actuator.v_offset
    return off - 0.2 * v, off + 0.2 * v, off, off - 0.03 * v


def apply_offset(rig, v):
    """The rig with amplifier offset v_0."""
    return rig.with_params("actuator", v_offset=v["v_offset"])


FAMILY = Family(
    name="voltage_amplifier",
    part="actuator",
    label="DC motor on a voltage amplifier",
    description="command τ as a fraction of the amplifier's full scale: v_a = v_offset + v_max·τ (no "
                "H-bridge map); armature electrics R_a, L_a, K_ω, K_t, rotor J_m, gear",
    order=11,
    params=(V_MAX, V_OFFSET),
    terms=(Term("drive", 10, voltage, "v_a = v_offset + v_max·τ_e", partials={"tau": d_voltage_d_tau},
                inverse=duty_of_voltage),),
    families=("voltage_amplifier",),
    why_not="a parameter of the voltage_amplifier family: its rig file says "
            "actuator.family: voltage_amplifier",
    drive="v_a",
    lacks={"rotor_response": DC_ROTOR},
    usual_effects=("back_emf", "rotor_viscous_friction", "rod_viscous_friction"),
    diagnoses=(Diagnosis("amplifier_offset", "electrical",
                         "amplifier output offset v_0 wrong: v_a = v_0 + V_max·τ (a negative offset acts "
                         "like a drop, a positive one drives the rotor at zero command)", ("v_offset",),
                         ("theta",),
                         sindy_terms={"theta_dot": ("L/J·Δf(v_0)",), "i_a": ("Δv_0/L_a",), "v_a": ("Δv_0",)},
                         confusable_with=("dead_zone",), truth={"v_offset": ((-0.5, -0.2), (0.2, 0.5))},
                         order=25, apply=apply_offset,
                         search=(Search("v_offset", "V", (-math.inf, math.inf), "actuator.v_offset",
                                        "amplifier output offset v_0", offset_range,
                                        "nominal ± 0.2 × v_a at the largest recorded duty"),)),),
)
