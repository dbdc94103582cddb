"""The λ sweep builds the regression once and solves it per λ: same models as independent fits.

``sweep_threshold`` (and ``identify``) build the λ-independent part of ``fit`` — library
evaluation, weak-form test-function integrals, base-model residual, rank check — once with
``regression_problem`` and solve it for every λ. These tests check on a short 50 dB thesis_sim
record that every swept model equals an independent ``fit`` call with that λ (same support,
coefficients equal to rounding) for the strong and the weak form, per-equation libraries, the
ensemble, discrepancy SINDy and the refined weak form (whose refinement passes depend on λ),
and that the shared problem is not altered by solving it. Also: ``free_run``'s faster loop (used
by ``identify`` and the refinement passes) against a plain RK4 reference; per-equation libraries
sharing one weak-form pass over their union, and the refinement operator reusing its subdomains.
"""

from __future__ import annotations

import numpy as np
import pytest

from aeropend_ident.errors import IdentificationError
from aeropend_ident.sindy.core import fit, regression_problem
from aeropend_ident.sindy.libraries import physics_library, structured_library
from aeropend_ident.sindy.model import NoEquationError, data_from_trajectory
from aeropend_ident.sindy.preprocess import add_derivatives
from aeropend_ident.sindy.sweep import sweep_threshold
from aeropend_sim.excitation import aprbs
from aeropend_sim.params import load_rig
from aeropend_sim.simulation import simulate

VARIABLES = ["theta", "theta_dot", "i_a", "omega_rotor", "v_a"]
TARGETS = ["theta_dot", "i_a", "omega_rotor"]
LAMBDAS = [0.0, 0.005, 0.02, 0.1, 0.5, 2.0]


@pytest.fixture(scope="module")
def split():
    """6 s APRBS (levels 0.2-0.9, holds 20-300 ms) of thesis_sim at 490 Hz, 50 dB, SG derivatives."""
    rig = load_rig("thesis_sim").with_effects(sensor_noise=True).with_params("sensors", snr_db=50)
    traj = simulate(rig, aprbs(6.0, lo=0.2, hi=0.9, min_hold=0.02, max_hold=0.3, seed=1).duty, seed=7)
    data = add_derivatives(data_from_trajectory(traj, measured=True), targets=TARGETS, method="savgol")
    return data.split(0.75)


def _assert_same(swept, single, lam) -> None:
    assert swept.feature_names == single.feature_names and swept.targets == single.targets
    np.testing.assert_array_equal(swept.support(), single.support(), err_msg=f"support at λ = {lam}")
    np.testing.assert_allclose(swept.coef, single.coef, rtol=1e-12, atol=0.0, err_msg=f"λ = {lam}")
    for a, b in ((swept.coef_std, single.coef_std), (swept.inclusion, single.inclusion)):
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=0.0)
    assert swept.threshold == single.threshold == lam
    assert swept.condition_number == pytest.approx(single.condition_number, rel=1e-12)
    assert swept.method == single.method


CASES = {
    "strong": (physics_library, dict(method="sindy", exclude_input_steps=3)),
    "weak": (physics_library, dict(method="weak", K=120, H_xt=0.05)),
    "weak-structured": (structured_library, dict(method="weak", K=120, H_xt=0.05, exclude_input_steps=3)),
    "strong-structured": (structured_library, dict(method="sindy", exclude_input_steps=3)),
}


@pytest.mark.parametrize("case", list(CASES))
def test_sweep_models_equal_independent_fits(split, case) -> None:
    train, test = split
    make, kw = CASES[case]
    lib = make(VARIABLES)
    pts, models = sweep_threshold(train, test, lib, LAMBDAS, targets=TARGETS, **kw)
    assert [p.threshold for p in pts] == LAMBDAS and sorted(models) == LAMBDAS
    supports = []
    for lam in LAMBDAS:
        single = fit(train, lib, TARGETS, threshold=lam, **kw)
        _assert_same(models[lam], single, lam)
        pt = next(p for p in pts if p.threshold == lam)
        excl = kw.get("exclude_input_steps", 0)
        assert pt.test_mse == pytest.approx(single.test_mse(test, exclude_input_steps=excl), rel=1e-12)
        supports.append(int(single.support().sum()))
    # the sweep is not degenerate: λ = 0 keeps every term, the largest λ prunes
    n_columns = sum(len(lib[tg]) for tg in TARGETS) if isinstance(lib, dict) else models[0.0].coef.size
    assert supports[0] == n_columns
    assert supports[-1] < supports[0]
    assert supports == sorted(supports, reverse=True)


