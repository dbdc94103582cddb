"""The weak form's regression matrices (thesis §3.2.2): test functions on subdomains of the record,
the library integrated against them (:func:`weak_matrices`, with the hold-exact quadrature of
:mod:`aeropend_ident.sindy.weak_quadrature`), and what a refinement pass adds
(:class:`WeakContext`).

The regression on them is :func:`aeropend_ident.sindy.core.fit`. No rclpy import.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pysindy as ps
from pysindy.utils import AxesArray

from aeropend_ident.errors import IdentificationError
from aeropend_ident.sindy.libraries import CandidateLibrary
from aeropend_ident.sindy.model import (
    BaseModel,
    IdentData,
    base_derivatives,
)
from aeropend_ident.sindy.weak_quadrature import WeakOperator
from aeropend_sim.params import Rig


def weak_matrices(data: IdentData, columns: np.ndarray, targets: Sequence[str], K: int = 200,
                  p: int = 4, H_xt: float | None = None, seed: int = 0,
                  columns_next: np.ndarray | None = None, zoh: np.ndarray | None = None,
                  *, _setup: _WeakSetup | None = None,
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Weak-form regression matrices with pysindy's ``WeakPDELibrary`` (thesis Eqs. 3.20-3.30).

    ``WeakPDELibrary(function_library=IdentityLibrary(), spatiotemporal_grid=t, K, p, H_xt)``
    integrates each given column against K test functions φ_k = (1 − t̃²)^p (random subdomains)
    assuming the column is linear between samples; the left side is pysindy's
    ``convert_u_dot_integral`` of the target states, −∫φ_k'·x dt.

    **Zero-order-hold inputs.** A column that reads an input held constant over each sample
    period (the duty cycle τ_k and hence v_a on [t_k, t_k+1)) jumps at every sample instant, and
    the linear-interpolation quadrature treats each jump as a ramp: an O(dt) error per step that
    wrecks the current equation (thesis_sim di_a/dt off by 380 % noise-free). For the columns
    flagged in ``zoh`` the integral is computed exactly for the held input instead: on each
    sample interval the column is F(x(t), u_k), taken linear in t between F(x_k, u_k)
    (``columns``) and F(x_k+1, u_k) (``columns_next``),

        ∫ φ_k F dt = Σ_j a_kj·F(x_j, u_j) + b_kj·F(x_j+1, u_j),

    with a_kj, b_kj the exact integrals of φ_k times the two linear hat halves on [t_j, t_j+1]
    (pysindy's own ``_phi_int``/``_xphi_int`` antiderivatives, same subdomains and test
    functions). For a column without input this is exactly pysindy's quadrature.

    Parameters
    ----------
    columns : ndarray, shape (N, M)
        Strong-form columns F(x_j, u_j) to integrate (library columns, model right-hand sides, ...).
    H_xt : float, optional
        Half-width of the subdomains [s] (pysindy default: 1/20 of the record).
    columns_next : ndarray, shape (N, M), optional
        F(x_j+1, u_j): the same columns with the states advanced one sample and the inputs not
        (row N−1 is not used). Needed when ``zoh`` flags any column.
    zoh : ndarray of bool, shape (M,), optional
        Columns that read a zero-order-hold input.

    Returns
    -------
    theta_w : ndarray, shape (K, M)
    lhs_w : ndarray, shape (K, n_targets)
    """
    t = data.t
    if _setup is None:
        _check_half_width(t, H_xt)
    cols_a = np.asarray(columns, dtype=float)
    zoh_mask = np.zeros(cols_a.shape[1], dtype=bool) if zoh is None else np.asarray(zoh, dtype=bool)
    if zoh_mask.shape != (cols_a.shape[1],):
        raise IdentificationError(f"zoh mask has shape {zoh_mask.shape}, expected ({cols_a.shape[1]},)")
    if zoh_mask.any() and (columns_next is None or np.shape(columns_next) != cols_a.shape):
        raise IdentificationError(
            f"zero-order-hold columns need columns_next of shape {cols_a.shape}, "
            f"got {None if columns_next is None else np.shape(columns_next)}"
        )
    if _setup is None:
        _setup = _weak_setup(np.asarray(t, dtype=float).tobytes(), K, p, H_xt, seed)
    setup = _setup
    lib = setup.lib
    cols = AxesArray(cols_a, {"ax_time": 0, "ax_coord": 1})
    x = np.column_stack([data.variables[tg] for tg in targets])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lib.fit([cols])
        theta_w = np.asarray(lib.transform([cols])[0]).copy()
        lhs_w = np.asarray(lib.convert_u_dot_integral(AxesArray(x, {"ax_time": 0, "ax_coord": 1})))
    if zoh_mask.any():
        nxt = np.asarray(columns_next, dtype=float)[:, zoh_mask]
        cur = cols_a[:, zoh_mask]
        for k, (idx, a, b) in enumerate(setup.zoh_weights()):
            theta_w[k, zoh_mask] = a @ cur[idx[:-1]] + b @ nxt[idx[:-1]]
    return theta_w, lhs_w


