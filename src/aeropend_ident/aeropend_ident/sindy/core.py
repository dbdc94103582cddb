"""Sparse identification of the aeropendulum: SINDy, ensemble, weak and discrepancy SINDy.

Thesis §3.2 and chapter 5. All estimators regress state derivatives on a named candidate
library (:mod:`aeropend_ident.sindy.libraries`) with pysindy 2.1's sequentially thresholded least
squares (``pysindy.STLSQ``, threshold λ), after **column normalisation**: every library column
and every target is scaled to unit RMS before the regression and the coefficients are scaled
back afterwards. λ is therefore dimensionless: a term is kept when it contributes at least
λ × RMS(target) per unit-RMS column, so one λ serves a 2 ms electrical equation and a 1 s
pendulum equation together.

Estimators (``method``):

``"sindy"``
    Strong form (thesis Eq. 3.15): Ẋ ≈ Θ(X, U)·Ξᵀ with Ẋ given (exact, or from
    :mod:`aeropend_ident.sindy.preprocess`).
``"ensemble"``
    Bagging ensemble (``pysindy.EnsembleOptimizer(bagging=True)``): median coefficients,
    per-term inclusion probability and coefficient spread (standard deviation over the models).
``"weak"``
    Weak/integral form (thesis §3.2.2, Eqs. 3.20-3.30) with control: the library columns
    (which may involve the input v_a) are integrated against pysindy ``WeakPDELibrary`` test
    functions on K subdomains; the left side −∫φ'·x dt needs no derivative. This is what
    ``SINDy(feature_library=WeakPDELibrary(function_library=..., spatiotemporal_grid=t, K=...))
    .fit(x, t=t, u=u)`` computes; the matrices are built with the same library calls so the
    normalisation above can be applied.
``"weak"`` with ``refine=n`` (the benchmark's *weak-iv*)
    Inputs held over each sample period (``zoh_inputs``, default v_a and τ) are integrated
    exactly; then n passes of :func:`fit_weak_refined` correct the intra-sample curvature of
    the states and regress on instruments from the previous model's free run (consistent under
    noise in the regressors).
discrepancy (any method, ``base=`` a rig)
    Thesis Eqs. 3.31-3.37: regress the residual Ẋ − f_model(X, U) of an approximate model (a
    rig file through :class:`aeropend_sim.model.PlantModel`); the identified model is
    f_model + Θ·Ξᵀ. In weak form the residual is −∫φ'·x − ∫φ·f_model.

Targets are named by their state: ``"theta"`` (dθ/dt), ``"theta_dot"`` (θ̈), ``"i_a"``
(di_a/dt), ``"omega_rotor"`` (dω₁/dt). A target whose state is not in the data is refused with
a message naming it (e.g. the current equation when i_a was not recorded).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pysindy as ps

from aeropend_ident.errors import IdentificationError, LibraryError
from aeropend_ident.sindy.libraries import CandidateLibrary
from aeropend_ident.sindy.model import (
    ZOH_INPUTS,
    BaseModel,
    IdentData,
    NoEquationError,
    SindyModel,
    _advance_states,
    base_derivatives,
    check_targets,
    free_run,
    input_instruments,
    input_step_mask,
)
from aeropend_ident.sindy.output_error import refine_output_error
from aeropend_ident.sindy.weak_form import (
    WeakContext,
    _check_half_width,
    _node_data,
    _WeakSetup,
    column_rms,
    weak_matrices,
)
from aeropend_ident.sindy.weak_quadrature import WeakOperator, curvature
from aeropend_sim.params import Rig

METHODS = ("sindy", "ensemble", "weak")
#: The weak-iv estimator of the issue-4 benchmark: weak form with the hold-exact input quadrature,
#: subdomain half-width H_xt [s], test functions covering the record ``coverage`` times, two
#: refinement passes (intra-sample curvature + instrumental variables), ridge α on the unit-RMS
#: scale, STLSQ threshold λ (see :func:`weak_iv_options`).
WEAK_IV: dict[str, float] = {"H_xt": 0.02, "coverage": 3.0, "refine": 2, "alpha": 1.0, "threshold": 0.1}


def _normalised_cond(theta: np.ndarray) -> float:
    s = np.linalg.svd(theta / column_rms(theta), compute_uv=False)
    return float(s.max() / s.min()) if s.min() > 0 else float("inf")


def _stlsq(threshold: float, alpha: float, max_iter: int) -> ps.STLSQ:
    return ps.STLSQ(threshold=threshold, alpha=alpha, max_iter=max_iter, normalize_columns=False, unbias=True)


def sparse_regression(
    theta: np.ndarray, y: np.ndarray, threshold: float, method: str = "sindy", alpha: float = 1e-10,
    max_iter: int = 20, n_models: int = 40, subset_fraction: float = 0.6, seed: int = 0,
    zero_below: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Normalised STLSQ (or bagged ensemble) on a regression matrix.

    Parameters
    ----------
    theta : ndarray, shape (N, M)
        Library matrix (strong or weak form).
    y : ndarray, shape (N, T)
        Targets.
    threshold : float
        λ on the unit-RMS scale.
    method : {"sindy", "weak", "ensemble"}
        ``"ensemble"`` bags ``n_models`` fits on random ``subset_fraction`` row subsets
        (without replacement) and returns the median, the spread and the inclusion probability.
    alpha : float
        Ridge weight of STLSQ's thresholding iterations (on the unit scale); the final fit on the
        support is unbiased least squares.
    zero_below : ndarray, shape (T,), optional
        A target whose RMS is below this is taken as identically zero (all coefficients 0)
        instead of being scaled up to unit RMS: a discrepancy residual that is round-off only.

    Returns
    -------
    coef : ndarray (T, M)
    std : ndarray (T, M) or None
    inclusion : ndarray (T, M) or None
    """
    if not threshold >= 0:
        raise IdentificationError(f"threshold λ = {threshold!r} must be >= 0")
    cs, ys = column_rms(theta), column_rms(y)
    zero = np.zeros(y.shape[1], dtype=bool) if zero_below is None else ys <= np.asarray(zero_below)
    if zero.all():
        m = theta.shape[1]
        empty = np.zeros((y.shape[1], m))
        return empty, (empty.copy() if method == "ensemble" else None), (
            empty.copy() if method == "ensemble" else None)
    if zero.any():
        coef, std, incl = sparse_regression(
            theta, y[:, ~zero], threshold, method, alpha, max_iter, n_models, subset_fraction, seed
        )
        full = [np.zeros((y.shape[1], theta.shape[1])) if a is not None else None for a in (coef, std, incl)]
        for f, a in zip(full, (coef, std, incl), strict=True):
            if f is not None:
                f[~zero] = a
        return full[0], full[1], full[2]
    a, b = theta / cs, y / ys
    if method == "ensemble":
        np.random.seed(seed)  # pysindy's bagging draws from the global generator
        opt = ps.EnsembleOptimizer(
            opt=_stlsq(threshold, alpha, max_iter), bagging=True, n_models=n_models,
            n_subset=max(a.shape[1] + 1, int(subset_fraction * a.shape[0])), replace=False,
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            opt.fit(a, b)
        stack = np.asarray(opt.coef_list) * ys[None, :, None] / cs[None, None, :]
        return np.median(stack, axis=0), np.std(stack, axis=0), np.mean(stack != 0.0, axis=0)
    opt = _stlsq(threshold, alpha, max_iter)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opt.fit(a, b)
    coef = _enforce_threshold(a, b, np.asarray(opt.coef_, dtype=float), threshold)
    return coef * ys[:, None] / cs[None, :], None, None


def _enforce_threshold(a: np.ndarray, b: np.ndarray, coef: np.ndarray, threshold: float) -> np.ndarray:
    """Drop terms the final unbiased refit leaves below λ (unit-RMS scale) and refit, until none.

    STLSQ thresholds the ridge iterates; its unbiased refit on the support can leave a term
    below λ (a ridge-shrunk near-collinear combination). Such a term is removed here.
    """
    coef = coef.copy()
    for i in range(coef.shape[0]):
        for _ in range(coef.shape[1]):
            small = (coef[i] != 0.0) & (np.abs(coef[i]) < threshold)
            if not small.any():
                break
            keep = (coef[i] != 0.0) & ~small
            coef[i] = 0.0
            if keep.any():
                coef[i, keep] = np.linalg.lstsq(a[:, keep], b[:, i], rcond=None)[0]
    return coef


def _model_rhs(model: SindyModel) -> Callable[[Mapping[str, np.ndarray]], dict[str, np.ndarray]]:
    """The identified right-hand side on variable arrays (θ̇ for θ when only θ̈ is modelled)."""

    def rhs(vals: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        th = model.library.evaluate(vals)
        out = {tg: th @ model.coef[i] for i, tg in enumerate(model.targets)}
        if model.base is not None:
            fb = base_derivatives(model.base, _node_data(vals, "model"), model.targets)
            out = {tg: out[tg] + fb[tg] for tg in model.targets}
        if "theta" not in out and "theta_dot" in out and "theta_dot" in vals:
            out["theta"] = np.asarray(vals["theta_dot"], dtype=float)
        return out

    return rhs


def fit_weak_refined(
    data: IdentData, library: CandidateLibrary | Mapping[str, CandidateLibrary], targets: Sequence[str],
    passes: int = 2, instruments: bool = True, max_nrmse: float = math.inf, **kw: Any,
) -> SindyModel:
    """Weak SINDy with model-based refinement: intra-sample curvature and instrumental variables.

    Pass 0 is the plain weak form (:func:`fit` with ``method="weak"``, hold inputs exact). Each
    further pass uses the previous model twice:

    1. **curvature**: the library columns are integrated with Boole's rule on every sample
       interval, the states between samples taken as the straight line plus the deviation the
       model's own path from x_k shows (:func:`aeropend_ident.sindy.weak_quadrature.curvature`). On
       ``thesis_sim`` this removes the ~1 % bias linear interpolation puts on the current
       equation (modes of 6 and 26 ms sampled every 2 ms);
    2. **instruments** (``instruments=True``): the model is run free over the record from the
       first sample (inputs and unmodelled variables from the data); the same weak columns of
       that noise-free path are the instruments Z, and STLSQ runs on Θ_w projected onto them,
       Z(ZᵀZ)⁻¹ZᵀΘ_w (two-stage least squares). Noise in the regressors (i_a in the rotor
       equation, ω₁ in the current equation) biases plain least squares towards zero — 10-20 %
       at 50 dB SNR on ``thesis_sim`` — while the projected regression is consistent (the
       simulated path does not contain the measurement noise). This is the refined
       instrumental-variable idea of continuous-time system identification (Young's SRIVC)
       applied to the weak-form SINDy regression. If the free run diverges, the pass falls back
       to the curvature correction alone; a state whose free run strays from the data (NRMSE
       above ``max_nrmse``) is not used as an instrument (its measured signal is kept).

    Parameters
    ----------
    passes : int
        Refinement passes after the plain fit (>= 1).
    max_nrmse : float
        Largest free-run NRMSE (RMS error / std of the measured state) of a simulated state
        used as an instrument.
    kw
        Everything else of :func:`fit` (λ, K, p, H_xt, seed, base, zoh_inputs, ...).

    Returns
    -------
    SindyModel
        The last pass's model (``method`` as for the plain weak form).
    """
    if passes < 1:
        raise IdentificationError(f"passes = {passes!r} must be >= 1")
    kw = {k: v for k, v in kw.items() if k not in ("refine", "instruments", "_context")}
    t0 = time.perf_counter()
    model = fit(data, library, targets, **kw)
    op = WeakOperator(data.t, K=kw.get("K", 200), p=kw.get("p", 4), H_xt=kw.get("H_xt"),
                      seed=kw.get("seed", 0))
    drive = _instrument_drive(data) if instruments else None
    model = _refine_passes(model, data, library, targets, passes, drive, max_nrmse, op, kw)
    model.fit_time = time.perf_counter() - t0
    return model


def _instrument_drive(data: IdentData) -> IdentData:
    """The data with the noise-free stand-in of v_a (:func:`input_instruments`) for the free runs."""
    return IdentData(t=data.t, variables={**data.variables, **input_instruments(data)}, source=data.source)


def _refine_passes(model: SindyModel, data: IdentData,
                   library: CandidateLibrary | Mapping[str, CandidateLibrary], targets: Sequence[str],
                   passes: int, drive: IdentData | None, max_nrmse: float, op: WeakOperator,
                   kw: Mapping[str, Any]) -> SindyModel:
    """The refinement passes of :func:`fit_weak_refined` after the plain model ``model``.

    ``drive`` (:func:`_instrument_drive`, None without instruments) and ``op`` depend only on the
    data and the weak-form options, so a λ sweep builds them once.
    """
    dt = float(np.mean(np.diff(data.t)))
    held = sorted(set(kw.get("zoh_inputs", ZOH_INPUTS)) & set(data.variables))
    for _ in range(passes):
        rhs = _model_rhs(model)
        states = [s for s in rhs(_first_rows(data.variables)) if s in data.variables]
        with np.errstate(all="ignore"):
            curv = curvature(data.variables, rhs, states, held, dt)
        sim, sim_curv = None, {}
        if drive is not None:
            # drive the free run with the noise-free stand-in of v_a: the measured v_a's noise,
            # filtered by the model, would otherwise reach the instruments of the same subdomain
            fr = free_run(model, drive, substeps=1)
            good = {k: v for k, v in fr.states.items() if fr.nrmse[k] < max_nrmse}
            if good:
                sim = dict(drive.variables)
                sim.update(good)
                with np.errstate(all="ignore"):
                    sim_curv = curvature(sim, rhs, states, held, dt)
        ctx = WeakContext(operator=op, held=held, curvature=curv, simulated=sim, simulated_curvature=sim_curv)
        model = fit(data, library, targets, _context=ctx, **kw)
    return model


def _first_rows(variables: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: np.asarray(v, dtype=float)[:2] for k, v in variables.items()}


def weak_iv_options(duration: float) -> dict[str, Any]:
    """:func:`fit` keywords of the weak-iv estimator (:data:`WEAK_IV`) for a record of ``duration`` s.

    The subdomain half-width is :data:`WEAK_IV` ``H_xt``, at most a fifth of the record; the number
    of test functions K = coverage·duration/(2·H_xt), at least 50. λ is not included (``threshold``
    of :data:`WEAK_IV` is the benchmark's fixed value).

    Returns
    -------
    dict
        ``method="weak"``, ``K``, ``H_xt``, ``refine``, ``alpha``.
    """
    h = min(WEAK_IV["H_xt"], 0.2 * duration)
    k = max(50, int(WEAK_IV["coverage"] * duration / (2 * h)))
    return {"method": "weak", "K": k, "H_xt": h, "refine": int(WEAK_IV["refine"]), "alpha": WEAK_IV["alpha"]}


def fit(
    data: IdentData,
    library: CandidateLibrary | Mapping[str, CandidateLibrary],
    targets: Sequence[str] = ("theta_dot", "i_a", "omega_rotor"),
    threshold: float = 0.05,
    method: str = "sindy",
    base: Rig | BaseModel | None = None,
    K: int = 200,
    p: int = 4,
    H_xt: float | None = None,
    n_models: int = 40,
    subset_fraction: float = 0.6,
    alpha: float = 1e-10,
    seed: int = 0,
    exclude_input_steps: int = 0,
    zoh_inputs: Sequence[str] = ZOH_INPUTS,
    refine: int = 0,
    instruments: bool = True,
    output_error: Sequence[str] = (),
    _context: WeakContext | None = None,
) -> SindyModel:
    """Identify a sparse model (see the module docstring for the methods).

    Runs as ``regression_problem(data, library, targets, ...).solve(threshold)``: build the
    λ-independent regression, then the sparse regression for λ (several λ on the same data:
    build the problem once, see :func:`regression_problem` and :func:`sweep_threshold`).

    Parameters
    ----------
    data : IdentData
        Training data (strong form needs ``data.derivatives`` for the targets).
    library : CandidateLibrary or mapping target -> CandidateLibrary
        One library for all equations (as in the thesis), or one per target (physics-structured,
        e.g. :func:`aeropend_ident.sindy.libraries.structured_library`); then each equation is fitted
        on its own library and the model's columns are the union.
    targets : sequence of str
        Target states (``"theta"``, ``"theta_dot"``, ``"i_a"``, ``"omega_rotor"``).
    threshold : float
        λ (dimensionless, unit-RMS scale).
    method : {"sindy", "ensemble", "weak"}
        Ensemble bagging uses the strong form.
    base : Rig or callable, optional
        Approximate model for discrepancy SINDy (strong or weak form): a rig (its
        :class:`~aeropend_sim.model.PlantModel`) or ``f(data) -> {target: ndarray (N,)}``.
    K, p, H_xt : int, int, float
        Weak form: number of subdomains, test-function degree, subdomain half-width [s].
    n_models, subset_fraction : int, float
        Ensemble: number of bagged models and the row fraction each sees.
    exclude_input_steps : int
        Strong form: leave out the rows within ± this many samples of a duty-cycle step.
        Estimated derivatives are wrong across the kinks a zero-order-hold input puts into
        di_a/dt (at 490 Hz, central differences of a noise-free thesis_sim i_a are 16 % off in
        RMS; 0.1 % with ±3 samples left out). Needs ``duty`` in the data.
    zoh_inputs : sequence of str
        Weak form: variables held constant over each sample period (zero-order hold; default
        the duty cycle and v_a, which the H-bridge applies from τ_k on [t_k, t_k+1)). Library
        columns reading them are integrated exactly for the held input (see
        :func:`weak_matrices`); ``()`` treats every column as linear between samples
        (pysindy's plain quadrature).
    refine : int
        Weak form: number of model-based refinement passes (errors-in-variables and
        intra-sample curvature, see :func:`fit_weak_refined`); 0 = the plain weak form.
    instruments : bool
        With ``refine``: regress on the library projected onto instruments built from a free
        run of the previous pass's model (instrumental variables, consistent when the
        regressors are noisy); ``False`` keeps only the curvature correction.
    output_error : sequence of str
        Equations whose non-zero coefficients are then re-estimated by output-error
        (simulation-error) minimisation with the selected structure kept
        (:func:`aeropend_ident.sindy.output_error.refine_output_error`, default options), e.g.
        ``("i_a", "omega_rotor")``; ``()`` (default) skips it.

    Raises
    ------
    IdentificationError
        Unknown method, a target or library variable the data lacks (named), too few samples
        for the library, or a rank-deficient (unexcited) library.
    """
    return regression_problem(
        data, library, targets, method=method, base=base, K=K, p=p, H_xt=H_xt, n_models=n_models,
        subset_fraction=subset_fraction, alpha=alpha, seed=seed, exclude_input_steps=exclude_input_steps,
        zoh_inputs=zoh_inputs, refine=refine, instruments=instruments, output_error=output_error,
        _context=_context,
    ).solve(threshold)


#: Keywords of :func:`fit` that shape the plain (pass-0) regression, λ excluded.
_PLAIN_KEYS = ("method", "base", "K", "p", "H_xt", "n_models", "subset_fraction", "alpha", "seed",
               "exclude_input_steps", "zoh_inputs")


@dataclass
class _Regression:
    """The λ-independent regression of one library: Θ (weak or strong rows), left side, checks."""

    library: CandidateLibrary
    targets: list[str]
    theta: np.ndarray
    y: np.ndarray
    zero_below: np.ndarray | None
    condition_number: float
    name: str
    base: Rig | BaseModel | None
    build_time: float


@dataclass(frozen=True)
class _WeakUnion:
    """Weak-form integrals of the union of several equations' libraries, computed in one pass.

    Each column's integral against the test functions does not depend on the other columns, so
    per-equation libraries (the physics-structured default) can slice theirs from one
    :func:`weak_matrices` call over the union instead of one call each: pysindy's per-subdomain
    loop, not the column count, is its cost.
    """

    index: dict[str, int]
    theta_w: np.ndarray
    targets: list[str]
    lhs_w: np.ndarray

    def covers(self, library: CandidateLibrary, targets: Sequence[str]) -> bool:
        return set(library.names) <= self.index.keys() and set(targets) <= set(self.targets)

    def columns(self, library: CandidateLibrary, targets: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        return (self.theta_w[:, [self.index[n] for n in library.names]],
                self.lhs_w[:, [self.targets.index(tg) for tg in targets]])


def _weak_union(data: IdentData, libraries: Sequence[CandidateLibrary], targets: list[str],
                build: dict[str, Any]) -> None:
    """Store the union's weak-form integrals in ``build["cache"]["union"]`` (see :class:`_WeakUnion`).

    Nothing is stored when the union cannot be evaluated on this data (a missing channel, say):
    the per-equation regressions then compute their own and raise or drop as they would.
    """
    union = libraries[0]
    for lib in libraries[1:]:
        union = union + lib
    held = sorted(set(build["zoh_inputs"]) & set(data.variables))
    try:
        cols = union.evaluate(data.variables)
        mask = np.array([bool(set(c.variables) & set(held)) for c in union.candidates])
        nxt = union.evaluate(_advance_states(data, held).variables) if mask.any() else None
        _check_half_width(data.t, build["H_xt"])
    except (LibraryError, IdentificationError, KeyError):
        return
    cache = build["cache"]
    if "weak" not in cache:
        cache["weak"] = _WeakSetup(data.t, build["K"], build["p"], build["H_xt"], build["seed"])
    mat, lhs_w = weak_matrices(data, cols, targets, K=build["K"], p=build["p"], H_xt=build["H_xt"],
                               seed=build["seed"], columns_next=nxt, zoh=mask, _setup=cache["weak"])
    cache["union"] = _WeakUnion({n: j for j, n in enumerate(union.names)}, mat, list(targets), lhs_w)


def _build_regression(
    data: IdentData, library: CandidateLibrary, targets: list[str], method: str, base: Rig | BaseModel | None,
    K: int, p: int, H_xt: float | None, seed: int, exclude_input_steps: int, zoh_inputs: Sequence[str],
    context: WeakContext | None, cache: dict[str, Any],
) -> _Regression:
    """Library evaluation, weak-form integrals (or strong-form rows), residual of the base model and
    the rank check of :func:`fit` for one library; ``cache`` shares the weak-form setup."""
    check_targets(data, targets, library, need_derivatives=method != "weak")
    t0 = time.perf_counter()
    try:
        theta = library.evaluate(data.variables)
    except LibraryError as exc:
        raise IdentificationError(f"{data.source}: {exc}") from exc
    fb = base_derivatives(base, data, targets) if base is not None else None
    if method == "weak" and context is not None:
        theta_r, y, y_ref = context.matrices(data, library, targets, base)
    elif method == "weak":
        _check_half_width(data.t, H_xt)
        if "weak" not in cache:
            cache["weak"] = _WeakSetup(data.t, K, p, H_xt, seed)
        union = cache.get("union")
        if fb is None and union is not None and union.covers(library, targets):
            mat, lhs_w = union.columns(library, targets)  # no columns to evaluate or integrate here
        else:
            extra = (np.column_stack([fb[tg] for tg in targets]) if fb is not None
                     else np.empty((len(data), 0)))
            held = sorted(set(zoh_inputs) & set(data.variables))
            mask = np.array([bool(set(c.variables) & set(held)) for c in library.candidates]
                            + [bool(held)] * extra.shape[1])
            nxt = None
            if mask.any():
                shifted = _advance_states(data, held)
                nxt = library.evaluate(shifted.variables)
                if base is not None:
                    fb_next = base_derivatives(base, shifted, targets)
                    nxt = np.hstack([nxt, np.column_stack([fb_next[tg] for tg in targets])])
            mat, lhs_w = weak_matrices(data, np.hstack([theta, extra]), targets, K=K, p=p, H_xt=H_xt,
                                       seed=seed, columns_next=nxt, zoh=mask, _setup=cache["weak"])
        theta_r, y = mat[:, : theta.shape[1]], lhs_w
        y_ref = lhs_w
        if fb is not None:
            y = lhs_w - mat[:, theta.shape[1]:]
    else:
        theta_r = theta
        y = y_ref = np.column_stack([data.derivatives[tg] for tg in targets])
        if fb is not None:
            y = y - np.column_stack([fb[tg] for tg in targets])
        if exclude_input_steps > 0:
            keep = input_step_mask(data, exclude_input_steps)
            theta_r, y, y_ref = theta_r[keep], y[keep], y_ref[keep]
    if theta_r.shape[0] <= theta_r.shape[1]:
        raise IdentificationError(
            f"{data.source}: {theta_r.shape[0]} regression rows for {theta_r.shape[1]} candidates; "
            "record longer data (or raise K for the weak form)"
        )
    cond = _normalised_cond(theta_r)
    if not math.isfinite(cond) or cond > 1e13:
        raise IdentificationError(
            f"{data.source}: the library is rank deficient on this data (condition number {cond:.3g}): "
            "the data does not excite it; see libraries.collinearity_report"
        )
    theta_r, y = np.array(theta_r, dtype=float), np.array(y, dtype=float)
    theta_r.setflags(write=False)  # shared by every λ of a sweep
    y.setflags(write=False)
    return _Regression(
        library=library, targets=list(targets), theta=theta_r, y=y,
        zero_below=1e-9 * column_rms(y_ref) if fb is not None else None, condition_number=cond,
        name=method if base is None else f"discrepancy-{method}", base=base,
        build_time=time.perf_counter() - t0,
    )


def _solve_regression(reg: _Regression, threshold: float, options: Mapping[str, Any]) -> SindyModel:
    t0 = time.perf_counter()
    coef, std, incl = sparse_regression(
        reg.theta, reg.y, threshold, method=options["method"], alpha=options["alpha"],
        n_models=options["n_models"], subset_fraction=options["subset_fraction"], seed=options["seed"],
        zero_below=reg.zero_below,
    )
    return SindyModel(
        method=reg.name, targets=list(reg.targets), feature_names=reg.library.names, coef=coef,
        threshold=threshold, library=reg.library, coef_std=std, inclusion=incl,
        condition_number=reg.condition_number, fit_time=reg.build_time + time.perf_counter() - t0,
        base=reg.base,
    )


def _merge_models(parts: Sequence[SindyModel], targets: list[str]) -> SindyModel:
    """One equation per model (per-target libraries); the merged model's columns are the union."""
    union = parts[0].library
    for m in parts[1:]:
        union = union + m.library
    names = union.names
    coef = np.zeros((len(targets), len(names)))
    std = np.zeros_like(coef) if parts[0].coef_std is not None else None
    incl = np.zeros_like(coef) if parts[0].inclusion is not None else None
    for i, m in enumerate(parts):
        cols = [names.index(n) for n in m.feature_names]
        coef[i, cols] = m.coef[0]
        if std is not None and m.coef_std is not None:
            std[i, cols] = m.coef_std[0]
        if incl is not None and m.inclusion is not None:
            incl[i, cols] = m.inclusion[0]
    return SindyModel(
        method=parts[0].method, targets=targets, feature_names=names, coef=coef, threshold=parts[0].threshold,
        library=union, coef_std=std, inclusion=incl,
        condition_number=max(m.condition_number for m in parts), fit_time=sum(m.fit_time for m in parts),
        base=parts[0].base,
    )


@dataclass
class RegressionProblem:
    """What :func:`fit` computes before λ enters, built once by :func:`regression_problem`.

    The library evaluation, the weak-form test-function integrals (one pysindy ``WeakPDELibrary``
    setup shared by every equation), the strong-form rows, the base model's residual, the rank
    check and, with ``refine``, the refinement's quadrature operator and instrument drive do not
    depend on λ. :meth:`solve` runs the sparse regression (and the λ-dependent refinement passes
    and output-error step) for one λ and returns exactly what ``fit(..., threshold=λ)`` returns.

    Attributes
    ----------
    data : IdentData
    library : CandidateLibrary or dict target -> CandidateLibrary
        Per-equation libraries of the kept equations only.
    targets : list of str
        Equations kept.
    options : dict
        The :func:`fit` keywords other than λ.
    dropped : dict target -> str
        Equations left out with ``drop_unidentifiable`` and why (per-equation libraries only).
    """

    data: IdentData
    library: CandidateLibrary | dict[str, CandidateLibrary]
    targets: list[str]
    options: dict[str, Any]
    dropped: dict[str, str] = field(default_factory=dict)
    _parts: list[_Regression] = field(default_factory=list, repr=False)
    _per_target: bool = False
    _operator: WeakOperator | None = field(default=None, repr=False)
    _drive: IdentData | None = field(default=None, repr=False)

    def solve(self, threshold: float) -> SindyModel:
        """The model :func:`fit` identifies with this λ (dimensionless, unit-RMS scale).

        Raises
        ------
        IdentificationError
            If ``threshold`` is negative (or from the refinement / output-error steps).
        """
        o = self.options
        t0 = time.perf_counter()
        models = [_solve_regression(part, threshold, o) for part in self._parts]
        model = _merge_models(models, list(self.targets)) if self._per_target else models[0]
        if o["refine"] > 0:
            assert self._operator is not None
            kw = {"threshold": threshold, **{k: o[k] for k in _PLAIN_KEYS}}
            model = _refine_passes(model, self.data, self.library, self.targets, o["refine"], self._drive,
                                   math.inf, self._operator, kw)
            model.fit_time = sum(part.build_time for part in self._parts) + time.perf_counter() - t0
        if o["output_error"]:
            model = refine_output_error(model, self.data, targets=o["output_error"],
                                        zoh_inputs=o["zoh_inputs"])
        return model


def regression_problem(
    data: IdentData,
    library: CandidateLibrary | Mapping[str, CandidateLibrary],
    targets: Sequence[str] = ("theta_dot", "i_a", "omega_rotor"),
    method: str = "sindy",
    base: Rig | BaseModel | None = None,
    K: int = 200,
    p: int = 4,
    H_xt: float | None = None,
    n_models: int = 40,
    subset_fraction: float = 0.6,
    alpha: float = 1e-10,
    seed: int = 0,
    exclude_input_steps: int = 0,
    zoh_inputs: Sequence[str] = ZOH_INPUTS,
    refine: int = 0,
    instruments: bool = True,
    output_error: Sequence[str] = (),
    drop_unidentifiable: bool = False,
    _context: WeakContext | None = None,
) -> RegressionProblem:
    """Build the λ-independent part of :func:`fit` once; ``.solve(λ)`` per threshold.

    ``regression_problem(data, library, targets, **kw).solve(λ)`` is ``fit(data, library, targets,
    threshold=λ, **kw)`` (it is how :func:`fit` runs); :func:`sweep_threshold` builds one problem
    and solves it for every λ instead of rebuilding the library and weak-form matrices per λ.

    Parameters
    ----------
    data, library, targets, method, base, K, p, H_xt, n_models, subset_fraction, alpha, seed,
    exclude_input_steps, zoh_inputs, refine, instruments, output_error
        As for :func:`fit`.
    drop_unidentifiable : bool
        With per-equation libraries: an equation whose regression cannot be set up on this data
        (rank-deficient library, missing channel, too few rows) is left out and listed in
        ``dropped`` instead of raising; raises only if no equation is left.

    Raises
    ------
    IdentificationError
        As :func:`fit` (except a negative λ, which :meth:`RegressionProblem.solve` refuses).
    NoEquationError
        With ``drop_unidentifiable``, when every equation is left out (reasons in ``dropped``).
    """
    if method not in METHODS:
        raise IdentificationError(f"method = {method!r}; expected one of {METHODS}")
    targets = list(targets)
    if refine > 0 and method != "weak":
        raise IdentificationError(f"refine = {refine!r} needs method='weak', got method={method!r}")
    options: dict[str, Any] = dict(
        method=method, base=base, K=K, p=p, H_xt=H_xt, n_models=n_models, subset_fraction=subset_fraction,
        alpha=alpha, seed=seed, exclude_input_steps=exclude_input_steps, zoh_inputs=zoh_inputs, refine=refine,
        instruments=instruments, output_error=tuple(output_error),
    )
    build: dict[str, Any] = dict(method=method, base=base, K=K, p=p, H_xt=H_xt, seed=seed,
                                 exclude_input_steps=exclude_input_steps, zoh_inputs=zoh_inputs,
                                 context=_context, cache={})
    dropped: dict[str, str] = {}
    if isinstance(library, Mapping):
        missing = [tg for tg in targets if tg not in library]
        if missing:
            raise IdentificationError(
                f"no library for target(s) {missing}; libraries given for {sorted(library)}"
            )
        if method == "weak" and _context is None and base is None and len(targets) > 1:
            _weak_union(data, [library[tg] for tg in targets], targets, build)
        parts = []
        for tg in targets:
            try:
                parts.append(_build_regression(data, library[tg], [tg], **build))
            except IdentificationError as exc:
                if not drop_unidentifiable:
                    raise
                dropped[tg] = str(exc)
        if not parts:
            raise NoEquationError(f"{data.source}: no equation can be identified: {dropped}", dropped)
        targets = [part.targets[0] for part in parts]
        lib: CandidateLibrary | dict[str, CandidateLibrary] = {tg: library[tg] for tg in targets}
    else:
        parts = [_build_regression(data, library, targets, **build)]
        lib = library
    op, drive = None, None
    if refine > 0:
        shared = build["cache"].get("weak")  # the same grid, K, p, H_xt and seed: reuse its subdomains
        op = WeakOperator(data.t, K=K, p=p, H_xt=H_xt, seed=seed,
                          lib=shared.lib if shared is not None else None)
        drive = _instrument_drive(data) if instruments else None
    return RegressionProblem(data=data, library=lib, targets=targets, options=options, dropped=dropped,
                             _parts=parts, _per_target=isinstance(library, Mapping), _operator=op,
                             _drive=drive)


