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
sin, cos, tanh, exp, sqrt = math.sin, math.cos, math.tanh, math.exp, math.sqrt
abs = abs  # the builtin, exported under the namespace's name


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
