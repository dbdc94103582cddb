"""Effect ``end_stops``: mechanical end stops, a one-sided spring-damper contact beyond θ_min/θ_max.

Beyond θ_max: θ̈ += min(0, −k_s·(θ − θ_max) − c_s·θ̇) (mirror at θ_min): a contact that pushes,
never pulls. An absent limit (±∞) is no stop on that side.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from aeropend_sim.components.base import Diagnosis, Effect, Param, Search, Term

THETA_MIN = Param("pendulum.theta_min", "rad", "lower end stop", absent=-math.inf, symbol="θ_min")
THETA_MAX = Param("pendulum.theta_max", "rad", "upper end stop", absent=math.inf, symbol="θ_max")
K_S = Param("pendulum.stop_stiffness", "1/s^2", "end-stop contact stiffness over inertia", sign="nonneg",
            absent=0.0, symbol="k_s")
C_S = Param("pendulum.stop_damping", "1/s", "end-stop contact damping over inertia", sign="nonneg",
            absent=0.0, symbol="c_s")


def accel(xp, theta, theta_dot, theta_min, theta_max, stop_stiffness, stop_damping):
    """Contact acceleration [rad/s²]: pushes back beyond a stop, never pulls."""
    upper = xp.minimum(0.0, -stop_stiffness * (theta - theta_max) - stop_damping * theta_dot)
    lower = xp.maximum(0.0, -stop_stiffness * (theta - theta_min) - stop_damping * theta_dot)
    return xp.where(theta > theta_max, upper, xp.where(theta < theta_min, lower, 0.0))


def _pushing(xp, theta, theta_dot, theta_min, theta_max, stop_stiffness, stop_damping):
    up = (theta > theta_max) * (-stop_stiffness * (theta - theta_max) - stop_damping * theta_dot < 0.0)
    low = (theta < theta_min) * (-stop_stiffness * (theta - theta_min) - stop_damping * theta_dot > 0.0)
    return up + low


def d_accel_d_theta(xp, theta, theta_dot, theta_min, theta_max, stop_stiffness, stop_damping):
    """∂/∂θ [1/s²]: −k_s while the contact pushes (the active branch at its onset)."""
    pushing = _pushing(xp, theta, theta_dot, theta_min, theta_max, stop_stiffness, stop_damping)
    return -stop_stiffness * pushing


def d_accel_d_theta_dot(xp, theta, theta_dot, theta_min, theta_max, stop_stiffness, stop_damping):
    """∂/∂θ̇ [1/s]: −c_s while the contact pushes."""
    return -stop_damping * _pushing(xp, theta, theta_dot, theta_min, theta_max, stop_stiffness, stop_damping)


def _ordered(v: Mapping[str, float]) -> str | None:
    if not v["pendulum.theta_min"] < v["pendulum.theta_max"]:
        return (f"pendulum.theta_min = {v['pendulum.theta_min']} must be < theta_max = "
                f"{v['pendulum.theta_max']}")
    return None


#: Contact stiffness of an end stop added to a rig without one, in units of mgd/J [1/rad]
#: (penetration 5 mrad under the full gravity torque).
STOP_STIFFNESS_FACTOR = 200.0


def search_range(ctx):
    """0.05 … π/2; probe just below the largest recorded angle."""
    p = ctx.rig.pendulum
    off = p.theta_max if ctx.rig.effects.end_stops else math.pi / 2
    return 0.05, math.pi / 2, off, min(ctx.theta_hi - 0.02, off)


def apply(rig, v):
    """The rig with an upper stop at θ_max; a rig without a contact model gets a stiff, critically
    damped contact whose penetration under the largest gravity torque is about
    1/:data:`STOP_STIFFNESS_FACTOR` rad."""
    new = rig.with_params("pendulum", theta_max=v["theta_max"]).with_effects(end_stops=True)
    p = rig.pendulum
    if p.stop_stiffness <= 0.0:
        k = STOP_STIFFNESS_FACTOR * p.mgd_over_J
        new = new.with_params("pendulum", stop_stiffness=k, stop_damping=2.0 * math.sqrt(k))
    return new


EFFECT = Effect(
    name="end_stops",
    part="pendulum",
    label="end stops",
    description="beyond θ_max: Ω̇ += min(0, −k_s (θ − θ_max) − c_s Ω) (mirror at θ_min): a contact that "
                "pushes, never pulls",
    order=63,
    params=(THETA_MIN, THETA_MAX, K_S, C_S),
    terms=(Term("rod", 40, accel, "contact(θ − θ_max), contact(θ − θ_min)",
                partials={"theta": d_accel_d_theta, "theta_dot": d_accel_d_theta_dot}, contact=True),),
    check=_ordered,
    diagnoses=(Diagnosis("end_stops", "pendulum",
                         "mechanical end stop at θ_max: one-sided spring-damper contact beyond it",
                         ("theta_max",), ("theta",), sindy_terms={"theta_dot": ("contact(θ − θ_max)",)},
                         truth={"theta_max": ((0.6, 0.8),)}, order=190, apply=apply,
                         search=(Search("theta_max", "rad", (0.0, math.pi), "pendulum.theta_max",
                                        "upper stop angle",
                                        search_range, "0.05 … π/2 (a stiff contact, 200·mgd/J, when the rig "
                                        "has "
                                        "none)"),)),),
)
