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
power      ``power(a, b)`` = a**b (a ≥ 0)
=========  ====================================================================
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

#: The operations every namespace provides (checked by the tests).
OPERATIONS: tuple[str, ...] = ("sin", "cos", "tanh", "exp", "sqrt", "abs", "sign", "maximum", "minimum",
                               "where", "power")


def _sign(v: float) -> float:
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


def _where(cond: bool, a: float, b: float) -> float:
    return a if cond else b


#: Scalar namespace (Python floats, :mod:`math`).
MATH = SimpleNamespace(
    name="math", sin=math.sin, cos=math.cos, tanh=math.tanh, exp=math.exp, sqrt=math.sqrt, abs=abs,
    sign=_sign, maximum=max, minimum=min, where=_where, power=pow,
)

#: Array namespace (NumPy, any shape, broadcasting).
NUMPY = SimpleNamespace(
    name="numpy", sin=np.sin, cos=np.cos, tanh=np.tanh, exp=np.exp, sqrt=np.sqrt, abs=np.abs,
    sign=np.sign, maximum=np.maximum, minimum=np.minimum, where=np.where, power=np.power,
)
