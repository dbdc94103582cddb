"""The gap diagnosis, the blind benchmarks and the grey-box fit read their tables from the registry.

Issue 35 stage B: each hypothesis of the gap catalog is declared once, by the component or effect
it belongs to (:class:`aeropend_sim.components.base.Diagnosis`: parameters with their search
ranges, how it is applied, revealing channels, relations, truth ranges), and the readers build
their tables from it: ``gap/effects.py``'s catalog per actuator family, ``gap/synth.py``'s truth
ranges, ``gap/drift.py``'s drift prior and ``greybox/fit.py``'s bounds. These tests check the
declarations are complete and that the readers hold nothing of their own.
"""

from __future__ import annotations

import numpy as np
import pytest

from aeropend_ident.errors import GapError, IdentificationError
from aeropend_ident.gap import drift
from aeropend_ident.gap.effects import EFFECTS, EffectContext, catalog, drift_only, get_effect, timing_effects
from aeropend_ident.greybox.parameters import parameter_spec
from aeropend_sim.components import registry
from aeropend_sim.params import load_rig
from bench.fixtures import gap_synth as synth
from bench.fixtures.component_rigs import rig as family_rig

FAMILIES = [f.name for f in registry.families()]


def _ctx(rig):
    t = np.arange(3000) * rig.sample_period
    return EffectContext.from_data(rig, 0.4 + 0.2 * np.sin(t), np.where(t > 1.0, 0.7, 0.3))


def test_every_hypothesis_is_declared_once_with_its_search_and_relations():
    names = [d.name for d in registry.diagnoses()]
    assert len(names) == len(set(names)) and set(EFFECTS) == set(names)
    orders = [d.order for d in registry.diagnoses()]
    assert len(orders) == len(set(orders)), "catalog orders must be distinct"
    for d in registry.diagnoses():
        assert tuple(s.name for s in d.search) == d.params, d.name
        assert d.apply is not None or d.kind == "measurement", d.name
        for s in d.search:
            assert s.range_doc and s.unit, (d.name, s.name)
            section = s.target.partition(".")[0]
            assert section == "measurement" or s.target in registry.params(), (d.name, s.target)
        for other in (*d.confusable_with, *d.exclusive_with, *d.nests, *d.refines):
            assert other in names, (d.name, other)


@pytest.mark.parametrize("family", FAMILIES)
def test_the_catalog_of_a_family_is_the_registry_s_hypotheses_that_belong_on_it(family):
    fam = registry.family(family)
    got = [e.name for e in catalog(family)]
    assert got == [d.name for d in registry.diagnoses(family) if d.kind != "drift"]
    drift_names = [d.name for d in registry.diagnoses(family) if d.kind == "drift"]
    assert [e.name for e in drift_only(family)] == drift_names
    # everything left out is left out by its declaring part, which says why
    for d in registry.diagnoses():
        if d.name not in got and d.kind != "drift":
            assert registry.diagnosis_owner(d.name).applies_to(fam), (family, d.name)
    # every entry's search range is a valid interval on a rig of the family
    rig = family_rig(family)
    ctx = _ctx(rig)
    for e in catalog(family):
        assert family in e.families
        for p in e.parameters:
            r = p.bind(ctx)
            assert r.lower < r.upper and r.lower <= r.probe <= r.upper, (e.name, p.name, r)
            assert r.probe != r.off, (e.name, p.name)
            if r.log:
                assert r.lower > 0
        e.apply(rig, e.probe_values(ctx))  # applies to the family's rig


