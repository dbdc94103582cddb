"""Component ``propeller``: thrust f = K_q·|ω₂|^α·sign(ω₂) (thesis Eq. 3.3 with α = 2).

The exponent α is the ``thrust_exponent`` effect's parameter (2 when that effect is off).
"""

from __future__ import annotations

from aeropend_sim.components.base import POSITIVE, Component, Diagnosis, Param, Search, Term, scaled

K_Q = Param("thrust.K_q", "N*s^2/rad^2", "thrust coefficient K_q (for α = 2)", sign="nonneg",
            relative_truth=((0.75, 0.88), (1.12, 1.25)), symbol="K_q", typical=1e-05,
            measure='thrust vs command from a load cell (a thrust table: rig fit RIG ... thrust.csv)')


def thrust(xp, omega_prop, K_q, exponent):
    """f = K_q·|ω₂|^α·sign(ω₂) [N].

    Written with a safe base at rest (ω₂ = 0: f = 0 without evaluating 0^α) so that automatic
    differentiation gives finite derivatives there: ∂(|ω₂|^α)/∂α = |ω₂|^α·ln|ω₂| is 0·(−∞) = NaN at
    a zero base, and forward-mode AD multiplies it by a zero seed (NaN) even when α is not
    differentiated. The values are those of K_q·sign(ω₂)·|ω₂|^α, bit for bit.
    """
    zero = omega_prop == 0.0
    base = xp.abs(omega_prop) + zero  # 1 at rest
    return xp.where(zero, 0.0 * K_q, K_q * xp.sign(omega_prop) * xp.power(base, exponent))


def d_thrust(xp, omega_prop, K_q, exponent):
    """∂f/∂ω₂ [N·s/rad] (at ω₂ = 0: K_q for α = 1, else 0)."""
    zero = omega_prop == 0.0
    base = xp.abs(omega_prop) + zero  # a safe base at ω₂ = 0
    return xp.where(zero, (exponent == 1.0) * K_q, K_q * exponent * xp.power(base, exponent - 1.0))


def speed_of_thrust(xp, y, K_q, exponent):
    """ω₂ ≥ 0 giving a thrust y ≥ 0 [rad/s]."""
    return xp.where(y > 0.0, xp.power(xp.maximum(y, 0.0) / K_q, 1.0 / exponent), 0.0)


#: Session-to-session drift of K_q (σ of its log change, 15 %): thrust ∝ air density ρ = p/(R·T)
#: (weather ±2–3 %, lab temperature 18–28 °C ±1.7 %) times the propeller's thrust coefficient,
#: which changes when a moulded propeller is re-mounted, chipped or replaced (pitch and finish
#: tolerances of a few to ~10 %); docs/gap.md, "Drift prior".
DRIFT_SIGMA = 0.15


def search_range(ctx):
    """0.2 … 5 × nominal K_q."""
    return scaled(ctx.rig.thrust.K_q, 0.2, 5.0, 1.2)


def apply(rig, v):
    """The rig with thrust coefficient K_q."""
    return rig.with_params("thrust", K_q=v["K_q"])


COMPONENT = Component(
    name="propeller",
    part="thrust",
    label="propeller thrust",
    description="f = K_q |ω₂|^α sign(ω₂), α = 2 unless `thrust_exponent` (Eq. 3.3)",
    order=50,
    params=(K_Q,),
    terms=(Term("thrust", 10, thrust, "f = K_q·|ω₂|^α·sign(ω₂)", partials={"omega_prop": d_thrust},
                inverse=speed_of_thrust),),
    diagnoses=(Diagnosis("thrust_coefficient", "aerodynamic",
                         "thrust coefficient K_q wrong (a static load-cell fit, thesis Eq. 4.4): f = K_q·ω₂²",
                         ("K_q",), ("theta",), sindy_terms={"theta_dot": ("ΔK_q·(L/J)·ω₂²",)},
                         confusable_with=("thrust_law", "gravity", "sensor_scale", "inertia"),
                         exclusive_with=("thrust_law",), order=120, apply=apply, drift_sigma=DRIFT_SIGMA,
                         search=(Search("K_q", "N*s^2/rad^2", POSITIVE, "thrust.K_q",
                                        "thrust coefficient K_q",
                                        search_range, "0.2 … 5 × nominal", log=True),)),),
)
