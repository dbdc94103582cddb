"""Issue 4's noise bars on an excitation designed for identifiability (thesis_sim plant).

On the thesis' Latin-hypercube steps and on an APRBS with 20-300 ms holds, i_a, ω₁ and v_a stay
nearly collinear (the rotor follows the current below its 162 s⁻¹ pole), so R_a/L_a has a 6 %
standard error at 50 dB (test_ident_output_error.py): no unbiased estimator can meet 1 %. The
design here, ``density_prbs`` (binary 0/1 holds of 5-30 ms whose density follows a slow APRBS
in [0.3, 0.7]), excites the armature and rotor above that pole and still moves the pendulum.
120 s at 490 Hz, first 75 % (90 s) fitted, 50 dB noise on every channel (seed 7), weak-iv
(``fit(method="weak", refine=2, alpha=1)``) followed by output-error refinement of di_a/dt and
dω₁/dt; at 20 dB weak-iv alone. Other seeds and SNRs: bench/results/sindy_oe_designed.md; the
Cramér-Rao bounds of the designs: bench/results/design_crb.md.
"""

from __future__ import annotations

import pytest

from aeropend_ident.sindy.model import structure_errors
from aeropend_sim.excitation import density_modulated_prbs
from bench.fixtures.sindy_case import TRUTH, case_data, k_q_error, weak_iv_fit

OE = ("i_a", "omega_rotor")
R_OVER_L = 8.6957
DESIGN = density_modulated_prbs(120.0, seed=1).duty
# the module fixture (weak-iv and output-error fit, 23-27 s) is made once, by one worker: without the
# group the CI of bf2189d made it in two workers (docs/testing.md, "Groups")
pytestmark = pytest.mark.xdist_group("sindy_test_design")


@pytest.fixture(scope="module")
def designed50():
    data = case_data(50.0, seed=7, duty=DESIGN)
    return data, weak_iv_fit(data, output_error=OE)


@pytest.mark.slow
def test_50db_bar_exact_structure_and_all_coefficients_within_one_percent(designed50) -> None:
    _, m = designed50
    for tg, e in structure_errors(m, TRUTH).items():
        assert e["false_positive"] == [] and e["false_negative"] == [], (tg, m.equations())
        assert e["max_rel_error"] < 0.01, (tg, e, m.equations())
    assert k_q_error(m) < 0.01


@pytest.mark.slow  # its module fixture is the slow part
def test_design_cuts_the_standard_error_of_r_over_l(designed50) -> None:
    _, m = designed50
    i, j = m.targets.index("i_a"), m.feature_names.index("i_a")
    # Cramér-Rao bound of this design over 90 s: 0.37 %; the APRBS record: > 3 % (6 %)
    assert m.coef_std[i, j] / R_OVER_L < 0.006
    for tg in OE:  # every refined coefficient within 3 of its own standard errors of the truth
        i = m.targets.index(tg)
        for name, c in TRUTH[tg].items():
            k = m.feature_names.index(name)
            assert abs(m.coef[i, k] - c) < 3.0 * m.coef_std[i, k], (tg, name, m.equations())


@pytest.mark.slow
def test_20db_all_four_structures_and_thrust_coefficient() -> None:
    """20 dB on every channel, weak-iv alone: the design keeps all four supports exact
    (bench, seeds 7-9: θ̈ 0.52-0.75 %, di_a/dt 11-12 %); bar: K_q within 10 %."""
    m = weak_iv_fit(case_data(20.0, seed=7, duty=DESIGN))
    errs = structure_errors(m, TRUTH)
    for tg, e in errs.items():
        assert e["false_positive"] == [] and e["false_negative"] == [], (tg, m.equations())
    assert errs["theta_dot"]["max_rel_error"] < 0.02
    assert k_q_error(m) < 0.02
