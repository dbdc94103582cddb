"""Family ``voltage_amplifier``: a DC motor driven by a voltage amplifier (e.g. the Quanser Aero).

The command τ is a fraction of the amplifier's full scale: v_a = v_offset + v_max·τ_e, no H-bridge
map. The motor is :mod:`..rotor.dc_motor` (armature electrics R_a, L_a, K_ω, K_t, J_m).
"""

from __future__ import annotations

from aeropend_sim.components.base import DC_ROTOR, Family, Param, Term

V_MAX = Param("actuator.v_max", "V", "amplifier full scale: v_a = v_offset + v_max·τ", sign="positive",
              symbol="V_max")
V_OFFSET = Param("actuator.v_offset", "V", "amplifier output at zero command (offset)", absent=0.0,
                 symbol="v_0")


def voltage(xp, tau, v_max, v_offset):
    """Amplifier output v_a = v_offset + v_max·τ_e [V]."""
    return v_offset + v_max * tau


def d_voltage_d_tau(xp, tau, v_max, v_offset):
    """∂v_a/∂τ_e [V]."""
    return v_max + 0.0 * tau


def duty_of_voltage(xp, y, v_max, v_offset):
    """τ_e of a voltage y [V]."""
    return (y - v_offset) / v_max


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
)
