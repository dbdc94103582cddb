"""Study prototype (issue 37): CasADi backend.

Composition: the generated rhs of :func:`components.build` is called once with symbolic SX
arguments and ``xp =`` :class:`CasadiXP`, which builds the expression graph of the composed
contributions; the parameters are a symbolic input (values at call time). One RK4 sample is an SX
``Function``; ``mapaccum`` chains it over the N samples; ``map`` evaluates batches of parameter
sets; the Jacobian d θ / d p is CasADi's algorithmic differentiation of the same graph. The
functions run in CasADi's virtual machine, or are generated as C and compiled with the system's
gcc (``jit``).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from bench.backends import components as comp


class CasadiXP:
    """The operation set on CasADi symbols."""

    sin, cos, tanh, exp, sqrt, fabs, sign = ca.sin, ca.cos, ca.tanh, ca.exp, ca.sqrt, ca.fabs, ca.sign
    abs = staticmethod(ca.fabs)
    maximum, minimum = staticmethod(ca.fmax), staticmethod(ca.fmin)

    @staticmethod
    def power(a, b):
        # ∂(a^b)/∂b = a^b·log a is NaN at a = 0, and CasADi's AD multiplies it by a zero seed
        # (NaN·0 = NaN) even when b is a constant parameter: mask the base-0 point
        return ca.if_else(a == 0, 0, ca.power(a, b))

    @staticmethod
    def where(c, a, b):
        return ca.if_else(c, a, b)


def _opts(jit: bool) -> dict:
    if not jit:
        return {}
    return {"jit": True, "compiler": "shell",
            "jit_options": {"compiler": "gcc", "flags": ["-O2"], "verbose": False}}


def make_functions(built: comp.Built, k: int, frac: float, dt: float, n: int, jac_index: tuple[int, ...],
                   jit: bool = False, batch: int = 64):
    """CasADi functions for one replay of ``n`` samples.

    Returns a dict: ``replay(x0, U, p) -> X`` with U (2, n) = [u_a; u_b] and X (5, n) the state at
    each sample instant (before the sample's input acts); ``batch(x0, U, P) -> Θ`` (batch, n) over
    the columns of P; ``jac(x0, U, p, p[jac_index]) -> (n, len(jac_index))`` = d θ / d p[jac_index].
    """
    x = ca.SX.sym("x", 5)
    u = ca.SX.sym("u", 2)
    p = ca.SX.sym("p", built.p.size)

    def f(xx, uu):
        return ca.vertcat(*built.rhs(CasadiXP, xx, uu, p))

    def rk4(xx, uu, h, m):
        for _ in range(m):
            a = f(xx, uu)
            b = f(xx + 0.5 * h * a, uu)
            c = f(xx + 0.5 * h * b, uu)
            d = f(xx + h * c, uu)
            xx = xx + h / 6.0 * (a + 2.0 * (b + c) + d)
        return xx

    n_a, h_a, n_b, h_b = comp.pieces(frac, k, dt)
    y = rk4(x, u[0], h_a, n_a)
    y = rk4(y, u[1], h_b, n_b)
    opts = _opts(jit)
    step = ca.Function("step", [x, u, p], [y], opts)
    acc = step.mapaccum("acc", n)  # x_{j+1} for j = 0..n-1
    x0 = ca.MX.sym("x0", 5)
    U = ca.MX.sym("U", 2, n)
    P = ca.MX.sym("P", built.p.size)
    X_next = acc(x0, U, P)
    X = ca.horzcat(x0, X_next[:, : n - 1])
    replay = ca.Function("replay", [x0, U, P], [X], opts)
    theta = X[0, :].T
    q = ca.MX.sym("q", len(jac_index))
    P_q = ca.MX(P)
    for j, i in enumerate(jac_index):
        P_q[i] = q[j]
    theta_q = ca.substitute(theta, P, P_q)
    jac = ca.Function("dtheta_dp", [x0, U, P, q], [ca.jacobian(theta_q, q)], opts)
    theta_fn = ca.Function("theta", [x0, U, P], [theta])
    PB = ca.MX.sym("PB", built.p.size, batch)
    batch_fn = ca.Function("batch", [x0, U, PB], [theta_fn.map(batch)(x0, U, PB)], opts)
    return {"replay": replay, "batch": batch_fn, "jac": jac}


def versions() -> dict[str, str]:
    return {"casadi": ca.__version__}


def as_inputs(u_a: np.ndarray, u_b: np.ndarray) -> np.ndarray:
    return np.vstack((u_a, u_b))
