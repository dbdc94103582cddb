"""Blind-benchmark generator and scorer of the gap diagnosis (bench.fixtures.gap_synth)."""

from __future__ import annotations

import numpy as np
import pytest

from aeropend_ident.errors import GapError
from aeropend_sim.params import load_rig
from bench.fixtures.gap_synth import (
    REST,
    confusion,
    draw_truth,
    make_case,
    record,
    relative_key,
    score_case,
    summarise,
    thrust_reference_speed,
    truth_ranges,
)

RIG = load_rig("thesis_rig")


def test_truth_ranges_cover_the_catalog_and_draws_stay_inside():
    rng = np.random.default_rng(0)
    from aeropend_ident.gap.effects import CATALOG, EFFECTS

    for e in CATALOG:  # the diagnosis' catalog (not drift-only entries); ranges declared with each effect
        name, params = e.name, truth_ranges(e.name)
        assert params, name
        for _ in range(5):
            v = draw_truth(name, rng, RIG)
            for p, intervals in params.items():
                key = relative_key(name, p)  # factors of the nominal value
                scale = RIG.value(key) if key else 1.0
                assert any(lo * scale <= v[p] <= hi * scale for lo, hi in intervals), (name, p, v)
            # every drawn value is a valid physical value of the catalog effect
            EFFECTS[name].values({**EFFECTS[name].held_values(RIG), **v})  # a held width: the rig's
    # the thrust-law truth keeps the nominal thrust at the reference speed
    v = draw_truth("thrust_law", rng, RIG)
    w = thrust_reference_speed(RIG)
    assert v["K_q"] * w ** v["exponent"] == pytest.approx(RIG.thrust.K_q * w**2, rel=1e-12)
    with pytest.raises(GapError, match="unknown effect"):
        draw_truth("magic", rng, RIG)


def test_case_is_reproducible_and_fit_differs_from_held_out():
    a = make_case(RIG, ["dead_zone"], 3, fit_duration=4.0, held_out_steps=2)
    b = make_case(RIG, ["dead_zone"], 3, fit_duration=4.0, held_out_steps=2)
    assert a.truth == b.truth and a.snr_db == b.snr_db
    np.testing.assert_array_equal(a.fit[0].channels["theta"], b.fit[0].channels["theta"])
    np.testing.assert_array_equal(a.held_out[0].duty, b.held_out[0].duty)
    # different excitation between fit and held-out
    n = min(len(a.fit[0]), len(a.held_out[0]))
    assert not np.array_equal(a.fit[0].duty[:n], a.held_out[0].duty[:n])
    assert set(a.fit[0].channels) == {"theta", "i_a", "v_a", "omega_rotor"}
    assert 45.0 <= a.snr_db <= 60.0
    c = make_case(RIG, ["dead_zone"], 4, fit_duration=4.0, held_out_steps=2, channels=("theta",))
    assert set(c.fit[0].channels) == {"theta"}


def test_hidden_effects_are_in_the_recordings():
    # sensor offset: the rod rests at θ = 0, the sensor reads −θ_offset
    case = make_case(RIG, ["sensor_offset"], 1, fit_duration=3.0, held_out_steps=2,
                     truth={"sensor_offset": {"theta_offset": 0.08}}, snr_db=60.0)
    rest = case.fit[0].channels["theta"][: round(REST / RIG.sample_period)]
    assert np.mean(rest) == pytest.approx(-0.08, abs=2e-3)
    # dead zone of 0.12: v_a at duty 0.1 is 0 V (nominal: > 0)
    case = make_case(RIG, ["dead_zone"], 1, fit_duration=3.0, held_out_steps=2,
                     truth={"dead_zone": {"dead_zone": 0.3}}, snr_db=60.0)
    r = case.fit[0]
    low = (r.duty > 0.0) & (r.duty < 0.3)
    if low.any():
        assert np.max(np.abs(r.channels["v_a"][low])) < 0.05
    # quantisation: the angle lies on the drawn lattice
    case = make_case(RIG, ["quantisation"], 2, fit_duration=3.0, held_out_steps=2,
                     truth={"quantisation": {"theta_quantum": 0.01}})
    th = case.fit[0].channels["theta"]
    np.testing.assert_allclose(th / 0.01, np.round(th / 0.01), atol=1e-9)


