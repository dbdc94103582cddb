"""The diagnosis data declared with the components equal the tables aeropend_ident still keeps.

Issue 35 stage A moved each effect's diagnosis metadata (revealing channels, confusable effects,
discrepancy-SINDy terms, truth ranges, fit bounds) into its component or effect module as plain
data; stage B points the readers (``gap/effects.py``'s CATALOG, ``gap/synth.py``'s TRUTH_RANGES
and RELATIVE, ``greybox/fit.py``'s PHYSICAL_BOUNDS, _LINEAR_SCALE and _EFFECT_OF) at the registry
and deletes those tables. Until then this test keeps the two copies equal, entry by entry.
"""

from __future__ import annotations

from aeropend_ident.gap import synth
from aeropend_ident.gap.effects import EFFECTS
from aeropend_ident.greybox import fit
from aeropend_sim.components import registry
from aeropend_sim.components.base import Effect


def _diagnoses():
    return {d.name: (part, d) for part in registry.parts() for d in part.diagnoses}


def test_every_catalog_entry_is_declared_once_in_the_registry():
    """Every catalog entry has its declaration; the registry may declare more (new effects, which the
    catalog gains when stage B builds it from the registry)."""
    diags = _diagnoses()
    assert len(diags) == sum(len(p.diagnoses) for p in registry.parts())  # no name twice
    assert set(EFFECTS) <= set(diags)


def test_diagnosis_metadata_equals_the_catalog():
    for name, (_, d) in _diagnoses().items():
        if name not in EFFECTS:
            continue
        e = EFFECTS[name]
        assert d.subsystem == e.subsystem, name
        assert d.description == e.description, name
        assert d.params == e.parameter_names, name
        assert d.reveals == e.needs_channels, name
        assert dict(d.sindy_terms) == dict(e.terms), name
        assert d.confusable_with == e.confusable_with, name
        assert (d.kind, d.screened, d.exclusive_with, d.nests, d.refines) == (
            e.kind, e.screened, e.exclusive_with, e.nests, e.refines), name


def test_truth_ranges_equal_the_blind_benchmark_tables():
    params = registry.params()
    diags = _diagnoses()
    for name, ranges in synth.TRUTH_RANGES.items():
        _, d = diags[name]
        for pname, intervals in ranges.items():
            rel = synth.RELATIVE.get((name, pname))
            if rel is not None:
                assert params[rel].relative_truth == tuple(intervals), (name, pname)
                assert pname not in d.truth, (name, pname)
            else:
                assert d.truth[pname] == tuple(intervals), (name, pname)
    # and nothing more: every relative truth and absolute range of the registry is in the tables
    rel_keys = {k for k, p in params.items() if p.relative_truth}
    assert rel_keys == set(synth.RELATIVE.values())
    for name, (_, d) in diags.items():
        for pname in d.truth:
            assert name in EFFECTS and pname in synth.TRUTH_RANGES[name], (name, pname)


def test_fit_bounds_and_switches_equal_the_greybox_tables():
    params = registry.params()
    declared = {k: p.fit for k, p in params.items() if p.fit is not None}
    assert set(declared) == set(fit.PHYSICAL_BOUNDS)
    for key, (lo, hi, log) in fit.PHYSICAL_BOUNDS.items():
        f = declared[key]
        assert (f.lower, f.upper, f.log) == (lo, hi, log), key
        assert f.scale == fit._LINEAR_SCALE.get(key), key
    assert set(fit._LINEAR_SCALE) <= set(declared)
    owners = registry.owners()
    for key, (switch, value) in fit._EFFECT_OF.items():
        owner = owners[key]
        if key == "actuator.v_supply":  # the ideal map's supply acts only while hbridge_map is off
            assert (switch, value) == ("hbridge_map", False)
            continue
        assert isinstance(owner, Effect) and (owner.name, owner.on) == (switch, value), key
