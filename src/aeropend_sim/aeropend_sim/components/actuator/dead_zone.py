"""Effect ``dead_zone``: a duty-cycle dead zone τ_dz, τ_e = max(0, τ − τ_dz)/(1 − τ_dz).

Commands below τ_dz do nothing; full scale is kept. Not on an ESC: there the idle throttle τ_0 of
the throttle map is the dead zone, and a second one could not be told apart from it.
"""

from __future__ import annotations

from aeropend_sim.components.base import Diagnosis, Effect, FitBounds, Param, Search, Term

DEAD_ZONE = Param("actuator.dead_zone", "1", "duty-cycle dead zone τ_dz", sign="nonneg", below=1.0,
                  absent=0.0, fit=FitBounds(0.0, 0.95, False, 0.05), symbol="τ_dz", typical=0.05,
                  measure='a balance table (command vs angle) down to the command where the rod lifts')


def effective_duty(xp, tau, dead_zone):
    """τ_e = max(0, τ − τ_dz)/(1 − τ_dz) [1]."""
    return xp.maximum(0.0, tau - dead_zone) / (1.0 - dead_zone)


def d_effective_duty(xp, tau, dead_zone):
    """∂τ_e/∂τ [1]: 1/(1 − τ_dz) above the dead zone, 0 inside it."""
    return xp.where(tau > dead_zone, 1.0 / (1.0 - dead_zone), 0.0)


def duty_of_effective(xp, y, dead_zone):
    """The duty τ giving τ_e = y (0 for y ≤ 0)."""
    return xp.where(y > 0.0, y * (1.0 - dead_zone) + dead_zone, 0.0)


def search_range(ctx):
    """0 … min(0.6, 0.9·largest recorded duty); absent at the rig's τ_dz (0 when off)."""
    off = ctx.rig.actuator.dead_zone if ctx.rig.effects.dead_zone else 0.0
    return 0.0, min(0.6, 0.9 * ctx.duty_max), off, off + 0.05


def apply(rig, v):
    """The rig with a dead zone τ_dz."""
    return rig.with_params("actuator", dead_zone=v["dead_zone"]).with_effects(dead_zone=True)


EFFECT = Effect(
    name="dead_zone",
    part="actuator",
    label="dead zone",
    description="τ_e = max(0, τ_f − τ_dz)/(1 − τ_dz) (full scale kept)",
    order=22,
    params=(DEAD_ZONE,),
    terms=(Term("duty", 10, effective_duty, "τ_e = max(0, τ − τ_dz)/(1 − τ_dz)",
                partials={"tau": d_effective_duty}, inverse=duty_of_effective),),
    active_when=lambda v: v["actuator.dead_zone"] > 0.0,
    diagnoses=(Diagnosis("dead_zone", "actuator",
                         "duty-cycle dead zone τ_dz: τ_e = max(0, τ − τ_dz)/(1 − τ_dz)", ("dead_zone",),
                         ("theta",),
                         sindy_terms={"theta_dot": ("L/J·Δf(τ_dz)",), "i_a": ("Δv_a(τ_dz)/L_a",),
                                      "v_a": ("Δv_a(τ_dz)",)},
                         confusable_with=("hbridge_drop",), truth={"dead_zone": ((0.05, 0.12),)},
                         order=10, apply=apply,
                         search=(Search("dead_zone", "1", (0.0, 0.95), "actuator.dead_zone",
                                        "dead-zone width τ_dz",
                                        search_range, "0 … min(0.6, 0.9·largest recorded duty)"),)),),
)
