"""Rig files: every shipped rig loads, round-trips, and bad files give specific errors."""

from __future__ import annotations

import copy

import pytest
import yaml

from aeropend_sim.params import RigFileError, load_rig, rig_from_dict, rig_to_dict, save_rig, shipped_rigs


def test_shipped_rigs_include_thesis_and_third_party():
    names = shipped_rigs()
    assert {"thesis_rig", "thesis_sim"} <= set(names)


@pytest.mark.parametrize("name", shipped_rigs())
def test_every_shipped_rig_loads_and_round_trips(name, tmp_path):
    rig = load_rig(name)
    assert rig.sample_period > 0
    assert all(src.strip() for src in rig.sources.values())
    path = tmp_path / f"{name}.yaml"
    save_rig(rig, path)
    assert load_rig(path) == rig


def _base() -> dict:
    return rig_to_dict(load_rig("thesis_rig"))


def test_wrong_unit_names_key_and_expected_unit():
    d = _base()
    d["motor"]["L_a"]["unit"] = "mH"
    with pytest.raises(RigFileError, match=r"motor\.L_a has unit 'mH'; expected 'H'"):
        rig_from_dict(d, "x.yaml")


def test_missing_source_and_missing_key_are_refused():
    d = _base()
    del d["thrust"]["K_q"]["source"]
    with pytest.raises(RigFileError, match=r"thrust\.K_q has no 'source'"):
        rig_from_dict(d, "x.yaml")
    d = _base()
    del d["pendulum"]["mgd_over_J"]
    with pytest.raises(RigFileError, match=r"missing pendulum\.mgd_over_J \[1/s\^2\]"):
        rig_from_dict(d, "x.yaml")
    # an optional key (an effect's parameter) left out is not modelled, and the load report says so
    d = _base()
    del d["pendulum"]["c_over_J"]
    rig = rig_from_dict(d, "x.yaml")
    assert rig.pendulum.c_over_J == 0.0 and rig.status("pendulum.c_over_J") == "not modelled"
    assert any(n.startswith("pendulum.c_over_J: not modelled") for n in rig.load_notes)


def test_unphysical_values_and_unknown_effects_are_refused():
    d = _base()
    d["motor"]["R_a"]["value"] = -1.0
    with pytest.raises(RigFileError, match=r"motor\.R_a = -1\.0 must be > 0"):
        rig_from_dict(d, "x.yaml")
    d = _base()
    d["effects"]["wind"] = True
    with pytest.raises(RigFileError, match=r"unknown effect\(s\) \['wind'\]"):
        rig_from_dict(d, "x.yaml")
    d = _base()
    d["effects"]["armature_inductance"] = "sometimes"
    with pytest.raises(RigFileError, match="armature_inductance"):
        rig_from_dict(d, "x.yaml")
    d = copy.deepcopy(_base())
    d["pendulum"]["theta_min"]["value"] = 2.0
    with pytest.raises(RigFileError, match="theta_min"):
        rig_from_dict(d, "x.yaml")


def test_misspelt_top_level_section_is_refused():
    d = _base()
    d["efects"] = d.pop("effects")
    with pytest.raises(RigFileError, match=r"unknown top-level key\(s\) \['efects'\]"):
        rig_from_dict(d, "x.yaml")


def test_load_errors_name_the_file(tmp_path):
    with pytest.raises(RigFileError, match="no rig named 'nope'"):
        load_rig("nope")
    with pytest.raises(RigFileError, match="does not exist"):
        load_rig(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("motor: [1, 2\n")
    with pytest.raises(RigFileError, match=r"bad\.yaml: not valid YAML"):
        load_rig(bad)
    bad.write_text(yaml.safe_dump({"name": "x"}))
    with pytest.raises(RigFileError, match=r"bad\.yaml: missing section 'actuator'"):
        load_rig(bad)


def test_with_params_validates():
    rig = load_rig("thesis_rig")
    assert rig.with_params("motor", R_a=2.0).motor.R_a == 2.0
    with pytest.raises(RigFileError, match="no parameter"):
        rig.with_params("motor", R=2.0)
    with pytest.raises(RigFileError, match="must be > 0"):
        rig.with_params("motor", L_a=0.0)


@pytest.mark.parametrize("family", ["dc_hbridge", "voltage_amplifier", "esc"])
def test_a_rig_unpickles_in_a_fresh_process(family):
    """A rig sent to another process (a Dask worker of ``gap-batch``, a process pool) unpickles there:
    its section classes are generated on first use, so the fresh process must build them by name
    (reproducer: gap-batch's workers died with ``Can't get attribute 'DcHbridgeActuatorParams'``)."""
    import pickle
    import subprocess
    import sys

    from bench.fixtures.component_rigs import rig

    r = rig(family)
    code = ("import pickle, sys; r = pickle.loads(sys.stdin.buffer.read()); "
            "print(type(r.actuator).__name__, r == pickle.loads(pickle.dumps(r)))")
    out = subprocess.run([sys.executable, "-c", code], input=pickle.dumps(r), capture_output=True, check=True)
    assert out.stdout.decode().split() == [type(r.actuator).__name__, "True"]
