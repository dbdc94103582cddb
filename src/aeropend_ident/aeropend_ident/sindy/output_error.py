"""Output-error (prediction-error) refinement of an identified sparse model.

SINDy (strong or weak form) is an *equation-error* estimator: it regresses derivatives (or their
weak integrals) on library columns built from the measured, noisy signals. When two regressors
are nearly collinear — on ``thesis_sim`` ω₁ follows 23.5·i_a with a 5 ms lag — the equation
error carries little information to split their coefficients and the estimate scatters with the
noise realisation (the current equation's R_a/L_a: 1.6-20 % over noise seeds at 50 dB).

The output-error estimator keeps the structure SINDy selected and re-estimates the non-zero
coefficients of chosen equations by minimising the **simulation error** of the recorded
channels: the target states are integrated from the model, every other library variable (inputs,
states the refined equations do not describe) is taken from the data, and

    min_{ξ, x₀}  Σ_w Σ_k Σ_s ((x̂_s(t_k; ξ, x₀,w) − y_s(t_k)) / RMS(y_s))²

is solved with ``scipy.optimize.least_squares`` (trust-region reflective). Under white output
noise of equal SNR per channel this is the maximum-likelihood (prediction-error) estimate
(Ljung, *System Identification*, 2nd ed., §7.3; output-error models), statistically efficient
where the equation error is not. The record is cut into windows (multiple shooting,
Bock & Plitt 1984): each window starts from its own initial state, estimated as extra
parameters, so an imperfect model cannot drift over the whole record and the problem stays
well conditioned; the window states enter the Jacobian block-diagonally, so
its forward differences cost one simulation per coefficient plus one per simulated state, and it
is kept sparse (n_r·(n_c + n_s) entries; the trust-region step is solved by LSMR): held dense, a
120 s record at 1 kHz made a 0.9 GB matrix whose SVD took most of the fit (docs/identification.md).

Integration: fixed-step RK4 with ``substeps`` steps per sample, all windows in parallel (one
vectorised library evaluation per stage). Inputs held over each sample period (``zoh_inputs``:
v_a, τ) are constant on [t_k, t_k+1); other data variables are linear between samples. A
measured v_a drives the simulation as recorded; optionally (``clean_inputs``) it is replaced by
its polynomial fit v_a(τ) (the stand-in the weak-iv instruments use).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix

from aeropend_ident.errors import IdentificationError, LibraryError
from aeropend_ident.sindy.libraries import CandidateLibrary
from aeropend_ident.sindy.model import ZOH_INPUTS, IdentData, SindyModel, input_instruments

#: Forward-difference step on the scaled parameters (coefficient multipliers ~1, states / RMS).
_EPS = 1e-7
#: Stopping tolerances (atol, btol) of LSMR, the trust-region step's sparse least-squares solver.
LSMR_TOL = 1e-12


def _windows(n: int, length: int) -> np.ndarray:
    """Start indices of consecutive windows of ``length`` samples covering [0, n)."""
    n_w = max(1, (n - 1) // length)
    return np.arange(n_w) * length


def _checked_request(model: SindyModel, data: IdentData, targets: list[str], window: float,
                     substeps: int) -> tuple[float, int, list[int], np.ndarray, np.ndarray]:
    """Check a :func:`refine_output_error` request.

    Returns (dt, window samples, target rows, support, start coefficients).
    """
    if model.base is not None:
        raise IdentificationError("output-error refinement needs a model without a discrepancy base model")
    bad = [tg for tg in targets if tg not in model.targets]
    if not targets or bad:
        raise IdentificationError(
            f"targets {bad or targets!r} are not equations of the model {model.targets}"
        )
    if substeps < 1:
        raise IdentificationError(f"substeps = {substeps!r} must be >= 1")
    need = sorted(set(model.library.variables) | set(targets))
    missing = [v for v in need if v not in data.variables]
    if missing:
        raise IdentificationError(f"{data.source}: output-error refinement needs {missing}; "
                                  f"data has {sorted(data.variables)}")
    dt = float(np.mean(np.diff(data.t)))
    length = round(window / dt)
    if not window > 0 or length < 2 or 2 * length > len(data):
        raise IdentificationError(
            f"window = {window!r} s is {length} samples; expected >= 2 samples and at most half the "
            f"record ({len(data)} samples of {dt:.4g} s)"
        )
    rows = [model.targets.index(tg) for tg in targets]
    support = model.coef[rows] != 0.0
    empty = [tg for tg, s in zip(targets, support, strict=True) if not s.any()]
    if empty:
        raise IdentificationError(f"equation(s) {empty} have no terms to refine")
    c0 = model.coef[rows][support]
    return dt, length, rows, support, c0


def _window_simulator(lib: CandidateLibrary, targets: list[str], cols: np.ndarray,
                      exo_k: dict[str, np.ndarray], held: set[str], shape: tuple[int, int, int], dt: float,
                      substeps: int) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """RK4 simulation of the target equations over all windows at once (refine_output_error)."""
    n_w, length, n_s = shape

    def exo_at(k: int, frac: float) -> dict[str, np.ndarray]:
        out = {}
        for v, a in exo_k.items():
            out[v] = a[:, k] if (v in held or frac == 0.0) else (1 - frac) * a[:, k] + frac * a[:, k + 1]
        return out

    def simulate(coef_t: np.ndarray, x0: np.ndarray) -> np.ndarray:
        """States (n_w, L+1, n_s) from initial states x0 (n_w, n_s) with target rows coef_t."""
        ct = coef_t[:, cols]

        def f(x: np.ndarray, ex: dict[str, np.ndarray]) -> np.ndarray:
            vals = dict(ex)
            vals.update({tg: x[:, i] for i, tg in enumerate(targets)})
            return lib.evaluate(vals) @ ct.T

        out = np.empty((n_w, length + 1, n_s))
        out[:, 0] = x = x0
        h = dt / substeps
        for k in range(length):
            for j in range(substeps):
                a = exo_at(k, j / substeps)
                m = exo_at(k, (j + 0.5) / substeps)
                b = exo_at(k, (j + 1) / substeps)
                k1 = f(x, a)
                k2 = f(x + 0.5 * h * k1, m)
                k3 = f(x + 0.5 * h * k2, m)
                k4 = f(x + h * k3, b)
                x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            out[:, k + 1] = x
        return out

    return simulate


def _coef_std(model: SindyModel, coef: np.ndarray, sol: Any, rows: list[int], support: np.ndarray,
              c0: np.ndarray, dof_raw: int) -> np.ndarray:
    """Standard errors of the refined coefficients from the Jacobian, s²·(JᵀJ)⁻¹ (others kept)."""
    n_c = c0.size
    std = np.full_like(coef, np.nan) if model.coef_std is None else model.coef_std.copy()  # NaN: unknown
    jtj = (sol.jac.T @ sol.jac).toarray()  # sparse J (_sparse_jacobian); JᵀJ (n_p, n_p) small
    dof = max(dof_raw, 1)
    s2 = 2.0 * sol.cost / dof
    try:
        cov = np.linalg.inv(jtj)[:n_c, :n_c] * s2
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None)) * np.abs(c0)
    except np.linalg.LinAlgError:
        se = np.full(n_c, np.nan)
    std_t = np.zeros(support.shape)
    std_t[support] = se
    std[rows] = std_t
    return std


def _window_data(data: IdentData, lib: Any, targets: Sequence[str], length: int, clean_inputs: bool
                 ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """The windows of :func:`refine_output_error`: the recorded targets per window (n_w, L+1, n_s),
    each target's RMS scale (n_s,) and the exogenous library variables at the window samples
    (instrumented inputs with ``clean_inputs``)."""
    variables = dict(data.variables)
    if clean_inputs:
        variables.update(input_instruments(data))
    exo = [v for v in lib.variables if v not in targets]
    starts = _windows(len(data), length)
    idx = starts[:, None] + np.arange(length + 1)[None, :]  # (n_w, L+1) sample indices per window
    y = np.stack([data.variables[tg][idx] for tg in targets], axis=-1)  # (n_w, L+1, n_s)
    scale = np.sqrt(np.mean(np.stack([data.variables[tg] for tg in targets], axis=-1) ** 2, axis=0))
    scale = np.where(scale > 0, scale, 1.0)
    return y, scale, {v: np.asarray(variables[v])[idx] for v in exo}


def _sparse_jacobian(residuals: Callable[[np.ndarray], np.ndarray], cache: dict[str, np.ndarray], n_c: int,
                     n_w: int, n_s: int, per_w: int) -> Callable[[np.ndarray], csr_matrix]:
    """The Jacobian of :func:`refine_output_error`'s residuals (``cache``: the last point and residual):
    forward differences, sparse (n_r, n_c + n_w·n_s) with n_r = n_w·per_w: one simulation per
    coefficient (a dense column) and one per state for all window starts together (a window's
    residuals, rows w·per_w … (w+1)·per_w − 1, depend only on its own initial state)."""
    n_r = n_w * per_w
    every_row = np.arange(n_r)

    def jacobian(p: np.ndarray) -> csr_matrix:
        r = cache["r"] if np.array_equal(p, cache["p"]) else residuals(p)
        dense = np.empty((n_r, n_c))
        for i in range(n_c):
            q = p.copy()
            q[i] += _EPS
            dense[:, i] = (residuals(q) - r) / _EPS
        vals, cols, rows = [dense.ravel()], [np.tile(np.arange(n_c), n_r)], [np.repeat(every_row, n_c)]
        for s_ in range(n_s):
            q = p.copy()
            q[n_c + s_::n_s] += _EPS
            vals.append((residuals(q) - r) / _EPS)
            cols.append(np.repeat(n_c + np.arange(n_w) * n_s + s_, per_w))
            rows.append(every_row)
        return csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(n_r, p.size))

    return jacobian


def refine_output_error(
    model: SindyModel,
    data: IdentData,
    targets: Sequence[str] = ("i_a", "omega_rotor"),
    window: float = 0.5,
    substeps: int = 2,
    zoh_inputs: Sequence[str] = ZOH_INPUTS,
    clean_inputs: bool = False,
    max_nfev: int = 100,
) -> SindyModel:
    """Re-estimate the non-zero coefficients of some equations by output-error minimisation.

    Parameters
    ----------
    model : SindyModel
        An identified model without a discrepancy base (its support is kept; its coefficients
        are the starting point).
    data : IdentData, N samples
        Recorded data (uniform sampling) with every target state and every library variable.
    targets : sequence of str
        Equations to refine; their states are simulated (jointly), everything else the library
        reads comes from the data. Simulate together the states that drive each other (i_a and
        ω₁ on the aeropendulum): a measured, noisy regressor would bring the errors-in-variables
        problem back.
    window : float
        Multiple-shooting window length [s]; each window's initial state is estimated. Longer
        than the slowest simulated mode (thesis_sim: 26 ms) and short enough that an imperfect
        start does not drift.
    substeps : int
        RK4 steps per sample period (>= 1).
    zoh_inputs : sequence of str
        Data variables held constant over each sample period (default v_a and the duty cycle).
    clean_inputs : bool
        Replace a measured v_a by its static fit v_a(τ) (``sindy.model.input_instruments``): removes
        the input noise (an errors-in-variables bias at low SNR) but adds the polynomial's own
        error (0.09 % on R_a/L_a noise-free); at 50 dB on thesis_sim the measured v_a gave the
        smaller scatter over six noise seeds (bench/results/sindy_oe*.md), hence the default.
    max_nfev : int
        Function-evaluation budget of ``least_squares``.

    Returns
    -------
    SindyModel
        Same support, refined coefficients in the target rows; ``coef_std`` holds the
        coefficients' standard errors from the Jacobian, s²·(JᵀJ)⁻¹ with s² the residual
        variance (0 for terms outside the support; NaN in rows not refined when the input model
        had no spread); ``method`` gets the suffix ``"+oe"``.

    Raises
    ------
    IdentificationError
        Model with a base model, a target that is not an equation of the model, a missing data
        variable, a refined equation without terms, bad window/substeps, a record shorter than
        two windows' worth of samples, or a simulation that diverges from the start values.
    """
    t0 = time.perf_counter()
    targets = list(targets)
    dt, length, rows, support, c0 = _checked_request(model, data, targets, window, substeps)

    cols = np.flatnonzero(support.any(axis=0))
    lib = model.library.without(*[n for j, n in enumerate(model.feature_names) if j not in set(cols)])
    y, scale, exo_k = _window_data(data, lib, targets, length, clean_inputs)
    n_w, n_s = y.shape[0], len(targets)
    simulate = _window_simulator(lib, targets, cols, exo_k, set(zoh_inputs), (n_w, length, n_s), dt, substeps)

    n_c = c0.size

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        coef_t = np.zeros(support.shape)
        coef_t[support] = p[:n_c] * c0
        x0 = p[n_c:].reshape(n_w, n_s) * scale
        return coef_t, x0

    def residuals(p: np.ndarray) -> np.ndarray:
        coef_t, x0 = unpack(p)
        try:
            with np.errstate(all="ignore"):
                r = (simulate(coef_t, x0) - y) / scale
        except LibraryError:  # a diverging trial step: non-finite library column
            r = np.full(y.shape, 1e6)
        r = np.where(np.isfinite(r), r, 1e6)
        return r.ravel()

    p0 = np.r_[np.ones(n_c), (y[:, 0] / scale).ravel()]
    r0 = residuals(p0)
    if np.abs(r0).max() >= 1e6:
        raise IdentificationError(f"{data.source}: the model {model.equations()} diverges over a "
                                  f"{window:g} s window from the start values; shorten the window")
    n_r = r0.size
    per_w = (length + 1) * n_s
    cache: dict[str, np.ndarray] = {"p": p0, "r": r0}

    jacobian = _sparse_jacobian(residuals, cache, n_c, n_w, n_s, per_w)

    def fun(p: np.ndarray) -> np.ndarray:
        r = residuals(p)
        cache["p"], cache["r"] = p.copy(), r
        return r

    with np.errstate(all="ignore"):
        sol = least_squares(fun, p0, jac=jacobian, method="trf", tr_solver="lsmr", x_scale=1.0,
                            max_nfev=max_nfev, xtol=1e-12, ftol=1e-12, gtol=1e-10,
                            tr_options={"atol": LSMR_TOL, "btol": LSMR_TOL})
    coef_t, _ = unpack(sol.x)
    coef = model.coef.copy()
    coef[rows] = coef_t
    std = _coef_std(model, coef, sol, rows, support, c0, n_r - p0.size)
    return replace(model, coef=coef, coef_std=std, method=f"{model.method}+oe",
                   fit_time=model.fit_time + time.perf_counter() - t0)
