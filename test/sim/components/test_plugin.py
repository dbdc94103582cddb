"""A lab-written actuator family and effect plug in the way shipped ones do (issue 64).

The family below is written here, in the test file, as a lab would write it in its own package:
one module-level declaration. :func:`registry.register` (or the entry-point group
``aeropend.components`` of an installed package) makes it a family like the shipped three: ``rig
new`` writes a rig file for it, the loader reads it and the simulator runs it. Its physics: an
ESC whose rotor-speed set-point is linear in the throttle, ω_sp = ω_full·τ (no idle, no curve),
with the shipped ESC speed response T_m; the steady angle it holds is worked out here by hand from
the rod's balance (mgd/J)·sin θ = (L/J)·K_q·(ω₁/n)², never by aeropend's model.

Declarations that do not fit are refused when they are registered, naming the part: an effect
whose term reads another effect's parameter, a family without a drive map.
"""

from __future__ import annotations

import importlib.metadata
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.cli.rig import main as rig_main
from aeropend_sim.components import registry
from aeropend_sim.components.base import Effect, Family, Param, Term
from aeropend_sim.params import load_rig
from aeropend_sim.simulation import simulate

OMEGA_FULL = Param("actuator.omega_full", "rad/s", "rotor speed at full throttle (linear ESC)",
                   sign="positive", symbol="ω_full", typical=900.0, measure="a tachometer at full throttle")


def linear_speed(xp, tau, omega_full):
    """ω_sp = ω_full·τ_e [rad/s]."""
    return omega_full * tau


def d_linear_speed(xp, tau, omega_full):
    """∂ω_sp/∂τ_e [rad/s]."""
    return omega_full + 0.0 * tau


def duty_of_speed(xp, y, omega_full):
    """τ_e of a set-point y [rad/s]."""
    return y / omega_full


NO_ARMATURE = "a linear ESC runs its own speed loop: no armature to model"
FAMILY = Family(
    name="linear_esc", part="actuator", label="brushless motor, linear ESC",
    description="throttle τ → rotor-speed set-point ω_sp = ω_full·τ, first-order speed response T_m",
    order=13, params=(OMEGA_FULL,),
    terms=(Term("drive", 10, linear_speed, "ω_sp = ω_full·τ_e", partials={"tau": d_linear_speed},
                inverse=duty_of_speed),),
    families=("linear_esc",), drive="omega_sp",
    lacks={"armature": NO_ARMATURE, "rotor_torque": NO_ARMATURE},
    channels=("theta", "theta_dot", "omega_rotor", "omega_prop"),
    usual_effects=("rod_viscous_friction",),
)


@pytest.fixture
def linear_esc():
    registry.register(FAMILY)
    yield FAMILY
    registry.unregister(FAMILY.name)


def test_a_family_written_in_a_test_file_plugs_in_and_simulates(linear_esc: Family, tmp_path: Path) -> None:
    assert "linear_esc" in [f.name for f in registry.families()]
    parts = {p.name for p in registry.family_parts("linear_esc")}
    assert {"esc_rotor", "propeller", "rod"} <= parts and "dc_motor" not in parts, parts
    assert "back_emf" not in {e.name for e in registry.family_effects("linear_esc")}
    out = tmp_path / "linear.yaml"
    assert rig_main(["new", "--actuator", "linear_esc", "--stated", "actuator.omega_full=600rad/s",
                     "-o", str(out)]) == 0
    rig = load_rig(out)
    assert rig.family == "linear_esc" and rig.actuator.omega_full == 600.0
    tau = 0.45
    tr = simulate(rig, np.full(3000, tau), seed=1)
    # by hand: ω₁ → ω_full·τ (T_m), f = K_q·(ω₁/n)², balance (mgd/J) sin θ = (L/J)·f
    w = 600.0 * tau / rig.motor.gear_ratio
    s = rig.pendulum.L_over_J * rig.thrust.K_q * w * w / rig.pendulum.mgd_over_J
    assert 0.1 < s < 0.99, s
    held = tr.x[-200:, 0]
    print(f"linear_esc: θ held {held.mean():.6f} rad, by hand {math.asin(s):.6f} rad")
    assert held.mean() == pytest.approx(math.asin(s), abs=1e-3)
    assert tr.x[-1, 3] == pytest.approx(600.0 * tau, rel=1e-3)  # ω₁ at the set-point
    assert set(tr.channels()) >= {"theta", "omega_rotor"} and "i_a" not in tr.channels()
    registry.unregister("linear_esc")
    assert "linear_esc" not in [f.name for f in registry.families()]
    registry.register(FAMILY)  # for the fixture's teardown