def _check_half_width(t: np.ndarray, H_xt: float | None) -> None:
    if H_xt is not None and not 0 < 2 * H_xt < t[-1] - t[0]:
        raise IdentificationError(f"H_xt = {H_xt!r} s must be in (0, record/2 = {(t[-1] - t[0]) / 2:g} s)")


class _WeakSetup:
    """pysindy's ``WeakPDELibrary`` on one time grid and its exact zero-order-hold weights.

    Both depend only on the grid, K, p, H_xt and the seed (not on the library columns, the
    targets or λ), so one setup serves every equation and every λ of a sweep; building it is
    most of the cost of :func:`weak_matrices` (0.12 s of 0.2 s for K = 300 on 16 500 samples).
    """

    def __init__(self, t: np.ndarray, K: int, p: int, H_xt: float | None, seed: int) -> None:
        _check_half_width(t, H_xt)
        self.t, self.p = t, p
        np.random.seed(seed)  # pysindy draws the subdomain centres from the global generator
        self.lib = ps.WeakPDELibrary(function_library=ps.IdentityLibrary(), spatiotemporal_grid=t, K=K, p=p,
                                     H_xt=H_xt)
        self._zoh: list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None

    def zoh_weights(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per subdomain: sample indices and the weights a, b of :func:`weak_matrices` (cached)."""
        if self._zoh is None:
            out = []
            for k in range(self.lib.K):
                idx = np.asarray(self.lib.inds_k[k][0])
                out.append((idx, *_zoh_weights(self.lib, self.t[idx], self.p)))
            self._zoh = out
        return self._zoh


@functools.lru_cache(maxsize=8)
def _weak_setup(t_bytes: bytes, K: int, p: int, H_xt: float | None, seed: int) -> _WeakSetup:
    """The :class:`_WeakSetup` of a time grid (given as its float64 bytes), kept for the next call on
    the same grid: the gap's screening builds the weak form of every equation of a recording on one
    grid, and its second-effect screening again."""
    return _WeakSetup(np.frombuffer(t_bytes, dtype=float).copy(), K, p, H_xt, seed)


def _zoh_weights(lib: ps.WeakPDELibrary, tk: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact ∫φ·(1−s) and ∫φ·s over each sample interval of one subdomain (s: 0→1 across it)."""
    h = (tk[-1] - tk[0]) / 2.0
    xs = (tk - (tk[-1] + tk[0]) / 2.0) / h
    w = lib._phi_int(xs, 0, p)
    z = lib._xphi_int(xs, 0, p)
    dw, dz = np.diff(w), np.diff(z)
    x1, x2 = xs[:-1], xs[1:]
    span = x2 - x1
    return h * (x2 * dw - dz) / span, h * (dz - x1 * dw) / span


@dataclass
class WeakContext:
    """What a refinement pass of the weak form adds to the plain one (see
    :func:`aeropend_ident.sindy.core.fit_weak_refined`).

    Attributes
    ----------
    operator : WeakOperator
        Subdomains, test functions and Boole quadrature over the sample intervals.
    held : list of str
        Zero-order-hold inputs.
    curvature : dict state -> ndarray (N−1, 5)
        Intra-sample curvature correction of the measured path (previous model).
    simulated : dict name -> ndarray (N,) or None
        Free run of the previous model (targets simulated, the rest from the data): the
        source of the instruments; None when no instruments are used.
    simulated_curvature : dict state -> ndarray (N−1, 5)
    """

    operator: WeakOperator
    held: list[str]
    curvature: dict[str, np.ndarray]
    simulated: dict[str, np.ndarray] | None = None
    simulated_curvature: dict[str, np.ndarray] = field(default_factory=dict)

    def matrices(self, data: IdentData, library: CandidateLibrary, targets: Sequence[str],
                 base: Rig | BaseModel | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(regression matrix, left side, left side before the base model), each with K rows."""
        op = self.operator
        nodes = op.node_values(data.variables, self.held, self.curvature)
        theta_w = op.integrate(library.evaluate(nodes))
        y = y_ref = op.derivative_integral(np.column_stack([nodes[tg] for tg in targets]))
        if base is not None:
            fb = base_derivatives(base, _node_data(nodes, data.source), targets)
            y = y - op.integrate(np.column_stack([fb[tg] for tg in targets]))
        if self.simulated is None:
            return theta_w, y, y_ref
        sim_nodes = op.node_values(self.simulated, self.held, self.simulated_curvature)
        z = op.integrate(library.evaluate(sim_nodes))
        zs, ts = column_rms(z), column_rms(theta_w)
        proj = np.linalg.lstsq(z / zs, theta_w / ts, rcond=None)[0]
        return (z / zs) @ proj * ts, y, y_ref


# ---------------------------------------------------------------------------------- regression
def column_rms(a: np.ndarray) -> np.ndarray:
    """RMS of each column of ``a`` (shape (N, k) -> (k,)), 1 where it is 0: the unit-RMS scale."""
    r = np.sqrt(np.mean(np.asarray(a) ** 2, axis=0))
    return np.where(r > 0, r, 1.0)


def _node_data(nodes: Mapping[str, np.ndarray], source: str) -> IdentData:
    n = len(next(iter(nodes.values())))
    return IdentData(t=np.arange(float(n)), variables=dict(nodes), source=f"{source}(quadrature nodes)")
