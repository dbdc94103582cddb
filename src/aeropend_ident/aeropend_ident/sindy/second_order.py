"""The pendulum equation from the recorded angle alone: the second-order weak form.

No aeropendulum measures θ̇ (the thesis rig, AeroShield and the third-party rigs read θ from an
encoder or potentiometer; ``csv_import`` and the bridge deliver θ, i_a, v_a, ω₁). Any estimate
of θ̇ from noisy θ puts noise into a regressor and its bias into the damping and thrust
coefficients (errors in variables): with a Savitzky-Golay θ̇, the weak form put K_q 10.6 % low
at 30 dB and 22-27 % low at 20 dB on the independent truth plant. Here the pendulum equation

    θ̈ = ξ_1·θ̇ + ξ_2·sin θ + ξ_3·ω₁² (+ ξ_4·sgn θ̇)

is integrated against test functions φ_k with both derivatives moved onto φ_k by parts
(:class:`aeropend_ident.sindy.weak_quadrature.SecondOrderTestFunctions`):

    ∫φ_k''·θ dt = ξ_1·(−∫φ_k'·θ dt) + ξ_2·∫φ_k·sin θ dt + ξ_3·∫φ_k·ω₁² dt (+ ...),

so θ enters only through integrals; ω₁² comes from the measured rotor speed with the noise-free
regressor of :func:`aeropend_ident.sindy.libraries.lagged_square`, sin θ from the measured angle (its
noise bias, a factor exp(−σ²/2), is 0.04 % at 20 dB). A friction candidate sgn θ̇ can only be
read from an estimated θ̇ (Savitzky-Golay, cross-validated window); its noise is bounded by the
sign.

λ is chosen by BIC on the weak-form residual of a validation tail of the training data; the
selected terms are then pruned backwards by the **free-run** error of θ on the same tail: a term
whose removal changes the validation free-run NRMSE of θ by less than ``prune_tolerance``
(default 1 %) is removed (the data do not support it). The final coefficients are the
least-squares fit of the kept terms on the whole training data.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeropend_ident.errors import IdentificationError, LibraryError
from aeropend_ident.sindy.core import sparse_regression
from aeropend_ident.sindy.libraries import CandidateLibrary, pendulum_library
from aeropend_ident.sindy.model import IdentData, SindyModel, free_run
from aeropend_ident.sindy.preprocess import differentiate
from aeropend_ident.sindy.sweep import SweepPoint, select_threshold
from aeropend_ident.sindy.weak_quadrature import SecondOrderTestFunctions

#: λ grid of the pendulum equation (dimensionless, unit-RMS scale as in :mod:`aeropend_ident.sindy.core`).
LAMBDAS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2)
#: Subdomain half-width [s]: 0.4 s subdomains, about 0.7 of the period 2π/ω_n of a pendulum with
#: mgd/J ≈ 130 s⁻² (ω_n ≈ 11.5 rad/s). Measured on the independent plant at 20 dB (3 noise seeds):
#: K_q bias −1.2 to −3.0 % at 0.2 s, −1.4 to −2.6 % at 0.1 s, −4.0 to −5.0 % at 0.4 s (plain ω₁²).
H_XT = 0.2
#: Test functions cover the record this many times.
COVERAGE = 3.0
#: Test-function degree.
P = 4
#: Relative change of the validation free-run NRMSE of θ below which a term is pruned.
PRUNE_TOLERANCE = 0.01


@dataclass
class PendulumFit:
    """The identified pendulum equation and how it was chosen.

    Attributes
    ----------
    model : SindyModel
        Target ``theta_dot`` (θ̈); method ``"weak2"``.
    threshold : float
        λ chosen by BIC.
    sweep : list of dict
        Per λ: ``threshold``, ``n_terms``, ``bic`` (validation weak residual).
    pruning : list of dict
        Per backward step: ``removed`` (term or None), ``nrmse_before``, ``nrmse_after`` (validation
        free run of θ) and the change of every candidate removal tried.
    H_xt : float
        Subdomain half-width [s].
    K : int
        Test functions on the whole training data.
    """

    model: SindyModel
    threshold: float
    sweep: list[dict[str, Any]] = field(default_factory=list)
    pruning: list[dict[str, Any]] = field(default_factory=list)
    H_xt: float = H_XT
    K: int = 0


def _test_functions(data: IdentData, H_xt: float, p: int, coverage: float, seed: int
                    ) -> SecondOrderTestFunctions:
    duration = float(data.t[-1] - data.t[0])
    h = min(H_xt, 0.2 * duration)
    k = max(50, int(coverage * duration / (2.0 * h)))
    try:
        return SecondOrderTestFunctions(data.t, K=k, p=p, H_xt=h, seed=seed)
    except ValueError as exc:
        raise IdentificationError(f"{data.source}: {exc}") from exc


def pendulum_regression(data: IdentData, library: CandidateLibrary, tf: SecondOrderTestFunctions
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Second-order weak-form regression of θ̈ on ``library``.

    The candidate named ``θ̇`` is integrated by parts (−∫φ'·θ); every other candidate is
    ∫φ·F with F's noise-free regressor (``evaluate(regressor=True)``).

    Returns
    -------
    theta_w : ndarray, shape (K, M)
    y : ndarray, shape (K,)
        ∫φ''·θ dt.

    Raises
    ------
    IdentificationError
        If θ or a library variable is missing.
    """
    v = data.variables
    if "theta" not in v:
        raise IdentificationError(f"{data.source}: the pendulum equation needs the angle θ")
    other = CandidateLibrary(tuple(c for c in library.candidates if c.name != "θ̇")) \
        if any(c.name != "θ̇" for c in library.candidates) else None
    cols = {}
    if other is not None:
        try:
            f = other.evaluate(v, regressor=True)
        except LibraryError as exc:
            raise IdentificationError(f"{data.source}: {exc}") from exc
        integ = tf.integrate(f)
        cols = {c.name: integ[:, j] for j, c in enumerate(other.candidates)}
    if "θ̇" in library.names:
        cols["θ̇"] = tf.rate(v["theta"])
    theta_w = np.column_stack([cols[n] for n in library.names])
    return theta_w, tf.acceleration(v["theta"])