def test_record_requires_theta():
    with pytest.raises(GapError, match="lack 'theta'"):
        record(RIG, None, np.zeros(10), 0, ("i_a",), "x")  # type: ignore[arg-type]


def _diag(significant, ranked, params=None, not_ident=(), shrink=(0.1, 0.01)):
    return {
        "significant": significant,
        "ranking": [{"effect": n, "parameters": (params or {}).get(n, {})} for n in ranked],
        "not_identifiable": [{"effect": n, "reason": "x"} for n in not_ident],
        "chosen": list(ranked[:1]),
        "validation": [{"effects": [], "nrmse": shrink[0]}] + (
            [{"effects": ranked[:1], "nrmse": shrink[1]}] if significant else []),
    }


class _Case:
    def __init__(self, truth, channels=("theta",), off=None):
        self.case_id, self.truth, self.channels, self.snr_db = "c", truth, channels, 50.0
        self.meta = {"off": off or {}}


def test_scorer_top1_top3_confusable_magnitude_and_shrink():
    case = _Case({"input_delay": {"input_delay": 0.05}})
    s = score_case(case, _diag(True, ["actuator_lag", "input_delay"],
                               {"input_delay": {"input_delay": {"value": 0.06}}}))
    assert s["top1"] is False and s["top1_confusable"] is True and s["top3"] is True
    assert s["magnitude_error"]["input_delay"] == pytest.approx(0.2)
    assert s["shrink"] == pytest.approx(0.9)
    s = score_case(case, _diag(True, ["input_delay"], {"input_delay": {"input_delay": {"value": 0.05}}}))
    assert s["top1"] is True and s["magnitude_error"]["input_delay"] == pytest.approx(0.0)
    # parameter errors: relative to |true − nominal|
    case = _Case({"gravity": {"mgd_over_J": 120.0}}, off={"gravity": {"mgd_over_J": 100.0}})
    s = score_case(case, _diag(True, ["gravity"], {"gravity": {"mgd_over_J": {"value": 125.0}}}))
    assert s["magnitude_error"]["gravity"] == pytest.approx(0.25)


def test_scorer_no_effect_and_not_identifiable():
    s = score_case(_Case({}), _diag(False, []))
    assert s["top1"] is True and s["shrink"] == 0.0
    s = score_case(_Case({}), _diag(True, ["gravity"]))
    assert s["top1"] is False
    s = score_case(_Case({"back_emf": {"K_omega": 1.5}}),
                   _diag(True, ["gravity"], not_ident=["back_emf"]))
    assert s["top1"] is None and s["reported_not_identifiable"] == ["back_emf"]


def test_summary_and_confusion_aggregate_scores():
    scores = [
        score_case(_Case({"dead_zone": {"dead_zone": 0.1}}), _diag(True, ["dead_zone"])),
        score_case(_Case({"dead_zone": {"dead_zone": 0.1}}), _diag(True, ["hbridge_drop", "dead_zone"])),
        score_case(_Case({}), _diag(False, [])),
        score_case(_Case({"back_emf": {"K_omega": 1.5}}),
                   _diag(True, ["gravity"], not_ident=["back_emf"])),
    ]
    summ = summarise(scores)
    assert summ["cases"] == 4 and summ["scored_cases"] == 3
    assert summ["top1"] == pytest.approx(2 / 3)
    assert summ["top3"] == pytest.approx(1.0)
    assert summ["per_effect"]["dead_zone"]["top1"] == pytest.approx(0.5)
    assert summ["per_effect"]["dead_zone"]["top1_confusable"] == pytest.approx(1.0)
    assert summ["not_identifiable_reported"] == pytest.approx(1.0)
    assert summ["median_shrink"] == pytest.approx(0.9)
    assert confusion(scores) == {"dead_zone": {"dead_zone": 1, "hbridge_drop": 1}, "none": {"none": 1}}
