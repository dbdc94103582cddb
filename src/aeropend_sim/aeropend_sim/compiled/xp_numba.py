"""The ``xp`` namespace of :mod:`aeropend_sim.components.xp` for numba-compiled scalar code.

A module, not an object: numba types a module as a compile-time constant, so ``xp.tanh(v)`` in a
term function compiles to the libm call and the helpers below are inlined. Each operation gives
the same value as :data:`aeropend_sim.components.xp.MATH` (``maximum``/``minimum`` follow Python's
``max``/``min``: the first argument unless the second is strictly larger/smaller, so signed
zeros and NaN come out the same).
"""

import math

from numba import njit

name = "numba"
sin, cos, exp, sqrt = math.sin, math.cos, math.exp, math.sqrt
abs = abs  # the builtin, exported under the namespace's name

#: |v| from which ``tanh(v)`` is ±1.0 in double precision: libm returns exactly ±1.0 there (glibc's
#: ``tanh`` has this very cut-off; the true value is within 1.6e-19 of 1, far inside half an ulp).
TANH_SATURATED = 22.0


@njit(inline="always")
def tanh(v):
    """``math.tanh(v)``, without the libm call where it is ±1.0 (|v| ≥ :data:`TANH_SATURATED`).

    A Coulomb friction's tanh(ω/ω_ε) is saturated most of the time (ω_ε is small), and a call
    makes the compiled right-hand side save and reload its live values around it. Paired in one
    process (2026-11-28, 40 and 60 rounds): 0.94-0.96× the replay time of the rig with every
    effect on, θ identical bit for bit (docs/findings/simulator_backends.md). NaN goes to libm
    (NaN); ±inf gives ±1.0, as libm does.
    """
    return math.copysign(1.0, v) if abs(v) >= TANH_SATURATED else math.tanh(v)


@njit(inline="always")
def sign(v):
    """−1, 0 or 1 (0 for NaN, as ``MATH.sign``)."""
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


@njit(inline="always")
def where(c, a, b):
    """a where c holds, else b (both already evaluated)."""
    return a if c else b


@njit(inline="always")
def maximum(a, b):
    """Python's ``max(a, b)``."""
    return b if b > a else a


@njit(inline="always")
def minimum(a, b):
    """Python's ``min(a, b)``."""
    return b if b < a else a


@njit(inline="always")
def power(a, b):
    """a**b; the correctly rounded square a·a when b is exactly 2 (as ``MATH.power``: the
    :mod:`aeropend_sim.components.xp` doc, "Squares")."""
    return a * a if b == 2.0 else a**b