def _model(library: CandidateLibrary, coef: np.ndarray, threshold: float) -> SindyModel:
    return SindyModel(method="weak2", targets=["theta_dot"], feature_names=library.names,
                      coef=np.asarray(coef, dtype=float).reshape(1, -1), threshold=threshold, library=library)


def _lstsq_support(a: np.ndarray, y: np.ndarray, support: np.ndarray) -> np.ndarray:
    coef = np.zeros(a.shape[1])
    if support.any():
        scale = np.sqrt(np.mean(a[:, support] ** 2, axis=0))
        scale = np.where(scale > 0, scale, 1.0)
        coef[support] = np.linalg.lstsq(a[:, support] / scale, y, rcond=None)[0] / scale
    return coef


def with_rate_estimate(data: IdentData) -> IdentData:
    """``data`` with an estimated θ̇ (cross-validated Savitzky-Golay) when none is recorded.

    The estimate only serves the free run's initial state and a friction candidate sgn θ̇; the
    regression itself never reads it.
    """
    if "theta_dot" in data.variables:
        return data
    thd = differentiate(data.t, data.variables["theta"], method="savgol").dydt
    return IdentData(t=data.t, variables={**data.variables, "theta_dot": thd},
                     derivatives=dict(data.derivatives), source=data.source)


def _val_nrmse(library: CandidateLibrary, coef: np.ndarray, val: IdentData) -> float:
    fr = free_run(_model(library, coef, 0.0), val, substeps=1)
    return float(fr.nrmse["theta"])


