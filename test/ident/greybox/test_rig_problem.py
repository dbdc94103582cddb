"""rig fit's covariance (``aeropend_ident.greybox.rig_problem.covariance``): never a negative variance.

rig check crashed with ``math domain error`` on YangZhu's Quanser AERO step (a fitted rig whose
Jacobian is ill-conditioned): ``pinv(JᵀJ)`` squares J's condition number and returned a negative
diagonal entry; the covariance now comes from the SVD of J.
"""

from __future__ import annotations

import numpy as np

from aeropend_ident.greybox.rig_problem import covariance


def _ill_conditioned() -> np.ndarray:
    """A Jacobian with two nearly collinear, very differently scaled columns on which pinv(JᵀJ) has a
    negative diagonal entry (searched from a fixed seed)."""
    rng = np.random.default_rng(0)
    for _ in range(2000):
        n, m = int(rng.integers(3, 8)), 200
        J = rng.normal(size=(m, n))
        J[:, 1] = J[:, 0] * (1 + 10 ** rng.uniform(-9, -5)) + 10 ** rng.uniform(-9, -6) * rng.normal(size=m)
        J *= 10 ** rng.uniform(-3, 6, size=n)
        free = np.flatnonzero(np.ones(n, dtype=bool))  # as covariance() indexed its free columns
        if np.any(np.diag(np.linalg.pinv(J[:, free].T @ J[:, free])) < 0.0):
            return J
    raise AssertionError("no ill-conditioned example found")


def test_variances_of_an_ill_conditioned_jacobian_are_not_negative():
    J = _ill_conditioned()
    cov = covariance(J, np.zeros(J.shape[1], dtype=bool))
    assert np.all(np.diag(cov) >= 0.0)


def test_well_conditioned_covariance_is_the_inverse_and_pinned_are_nan():
    rng = np.random.default_rng(1)
    J = rng.normal(size=(100, 4))
    pinned = np.array([False, True, False, False])
    cov = covariance(J, pinned)
    free = [0, 2, 3]
    np.testing.assert_allclose(cov[np.ix_(free, free)], np.linalg.inv(J[:, free].T @ J[:, free]), rtol=1e-10)
    assert np.all(np.isnan(cov[1])) and np.all(np.isnan(cov[:, 1]))