@pytest.mark.slow
def test_sweep_equal_for_ensemble_discrepancy_and_refined(split) -> None:
    train, test = split
    lib = physics_library(VARIABLES)
    lams = [0.01, 0.1, 0.5]
    for kw in (dict(method="ensemble", n_models=8, seed=3),
               dict(method="weak", K=120, H_xt=0.05, base=load_rig("thesis_sim")),
               dict(method="weak", K=120, H_xt=0.05, refine=1)):
        _pts, models = sweep_threshold(train, test, lib, lams, targets=TARGETS, **kw)
        for lam in lams:
            _assert_same(models[lam], fit(train, lib, TARGETS, threshold=lam, **kw), lam)


def test_problem_solves_repeatably(split) -> None:
    train, _ = split
    lib = physics_library(VARIABLES)
    problem = regression_problem(train, lib, TARGETS, method="weak", K=120, H_xt=0.05)
    first = problem.solve(0.1)
    problem.solve(0.0)
    problem.solve(1.0)
    again = problem.solve(0.1)
    np.testing.assert_array_equal(first.coef, again.coef)  # solving other λ left the problem unchanged
    assert problem.targets == TARGETS and problem.dropped == {}
    with pytest.raises(IdentificationError, match=r"threshold λ = -0\.1"):
        problem.solve(-0.1)


def test_drop_unidentifiable_equations(split) -> None:
    """A per-equation library the data leaves rank deficient (constant v_a) is dropped, with its reason."""
    train, _ = split
    flat = type(train)(t=train.t, variables={**train.variables, "v_a": np.full(len(train), 2.0)},
                       derivatives=train.derivatives, source="constant v_a")
    libs = structured_library(VARIABLES)
    with pytest.raises(IdentificationError, match="rank deficient"):
        regression_problem(flat, libs, TARGETS, method="weak", K=120, H_xt=0.05)
    problem = regression_problem(flat, libs, TARGETS, method="weak", K=120, H_xt=0.05,
                                 drop_unidentifiable=True)
    assert problem.targets == ["theta_dot", "omega_rotor"] and list(problem.dropped) == ["i_a"]
    assert "rank deficient" in problem.dropped["i_a"]
    model = problem.solve(0.05)
    assert model.targets == ["theta_dot", "omega_rotor"]
    _assert_same(model, fit(flat, {tg: libs[tg] for tg in problem.targets}, problem.targets, threshold=0.05,
                            method="weak", K=120, H_xt=0.05), 0.05)
    # the rotor equation needs no v_a: its coefficients recover thesis_sim's 4519.2 i_a − 192.31 ω₁ (±3 %)
    assert model.coefficient("omega_rotor", "i_a") == pytest.approx(4519.2, rel=0.03)
    assert model.coefficient("omega_rotor", "ω₁") == pytest.approx(-192.31, rel=0.03)
    none = {tg: libs["i_a"] for tg in ["i_a"]}
    with pytest.raises(NoEquationError) as err:
        regression_problem(flat, none, ["i_a"], method="weak", K=120, H_xt=0.05, drop_unidentifiable=True)
    assert list(err.value.dropped) == ["i_a"]


