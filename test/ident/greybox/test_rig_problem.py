"""rig fit's covariance (``aeropend_ident.greybox.rig_problem.covariance``): never a negative variance.

rig check crashed with ``math domain error`` on YangZhu's Quanser AERO step (a fitted rig whose
Jacobian is ill-conditioned): ``pinv(JᵀJ)`` squares J's condition number and returned a negative
diagonal entry; the covariance now comes from the SVD of J.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_ident.greybox.rig_problem import _last_finite, _reach, covariance
from aeropend_sim.model import ModelError, plant_model
from aeropend_sim.params import load_rig


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


def test_an_uninformed_direction_has_no_finite_variance():
    """Issue 60 item 2: a coordinate no row depends on was 'known exactly' (± 3.9e-24) by the
    pseudo-inverse; its variance is infinite, the others' unchanged."""
    from aeropend_ident.greybox.rig_problem import covariance

    rng = np.random.default_rng(0)
    J = np.column_stack([rng.normal(size=50), rng.normal(size=50), np.zeros(50)])
    cov = covariance(J, np.zeros(3, dtype=bool))
    assert np.isinf(cov[2, 2])
    assert cov[0, 0] == pytest.approx(np.linalg.inv(J[:, :2].T @ J[:, :2])[0, 0])


def test_a_blind_direction_leaves_the_well_determined_coordinates_finite():
    """jahoyosr's staircase: c/J (a column 1e-7 of the largest) is blind; the dead zone and the dry
    friction, with a round-off share in that direction, read '± inf' until the SVD was taken again
    without the blind coordinate. Their variances are now those with it held."""
    from aeropend_ident.greybox.rig_problem import covariance

    rng = np.random.default_rng(1)
    a, b = rng.normal(size=200) * 700.0, rng.normal(size=200) * 9000.0
    weak = 1e-5 * a + 1e-9 * rng.normal(size=200)  # nearly zero, and nearly along a
    J = np.column_stack([a, b, weak])
    cov = covariance(J, np.zeros(3, dtype=bool))
    assert np.isinf(cov[2, 2])
    held = np.linalg.inv(J[:, :2].T @ J[:, :2])
    assert cov[0, 0] == pytest.approx(held[0, 0]) and cov[1, 1] == pytest.approx(held[1, 1])
    assert np.isnan(cov[0, 2]) and np.isnan(cov[2, 1])


@pytest.mark.slow
def test_the_sandwich_covariance_widens_with_correlated_residuals():
    """A line fitted to 20 clusters of 50 points each sharing one offset (a misfit the white-noise
    weights do not know of): the Jacobian's σ of the intercept is ~0.1/√1000, the truth ~1/√20; the
    cluster-robust estimate recovers the latter within a factor 1.5 over 200 draws (its RMS)."""
    from aeropend_ident.greybox.rig_problem import covariance, robust_covariance

    rng = np.random.default_rng(1)
    x = np.tile(np.linspace(-1.0, 1.0, 50), 20)
    J = np.column_stack([np.ones_like(x), x])
    naive, robust, est = [], [], []
    for _ in range(200):
        y = np.repeat(rng.normal(0.0, 1.0, 20), 50) + rng.normal(0.0, 0.1, x.size)
        coef, *_ = np.linalg.lstsq(J, y, rcond=None)
        r = y - J @ coef
        cov = covariance(J / 0.1, np.zeros(2, dtype=bool))   # weighted by the white noise σ 0.1
        rob = robust_covariance(J / 0.1, r / 0.1, [50] * 20, cov)
        naive.append(math.sqrt(cov[0, 0]))
        robust.append(math.sqrt(rob[0, 0]))
        est.append(coef[0])
    truth = float(np.std(est))
    assert truth == pytest.approx(1.0 / math.sqrt(20.0), rel=0.2)
    assert np.median(naive) < 0.05 * truth
    assert math.sqrt(np.mean(np.square(robust))) == pytest.approx(truth, rel=0.5)