def fit_pendulum(
    data: IdentData, library: CandidateLibrary | None = None, thresholds: Sequence[float] = LAMBDAS,
    H_xt: float = H_XT, p: int = P, coverage: float = COVERAGE, validation_fraction: float = 0.25,
    prune_tolerance: float = PRUNE_TOLERANCE, seed: int = 0,
) -> PendulumFit:
    """Identify θ̈ from θ (and ω₁) without a θ̇ channel (module docstring).

    Parameters
    ----------
    data : IdentData
        Training data: ``theta`` [rad], ``omega_rotor`` [rad/s] (and whatever else the library
        reads); ``theta_dot`` is optional (estimated when missing, see :func:`with_rate_estimate`).
    library : CandidateLibrary, optional
        Default :func:`aeropend_ident.sindy.libraries.pendulum_library` (θ̇, sin θ, ω₁², sgn θ̇).
    thresholds : sequence of float
        λ grid; the BIC of the validation tail's weak residual picks one (ties: larger λ).
    H_xt, p, coverage : float, int, float
        Subdomain half-width [s], test-function degree, coverage of the record.
    validation_fraction : float
        Share of ``data`` (its end) used as the validation tail for λ and pruning.
    prune_tolerance : float
        Relative change of the validation free-run NRMSE of θ below which a term is removed.

    Raises
    ------
    IdentificationError
        Missing θ / ω₁, too short a record, a rank-deficient library.
    """
    lib = library if library is not None else pendulum_library()
    if not 0.0 < validation_fraction < 1.0:
        raise IdentificationError(f"validation_fraction = {validation_fraction!r} must be in (0, 1)")
    data = with_rate_estimate(data)
    fit_part, val_part = data.split(1.0 - validation_fraction)
    tf_fit = _test_functions(fit_part, H_xt, p, coverage, seed)
    tf_val = _test_functions(val_part, H_xt, p, coverage, seed)
    a_fit, y_fit = pendulum_regression(fit_part, lib, tf_fit)
    a_val, y_val = pendulum_regression(val_part, lib, tf_val)
    s = np.linalg.svd(a_fit / np.sqrt(np.mean(a_fit**2, axis=0)).clip(1e-300), compute_uv=False)
    if s.min() <= s.max() * 1e-12:
        raise IdentificationError(f"{data.source}: the pendulum library {lib.names} is rank deficient on "
                                  "this data (is the rod excited?)")
    n = a_val.shape[0]
    points, coefs = [], {}
    for lam in thresholds:
        coef = sparse_regression(a_fit, y_fit[:, None], float(lam))[0][0]
        mse = float(np.mean((a_val @ coef - y_val) ** 2))
        k = int(np.count_nonzero(coef))
        bic = n * math.log(max(mse, 1e-300)) + k * math.log(n)
        points.append(SweepPoint(float(lam), {"theta_dot": k}, {"theta_dot": mse}, math.nan, bic))
        coefs[float(lam)] = coef
    sweep = [{"threshold": pt.threshold, "n_terms": pt.n_terms["theta_dot"], "bic": pt.bic} for pt in points]
    lam = select_threshold(points, "bic").threshold  # ties go to the sparser model
    coef = coefs[lam]
    support = coef != 0.0
    pruning = []
    base = _val_nrmse(lib, coef, val_part)
    while support.sum() > 1:
        tried = {}
        for j in np.flatnonzero(support):
            s2 = support.copy()
            s2[j] = False
            tried[lib.names[j]] = _val_nrmse(lib, _lstsq_support(a_fit, y_fit, s2), val_part)
        name, nr = min(tried.items(), key=lambda kv: kv[1])
        step = {"nrmse_before": base, "tried": tried, "removed": None, "nrmse_after": base}
        if math.isfinite(nr) and (not math.isfinite(base) or nr < base * (1.0 + prune_tolerance)):
            support[lib.names.index(name)] = False
            step.update(removed=name, nrmse_after=nr)
            base = nr
            pruning.append(step)
            continue
        pruning.append(step)
        break
    tf_all = _test_functions(data, H_xt, p, coverage, seed)
    a_all, y_all = pendulum_regression(data, lib, tf_all)
    final = _lstsq_support(a_all, y_all, support)
    return PendulumFit(model=_model(lib, final, lam), threshold=lam, sweep=sweep, pruning=pruning,
                       H_xt=min(H_xt, 0.2 * float(data.t[-1] - data.t[0])), K=tf_all.K)


def combine_models(models: Sequence[SindyModel], method: str) -> SindyModel:
    """One model from models with disjoint targets (library: the union of their columns)."""
    union = models[0].library
    for m in models[1:]:
        union = union + m.library
    names = union.names
    targets = [tg for m in models for tg in m.targets]
    if len(set(targets)) != len(targets):
        raise IdentificationError(f"models to combine share targets: {targets}")
    coef = np.zeros((len(targets), len(names)))
    std = np.full_like(coef, np.nan) if any(m.coef_std is not None for m in models) else None
    row = 0
    for m in models:
        cols = [names.index(nm) for nm in m.feature_names]
        for i in range(len(m.targets)):
            coef[row, cols] = m.coef[i]
            if std is not None and m.coef_std is not None:
                std[row, cols] = m.coef_std[i]
            row += 1
    return SindyModel(method=method, targets=targets, feature_names=names, coef=coef,
                      threshold=max(m.threshold for m in models), library=union, coef_std=std,
                      condition_number=max(m.condition_number for m in models),
                      fit_time=sum(m.fit_time for m in models))
