"""Effect ``rod_coulomb_friction``: dry friction of the rod with an optional Stribeck part.

    θ̈ −= (T_f/J + ((T_s − T_f)/J)·exp(−(θ̇/v_s)²))·sgn(θ̇)

The static friction T_s exceeds the sliding (Coulomb) friction T_f and falls off over the
Stribeck velocity v_s (``stribeck_over_J`` = 0: plain Coulomb friction). sgn(θ̇) is regularised
as tanh(θ̇/v_ε) (v_ε = ``friction_velocity``) so the ODE stays Lipschitz: the rod then creeps at
about v_ε·atanh(load/T_f) under loads below the breakaway torque instead of sticking exactly.
Split from the pre-issue-35 ``coulomb_friction`` switch, which also turned on the rotor's brush
friction; that switch is still read as both.

The gap diagnosis can fit v_ε with the friction level (``coulomb_friction``,
``stribeck_friction``): how fast the rod creeps under a load below breakaway, the width of the
sliding onset (a static stand-in for the presliding creep that Dahl- and LuGre-type friction
models describe dynamically), is a property of the rod's bearing, not a numerical constant. It is
fitted only where the validation recordings say the free width predicts better
(``aeropend_ident.gap.which.candidates._free_settings_if_validated``), over :data:`WIDTH_RANGE`. Held at the
rig file's 10 mrad/s where a rod creeps at 2 mrad/s, the model creeps 5× too fast through every
hold, and the fitted T_f/J grows to slow it by an amount set by how long the recording holds the
rod still: a step test and an APRBS of the same unchanged rod gave T_f/J 26 % apart (z 6 over the
within-session spread), an alarm of drift that no plant change caused (docs/findings/gap.md).
"""

from __future__ import annotations

import math

from aeropend_sim.components.base import Diagnosis, Effect, FitBounds, Param, Search, Term

T_F = Param("pendulum.coulomb_over_J", "rad/s^2", "Coulomb friction torque over inertia T_f/J", sign="nonneg",
            absent=0.0, fit=FitBounds(0.0, 1e3, False, 1.0), symbol="T_f/J", typical=0.5,
            measure='a free decay (its linear envelope)')
T_S = Param("pendulum.stribeck_over_J", "rad/s^2",
            "Stribeck excess of the static over the Coulomb friction (T_s − T_f)/J (0 = none)", sign="nonneg",
            absent=0.0, symbol="(T_s − T_f)/J")
V_S = Param("pendulum.stribeck_velocity", "rad/s",
            "Stribeck velocity v_s: the excess decays as exp(−(θ̇/v_s)²)", sign="positive", absent=0.1,
            setting=True, symbol="v_s")
V_EPS = Param("pendulum.friction_velocity", "rad/s", "tanh regularisation width of sign(θ̇)", sign="positive",
              absent=0.01, setting=True, symbol="v_ε")


def accel(xp, theta_dot, coulomb_over_J, stribeck_over_J, stribeck_velocity, friction_velocity):
    """−(T_f/J + ((T_s − T_f)/J)·exp(−(θ̇/v_s)²))·tanh(θ̇/v_ε) [rad/s²]."""
    level = coulomb_over_J + stribeck_over_J * xp.exp(-((theta_dot / stribeck_velocity) ** 2))
    return -(level * xp.tanh(theta_dot / friction_velocity))


def d_accel(xp, theta_dot, coulomb_over_J, stribeck_over_J, stribeck_velocity, friction_velocity):
    """∂/∂θ̇ [1/s] (written with 1 − tanh², which cannot overflow)."""
    th = xp.tanh(theta_dot / friction_velocity)
    sech2 = 1.0 - th * th
    ex = xp.exp(-((theta_dot / stribeck_velocity) ** 2))
    slope = (coulomb_over_J / friction_velocity * sech2
             + stribeck_over_J * ex * (sech2 / friction_velocity
                                       - 2.0 * theta_dot / stribeck_velocity**2 * th))
    return -slope


def coulomb_range(ctx):
    """Nominal … nominal + 0.5·mgd/J."""
    p = ctx.rig.pendulum
    off = p.coulomb_over_J if ctx.rig.effects.rod_coulomb_friction else 0.0
    return 0.0, off + 0.5 * p.mgd_over_J, off, off + 0.01 * p.mgd_over_J


def stribeck_range(ctx):
    """Nominal … nominal + 0.5·mgd/J."""
    p = ctx.rig.pendulum
    off = p.stribeck_over_J if ctx.rig.effects.rod_coulomb_friction else 0.0
    return 0.0, off + 0.5 * p.mgd_over_J, off, off + 0.01 * p.mgd_over_J


def stribeck_velocity_range(ctx):
    """From 3× the width v_ε of the model's smooth sign to max(2, 30·v_ε) rad/s: a narrower
    "Stribeck" bump would only reshape the regularisation (it would stand in for a sharper sign,
    not for stiction)."""
    lo = 3.0 * ctx.rig.pendulum.friction_velocity
    return lo, max(2.0, 10.0 * lo), max(2.0, 10.0 * lo), max(0.1, 3.0 * lo)


