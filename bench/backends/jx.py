"""Study prototype (issue 37): JAX backend.

Composition: the generated rhs of :func:`components.build` is called with ``xp = jax.numpy``
while JAX traces it, so the contributions are used exactly as written (no per-backend copy); the
parameters are a traced array, so a new parameter set reuses the compiled code, and ``jax.vmap``
(batches of parameter sets) and ``jax.jacfwd`` (d θ(t)/d p) transform the same replay.
"""

from __future__ import annotations

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
from jax import lax  # noqa: E402

from bench.backends import components as comp  # noqa: E402


def make_replay(built: comp.Built, k: int, frac: float, dt: float):
    """``replay(x0, u_a, u_b, p) -> states (N, 5)``: RK4 with sub-steps of at most dt/k on each
    piece of each sample (:func:`components.pieces`), ``lax.scan`` over samples."""
    rhs = built.rhs

    def f(x, u, p):
        return jnp.stack(rhs(jnp, x, u, p))

    def rk4(x, u, p, h, n):
        def body(_, x):
            a = f(x, u, p)
            b = f(x + 0.5 * h * a, u, p)
            c = f(x + 0.5 * h * b, u, p)
            d = f(x + h * c, u, p)
            return x + h / 6.0 * (a + 2.0 * (b + c) + d)

        return lax.fori_loop(0, n, body, x, unroll=True)

    n_a, h_a, n_b, h_b = comp.pieces(frac, k, dt)

    def replay(x0, u_a, u_b, p):
        def step(x, u):
            ua, ub = u
            y = rk4(x, ua, p, h_a, n_a) if n_a else x
            return rk4(y, ub, p, h_b, n_b), x

        _, xs = lax.scan(step, x0, (u_a, u_b))
        return xs

    return replay


def make_adaptive_replay(built: comp.Built, frac: float, dt: float, rtol: float = 1e-8, atol: float = 1e-10,
                         solver: str = "Tsit5", max_steps: int = 4096):
    """Jitted ``replay(x0, u_a, u_b, p) -> (states (N, 5), steps (N,))`` with diffrax's adaptive
    ``solver`` (PID step-size control at the given tolerances) restarted on each piece of each
    sample, like LSODA in :func:`aeropend_sim.simulation.simulate` but compiled; ``steps`` counts
    the accepted steps per sample."""
    import diffrax as dfx

    rhs = built.rhs
    term = dfx.ODETerm(lambda t, x, args: jnp.stack(rhs(jnp, x, args[0], args[1])))
    solv = getattr(dfx, solver)()
    ctrl = dfx.PIDController(rtol=rtol, atol=atol)

    def piece(x, u, p, length):
        sol = dfx.diffeqsolve(term, solv, 0.0, length, length, x, args=(u, p), stepsize_controller=ctrl,
                              saveat=dfx.SaveAt(t1=True), max_steps=max_steps)
        return sol.ys[-1], sol.stats["num_accepted_steps"]

    def replay(x0, u_a, u_b, p):
        def step(x, u):
            ua, ub = u
            n = 0
            y = x
            if frac > 0.0:
                y, n = piece(x, ua, p, frac * dt)
            y, m = piece(y, ub, p, (1.0 - frac) * dt)
            return y, (x, n + m)

        _, (xs, steps) = lax.scan(step, x0, (u_a, u_b))
        return xs, steps

    return jax.jit(replay)


def make_jitted(built: comp.Built, k: int, frac: float, dt: float, jac_index: tuple[int, ...]):
    """Jitted single replay, vmapped batch (θ only) and forward-mode Jacobian d θ / d p[jac_index]."""
    replay = make_replay(built, k, frac, dt)
    single = jax.jit(replay)
    batch = jax.jit(jax.vmap(lambda x0, ua, ub, p: replay(x0, ua, ub, p)[:, 0],
                             in_axes=(None, None, None, 0)))
    idx = jnp.asarray(jac_index)

    def theta_of(q, x0, ua, ub, p):
        return replay(x0, ua, ub, p.at[idx].set(q))[:, 0]

    jac = jax.jit(lambda x0, ua, ub, p: jax.jacfwd(theta_of)(p[idx], x0, ua, ub, p))
    return single, batch, jac


def versions() -> dict[str, str]:
    import jaxlib

    out = {"jax": jax.__version__, "jaxlib": jaxlib.__version__}
    try:
        import diffrax

        out["diffrax"] = diffrax.__version__
    except ImportError:
        pass
    return out
