"""Array namespaces the plant's physics is written against (``xp`` argument of every term).

A term function is written once, e.g. ``def torque(xp, omega, B_m): return -B_m * omega``, and
evaluated with

* :data:`MATH`: Python floats through :mod:`math` (the fast path of the scalar ODE right-hand
  side that LSODA calls; no NumPy scalar overhead);
* :data:`NUMPY`: NumPy arrays of any shape (vectorised equation-error terms, simulated channels).

A compiled backend (issue 37: numba, JAX or CasADi) supplies one more namespace with the same
operations. Only these operations are allowed in a term, so each namespace stays small:

=========  ====================================================================
name       meaning
=========  ====================================================================
sin, cos   trigonometric functions
tanh, exp  hyperbolic tangent, exponential
sqrt       square root (argument ≥ 0: guard it with ``maximum``)
abs        absolute value
sign       −1, 0 or 1
maximum    element-wise larger of two values
minimum    element-wise smaller of two values
where      ``where(c, a, b)``: a where c holds, else b (both are evaluated)
power      ``power(a, b)`` = a**b (a ≥ 0); a·a when b is exactly 2 (below)
=========  ====================================================================

**Squares.** ``power(a, 2.0)`` is the correctly rounded square a·a in every namespace, not libm's
``pow``: glibc's ``pow`` is faithful, not correctly rounded, and differs from a·a by one ulp for
about 1 base in 1,200 (NumPy's ``power`` with a scalar exponent of 2 already squares, so the
namespaces disagreed there), and it costs about a third of a compiled RK4 sub-step of a rig whose
thrust exponent α is 2 (docs/findings/simulator_backends.md, "Squares, and the Python around the replays").
"""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np

#: The operations every namespace provides (checked by the tests).
OPERATIONS: tuple[str, ...] = ("sin", "cos", "tanh", "exp", "sqrt", "abs", "sign", "maximum", "minimum",
                               "where", "power")


def _sign(v: float) -> float:
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


def _where(cond: bool, a: float, b: float) -> float:
    return a if cond else b


def _power(a: float, b: float) -> float:
    return a * a if b == 2.0 else a**b


def _np_power(a: Any, b: Any) -> Any:
    if np.ndim(b) == 0:
        return np.multiply(a, a) if b == 2.0 else np.power(a, b)
    return np.where(np.equal(b, 2.0), np.multiply(a, a), np.power(a, b))


#: Scalar namespace (Python floats, :mod:`math`).
MATH = SimpleNamespace(
    name="math", sin=math.sin, cos=math.cos, tanh=math.tanh, exp=math.exp, sqrt=math.sqrt, abs=abs,
    sign=_sign, maximum=max, minimum=min, where=_where, power=_power,
)

#: Array namespace (NumPy, any shape, broadcasting).
NUMPY = SimpleNamespace(
    name="numpy", sin=np.sin, cos=np.cos, tanh=np.tanh, exp=np.exp, sqrt=np.sqrt, abs=np.abs,
    sign=np.sign, maximum=np.maximum, minimum=np.minimum, where=np.where, power=_np_power,
)