#: Search range [rad/s] of the sign's width v_ε (sliding onset): from 0.5 mrad/s, a rod that
#: creeps less than an encoder count (1.5 mrad at 12 bits) over a 3 s hold, which a replay still
#: integrates with a few RK4 sub-steps per sample at T_f/J of a few rad/s², to 50 mrad/s
#: (3 °/s), where the "onset" spans the slow motions of a swing and the law is a viscous one.
WIDTH_RANGE = (5e-4, 5e-2)


def width_range(ctx):
    """:data:`WIDTH_RANGE`; off at the rig's v_ε, probe a third of it (a sharper onset than the
    rig file's regularisation, as a rod that sticks has; three times it where that leaves the range)."""
    v = ctx.rig.pendulum.friction_velocity
    probe = v / 3.0 if v / 3.0 >= WIDTH_RANGE[0] else min(3.0 * v, WIDTH_RANGE[1])
    return WIDTH_RANGE[0], WIDTH_RANGE[1], v, probe


def apply_coulomb(rig, v):
    """The rig with rod Coulomb friction T_f/J (and the sign's width v_ε where given)."""
    new = rig.with_params("pendulum", coulomb_over_J=v["coulomb_over_J"])
    if "friction_velocity" in v:
        new = new.with_params("pendulum", friction_velocity=v["friction_velocity"])
    return new.with_effects(rod_coulomb_friction=True)


def apply_stribeck(rig, v):
    """The rig with rod dry friction T_f/J and a Stribeck part ((T_s − T_f)/J, v_s)."""
    new = apply_coulomb(rig, v)
    return new.with_params("pendulum", stribeck_over_J=v["stribeck_over_J"],
                           stribeck_velocity=v["stribeck_velocity"])


_COULOMB = Search("coulomb_over_J", "rad/s^2", (0.0, math.inf), "pendulum.coulomb_over_J",
                  "friction torque over inertia T_f/J", coulomb_range, "nominal … nominal + 0.5·mgd/J")
_WIDTH = Search("friction_velocity", "rad/s", (1e-6, 10.0), "pendulum.friction_velocity",
                "width v_ε of the sliding onset tanh(θ̇/v_ε)", width_range,
                f"{WIDTH_RANGE[0]:g} … {WIDTH_RANGE[1]:g} rad/s", log=True, held=True)

EFFECT = Effect(
    name="rod_coulomb_friction",
    part="pendulum",
    label="rod dry friction",
    description="−(T_f/J + ((T_s − T_f)/J)·exp(−(θ̇/v_s)²)) sgn(θ̇) on the rod (the Stribeck part is 0 "
                "unless set)",
    order=62,
    params=(T_F, T_S, V_S, V_EPS),
    terms=(Term("rod", 30, accel, "−(T_f/J + ((T_s − T_f)/J)·exp(−(θ̇/v_s)²))·tanh(θ̇/v_ε)",
                partials={"theta_dot": d_accel}, regularised_sign=True),),
    legacy_switch="coulomb_friction",
    diagnoses=(
        Diagnosis("coulomb_friction", "pendulum",
                  "Coulomb friction on the rod: θ̈ −= (T_f/J)·sgn(θ̇) (tanh-regularised)",
                  ("coulomb_over_J", "friction_velocity"), ("theta",),
                  sindy_terms={"theta_dot": ("−tanh(θ̇/v_ε)",)},
                  confusable_with=("viscous_friction",), truth={"coulomb_over_J": ((0.6, 1.5),)},
                  exclusive_with=("stribeck_friction",), order=150, apply=apply_coulomb,
                  search=(_COULOMB, _WIDTH)),
        Diagnosis("stribeck_friction", "pendulum",
                  "dry friction of the rod with a Stribeck part: "
                  "θ̈ −= (T_f/J + ((T_s − T_f)/J)·exp(−(θ̇/v_s)²))·"
                  "sgn(θ̇): the friction at rest (stiction) exceeds the sliding friction and falls off over "
                  "the Stribeck velocity v_s, so the damping depends on the swing's amplitude",
                  ("coulomb_over_J", "stribeck_over_J", "stribeck_velocity", "friction_velocity"), ("theta",),
                  sindy_terms={"theta_dot": ("−tanh(θ̇/v_ε)", "−exp(−(θ̇/v_s)²)·tanh(θ̇/v_ε)")},
                  confusable_with=("coulomb_friction", "viscous_friction"),
                  truth={"coulomb_over_J": ((0.6, 1.5),), "stribeck_over_J": ((1.5, 3.0),),
                         "stribeck_velocity": ((0.1, 0.3),)},
                  screened=False, exclusive_with=("coulomb_friction",), nests=("coulomb_friction",),
                  refines=("coulomb_friction",), order=160, apply=apply_stribeck,
                  search=(Search("coulomb_over_J", "rad/s^2", (0.0, math.inf), "pendulum.coulomb_over_J",
                                 "sliding (Coulomb) friction torque over inertia T_f/J", coulomb_range,
                                 "as coulomb_friction"),
                          Search("stribeck_over_J", "rad/s^2", (0.0, math.inf), "pendulum.stribeck_over_J",
                                 "excess of the static over the sliding friction (T_s − T_f)/J",
                                 stribeck_range,
                                 "as coulomb_friction"),
                          Search("stribeck_velocity", "rad/s", (1e-4, 100.0), "pendulum.stribeck_velocity",
                                 "Stribeck velocity v_s", stribeck_velocity_range,
                                 "3·v_ε … max(2, 30·v_ε) rad/s", log=True),
                          _WIDTH)),
    ),
)
