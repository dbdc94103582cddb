"""Effect ``hbridge_map``: the thesis' measured H-bridge map (Eq. 4.3) instead of v_supply·τ_e.

v_a = max(0, k0 + k1·sqrt(k2·τ_e + k3)), clipped at 0 V (Eq. 4.3 is negative below τ ≈ 0.95 %).
"""

from __future__ import annotations

from aeropend_sim.components.base import Effect, Param, Term

K0 = Param("actuator.hbridge_k0", "V", "Eq. 4.3 k0 in v_a = k0 + k1·sqrt(k2·τ + k3)", absent=0.0, symbol="k0")
K1 = Param("actuator.hbridge_k1", "V", "Eq. 4.3 k1", sign="positive", absent=0.0, symbol="k1")
K2 = Param("actuator.hbridge_k2", "1", "Eq. 4.3 k2 (τ as a fraction)", sign="positive", absent=0.0,
           symbol="k2")
K3 = Param("actuator.hbridge_k3", "1", "Eq. 4.3 k3", sign="nonneg", absent=0.0, symbol="k3")


def voltage(xp, tau, hbridge_k0, hbridge_k1, hbridge_k2, hbridge_k3):
    """v_a = max(0, k0 + k1·sqrt(k2·τ_e + k3)) [V]."""
    return xp.maximum(0.0, hbridge_k0 + hbridge_k1 * xp.sqrt(xp.maximum(hbridge_k2 * tau + hbridge_k3, 0.0)))


def d_voltage_d_tau(xp, tau, hbridge_k0, hbridge_k1, hbridge_k2, hbridge_k3):
    """∂v_a/∂τ_e [V] (0 where the map is clipped at 0 V)."""
    root = xp.sqrt(xp.maximum(hbridge_k2 * tau + hbridge_k3, 1e-300))
    return xp.where(hbridge_k0 + hbridge_k1 * root > 0.0, hbridge_k1 * hbridge_k2 / (2.0 * root), 0.0)


def duty_of_voltage(xp, y, hbridge_k0, hbridge_k1, hbridge_k2, hbridge_k3):
    """τ_e of a voltage y [V] (0 for y ≤ 0)."""
    te = xp.where(y > 0.0, (((y - hbridge_k0) / hbridge_k1) ** 2 - hbridge_k3) / hbridge_k2, 0.0)
    return xp.maximum(te, 0.0)


EFFECT = Effect(
    name="hbridge_map",
    part="actuator",
    label="H-bridge map",
    description="v_a = max(0, k0 + k1 sqrt(k2 τ_e + k3)) (thesis Eq. 4.3) instead of v_supply τ_e",
    order=23,
    params=(K0, K1, K2, K3),
    terms=(Term("drive", 20, voltage, "v_a = max(0, k0 + k1·sqrt(k2·τ_e + k3))",
                partials={"tau": d_voltage_d_tau}, inverse=duty_of_voltage),),
    families=("dc_hbridge",),
    why_not="the Eq. 4.3 map describes a PWM H-bridge; an ESC or a voltage amplifier has no H-bridge",
)
