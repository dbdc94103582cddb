"""Study prototype (issue 37): the ``xp`` operation set for numba (scalar float64), as a module so
numba types it as a compile-time constant and can cache functions that take it."""

import math

from numba import njit

sin, cos, tanh, exp, sqrt = math.sin, math.cos, math.tanh, math.exp, math.sqrt
abs = abs


@njit(inline="always", cache=True)
def sign(v):
    return 0.0 if v == 0.0 else math.copysign(1.0, v)


@njit(inline="always", cache=True)
def where(c, a, b):
    return a if c else b


@njit(inline="always", cache=True)
def maximum(a, b):
    return a if a > b else b


@njit(inline="always", cache=True)
def minimum(a, b):
    return a if a < b else b


@njit(inline="always", cache=True)
def power(a, b):
    return a**b
