"""Output-error refinement of weak-iv models on the thesis' simulated plant (issue 4, 50 dB bar).

The structure comes from weak-iv (``fit(method="weak", refine=2, alpha=1)``); the non-zero
coefficients of di_a/dt and dω₁/dt are then re-estimated by minimising the simulation error of
the recorded i_a and ω₁ (:mod:`aeropend_ident.sindy.output_error`). Data, truth and estimator options
are those of ``test_ident_noise.py`` (30 s APRBS, holds 20-300 ms, first 75 %). Per-seed figures
at none/50/30/20 dB: bench/results/sindy_oe.md.
"""

from __future__ import annotations

import pytest

from aeropend_ident.errors import IdentificationError
from aeropend_ident.sindy.model import structure_errors
from aeropend_ident.sindy.output_error import refine_output_error
from bench.fixtures.sindy_case import TRUTH, case_data, weak_iv_fit

# an expensive module fixture: under --dist loadgroup the module runs on one worker, which computes it once
pytestmark = pytest.mark.xdist_group("test_output_error")

OE = ("i_a", "omega_rotor")


@pytest.fixture(scope="module")
def clean():
    data = case_data(None)
    return data, weak_iv_fit(data)


@pytest.fixture(scope="module")
def noisy50():
    data = case_data(50.0, seed=7)
    return data, weak_iv_fit(data, output_error=OE)


@pytest.mark.slow
def test_noise_free_not_degraded(clean) -> None:
    data, m = clean
    exact = refine_output_error(m, data)
    mapped = refine_output_error(m, data, clean_inputs=True)  # v_a from its fitted static map v_a(τ)
    assert (exact.support() == m.support()).all() and exact.method == "weak+oe"
    for r, tol in ((exact, 2e-4), (mapped, 3e-3)):  # measured 0.005 % and 0.09 % (map bias)
        for tg, e in structure_errors(r, TRUTH).items():
            assert e["false_positive"] == [] and e["false_negative"] == [], (tg, r.equations())
            assert e["max_rel_error"] < tol, (tg, e, r.equations())
    # equations not refined are returned unchanged
    i = m.targets.index("theta_dot")
    assert (exact.coef[i] == m.coef[i]).all()


@pytest.mark.slow
def test_50db_structure_and_consistent_standard_errors(noisy50) -> None:
    _, m = noisy50
    errs = structure_errors(m, TRUTH)
    for tg, e in errs.items():
        assert e["false_positive"] == [] and e["false_negative"] == [], (tg, m.equations())
    assert errs["theta"]["max_rel_error"] < 0.01  # measured 0.22 % (weak-iv, not refined)
    assert errs["theta_dot"]["max_rel_error"] < 0.001  # measured 0.028 %
    assert errs["omega_rotor"]["max_rel_error"] < 0.01  # measured 0.16 %
    # every refined coefficient lies within 3 of its own standard errors of the truth
    for tg in OE:
        i = m.targets.index(tg)
        for name, c in TRUTH[tg].items():
            j = m.feature_names.index(name)
            assert abs(m.coef[i, j] - c) < 3.0 * m.coef_std[i, j], (tg, name, m.equations())
    # the information limit of this record: the standard error of R_a/L_a alone is ~6 % (1σ), so
    # no unbiased estimator meets the 1 % bar reliably on 22.5 s of this APRBS at 50 dB; the bar
    # is met on an excitation designed for identifiability (test_ident_design.py)
    j = m.feature_names.index("i_a")
    assert m.coef_std[m.targets.index("i_a"), j] / 8.6957 > 0.03


@pytest.mark.slow
def test_refuses_bad_requests(clean) -> None:
    data, m = clean
    with pytest.raises(IdentificationError, match="not equations of the model"):
        refine_output_error(m, data, targets=("duty",))
    with pytest.raises(IdentificationError, match="window"):
        refine_output_error(m, data, window=100.0)
    with pytest.raises(IdentificationError, match="substeps"):
        refine_output_error(m, data, substeps=0)
    with pytest.raises(IdentificationError, match="needs"):
        refine_output_error(m, data.__class__(t=data.t, variables={"i_a": data.variables["i_a"]}))