class _Toy:
    """Blocks of a toy problem: block i's residual is (z - c_i) weighted, no replay."""

    def __init__(self, centres: np.ndarray) -> None:
        self.centres = centres
        self.nuisance: list = []


def _toy_problem(n_blocks: int = 6, k: int = 3):
    from aeropend_ident.greybox.parameters import ParameterSpec
    from aeropend_ident.greybox.rig_problem import Problem

    rng = np.random.default_rng(3)
    centres = rng.uniform(2.0, 8.0, size=(n_blocks, k))
    problem = object.__new__(Problem)
    problem.specs = [ParameterSpec(f"p.{j}", "1", 5.0, 0.0, 10.0, False, 1.0) for j in range(k)]
    problem.blocks = [_Toy(c) for c in centres]
    problem.fixed = {}
    problem._cache = None
    problem._rig_or_none = lambda z: np.asarray(z, dtype=float)
    problem.nuisance_values = lambda z: [[] for _ in centres]
    # a residual that grows away from the block's centre (sin: several valleys for the screen)
    problem._weighted = lambda b, rig, v: np.concatenate([rig[:k] - b.centres, np.sin(rig[:k] * b.centres)])
    problem.block_residuals = lambda z, only=None: [problem._weighted(b, np.asarray(z), [])
                                                    for b in problem.blocks]
    return problem


def test_cost_unless_above_is_the_cost_or_inf():
    """The screen's pruned cost: the cost itself to the last bit when it stays below the limit,
    inf as soon as the blocks so far exceed it."""
    problem = _toy_problem()
    z = np.array([4.0, 6.0, 3.0])
    full = problem.cost(z)
    assert problem.cost_unless_above(z, full * 1.5) == full
    assert problem.cost_unless_above(z, math.inf) == full
    assert problem.cost_unless_above(z, 0.5 * full) == math.inf


def test_screen_open_keeps_the_same_start_as_every_cost_in_full(monkeypatch):
    """Pruning the screen's points that cannot be among its best changes nothing it returns."""
    problem = _toy_problem()
    z0 = np.array([5.0, 5.0, 5.0])
    pruned = problem.screen_open(z0, [], n=32)
    monkeypatch.setattr(type(problem), "cost_unless_above", lambda self, z, limit: self.cost(z))
    full = problem.screen_open(z0, [], n=32)
    np.testing.assert_array_equal(pruned, full)
    assert not np.array_equal(pruned, z0)


def test_screen_keeps_its_best_points_exactly():
    """The screen's ``keep`` best points and their costs are those of every cost in full; only the
    others may be inf."""
    problem = _toy_problem()
    z0 = np.array([5.0, 5.0, 5.0])
    full = problem.screen(z0, ["p.0", "p.1", "p.2"], n=32)
    pruned = problem.screen(z0, ["p.0", "p.1", "p.2"], n=32, keep=3)
    for (c1, z1), (c2, z2) in zip(full[:3], pruned[:3], strict=True):
        assert c1 == c2
        np.testing.assert_array_equal(z1, z2)
    assert any(math.isinf(c) for c, _ in pruned)  # the toy's worse points were not evaluated in full


def test_the_reach_by_brents_method_is_the_last_angle_the_bisection_finds():
    """A balance table's top angle (the actuator's reach, where the holding duty crosses 1) found by
    Brent's method on the unclipped duty is the last finite angle of the 40-step bisection."""
    m = plant_model(load_rig("thesis_sim"))  # its reach is below π/2

    def tau(theta: float) -> float:
        try:
            return float(m.equilibrium(theta)[1])
        except ModelError:
            return math.inf

    brent, bisected = _reach(m, tau), _last_finite(tau)
    assert 0.7 < brent < 0.8 and math.isfinite(tau(brent))
    assert abs(brent - bisected) < 1e-11
    assert m.holding_duty(brent) == pytest.approx(1.0, abs=1e-10)