def test_declarations_that_do_not_fit_are_refused_when_registered() -> None:
    before = [e.name for e in registry.effects()]
    nosy = Effect(name="nosy_friction", part="pendulum", label="reads another's parameter",
                  description="−c·Ω with the rod's c/J", order=99,
                  params=(Param("pendulum.nosy_c", "1/s", "a friction", absent=0.0, symbol="c_n",
                                typical=0.1),),
                  terms=(Term("rod", 99, lambda xp, theta_dot, nosy_c, c_over_J: -(nosy_c + c_over_J)
                              * theta_dot, "−(c_n + c/J)·Ω"),))
    with pytest.raises(registry.RegistryError, match=r"effect nosy_friction: term '−\(c_n \+ c/J\)·Ω' reads "
                                                     r"\['c_over_J'\], parameter\(s\) of effect "
                                                     r"rod_viscous_friction"):
        registry.register(nosy)
    assert [e.name for e in registry.effects()] == before  # the registry is as it was
    driveless = Family(name="driveless", part="actuator", label="no drive", description="none", order=14,
                       families=("driveless",), lacks={"armature": "x", "rotor_torque": "x"})
    with pytest.raises(registry.RegistryError, match=r"family driveless: 0 drive maps"):
        registry.register(driveless)
    assert "driveless" not in [f.name for f in registry.families()]


def test_an_installed_plugin_is_found_through_its_entry_point(tmp_path: Path, monkeypatch) -> None:
    """A lab package that names its module under the entry-point group is discovered like the
    shipped modules; one whose module cannot be imported is named, never skipped."""
    (tmp_path / "lab_linear_esc.py").write_text(Path(__file__).read_text(encoding="utf-8"), encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    found = [importlib.metadata.EntryPoint("linear_esc", "lab_linear_esc", registry.ENTRY_POINT_GROUP)]
    monkeypatch.setattr(registry, "entry_points", lambda group: found if group == registry.ENTRY_POINT_GROUP
                        else [])
    try:
        registry.refresh()
        assert registry.family("linear_esc").params[0].key == "actuator.omega_full"
        found[0] = importlib.metadata.EntryPoint("broken", "lab_no_such_module", registry.ENTRY_POINT_GROUP)
        registry.refresh()
        with pytest.raises(registry.RegistryError,
                           match=r"plug-in 'broken' \(lab_no_such_module, entry point "
                                 r"'aeropend.components'\) cannot be imported"):
            registry.families()
    finally:
        monkeypatch.undo()
        sys.modules.pop("lab_linear_esc", None)
        registry.refresh()
    assert "linear_esc" not in [f.name for f in registry.families()]


def test_rigs_loaded_before_a_registration_stay_valid() -> None:
    """A family registered and removed later leaves the shipped families' rig sections as they were:
    a rig loaded before still builds its variants (the section classes are kept by content; they
    were remade, and every rig loaded before was refused, in the first version)."""
    rig = load_rig("thesis_rig")
    registry.register(FAMILY)
    registry.unregister(FAMILY.name)
    assert rig.with_params("pendulum", c_over_J=2.0 * rig.pendulum.c_over_J).pendulum.c_over_J > 0.0


def test_an_effect_registered_after_the_rig_format_was_built_is_refused() -> None:
    """The rig format's effects section is made when aeropend_sim.params is imported: a lab's effect
    comes through its package's entry point; a late one is refused by name, the registry unchanged."""
    late = Effect(name="late_friction", part="pendulum", label="late", description="−c_l·Ω", order=98,
                  params=(Param("pendulum.late_c", "1/s", "a friction", absent=0.0, symbol="c_l",
                                typical=0.1),),
                  terms=(Term("rod", 98, lambda xp, theta_dot, late_c: -late_c * theta_dot, "−c_l·Ω"),))
    before = [e.name for e in registry.effects()]
    with pytest.raises(registry.RegistryError, match=r"effect\(s\) \['late_friction'\] after the rig format "
                                                     r"was built"):
        registry.register(late)
    assert [e.name for e in registry.effects()] == before
