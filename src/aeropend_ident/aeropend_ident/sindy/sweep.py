"""The STLSQ threshold λ chosen on a sweep: one regression problem solved for every λ
(:func:`sweep_threshold`, :class:`SweepPoint`) and the λ chosen from the sweep
(:func:`select_threshold`).

The regression is :func:`aeropend_ident.sindy.core.regression_problem`. No rclpy import.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from aeropend_ident.errors import IdentificationError
from aeropend_ident.sindy.core import regression_problem
from aeropend_ident.sindy.libraries import CandidateLibrary
from aeropend_ident.sindy.model import (
    IdentData,
    SindyModel,
    input_step_mask,
)


# ---------------------------------------------------------------------------------- selection
@dataclass(frozen=True)
class SweepPoint:
    """One λ of a threshold sweep, scored on held-out data.

    Attributes
    ----------
    threshold : float
    n_terms : dict[str, int]
        Active terms per target.
    test_mse : dict[str, float]
        Held-out derivative MSE per target.
    aic, bic : float
        Sum over targets of N·ln(MSE/var) + 2k (AIC) or + k·ln N (BIC) on the held-out data
        (MSE normalised by the target's variance, floored at 1e-300).
    """

    threshold: float
    n_terms: dict[str, int]
    test_mse: dict[str, float]
    aic: float
    bic: float


def sweep_threshold(
    train: IdentData, test: IdentData, library: CandidateLibrary | Mapping[str, CandidateLibrary],
    thresholds: Sequence[float], targets: Sequence[str] = ("theta_dot", "i_a", "omega_rotor"), **fit_kw: Any,
) -> tuple[list[SweepPoint], dict[float, SindyModel]]:
    """Fit for each λ and score on held-out data (the Pareto front: terms vs test error).

    ``fit_kw`` go to :func:`aeropend_ident.sindy.core.fit`; its ``exclude_input_steps`` also applies
    to the scoring. The λ-independent part (library, weak-form matrices, rank check) is built once
    (:func:`aeropend_ident.sindy.core.regression_problem`); each model equals ``fit(train, library,
    targets, threshold=λ, **fit_kw)``.
    """
    points, models = [], {}
    excl = int(fit_kw.get("exclude_input_steps", 0))
    n = int(input_step_mask(test, excl).sum()) if excl > 0 else len(test)
    problem = regression_problem(train, library, targets, **fit_kw)
    for lam in thresholds:
        m = problem.solve(float(lam))
        mse = m.test_mse(test, exclude_input_steps=excl)
        k = {tg: int(m.support()[i].sum()) for i, tg in enumerate(m.targets)}
        aic = bic = 0.0
        for tg in m.targets:
            var = float(np.var(test.derivatives[tg])) or 1.0
            ll = n * math.log(max(mse[tg] / var, 1e-300))
            aic += ll + 2 * k[tg]
            bic += ll + k[tg] * math.log(n)
        points.append(SweepPoint(float(lam), k, mse, aic, bic))
        models[float(lam)] = m
    return points, models


def select_threshold(points: Sequence[SweepPoint], criterion: str = "bic") -> SweepPoint:
    """Pick the sweep point with the lowest ``"bic"``, ``"aic"`` or total relative ``"test"`` MSE.

    Ties (within 1e-9 relative) go to the sparser model (larger λ).
    """
    if criterion not in ("bic", "aic", "test"):
        raise IdentificationError(f"criterion = {criterion!r}; expected 'bic', 'aic' or 'test'")
    if not points:
        raise IdentificationError("empty sweep")

    def score(pt: SweepPoint) -> float:
        if criterion == "test":
            return float(sum(pt.test_mse.values()))
        return pt.bic if criterion == "bic" else pt.aic

    best = min(score(pt) for pt in points)
    ok = [pt for pt in points if score(pt) <= best + 1e-9 * abs(best)]
    return max(ok, key=lambda pt: pt.threshold)
