"""Effect ``rod_viscous_friction``: viscous friction of the rod, θ̈ −= (c/J)·θ̇.

Split from the pre-issue-35 ``viscous_friction`` switch, which also turned on the rotor's B_m
(``rotor_viscous_friction``); that switch is still read as both.
"""

from __future__ import annotations

from aeropend_sim.components.base import Diagnosis, Effect, FitBounds, Param, Term

C_OVER_J = Param("pendulum.c_over_J", "1/s", "viscous friction c/J", sign="nonneg", absent=0.0,
                 fit=FitBounds(1e-4, 1e3, True), relative_truth=((0.35, 0.6), (1.7, 2.5)), symbol="c/J")


def accel(xp, theta_dot, c_over_J):
    """−(c/J)·θ̇ [rad/s²]."""
    return -c_over_J * theta_dot


def d_accel(xp, theta_dot, c_over_J):
    """∂/∂θ̇ [1/s]."""
    return -c_over_J + 0.0 * theta_dot


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
                         sindy_terms={"theta_dot": ("−θ̇",)}, confusable_with=("coulomb_friction",)),),
)
