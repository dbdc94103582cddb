"""Thesis §3.3 case study: SINDy, weak SINDy and discrepancy SINDy on the Lorenz system.

Complements ``test_ident_sindy.py::test_lorenz_sindy_weak_and_discrepancy`` (noise-free data,
exact derivatives, a mismatch in ẏ only, scored on the training trajectory) with the thesis'
protocol: train and test trajectories from *different* initial conditions (§3.3.2), an
approximate model wrong in both ẋ and ẏ (σ = 8 instead of 10, ρ = 25 instead of 28), and
measurement noise, where the weak form (no derivative of the noisy data) must beat the strong
form on *estimated* derivatives. Figures measured when the test was written are in each test.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from aeropend_ident.sindy.core import fit
from aeropend_ident.sindy.libraries import thesis_library
from aeropend_ident.sindy.model import IdentData, free_run, structure_errors
from aeropend_ident.sindy.preprocess import add_derivatives

SIGMA, RHO, BETA = 10.0, 28.0, 8.0 / 3.0
TRUTH = {"x": {"x": -SIGMA, "y": SIGMA}, "y": {"x": RHO, "y": -1.0, "x·z": -1.0},
         "z": {"z": -BETA, "x·y": 1.0}}
TRAIN_X0, TEST_X0 = (-8.0, 8.0, 27.0), (5.0, -6.0, 20.0)
LIB = thesis_library(variables=("x", "y", "z"), trig=False)  # 1, x, y, z and the 6 products


def _rhs(s: np.ndarray, sigma: float = SIGMA, rho: float = RHO) -> np.ndarray:
    x, y, z = s
    return np.array([sigma * (y - x), x * (rho - z) - y, x * y - BETA * z])


def lorenz(x0: tuple[float, float, float], t_end: float = 10.0, dt: float = 0.002, noise: float = 0.0,
           seed: int = 0, estimate: bool = False) -> IdentData:
    """Lorenz trajectory; ``noise`` = Gaussian noise std as a fraction of each state's std;
    exact derivatives, or Savitzky-Golay estimates from the (noisy) states when ``estimate``."""
    t = np.arange(0.0, t_end, dt)
    sol = solve_ivp(lambda _t, s: _rhs(s), (0.0, t_end), x0, t_eval=t, rtol=1e-11, atol=1e-11).y
    der = np.array([_rhs(s) for s in sol.T]).T
    if noise:
        rng = np.random.default_rng(seed)
        sol = sol + noise * sol.std(axis=1, keepdims=True) * rng.standard_normal(sol.shape)
    data = IdentData(t=t, variables={"x": sol[0], "y": sol[1], "z": sol[2]},
                     derivatives={} if estimate else {"x": der[0], "y": der[1], "z": der[2]},
                     source=f"lorenz{x0} noise {noise}")
    return add_derivatives(data, targets=["x", "y", "z"], method="savgol") if estimate else data


def _approx(d: IdentData) -> dict[str, np.ndarray]:
    """The mismatched model F_m(X; μ₁): σ = 8, ρ = 25 (wrong in ẋ and ẏ)."""
    f = _rhs(np.array([d.variables["x"], d.variables["y"], d.variables["z"]]), sigma=8.0, rho=25.0)
    return {"x": f[0], "y": f[1], "z": f[2]}


@pytest.fixture(scope="module")
def test_traj() -> IdentData:
    return lorenz(TEST_X0, t_end=5.0)


def test_sindy_and_weak_on_train_ic_predict_test_ic(test_traj) -> None:
    """Noise-free: both estimators exact; derivatives of another trajectory predicted to round-off
    and a 1 s free run from the test initial condition follows the chaotic trajectory."""
    train = lorenz(TRAIN_X0)
    for method, kw in (("sindy", {}), ("weak", {"K": 400})):
        m = fit(train, LIB, ["x", "y", "z"], threshold=0.05, method=method, **kw)
        for tg, e in structure_errors(m, TRUTH).items():
            assert (e["false_positive"], e["false_negative"]) == ([], []), (method, tg, m.equations())
            assert e["max_rel_error"] < 1e-3, (method, tg, e)
        mse = m.test_mse(test_traj)
        var = {k: float(np.var(v)) for k, v in test_traj.derivatives.items()}
        assert all(mse[k] < 1e-6 * var[k] for k in mse), (method, mse)
        run = free_run(m, test_traj.slice(0, 500), substeps=2)  # 1 s
        assert max(run.nrmse.values()) < 0.01, (method, run.nrmse)


@pytest.mark.slow
def test_weak_form_beats_strong_form_under_noise() -> None:
    """1 % noise: both find the exact structure, the weak form 5x more accurately (measured max
    coefficient error 0.09 % weak vs 0.49 % strong). 5 % noise, λ = 0.1: the strong form on estimated
    derivatives loses a true term of ẏ; the weak form keeps the exact ẏ and ż structures (1.1 %)."""
    errs = {}
    for noise in (0.01, 0.05):
        strong = fit(lorenz(TRAIN_X0, noise=noise, estimate=True), LIB, ["x", "y", "z"], threshold=0.1)
        weak = fit(lorenz(TRAIN_X0, noise=noise), LIB, ["x", "y", "z"], threshold=0.1, method="weak", K=400)
        errs[noise] = (structure_errors(strong, TRUTH), structure_errors(weak, TRUTH))
    s1, w1 = errs[0.01]
    for e in (*s1.values(), *w1.values()):
        assert e["false_positive"] == [] and e["false_negative"] == []
    worst_s = max(e["max_rel_error"] for e in s1.values())
    worst_w = max(e["max_rel_error"] for e in w1.values())
    assert worst_w < 0.002 and worst_w < 0.5 * worst_s
    s5, w5 = errs[0.05]
    assert s5["y"]["false_negative"] != []
    for tg in ("y", "z"):
        assert w5[tg]["false_positive"] == [] and w5[tg]["false_negative"] == []
        assert w5[tg]["max_rel_error"] < 0.03


@pytest.mark.parametrize("method", ["sindy", "weak"])
def test_discrepancy_sindy_corrects_x_and_y_and_generalises(method, test_traj) -> None:
    """Thesis §3.3.2/§3.3.3: regress the residual of the σ = 8, ρ = 25 model on the training
    trajectory (1 % noise; strong form on estimated derivatives, weak form on the states); the
    corrections are +2·(y − x) in ẋ and +3·x in ẏ, and the corrected model predicts the test
    trajectory's derivatives far better than the approximate model alone.

    ż needs no correction, but its residual is pure noise, and λ is relative to each residual's
    RMS: at λ = 0.1 both forms fit noise terms into ż, at λ = 0.3 the strong form gives ż exactly
    unchanged and the weak form ten tiny terms (measured). So for ż the test asserts that the
    correction is negligible on the test trajectory (< 1 % of RMS(ż)), not that it is empty."""
    noisy = lorenz(TRAIN_X0, noise=0.01, estimate=method == "sindy")
    kw = {"K": 400} if method == "weak" else {}
    m = fit(noisy, LIB, ["x", "y", "z"], threshold=0.3, method=method, base=_approx, **kw)
    assert set(m.terms("x")) == {"x", "y"} and set(m.terms("y")) == {"x"}, m.equations()
    tol = 0.01 if method == "weak" else 0.03  # measured 0.25 % (weak), 1.4 % (strong)
    assert m.terms("x")["x"] == pytest.approx(-2.0, rel=tol)
    assert m.terms("x")["y"] == pytest.approx(2.0, rel=tol)
    assert m.terms("y")["x"] == pytest.approx(3.0, rel=tol)
    assert m.equations()[1].startswith("dy/dt = f__approx")
    if method == "sindy":
        assert m.terms("z") == {}
    corrected = m.predict(test_traj)
    base = _approx(test_traj)
    dz_corr = corrected["z"] - base["z"]
    assert np.sqrt(np.mean(dz_corr**2)) < 0.01 * np.sqrt(np.mean(test_traj.derivatives["z"] ** 2))
    for k in ("x", "y"):
        err_c = float(np.mean((corrected[k] - test_traj.derivatives[k]) ** 2))
        err_a = float(np.mean((base[k] - test_traj.derivatives[k]) ** 2))
        assert err_c < 1e-3 * err_a, (k, err_c, err_a)
