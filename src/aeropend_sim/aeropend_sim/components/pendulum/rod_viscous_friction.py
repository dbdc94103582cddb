"""Effect ``rod_viscous_friction``: viscous friction of the rod, θ̈ −= (c/J)·θ̇.

Split from the pre-issue-35 ``viscous_friction`` switch, which also turned on the rotor's B_m
(``rotor_viscous_friction``); that switch is still read as both.
"""

from __future__ import annotations

import math

from aeropend_sim.components.base import POSITIVE, Diagnosis, Effect, FitBounds, Param, Search, Term

C_OVER_J = Param("pendulum.c_over_J", "1/s", "viscous friction c/J", sign="nonneg", absent=0.0,
                 fit=FitBounds(1e-4, 1e3, True), relative_truth=((0.35, 0.6), (1.7, 2.5)), symbol="c/J",
                 typical=1.0,
            measure='a free decay (its exponential envelope)')


def accel(xp, theta_dot, c_over_J):
    """−(c/J)·θ̇ [rad/s²]."""
    return -c_over_J * theta_dot


def d_accel(xp, theta_dot, c_over_J):
    """∂/∂θ̇ [1/s]."""
    return -c_over_J + 0.0 * theta_dot


#: Session-to-session drift of c/J (σ of its log change, 25 %): viscous bearing drag grows with
#: the lubricant's viscosity as (ν·n)^(2/3) (Palmgren/SKF), about −5 %/K at room temperature, and a
#: cold bearing, grease redistributed after standstill, run-in or dust move it more
#: (docs/gap.md, "Drift prior").
DRIFT_SIGMA = 0.25


def search_range(ctx):
    """0.05 … 20 × a nominal c/J (and up to twice critical damping); without one, 1e-3 … 2 × critical."""
    p, on = ctx.rig.pendulum, ctx.rig.effects.rod_viscous_friction
    crit = 2.0 * math.sqrt(max(p.mgd_over_J, 1e-9))
    if on and p.c_over_J > 0.0:
        c = p.c_over_J
        return min(0.05 * c, 1e-3 * crit), max(20.0 * c, 2.0 * crit), c, 1.5 * c
    return 1e-3 * crit, 2.0 * crit, 0.0, 0.1 * crit


def apply(rig, v):
    """The rig with rod viscous friction c/J."""
    return rig.with_params("pendulum", c_over_J=v["c_over_J"]).with_effects(rod_viscous_friction=True)


EFFECT = Effect(
    name="rod_viscous_friction",
    part="pendulum",
    label="rod viscous friction",
    description="−(c/J) θ̇ on the rod",
    order=61,
    params=(C_OVER_J,),
    terms=(Term("rod", 10, accel, "−(c/J)·θ̇", partials={"theta_dot": d_accel}),),
    legacy_switch="viscous_friction",
    legacy_default=True,
    diagnoses=(Diagnosis("viscous_friction", "pendulum",
                         "viscous friction of the rod wrong or omitted: θ̈ = … − (c/J)·θ̇", ("c_over_J",),
                         ("theta",),
                         sindy_terms={"theta_dot": ("−θ̇",)}, confusable_with=("coulomb_friction",), order=140,
                         drift_sigma=DRIFT_SIGMA,
                         apply=apply,
                         search=(Search("c_over_J", "1/s", POSITIVE, "pendulum.c_over_J",
                                        "viscous friction over inertia c/J", search_range,
                                        "0.05 … 20 × nominal (or up to twice critical damping)",
                                        log=True),)),),
)
