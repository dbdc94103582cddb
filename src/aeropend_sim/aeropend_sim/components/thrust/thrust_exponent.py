"""Effect ``thrust_exponent``: a thrust law f = K_q·|ω₂|^α with an exponent α other than 2.

Its parameter is read by the propeller's thrust term (:mod:`.propeller`); off, α = 2.
"""

from __future__ import annotations

from aeropend_sim.components.base import Diagnosis, Effect, FitBounds, Param

EXPONENT = Param("thrust.exponent", "1", "thrust-law exponent α (used when effects.thrust_exponent)",
                 sign="positive", absent=2.0, fit=FitBounds(0.5, 4.0, True), symbol="α")

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
                         nests=("thrust_coefficient",)),),
)
