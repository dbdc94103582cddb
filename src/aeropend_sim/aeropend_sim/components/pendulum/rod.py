"""Component ``rod``: the pendulum per unit inertia, θ̈ = −(mgd/J)·sin θ + (L/J)·f + Σ (thesis Eqs. 3.1-3.2).

A rig file gives ``mgd_over_J`` and ``L_over_J``, or the geometry they come from (:data:`GEOMETRY`:
mass m, centre-of-mass distance d, thrust arm L and optionally the inertia J about the pivot, by
default a point mass J = m·d²): mgd/J = m·g·d/J, L/J = L/J.
"""

from __future__ import annotations

from collections.abc import Mapping

from aeropend_sim.components.base import (
    POSITIVE,
    Component,
    Diagnosis,
    FitBounds,
    Param,
    Search,
    Term,
    scaled,
)

#: Standard gravity [m/s²].
G = 9.80665

MGD = Param("pendulum.mgd_over_J", "1/s^2", "gravity term m·g·d/J", sign="nonneg",
            fit=FitBounds(1e-2, 1e4, True), relative_truth=((0.8, 0.9), (1.12, 1.25)), symbol="mgd/J",
            typical=20.0,
            measure='a free decay (its swing frequency)')
LJ = Param("pendulum.L_over_J", "1/(kg*m)", "thrust lever arm over inertia L/J", sign="positive",
           fit=FitBounds(None, None, True), symbol="L/J", typical=20.0,
           measure='the geometry: pendulum.mass, com_distance and thrust_arm (the inertia from a free '
                   'decay)')

#: Geometry a rig file may give instead of mgd/J and L/J.
GEOMETRY = (
    Param("pendulum.mass", "kg", "mass of the moving part (rod, motor, propeller)", sign="positive",
          symbol="m"),
    Param("pendulum.com_distance", "m", "pivot to centre of mass d", sign="positive", symbol="d"),
    Param("pendulum.thrust_arm", "m", "pivot to the propeller's thrust line L", sign="positive", symbol="L"),
    Param("pendulum.inertia", "kg*m^2", "inertia J about the pivot (default: point mass m·d²)",
          sign="positive", absent=0.0, symbol="J"),
)


def derive(given: Mapping[str, float]) -> dict[str, tuple[float, str]]:
    """mgd/J and L/J of the geometry ``{key: value}`` (mass, com_distance, thrust_arm, inertia?).

    Raises
    ------
    KeyError
        Naming a missing geometry key (the rig loader turns it into its error).
    """
    for key in ("pendulum.mass", "pendulum.com_distance", "pendulum.thrust_arm"):
        if key not in given:
            raise KeyError(key)
    m, d, arm = given["pendulum.mass"], given["pendulum.com_distance"], given["pendulum.thrust_arm"]
    if given.get("pendulum.inertia", 0.0) > 0.0:
        j, j_how = given["pendulum.inertia"], "pendulum.inertia"
    else:
        j, j_how = m * d * d, "a point mass J = m·d² (no pendulum.inertia in the rig file)"
    return {
        "pendulum.mgd_over_J": (m * G * d / j, f"m·g·d/J from pendulum.mass, com_distance and {j_how}"),
        "pendulum.L_over_J": (arm / j, f"L/J from pendulum.thrust_arm and {j_how}"),
    }


def gravity(xp, theta, mgd_over_J):
    """−(mgd/J)·sin θ [rad/s²]."""
    return -mgd_over_J * xp.sin(theta)


def d_gravity(xp, theta, mgd_over_J):
    """∂/∂θ [1/s²]."""
    return -mgd_over_J * xp.cos(theta)


def thrust_torque(xp, thrust, L_over_J):
    """(L/J)·f [rad/s²]."""
    return L_over_J * thrust


def d_thrust_torque(xp, thrust, L_over_J):
    """∂/∂f [1/(kg·m)]."""
    return L_over_J + 0.0 * thrust


#: Session-to-session drift of mgd/J (σ of its log change, 10 %): mass and geometry are constant
#: on an untouched rig; they change when the rod is re-assembled, a counterweight, cable or sensor
#: mount moves, or the motor/propeller at the rod's end is exchanged (docs/gap.md, "Drift prior").
DRIFT_SIGMA = 0.10


def gravity_range(ctx):
    """0.2 … 5 × nominal mgd/J."""
    return scaled(ctx.rig.pendulum.mgd_over_J, 0.2, 5.0, 1.2)


def apply_gravity(rig, v):
    """The rig with gravity term mgd/J."""
    return rig.with_params("pendulum", mgd_over_J=v["mgd_over_J"])


def apply_inertia(rig, v):
    """The rig with the rod inertia J scaled by s = J/J_nominal: every per-inertia parameter of
    the rod's torques (mgd/J, c/J, L/J, T_f/J) divided by s."""
    s = v["J_scale"]
    p = rig.pendulum
    return rig.with_params("pendulum", mgd_over_J=p.mgd_over_J / s, c_over_J=p.c_over_J / s,
                           L_over_J=p.L_over_J / s, coulomb_over_J=p.coulomb_over_J / s)


COMPONENT = Component(
    name="rod",
    part="pendulum",
    label="pendulum rod",
    description="θ̇ = Ω; Ω̇ = −(mgd/J) sin θ + (L/J) f + Σ (Eqs. 3.1–3.2)",
    order=60,
    params=(MGD, LJ),
    terms=(Term("rod", 0, gravity, "−(mgd/J)·sin θ", partials={"theta": d_gravity}),
           Term("rod", 20, thrust_torque, "(L/J)·f", partials={"thrust": d_thrust_torque})),
    geometry=GEOMETRY,
    derive=derive,
    diagnoses=(
        Diagnosis("gravity", "pendulum", "gravity torque (mass · lever) wrong: θ̈ = −(mgd/J)·sin θ + …",
                  ("mgd_over_J",), ("theta",), sindy_terms={"theta_dot": ("−sin θ",)},
                  confusable_with=("thrust_coefficient", "sensor_scale", "inertia"), order=170,
                  drift_sigma=DRIFT_SIGMA,
                  apply=apply_gravity,
                  search=(Search("mgd_over_J", "1/s^2", POSITIVE, "pendulum.mgd_over_J",
                                 "gravity torque over inertia mgd/J", gravity_range, "0.2 … 5 × nominal",
                                 log=True),)),
        Diagnosis("inertia", "pendulum",
                  "rod inertia J wrong: every /J term (mgd/J, c/J, L/J, T_f/J) divided by J/J_nominal",
                  ("J_scale",), ("theta",), sindy_terms={"theta_dot": ("θ̈_model",)},
                  confusable_with=("gravity", "thrust_coefficient", "sensor_scale"),
                  truth={"J_scale": ((0.7, 0.85), (1.2, 1.45))}, order=180, apply=apply_inertia,
                  search=(Search("J_scale", "1", POSITIVE, "pendulum.L_over_J", "J true / J nominal",
                                 lambda ctx: (0.2, 5.0, 1.0,
                                              1.2), "0.2 … 5 (the rig stores only per-inertia ratios)",
                                 log=True),)),
    ),
)