def test_free_run_matches_rk4_reference_and_keeps_library_errors(split) -> None:
    """``free_run``'s hot loop (library row without per-column checks) against a plain RK4 of the
    same identified model written out here, and the library's error for a non-finite column."""
    from aeropend_ident.errors import LibraryError
    from aeropend_ident.sindy.libraries import Candidate, CandidateLibrary
    from aeropend_ident.sindy.model import SindyModel, free_run

    train, test = split
    model = fit(train, physics_library(VARIABLES), TARGETS, threshold=0.1, method="weak", K=120, H_xt=0.05)
    part = test.slice(0, 400)
    run = free_run(model, part, substeps=1)
    # reference: the same RK4 (inputs v_a held per sample, θ from θ̇) with CandidateLibrary.evaluate
    names = ["theta", *TARGETS]
    x = np.array([part.variables[s][0] for s in names])
    h = float(np.mean(np.diff(part.t)))
    ref = [x]

    def f(xs, k):
        vals = {"v_a": part.variables["v_a"][k:k + 1], **{s: xs[i:i + 1] for i, s in enumerate(names)}}
        row = model.library.evaluate(vals)[0]
        return np.array([xs[1], *(row @ model.coef[j] for j in range(len(TARGETS)))])

    for k in range(len(part) - 1):
        k1 = f(x, k)
        k2 = f(x + 0.5 * h * k1, k)
        k3 = f(x + 0.5 * h * k2, k)
        k4 = f(x + h * k3, k)
        x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        ref.append(x)
    ref = np.array(ref)
    for i, s in enumerate(names):
        np.testing.assert_allclose(run.states[s], ref[:, i], rtol=1e-12, atol=1e-12 * np.abs(ref[:, i]).max())
    assert run.nrmse["theta"] < 0.05  # and it tracks the data
    # a column that turns non-finite in the run raises the library's own message
    bad = CandidateLibrary((
        Candidate("θ̇", ("theta_dot",), lambda d: np.asarray(d["theta_dot"])),
        Candidate("log(i_a − 10)", ("i_a",), lambda d: np.log(np.asarray(d["i_a"]) - 10.0)),
    ))
    broken = SindyModel(method="weak", targets=["theta_dot"], feature_names=bad.names,
                        coef=np.array([[-1.0, 0.0]]), threshold=0.0, library=bad)
    with pytest.raises(LibraryError, match=r"candidate log\(i_a − 10\) is not finite"):
        free_run(broken, part)


def test_per_equation_libraries_share_one_weak_pass_over_their_union(split, monkeypatch) -> None:
    """The weak-form integrals of per-equation libraries come from one ``weak_matrices`` pass over
    their union (a column's integral does not depend on the other columns): each equation's
    regression matrix and left side equal those of the equation set up alone, to rounding, and the
    terms several equations share (ω₁, ω₁²) are integrated once."""
    import aeropend_ident.sindy.core as core

    calls = []
    real = core.weak_matrices
    monkeypatch.setattr(core, "weak_matrices", lambda *a, **k: calls.append(a[1].shape[1]) or real(*a, **k))
    train, _ = split
    lib = structured_library(VARIABLES)
    kw = dict(method="weak", K=120, H_xt=0.05)
    together = regression_problem(train, lib, TARGETS, **kw)
    union = set().union(*(lib[tg].names for tg in TARGETS))
    assert calls == [len(union)] and len(union) < sum(len(lib[tg]) for tg in TARGETS)
    for part in together._parts:
        (tg,) = part.targets
        alone = regression_problem(train, {tg: lib[tg]}, [tg], **kw)._parts[0]
        assert alone.library.names == part.library.names
        scale = np.abs(alone.theta).max()
        np.testing.assert_allclose(part.theta, alone.theta, rtol=1e-12, atol=1e-12 * scale)
        # y is a weak-form integral with cancellation: an entry far below the column's scale carries
        # the rounding of the terms summed (BLAS may sum in another order for another column count)
        np.testing.assert_allclose(part.y, alone.y, rtol=1e-12, atol=1e-12 * np.abs(alone.y).max())
        assert part.condition_number == pytest.approx(alone.condition_number, rel=1e-9)
    assert len(calls) == 1 + len(TARGETS)  # one pass together, one per equation alone


def test_the_refinement_operator_reuses_the_weak_setups_subdomains(split) -> None:
    """``WeakOperator(..., lib=...)`` on the library the weak-form matrices built (same grid, K, p,
    H_xt, seed) has exactly the test-function integrals of one built from scratch."""
    from aeropend_ident.sindy.weak_form import _WeakSetup
    from aeropend_ident.sindy.weak_quadrature import WeakOperator

    train, _ = split
    fresh = WeakOperator(train.t, K=120, p=4, H_xt=0.05, seed=0)
    setup = _WeakSetup(train.t, 120, 4, 0.05, 0)
    shared = WeakOperator(train.t, K=120, p=4, H_xt=0.05, seed=0, lib=setup.lib)
    assert shared.K == fresh.K == 120
    assert (shared.phi != fresh.phi).nnz == 0 and (shared.dphi != fresh.dphi).nnz == 0
