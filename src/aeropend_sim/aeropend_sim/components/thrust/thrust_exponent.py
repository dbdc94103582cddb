"""Effect ``thrust_exponent``: a thrust law f = K_q·|ω₂|^α with an exponent α other than 2.

Its parameter is read by the propeller's thrust term (:mod:`.propeller`); off, α = 2.
"""

from __future__ import annotations

from aeropend_sim.components.base import POSITIVE, Diagnosis, Effect, FitBounds, Param, Search

EXPONENT = Param("thrust.exponent", "1", "thrust-law exponent α (used when effects.thrust_exponent)",
                 sign="positive", absent=2.0, fit=FitBounds(0.5, 4.0, True), symbol="α")

def _exponent(rig):
    return rig.thrust.exponent if rig.effects.thrust_exponent else 2.0


def coefficient_range(ctx):
    """K_q of f = K_q·|ω₂|^α over every exponent in [1, 3.5] (0.2 × the least … 5 × the largest level
    that keeps the nominal thrust at ω_ref); start: thrust kept at ω_ref for α = 2.2."""
    k, a0 = ctx.rig.thrust.K_q, _exponent(ctx.rig)
    w = max(ctx.omega_ref, 1e-9)
    span = [k * w ** (a0 - a) for a in (1.0, 3.5)]
    return 0.2 * min(span), 5.0 * max(span), k, k * w ** (a0 - 2.2)


def exponent_range(ctx):
    """α from 1 to 3.5; absent at the rig's α (2 when off)."""
    return 1.0, 3.5, _exponent(ctx.rig), 2.2


def apply(rig, v):
    """The rig with thrust law f = K_q·|ω₂|^α."""
    return rig.with_params("thrust", K_q=v["K_q"], exponent=v["exponent"]).with_effects(thrust_exponent=True)


EFFECT = Effect(
    name="thrust_exponent",
    part="thrust",
    label="thrust exponent",
    description="f = K_q |ω₂|^α sign(ω₂)",
    order=51,
    params=(EXPONENT,),
    diagnoses=(Diagnosis("thrust_law", "aerodynamic",
                         "thrust law f = K_q·|ω₂|^α with its level and exponent both wrong (α ≠ 2)",
                         ("K_q", "exponent"), ("theta",), sindy_terms={"theta_dot": ("L/J·Δf(K_q, α)",)},
                         confusable_with=("thrust_coefficient", "propeller_drag", "gravity"),
                         truth={"exponent": ((1.7, 1.85), (2.15, 2.3))},
                         exclusive_with=("thrust_coefficient",),
                         nests=("thrust_coefficient",), power_law=("K_q", "exponent", 2.0), order=130,
                         apply=apply,
                         search=(Search("K_q", "N*s^a/rad^a", POSITIVE, "thrust.K_q",
                                        "thrust-law coefficient K_q (units N·(s/rad)^α)", coefficient_range,
                                        "over every level the exponents allow", log=True),
                                 Search("exponent", "1", (0.5, 4.0), "thrust.exponent",
                                        "thrust-law exponent α",
                                        exponent_range, "1 … 3.5"))),),
)
