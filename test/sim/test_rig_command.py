"""The ``rig`` command (docs/rig_command.md): rig new's file, unit conversion, the static-table and
free-decay methods on synthetic data with known answers, refusals by name, bound flags, rig check."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.integrate import solve_ivp

from aeropend_ident.cli.rig import main
from aeropend_ident.greybox.decay import analyse_decay
from aeropend_ident.greybox.rig_fit import fit_rig
from aeropend_ident.greybox.rig_fit_result import write_fitted
from aeropend_ident.greybox.rig_inputs import is_table, read_table
from aeropend_sim.components import registry
from aeropend_sim.model import PlantModel
from aeropend_sim.params import load_rig
from aeropend_sim.rigfile.units import UnitError, convert

ESC_STATED = ["pendulum.mass=120g", "pendulum.com_distance=18cm", "pendulum.thrust_arm=0.15m",
              "motor.gear_ratio=1", "actuator.omega_max=1085rad/s"]


def _new(tmp_path: Path, family: str, stated: list[str], name: str = "my_rig.yaml") -> Path:
    out = tmp_path / name
    extra = ["--stated", *stated] if stated else []
    assert main(["new", "--actuator", family, *extra, "-o", str(out)]) == 0
    return out


# ------------------------------------------------------------------------------ units
@pytest.mark.parametrize(("text", "unit", "value"), [
    ("0.12kg", "kg", 0.12), ("120 g", "kg", 0.12), ("80ms", "s", 0.08), ("18cm", "m", 0.18),
    ("1000rpm", "rad/s", 1000 * 2 * math.pi / 60), ("2.5 kg*cm^2", "kg*m^2", 2.5e-4), ("15mH", "H", 0.015),
    ("3e-6 N*s^2/rad^2", "N*s^2/rad^2", 3e-6), ("5%", "1", 0.05), ("30deg", "rad", math.pi / 6),
    ("7", "V", 7.0),
])
def test_stated_values_are_converted_to_the_registry_unit(text, unit, value):
    assert convert(text, unit) == pytest.approx(value, rel=1e-12)


def test_a_unit_of_another_dimension_is_refused_naming_both():
    with pytest.raises(UnitError, match=r"unit 'kg' does not convert to 's' \(kg vs s\)"):
        convert("3kg", "s")
    with pytest.raises(UnitError, match="unknown unit 'furlong'"):
        convert("3 furlong", "m")


# ------------------------------------------------------------------------------ rig new
@pytest.mark.parametrize("family", [f.name for f in registry.families()])
def test_rig_new_writes_every_family_parameter_marked_and_it_loads(tmp_path, family):
    path = _new(tmp_path, family, [])
    text = path.read_text(encoding="utf-8")
    rig = load_rig(path)
    statuses = {k: rig.status(k) for k in registry.family_params(family)}
    # the family's base parameters (except the gear, stated or 1) are to be fitted, from the registry
    base = {p.key for part in registry.family_parts(family) for p in part.params if not p.setting}
    todo = {k for k, s in statuses.items() if s == "to be fitted"}
    assert {k for k in base if k != "motor.gear_ratio"} <= todo
    assert "to be fitted" in rig.load_report() and "rig fit" in rig.load_report()
    for key, p in registry.family_params(family).items():
        if statuses[key] == "to be fitted":
            assert f"# {p.symbol or p.name} [{p.unit}]: {p.doc} — TO BE FITTED" in text
            assert rig.sources[key] == "to be fitted (rig fit)"
    assert "plausible" in text and "NOT MODELLED" in text


def test_rig_new_states_converted_values_and_fits_the_inertia_from_the_geometry(tmp_path):
    path = _new(tmp_path, "esc", [*ESC_STATED, "motor.T_m=80ms"])
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    assert doc["pendulum"]["mass"]["value"] == pytest.approx(0.12)
    assert doc["motor"]["T_m"] == {"value": pytest.approx(0.08), "unit": "s",
                                   "source": "stated by the lab (rig new --stated)"}
    assert doc["pendulum"]["inertia"]["source"] == "to be fitted (rig fit)"
    rig = load_rig(path)
    assert rig.status("motor.T_m") == "stated"
    assert rig.status("pendulum.mgd_over_J") == "to be fitted"  # derived from a to-be-fitted inertia
    # plausible inertia range from the geometry: J ≥ m·d² about the pivot
    j0 = 0.12 * 0.18**2
    assert f"plausible {j0:.4g} … {100 * j0:.4g} kg*m^2" in path.read_text(encoding="utf-8")


@pytest.mark.parametrize(("stated", "message"), [
    (["motor.R_a=2ohm"], "not a parameter of a esc rig"),
    (["pendulum.mass=0.1kg"], "the rod's geometry is used as a whole"),
    (["motor.T_m=3kg"], "does not convert"),
    (["motor.T_m"], "expected NAME=VALUE"),
    (["motor.T_m=-1s"], "must be > 0"),
])
def test_rig_new_refuses_bad_stated_values_in_one_line(tmp_path, capsys, stated, message):
    out = tmp_path / "r.yaml"
    assert main(["new", "--actuator", "esc", "--stated", *stated, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and not out.exists()


def test_rig_new_never_overwrites(tmp_path, capsys):
    out = tmp_path / "r.yaml"
    out.write_text("precious", encoding="utf-8")
    assert main(["new", "--actuator", "esc", "-o", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err and out.read_text(encoding="utf-8") == "precious"
    assert main(["new", "--actuator", "esc", "-o", str(out), "--overwrite"]) == 0


# ------------------------------------------------------------------------------ static table
def _balance(tmp_path: Path, rig_path: Path, values: dict[str, float], levels, noise=0.0, seed=0) -> Path:
    """A balance table of the rig with ``values`` in place (the model's own equilibrium)."""
    from aeropend_ident.greybox.rig_problem import BalanceBlock, apply_values

    doc = yaml.safe_load(rig_path.read_text(encoding="utf-8"))
    geo = {f"pendulum.{k}": float(v["value"]) for k, v in doc["pendulum"].items()
           if k in ("mass", "com_distance", "thrust_arm")}
    rig = apply_values(load_rig(rig_path), geo, values)
    levels = np.asarray(levels, dtype=float)
    block = BalanceBlock(source="t", label="", command=levels, angle=np.zeros(levels.size))
    theta = block.residual(rig, []) + np.random.default_rng(seed).normal(0.0, noise, levels.size)
    path = tmp_path / "balance.csv"
    rows = ["command,angle_rad,angle_std_rad"] + [f"{c},{a},{max(noise, 1e-4)}" for c, a in zip(levels, theta,
                                                                                               strict=True)]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_static_table_gives_the_map_and_refuses_what_it_cannot_separate(tmp_path):
    rig_path = _new(tmp_path, "esc", ESC_STATED)
    truth = {"actuator.idle_duty": 0.08, "actuator.curve_exponent": 1.2, "thrust.K_q": 8e-7}
    table = _balance(tmp_path, rig_path, truth, np.linspace(0.15, 0.9, 12))
    assert is_table(table) and read_table(table).kind == "balance"
    res = fit_rig(rig_path, [str(table)])
    for key, true in truth.items():
        o = res.outcome(key)
        assert o.status == "fitted", o.reason
        assert o.value == pytest.approx(true, rel=2e-3)
        assert "balance.csv (balance table" in o.provenance
    # a static table says nothing about timing or damping, nor about the inertia (only L/mgd matters)
    for key in ("motor.T_m", "actuator.input_delay", "pendulum.c_over_J", "pendulum.inertia"):
        o = res.outcome(key)
        assert o.status == "to be fitted" and key in o.reason
    assert "no recording changes the command" in res.outcome("motor.T_m").reason
    assert "holds of about" in res.outcome("motor.T_m").reason


def test_only_the_product_is_determined_names_both_and_how_to_state_one(tmp_path):
    rig_path = _new(tmp_path, "esc", ["motor.gear_ratio=1", "actuator.omega_max=1085rad/s",
                                       "pendulum.mgd_over_J=40"])
    table = _balance(tmp_path, rig_path, {"actuator.idle_duty": 0.08, "actuator.curve_exponent": 1.0,
                                          "thrust.K_q": 8e-7, "pendulum.L_over_J": 25.0},
                     np.linspace(0.15, 0.9, 10))
    res = fit_rig(rig_path, [str(table)])
    kq, lj = res.outcome("thrust.K_q"), res.outcome("pendulum.L_over_J")
    assert kq.status == lj.status == "to be fitted"
    assert "only K_q·L/J is determined by balance.csv" in kq.reason
    assert "thrust vs command from a load cell" in kq.reason and "the geometry" in kq.reason
    # the absorbing member holds the product, so the rig still predicts the table
    assert kq.value * lj.value == pytest.approx(8e-7 * 25.0, rel=1e-3)
    out = tmp_path / "fitted.yaml"
    write_fitted(res, out)
    rig = load_rig(out)
    assert rig.status("thrust.K_q") == "to be fitted" and rig.status("actuator.idle_duty") == "fitted"
    assert "# rig fit: STILL TO BE FITTED — thrust.K_q and pendulum.L_over_J: only K_q·L/J" in out.read_text(
        encoding="utf-8")


def test_a_value_on_its_search_bound_is_flagged_in_terminal_and_file(tmp_path):
    rig_path = _new(tmp_path, "esc", ESC_STATED)
    # the truth's idle throttle 0 sits on the bound of the search range [0, 0.6]
    table = _balance(tmp_path, rig_path, {"actuator.idle_duty": 0.0, "actuator.curve_exponent": 1.0,
                                          "thrust.K_q": 8e-7}, np.linspace(0.1, 0.9, 10))
    res = fit_rig(rig_path, [str(table)])
    o = res.outcome("actuator.idle_duty")
    assert o.status == "fitted" and o.bound == 0.0
    flagged = res.summary().split("AT A SEARCH BOUND")[1]
    assert re.search(r"actuator\.idle_duty = \S+ 1 \(bound 0; searched 0 … 0\.6\)", flagged)
    out = tmp_path / "fitted.yaml"
    write_fitted(res, out)
    text = out.read_text(encoding="utf-8")
    assert "# rig fit: AT SEARCH BOUND 0 1 (within 2% of it; searched 0 … 0.6)" in text
    assert "AT SEARCH BOUND" in load_rig(out).sources["actuator.idle_duty"]


@pytest.mark.parametrize(("header", "rows", "message"), [
    ("command,angle_rad", ["0.5,0.1", "0.6,0.2"], "at least 3"),
    ("command,angle_rad", ["0.5,0.1", "1.4,0.2", "0.6,0.3"], "outside [0, 1]"),
    ("command,angle_rad", ["0.5,0.1", "0.6,x", "0.7,0.3"], "row 3, column angle_rad: 'x' is not a number"),
    ("command,angle_rad,thrust_N", ["0.5,0.1,1", "0.6,0.2,1", "0.7,0.3,1"], "one kind"),
])
def test_bad_tables_are_refused_naming_the_row_and_column(tmp_path, header, rows, message):
    path = tmp_path / "t.csv"
    path.write_text("\n".join([header, *rows]) + "\n", encoding="utf-8")
    with pytest.raises(ValueError, match=re.escape(message)):
        read_table(path)


# ------------------------------------------------------------------------------ free decay
def _decay(F: float, c: float = 0.3, mgd: float = 25.0, seconds: float = 15.0, noise: float = 0.002):
    def f(_t, x):
        return [x[1], -mgd * np.sin(x[0]) - c * x[1] - F * np.tanh(x[1] / 1e-3)]

    t = np.arange(0.0, seconds, 0.01)
    s = solve_ivp(f, (0.0, seconds), [0.6, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=1e-3)
    return t, s.y[0] + np.random.default_rng(0).normal(0.0, noise, t.size)


def test_free_decay_exponential_envelope_gives_frequency_and_viscous_friction():
    t, th = _decay(0.0)
    env = analyse_decay(t, th, 0.002)
    assert env.envelope == "exponential" and not env.dry_friction
    assert env.c_over_J == pytest.approx(0.3, rel=0.05)
    assert env.mgd_over_J == pytest.approx(25.0, rel=0.02)
    assert env.theta_eq == pytest.approx(0.0, abs=0.01)


def test_free_decay_linear_envelope_shows_dry_friction():
    t, th = _decay(0.25, c=0.02, seconds=20.0, noise=5e-4)
    env = analyse_decay(t, th, 5e-4)
    assert env.dry_friction and "linear" in env.envelope
    assert env.coulomb_over_J == pytest.approx(0.25, rel=0.15)


def test_free_decay_without_swings_is_refused_with_what_to_do():
    t = np.arange(0.0, 3.0, 0.01)
    with pytest.raises(ValueError, match="release the rod from a larger angle"):
        analyse_decay(t, 1e-4 * np.random.default_rng(1).normal(size=t.size), 1e-4)


# ------------------------------------------------------------------------------ rig check
def test_rig_check_shows_the_status_table_and_the_reach(tmp_path, capsys):
    rig_path = _new(tmp_path, "esc", ESC_STATED)
    table = _balance(tmp_path, rig_path, {"actuator.idle_duty": 0.08, "actuator.curve_exponent": 1.0,
                                          "thrust.K_q": 8e-7}, np.linspace(0.15, 0.9, 10))
    out = tmp_path / "fitted.yaml"
    assert main(["fit", str(rig_path), str(table), "-o", str(out), "-q"]) == 0
    capsys.readouterr()
    assert main(["check", str(out), str(table)]) == 0
    text = capsys.readouterr().out
    assert "fitted        actuator.idle_duty" in text and "stated        pendulum.mass" in text
    assert "to be fitted  motor.T_m" in text
    from aeropend_control.design import reachable_angle

    reach = reachable_angle(load_rig(out), duty_margin=0.0)
    assert f"reach at full command (τ = 1): {reach:.3f} rad" in text
    assert "sensitivity of the inputs" in text and "not sensitive: these inputs do not depend on it" in text
    # the table cannot separate K_q from L/J (their product only): reported as a pair
    assert "thrust.K_q and pendulum.L_over_J: +1.000" in text


def test_rig_fit_refuses_to_overwrite_and_names_a_missing_input(tmp_path, capsys):
    rig_path = _new(tmp_path, "esc", ESC_STATED)
    out = tmp_path / "fitted.yaml"
    out.write_text("keep", encoding="utf-8")
    assert main(["fit", str(rig_path), str(tmp_path / "nope.csv"), "-o", str(out)]) == 2
    assert "exists" in capsys.readouterr().err and out.read_text(encoding="utf-8") == "keep"
    assert main(["fit", str(rig_path), str(tmp_path / "nope.csv"), "-o", str(tmp_path / "f2.yaml")]) == 2
    err = capsys.readouterr().err
    assert "nope.csv does not exist" in err and err.count("\n") == 1


def test_the_template_thrust_map_matches_the_model(tmp_path):
    """The balance residual is the model's own equilibrium: zero at the rig's own angles."""
    rig_path = _new(tmp_path, "esc", ESC_STATED)
    rig = load_rig(rig_path)
    th = 0.4
    tau = PlantModel(rig).equilibrium(th)[1]
    from aeropend_ident.greybox.rig_problem import BalanceBlock

    block = BalanceBlock(source="t", label="", command=np.array([tau]), angle=np.array([th]))
    assert abs(block.residual(rig, [])[0]) < 1e-8


def test_thrust_table_gives_K_q_and_the_map(tmp_path):
    """A load cell's thrust vs command: K_q and the ESC's map (ω_max stated) from the model's own
    steady thrust; the rod's parameters are not in it and are refused."""
    from aeropend_ident.greybox.fit import motor_equilibrium
    from aeropend_ident.greybox.rig_problem import apply_values

    rig_path = _new(tmp_path, "esc", ESC_STATED)
    truth = {"actuator.idle_duty": 0.07, "actuator.curve_exponent": 0.9, "thrust.K_q": 9e-7}
    rig = apply_values(load_rig(rig_path), {}, truth)
    model = PlantModel(rig)
    levels = np.linspace(0.1, 1.0, 10)
    f = [model.thrust(motor_equilibrium(rig, c)[1]) for c in levels]
    table = tmp_path / "thrust.csv"
    table.write_text("command,thrust_N\n" + "".join(f"{c},{v}\n" for c, v in zip(levels, f, strict=True)),
                     encoding="utf-8")
    res = fit_rig(rig_path, [str(table)])
    for key, true in truth.items():
        o = res.outcome(key)
        assert o.status == "fitted" and o.value == pytest.approx(true, rel=1e-4)
        assert "thrust.csv (thrust table (load cell" in o.provenance
    assert res.outcome("pendulum.inertia").status == "to be fitted"


def test_free_decay_recording_gives_the_inertia_and_damping(tmp_path):
    """A free decay simulated by the model itself (motor off): the fitted inertia and c/J are the
    truth within 2σ, and the envelope note says exponential."""
    from aeropend_ident.greybox.rig_problem import apply_values
    from aeropend_sim.simulation import simulate

    rig_path = _new(tmp_path, "esc", ESC_STATED)
    truth = {"pendulum.inertia": 0.0052, "pendulum.c_over_J": 0.6}
    doc = yaml.safe_load(rig_path.read_text(encoding="utf-8"))
    geo = {f"pendulum.{k}": float(doc["pendulum"][k]["value"])
           for k in ("mass", "com_distance", "thrust_arm")}
    rig = apply_values(load_rig(rig_path), geo, truth)
    n, dt, sigma = 800, 0.01, 0.003
    theta = simulate(rig, np.zeros(n), x0=np.array([0.5, 0.0, 0.0, 0.0, 0.0]), dt=dt).theta
    theta = theta + np.random.default_rng(3).normal(0.0, sigma, n)
    log = tmp_path / "decay.csv"
    log.write_text("time_s,duty,theta_rad\n" + "".join(f"{k * dt},0,{v}\n" for k, v in enumerate(theta)),
                   encoding="utf-8")
    preset = tmp_path / "lab_log.yaml"
    from bench.fixtures.rig_lab import PRESET

    preset.write_text(PRESET, encoding="utf-8")
    res = fit_rig(rig_path, [f"{log}:{preset}"])
    assert any("exponential envelope" in n for n in res.notes)
    for key, true in truth.items():
        o = res.outcome(key)
        assert o.status == "fitted", o.reason
        assert abs(o.value - true) <= 2.0 * o.std, (key, o.value, o.std)
    # the swing does not depend on the throttle map: refused, with the experiment that would determine it
    assert "a balance table" in res.outcome("actuator.idle_duty").reason


@pytest.mark.slow
def test_a_quantised_log_gives_the_fitted_rig_its_angle_lsb(tmp_path):
    """A free decay read by a 10-bit potentiometer ADC (q = 2π/1024 rad): rig fit writes the logs'
    LSB into the fitted rig (sensors.theta_quantum, effects.quantisation on), so a closed-loop check
    on it sees the sensor the controller reads; an unquantised log leaves the rig without one."""
    from aeropend_ident.greybox.rig_fit_result import write_fitted
    from aeropend_ident.greybox.rig_problem import apply_values
    from aeropend_sim.simulation import simulate
    from bench.fixtures.rig_lab import PRESET

    rig_path = _new(tmp_path, "esc", ESC_STATED)
    doc = yaml.safe_load(rig_path.read_text(encoding="utf-8"))
    geo = {f"pendulum.{k}": float(doc["pendulum"][k]["value"])
           for k in ("mass", "com_distance", "thrust_arm")}
    rig = apply_values(load_rig(rig_path), geo, {"pendulum.inertia": 0.0052, "pendulum.c_over_J": 0.6})
    n, dt, q = 800, 0.01, 2 * np.pi / 1024
    theta = simulate(rig, np.zeros(n), x0=np.array([0.5, 0.0, 0.0, 0.0, 0.0]), dt=dt).theta
    preset = tmp_path / "lab_log.yaml"
    preset.write_text(PRESET, encoding="utf-8")
    got = {}
    for name, y in (("adc10", q * np.round(theta / q)), ("smooth", theta)):
        log = tmp_path / f"{name}.csv"
        rows = "".join(f"{k * dt},0,{float(v)!r}\n" for k, v in enumerate(y))
        log.write_text("time_s,duty,theta_rad\n" + rows, encoding="utf-8")
        res = fit_rig(rig_path, [f"{log}:{preset}"])
        out = write_fitted(res, tmp_path / f"fitted_{name}.yaml")
        got[name] = (res, load_rig(out))
    res, fitted = got["adc10"]
    assert res.theta_quantum is not None and res.theta_quantum[0] == pytest.approx(q, rel=1e-6)
    assert fitted.effects.quantisation and fitted.sensors.theta_quantum == pytest.approx(q, rel=1e-6)
    assert f"sensors.theta_quantum = {q:.5g} rad (detected in the logs" in res.summary()
    res, fitted = got["smooth"]
    assert res.theta_quantum is None and not fitted.effects.quantisation
    # a quantum the lab states stands; the logs' other lattice is said in a note
    stated = _new(tmp_path, "esc", [*ESC_STATED, "sensors.theta_quantum=0.01rad"], name="stated.yaml")
    res = fit_rig(stated, [f"{tmp_path / 'adc10.csv'}:{preset}"])
    assert res.theta_quantum is None and res.rig.sensors.theta_quantum == 0.01
    assert any(f"lattice of {q:.5g} rad, the rig file states sensors.theta_quantum 0.01 rad" in n
               for n in res.notes)


def test_a_time_constant_refusal_quotes_the_holds_and_what_would_determine_it():
    from aeropend_ident.greybox.rig_fit import _timing_hint

    assert _timing_hint("motor.T_m", 0.05, 2.0, 0.01) == (
        "the recordings never change the command faster than 2 s; a step or PRBS with holds of about "
        "0.1 s would")
    # a lag shorter than three samples: no hold a lab can command resolves it at this logging rate
    # (the user was told "holds shorter than 0.003 s would" on a 1 ms log)
    short = _timing_hint("motor.T_m", 0.0012, 2.0, 0.001)
    assert short.startswith("at 0.0012 s it is shorter than three samples of these logs (0.001 s each)")
    assert "log faster (a sample period of 0.0004 s or less)" in short and "holds of" not in short


def test_one_step_holds_the_command_as_long_as_its_shorter_side():
    """A log with one step at 5 s (10 s after it) never changes the command faster than 5 s, not 10 s."""
    from aeropend_ident.greybox.rig_inputs import shortest_hold

    class _S:
        def __init__(self, duty):
            self.data = type("D", (), {"duty": duty, "dt": 0.01})()

    duty = np.concatenate([np.full(500, 0.3), np.full(1000, 0.6)])
    assert shortest_hold([_S(duty)]) == pytest.approx(5.0)


def test_rig_check_of_a_shipped_rig_without_inputs(capsys):
    assert main(["check", "thesis_rig"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("rig check: thesis_rig (dc_hbridge): ")
    assert "stated        motor.R_a" in out and "reach at full command (τ = 1):" in out
    assert "sensitivity" not in out


def test_rig_fit_shows_a_line_per_stage_unless_quiet(tmp_path, capsys):
    rig_path = _new(tmp_path, "esc", ESC_STATED)
    table = _balance(tmp_path, rig_path, {"actuator.idle_duty": 0.08, "actuator.curve_exponent": 1.0,
                                          "thrust.K_q": 8e-7}, np.linspace(0.15, 0.9, 8))
    capsys.readouterr()
    assert main(["fit", str(rig_path), str(table), "-o", str(tmp_path / "a.yaml")]) == 0
    loud = capsys.readouterr().out
    assert "rig fit: [1/5] reading 1 input(s)" in loud and "rig fit: [2/5] static tables: balance.csv" in loud
    assert main(["fit", str(rig_path), str(table), "-o", str(tmp_path / "b.yaml"), "-q"]) == 0
    assert "[1/5]" not in capsys.readouterr().out