def test_family_specific_hypotheses():
    esc = {e.name for e in catalog("esc")}
    amp = {e.name for e in catalog("voltage_amplifier")}
    thesis = {e.name for e in catalog("dc_hbridge")}
    # an ESC has no armature, no rotor torque balance and no dead zone of its own
    assert not esc & {"back_emf", "armature_resistance", "armature_inductance", "torque_constant",
                      "rotor_friction", "propeller_drag", "rotor_brush_friction", "motor_time_constant",
                      "dead_zone", "hbridge_drop"}
    assert {"esc_idle", "esc_speed_range", "esc_response", "input_delay", "thrust_coefficient"} <= esc
    assert "hbridge_drop" not in amp and "amplifier_offset" in amp and "back_emf" in amp
    assert "hbridge_drop" in thesis and not thesis & {"esc_idle", "amplifier_offset"}
    assert timing_effects("esc") == ("actuator_lag", "input_delay", "esc_response")
    assert set(timing_effects("dc_hbridge")) == {"actuator_lag", "input_delay", "motor_time_constant"}
    ctx = _ctx(family_rig("esc"))
    with pytest.raises(Exception, match="not a hypothesis for rig"):
        get_effect("back_emf").apply(family_rig("esc"), {"K_omega": 1e-3})
    assert ctx.drive_max == pytest.approx(family_rig("esc").actuator.omega_max * (0.7 - 0.1) / 0.9)


@pytest.mark.parametrize("family", FAMILIES)
def test_every_candidate_has_truth_ranges_for_the_blind_benchmark(family):
    rig = family_rig(family)
    rng = np.random.default_rng(1)
    for e in catalog(family):
        ranges = synth.truth_ranges(e.name)
        assert ranges, e.name
        keys = [synth.relative_key(e.name, p) for p in ranges]
        if any(k and rig.value(k) == 0.0 for k in keys):
            with pytest.raises(GapError, match="does not model"):
                synth.draw_truth(e.name, rng, rig)
            continue
        truth = synth.draw_truth(e.name, rng, rig)
        # a held parameter (the dry friction's onset width) keeps the rig's value: no truth range
        sized = {p.name for p in e.parameters if not p.held}
        assert set(truth) == sized or e.name == "thrust_law", e.name
        e.values({**e.held_values(rig), **truth})  # inside the physical limits


def test_relative_truths_multiply_the_nominal_value():
    rig = load_rig("thesis_rig")
    assert synth.relative_key("back_emf", "K_omega") == "motor.K_omega"
    assert synth.relative_key("dead_zone", "dead_zone") is None
    t = synth.draw_truth("armature_resistance", np.random.default_rng(0), rig)["R_a"] / rig.motor.R_a
    assert any(lo <= t <= hi for lo, hi in registry.param("motor.R_a").relative_truth)


def test_drift_prior_is_declared_with_the_hypotheses():
    assert drift.DRIFT_PRIOR == {d.name: d.drift_sigma for d in registry.diagnoses() if d.drift_sigma}
    assert drift.DRIFT_PARAMETERS["thrust_coefficient"] == ("thrust", "K_q")
    assert drift.drift_parameters(("theta", "v_a"), "esc") == ["thrust_coefficient", "viscous_friction",
                                                                "gravity"]
    assert "supply_voltage" in drift.drift_parameters(("theta", "v_a"), "dc_hbridge")
    assert "esc_speed_range" in drift.drift_parameters(("theta", "omega_rotor"), "esc")


def test_fit_bounds_and_switches_come_from_the_declarations():
    rig = load_rig("thesis_rig")
    for key, p in registry.params().items():
        if p.fit is None or key not in rig.values() or p.section == "sensors":
            continue
        owner = registry.owners()[key]
        on = rig.with_effects(**{owner.name: owner.on}) if hasattr(owner, "switch") else rig
        if key == "actuator.lag_time_constant":
            on = on.with_params("actuator", lag_time_constant=0.05)
        spec = parameter_spec(key, on)
        if p.fit.lower is not None:
            assert (spec.lower, spec.upper, spec.log) == (p.fit.lower, p.fit.upper, p.fit.log), key
        if not p.fit.log and p.fit.scale is not None:
            assert spec.scale == p.fit.scale, key
    # a parameter whose effect is off, or whose drive map an effect replaces, does not reach θ
    with pytest.raises(IdentificationError, match=r"needs effects\.dead_zone = True"):
        parameter_spec("actuator.dead_zone", rig)
    with pytest.raises(IdentificationError, match=r"needs effects\.hbridge_map = False"):
        parameter_spec("actuator.v_supply", rig)
    ideal = rig.with_effects(hbridge_map=False)
    assert parameter_spec("actuator.v_supply", ideal).initial == rig.actuator.v_supply
