"""Weak-form quadrature for sampled data with zero-order-hold inputs (thesis §3.2.2).

The weak form integrates each library column F(x(t), u(t)) against test functions φ_k on
subdomains of the record. pysindy's ``WeakPDELibrary`` places the subdomains and defines the
test functions φ_k = (1 − t̃²)^p (t̃ the time rescaled to [−1, 1] on the subdomain); its own
quadrature assumes every column is linear between samples. For an aeropendulum record two
things break that assumption:

* the duty cycle τ_k, and hence v_a, is **held** over [t_k, t_k+1) (zero-order hold): a
  column reading it is F(x(t), u_k) on the interval, not a ramp from u_k to u_k+1;
* the electrical states (modes at 39 and 162 s⁻¹ on ``thesis_sim``) **curve** within one
  2.048 ms sample: linear interpolation of i_a and ω₁ biases the current equation by about 1 %.

:class:`WeakOperator` integrates on every sample interval with Boole's five-point rule at
s = 0, ¼, ½, ¾, 1 of the interval, inputs held at u_k. The states at the interior nodes are
the linear interpolation plus an optional *curvature correction* δ(s) (zero at both ends):
the deviation from a straight line of the path an approximate model ẋ = f(x, u_k) takes from
x_k over the interval (four RK4 steps, vectorised over all intervals). With δ = 0 this is
pysindy's quadrature (up to Boole's O(dt⁶) error) with the hold handled exactly.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence

import numpy as np
import pysindy as ps
import scipy.sparse as sp
from pysindy.utils import AxesArray

#: Boole's rule on [0, 1]: node positions and weights.
NODES = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
WEIGHTS = np.array([7.0, 32.0, 12.0, 32.0, 7.0]) / 90.0

Derivative = Callable[[Mapping[str, np.ndarray]], Mapping[str, np.ndarray]]


class WeakOperator:
    """Test-function integrals over the sample intervals of a uniform record.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Uniform sample times [s].
    K : int
        Number of subdomains (pysindy ``WeakPDELibrary`` placement, seeded).
    p : int
        Test-function degree.
    H_xt : float or None
        Subdomain half-width [s] (pysindy default 1/20 of the record).
    seed : int
        Seed of the subdomain placement (pysindy draws from NumPy's global generator).
    lib : pysindy.WeakPDELibrary, optional
        A library already built on the same ``t``, ``K``, ``p``, ``H_xt`` and ``seed`` (the one the
        weak-form matrices of the same fit use): its subdomains are taken instead of building it
        again (building it is most of this constructor's cost).

    Attributes
    ----------
    phi, dphi : scipy.sparse.csr_matrix, shape (K, (N−1)·5)
        Boole weights × φ_k and × dφ_k/dt at the interval nodes.
    """

    def __init__(self, t: np.ndarray, K: int, p: int = 4, H_xt: float | None = None, seed: int = 0,
                 lib: ps.WeakPDELibrary | None = None) -> None:
        self.t = np.asarray(t, dtype=float)
        n = self.t.size
        if lib is None:
            np.random.seed(seed)
            lib = ps.WeakPDELibrary(function_library=ps.IdentityLibrary(), spatiotemporal_grid=self.t, K=K,
                                    p=p, H_xt=H_xt)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            lib.fit([AxesArray(np.zeros((n, 1)), {"ax_time": 0, "ax_coord": 1})])
        dt = np.diff(self.t)
        rows, cols, v0, v1 = [], [], [], []
        g = NODES.size
        for k in range(lib.K):
            idx = np.asarray(lib.inds_k[k][0])
            a, b = self.t[idx[0]], self.t[idx[-1]]
            c, h = 0.5 * (a + b), 0.5 * (b - a)
            j = idx[:-1]
            tn = self.t[j, None] + NODES[None, :] * dt[j, None]
            x = (tn - c) / h
            base = np.clip(1.0 - x**2, 0.0, None)
            phi = base**p
            dphi = -2.0 * p * x * base ** (p - 1) / h
            w = WEIGHTS[None, :] * dt[j, None]
            rows.append(np.full(j.size * g, k))
            cols.append((j[:, None] * g + np.arange(g)[None, :]).ravel())
            v0.append((phi * w).ravel())
            v1.append((dphi * w).ravel())
        shape = (lib.K, (n - 1) * g)
        r, cidx = np.concatenate(rows), np.concatenate(cols)
        self.phi = sp.csr_matrix((np.concatenate(v0), (r, cidx)), shape=shape)
        self.dphi = sp.csr_matrix((np.concatenate(v1), (r, cidx)), shape=shape)
        self.K = lib.K

    def node_values(self, variables: Mapping[str, np.ndarray], held: Sequence[str] = (),
                    curvature: Mapping[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """Variables at the interval nodes, flattened to ((N−1)·5,).

        Held variables take u_k on the whole interval; the others the linear interpolation
        between samples plus ``curvature[name]`` (shape (N−1, 5), zero at both ends) if given.
        """
        out = {}
        for name, v in variables.items():
            a = np.asarray(v, dtype=float)
            if name in held:
                nodes = np.repeat(a[:-1, None], NODES.size, axis=1)
            else:
                nodes = a[:-1, None] + NODES[None, :] * np.diff(a)[:, None]
                if curvature is not None and name in curvature:
                    nodes = nodes + curvature[name]
            out[name] = nodes.ravel()
        return out

    def integrate(self, node_columns: np.ndarray) -> np.ndarray:
        """∫φ_k·F dt for columns given at the nodes: ((N−1)·5, M) -> (K, M)."""
        return np.asarray(self.phi @ node_columns)

    def derivative_integral(self, node_states: np.ndarray) -> np.ndarray:
        """−∫φ_k'·x dt (= ∫φ_k·ẋ dt) for states at the nodes: ((N−1)·5, T) -> (K, T)."""
        return -np.asarray(self.dphi @ node_states)


def curvature(variables: Mapping[str, np.ndarray], rhs: Derivative, states: Sequence[str],
              held: Sequence[str], dt: float) -> dict[str, np.ndarray]:
    """Deviation of a model's intra-sample path from the straight line, per interval.

    For every interval [t_k, t_k+1] the model ẋ = rhs(x, u_k) is integrated from the sample
    x_k with four RK4 steps of dt/4 (all intervals at once); δ(s) is the path minus the line
    from x_k to the path's own end, at the Boole nodes s = 0, ¼, ½, ¾, 1.

    Parameters
    ----------
    variables : mapping name -> ndarray (N,)
        Samples of every variable the model reads.
    rhs : callable
        ``rhs(values) -> {state: derivative}`` on arrays of any common length.
    states : sequence of str
        States the model advances (others, and the ``held`` inputs, stay at their sample values).
    dt : float
        Sample period [s].

    Returns
    -------
    dict state -> ndarray (N−1, 5)
    """
    cur = {k: np.asarray(v, dtype=float)[:-1].copy() for k, v in variables.items()}
    x0 = {s: cur[s].copy() for s in states}
    path = {s: [x0[s].copy()] for s in states}
    h = dt / (NODES.size - 1)

    def f(vals: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        d = rhs(vals)
        return {s: np.asarray(d[s], dtype=float) for s in states}

    x = {s: x0[s].copy() for s in states}
    for _ in range(NODES.size - 1):
        def at(y: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
            v = dict(cur)
            v.update(y)
            return v
        k1 = f(at(x))
        k2 = f(at({s: x[s] + 0.5 * h * k1[s] for s in states}))
        k3 = f(at({s: x[s] + 0.5 * h * k2[s] for s in states}))
        k4 = f(at({s: x[s] + h * k3[s] for s in states}))
        x = {s: x[s] + h / 6.0 * (k1[s] + 2 * k2[s] + 2 * k3[s] + k4[s]) for s in states}
        for s in states:
            path[s].append(x[s].copy())
    out = {}
    for s in states:
        p = np.column_stack(path[s])
        line = p[:, :1] + NODES[None, :] * (p[:, -1:] - p[:, :1])
        d = p - line
        out[s] = np.where(np.isfinite(d), d, 0.0)
    return out


class SecondOrderTestFunctions:
    """Test functions for the weak form of a second-order equation, ẍ = Θ(x, ẋ, u)·ξ.

    With φ_k compactly supported and φ_k, φ_k' zero at both ends of its subdomain (degree
    p ≥ 2), integration by parts moves both derivatives onto the test function,

        ∫φ_k·ẍ dt = ∫φ_k''·x dt,        ∫φ_k·ẋ dt = −∫φ_k'·x dt,

    so the pendulum equation can be regressed on the recorded angle alone: no derivative of the
    noisy θ is ever formed. pysindy's ``WeakPDELibrary`` supplies the subdomain placement, the
    test functions φ_k = (1 − t̃²)^p and its own piecewise-linear quadrature weights
    (``_linear_weights(x, d, p)`` for the d-th derivative of φ); its regression only forms the
    first-order left side ``convert_u_dot_integral`` (−∫φ'·x) and no second time derivative,
    which is why the weights are assembled here.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Uniform sample times [s].
    K : int
        Number of subdomains.
    p : int
        Test-function degree (>= 2).
    H_xt : float
        Subdomain half-width [s].
    seed : int
        Seed of pysindy's subdomain placement.

    Attributes
    ----------
    w0, w1, w2 : scipy.sparse.csr_matrix, shape (K, N)
        Quadrature weights of ∫φ_k·f, ∫φ_k'·f and ∫φ_k''·f for f given at the samples.

    Raises
    ------
    ValueError
        If p < 2 or the subdomain does not fit into the record.
    """

    def __init__(self, t: np.ndarray, K: int, p: int = 4, H_xt: float = 0.2, seed: int = 0) -> None:
        if p < 2:
            raise ValueError(f"test-function degree p = {p!r}: the second-order weak form needs p >= 2 "
                             "(φ and φ' zero at the subdomain ends)")
        self.t = np.asarray(t, dtype=float)
        n = self.t.size
        if not 0.0 < 2.0 * H_xt < self.t[-1] - self.t[0]:
            half = (self.t[-1] - self.t[0]) / 2
            raise ValueError(f"H_xt = {H_xt!r} s must be in (0, record/2 = {half:g} s)")
        np.random.seed(seed)  # pysindy draws the subdomain centres from the global generator
        lib = ps.WeakPDELibrary(function_library=ps.IdentityLibrary(), spatiotemporal_grid=self.t, K=K, p=p,
                                H_xt=H_xt)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            lib.fit([AxesArray(np.zeros((n, 1)), {"ax_time": 0, "ax_coord": 1})])
        rows, cols, vals = [], [], ([], [], [])
        for k in range(lib.K):
            idx = np.asarray(lib.inds_k[k][0])
            tk = self.t[idx]
            h = 0.5 * (tk[-1] - tk[0])
            xs = (tk - 0.5 * (tk[-1] + tk[0])) / h
            rows.append(np.full(idx.size, k))
            cols.append(idx)
            for d in range(3):  # d/dt = (1/h)·d/dt̃, dt = h·dt̃
                vals[d].append(lib._linear_weights(xs, d, p) * h ** (1 - d))
        r, c = np.concatenate(rows), np.concatenate(cols)
        self.w0, self.w1, self.w2 = (sp.csr_matrix((np.concatenate(v), (r, c)), shape=(lib.K, n))
                                     for v in vals)
        self.K = lib.K

    def integrate(self, columns: np.ndarray) -> np.ndarray:
        """∫φ_k·F dt: (N,) or (N, M) -> (K,) or (K, M)."""
        return np.asarray(self.w0 @ np.asarray(columns, dtype=float))

    def rate(self, x: np.ndarray) -> np.ndarray:
        """∫φ_k·ẋ dt = −∫φ_k'·x dt from the samples of x: (N,) -> (K,)."""
        return -np.asarray(self.w1 @ np.asarray(x, dtype=float))

    def acceleration(self, x: np.ndarray) -> np.ndarray:
        """∫φ_k·ẍ dt = ∫φ_k''·x dt from the samples of x: (N,) -> (K,)."""
        return np.asarray(self.w2 @ np.asarray(x, dtype=float))
