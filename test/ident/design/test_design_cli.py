"""``excitation_design`` and ``excitation --design-for`` end to end on a small case (issue 63):
a D-optimal design for two pendulum parameters of a rig file from a simulated step log, its
files, the CSV the excitation node plays, and the error exits."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.design.cli import main
from aeropend_ident.io.bag_writer import write_bag
from aeropend_sim.excitation import make_signal
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording
from aeropend_sim.ros import excitation_node
from aeropend_sim.simulation import simulate

RIG = (Path(__file__).resolve().parents[3] / "src" / "aeropend_sim" / "aeropend_sim" / "rigs"
       / "thesis_sim.yaml")
DT = 0.02048


@pytest.fixture(scope="module")
def step_log(tmp_path_factory) -> Path:
    duty = np.concatenate([np.zeros(25), np.full(250, 0.45)])
    traj = simulate(load_rig("thesis_sim"), duty, dt=DT)
    theta = traj.true["theta"] + np.random.default_rng(0).normal(0.0, 2e-3, duty.size)
    rec = Recording(t=np.arange(duty.size) * DT, duty=duty, channels={"theta": theta}, source="step")
    path = tmp_path_factory.mktemp("rec") / "step_bag"
    write_bag(rec, path)
    return path


def test_parameter_design_writes_its_files(tmp_path, step_log, capsys):
    out = tmp_path / "design"
    code = excitation_node.main(["--design-for", str(RIG), str(step_log), "--parameters", "pendulum.c_over_J",
                                 "pendulum.mgd_over_J", "--duration", "6", "--budget", "4", "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    doc = json.loads((out / "design.json").read_text())
    assert doc["kind"] == "parameters" and doc["limits_check"]["ok"]
    for k in ("pendulum.c_over_J", "pendulum.mgd_over_J"):
        assert doc["sd_after"][k] < doc["sd_before"][k]
    sig = make_signal("file", file=str(out / "design.csv"))
    assert sig.duration == pytest.approx(6.0, abs=DT) and sig.dt == pytest.approx(DT, rel=1e-3)
    assert "Predicted relative 1σ" in (out / "design.md").read_text()


def test_a_closed_loop_parameter_design_writes_the_controllers_steps(tmp_path, step_log, capsys):
    import yaml

    out = tmp_path / "design"
    code = main(["--design-for", str(RIG), str(step_log), "--parameters", "pendulum.c_over_J", "--mode",
                 "reference", "--duration", "8", "--max-evaluations", "10", "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    doc = json.loads((out / "design.json").read_text())
    assert doc["mode"] == "reference" and doc["limits_check"]["ok"]
    assert doc["sd_after"]["pendulum.c_over_J"] < doc["sd_before"]["pendulum.c_over_J"]
    params = yaml.safe_load((out / "design_controller.yaml").read_text())["/**/aeropend_controller"]
    assert params["ros__parameters"]["rig"] == str(RIG) and len(params["ros__parameters"]["steps"]) >= 4
    assert (out / "design.csv").read_text().startswith("t,reference\n")
    assert "seeded set points" in (out / "design.md").read_text()


def test_error_exits(tmp_path, step_log, capsys):
    assert main(["--design-for", str(RIG), str(step_log), "--duration", "90", "-o", str(tmp_path / "x")]) == 2
    assert "at most 60 s" in capsys.readouterr().err
    ref = ["--mode", "reference", "--strategy", "no_such_strategy", "-o", str(tmp_path / "x")]
    assert main(["--design-for", str(RIG), str(step_log), "--parameters", "pendulum.c_over_J", *ref]) == 2
    assert "no_such_strategy" in capsys.readouterr().err
    assert main(["--design-for", str(RIG), str(step_log), "-o", str(tmp_path / "x")]) == 2  # no weak key
    assert "--parameters" in capsys.readouterr().err
    (tmp_path / "notgap").mkdir()
    (tmp_path / "notgap" / "report.json").write_text('{"tool": "other"}')
    assert main(["--design-for", str(tmp_path / "notgap"), str(step_log), "-o", str(tmp_path / "x")]) == 2
    assert "not a gap report" in capsys.readouterr().err


def _design_doc(cands: list, duty: np.ndarray, predicted: dict, **extra) -> dict:
    """A discrimination design.json of ``cands`` on ``duty`` (thesis_sim, θ alone, σ 2 mrad)."""
    return {"kind": "discrimination", "rig": str(RIG), "sigma": {"theta": 2e-3},
            "candidates": [c.as_dict() for c in cands], "duration_s": duty.size * DT, "seed": 0,
            "limits": {"dt": DT, "duty_min": 0.0, "duty_max": 1.0, "max_slew": 1e3, "theta_min": -1.0,
                       "theta_max": 1.5}, "limits_check": {"ok": True}, "evaluations": 1, "elapsed_s": 0.0,
            "predicted": {"per_candidate": predicted, "draws": 1},
            "predicted_baseline_aprbs": {"per_candidate": {}, "draws": 1},
            "min_divergence": 1.0, "baseline_min_divergence": 1.0, **extra}


def test_outcome_compares_the_prediction_with_a_new_report(tmp_path, capsys):
    from aeropend_ident.design.candidates import Candidate
    from aeropend_ident.design.discriminate import Predictor
    from aeropend_ident.design.report import write_design
    from aeropend_ident.gap.effects import apply_effects

    rig = load_rig("thesis_sim")
    lagged, meas = apply_effects(rig, {"actuator_lag": {"lag_time_constant": 0.02}})
    cands = [Candidate("nominal", (), rig), Candidate("actuator_lag", ("actuator_lag",), lagged, meas)]
    duty = np.concatenate([np.zeros(25), np.tile(np.repeat([0.3, 0.6], 15), 10)])
    doc = _design_doc(cands, duty, {"nominal": 0.97, "actuator_lag": 0.96}, chosen_before=[])
    write_design(tmp_path / "design", doc, duty, DT, cands)
    theta = Predictor(cands, ("theta",), DT, duty.size)(duty)["theta"][1]
    rec = Recording(t=np.arange(duty.size) * DT, duty=duty,
                    channels={"theta": theta + np.random.default_rng(1).normal(0, 2e-3, duty.size)})
    write_bag(rec, tmp_path / "designed")
    (tmp_path / "gap").mkdir()
    report = {"tool": "aeropend_ident gap", "which": {"significant": True, "chosen": ["actuator_lag"],
                                                     "ranking": []}}
    (tmp_path / "gap" / "report.json").write_text(json.dumps(report))
    assert main(["--outcome", str(tmp_path / "gap"), "--design", str(tmp_path / "design"),
                 str(tmp_path / "designed")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["matching_candidate"] == "actuator_lag" and out["predicted_first"] == 0.96
    assert out["changed"] and out["recording_first"] == "actuator_lag" and out["recording_agrees_with_gap"]
    assert out["recording_chi2"]["nominal"] > 2 * out["recording_chi2"]["actuator_lag"]
    # the recording's own verdict: the nominal rig refuted, the lag named
    assert out["recording_names"] == ["actuator_lag"] and out["not_separated"] == ["actuator_lag"]
    assert out["refuted_p"]["nominal"] < 0.05
    assert 0.8 < out["recording_best_rms_over_noise"] < 1.2  # the lag explains it: noise is left
    assert "note" not in out


@pytest.mark.slow
def test_outcome_refits_the_candidates_when_none_explains_the_designed_recording(tmp_path, capsys):
    """The truth has 30 % less thrust (K_q × 0.7); the design's candidates, the nominal rig and one
    with 20 % more inertia, both miss its designed recording by far more than the noise. ``--outcome``
    then refits them, their swap neighbours and nested special cases on the earlier recording
    (design.json's ``earlier``) and the designed one together and judges again: the thrust
    coefficient is named and explains the recording to its noise, the candidates given refuted;
    ``--no-refit`` stops at "explained by none"."""
    from aeropend_ident.design.candidates import Candidate
    from aeropend_ident.design.discriminate import Predictor
    from aeropend_ident.design.report import write_design
    from aeropend_ident.gap.effects import apply_effects
    from aeropend_sim.excitation import aprbs

    rig = load_rig("thesis_sim")
    kq = rig.thrust.K_q
    truth, tmeas = apply_effects(rig, {"thrust_coefficient": {"K_q": 0.7 * kq}})
    heavy, meas = apply_effects(rig, {"inertia": {"J_scale": 1.2}})
    cands = [Candidate("nominal", (), rig), Candidate("inertia", ("inertia",), heavy, meas)]
    rng = np.random.default_rng(3)

    def record(duty: np.ndarray, name: str) -> Path:
        y = Predictor([Candidate("truth", ("thrust_coefficient",), truth, tmeas)], ("theta",), DT,
                      duty.size)(duty)["theta"][0]
        rec = Recording(t=np.arange(duty.size) * DT, duty=duty,
                        channels={"theta": y + rng.normal(0.0, 2e-3, duty.size)}, source=name)
        write_bag(rec, tmp_path / name)
        return tmp_path / name

    earlier = record(aprbs(12.0, lo=0.35, hi=0.7, min_hold=0.2, max_hold=1.5, seed=1, dt=DT).duty, "earlier")
    duty = aprbs(16.0, lo=0.2, hi=0.8, min_hold=0.1, max_hold=1.0, seed=4, dt=DT).duty
    designed = record(duty, "designed")
    doc = _design_doc(cands, duty, {"nominal": 0.9, "inertia": 0.9}, chosen_before=["inertia"],
                      earlier=[str(earlier)], preset=None)
    write_design(tmp_path / "design", doc, duty, DT, cands)
    (tmp_path / "gap").mkdir()
    (tmp_path / "gap" / "report.json").write_text(json.dumps(
        {"tool": "aeropend_ident gap", "which": {"significant": True, "chosen": ["thrust_coefficient"],
                                                 "ranking": []}}))
    args = ["--outcome", str(tmp_path / "gap"), "--design", str(tmp_path / "design"), str(designed)]
    assert main([*args, "--no-refit"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["recording_unexplained"] and out["recording_best_rms_over_noise"] > 3.0
    assert out["recording_names"] is None and "refit" not in out
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    ref = out["refit"]
    assert "skipped" not in ref, ref
    assert out["recording_names_as_sized"] is None
    assert out["recording_names"] == ["thrust_coefficient"] == ref["names"], ref
    assert not ref["unexplained"] and 0.8 < ref["best_rms_over_noise"] < 1.2
    row = next(r for r in ref["sets_fitted"] if r["effects"] == ["thrust_coefficient"])
    assert "fit_sse" in row
    assert all(p < 0.05 / (len(ref["refuted_p"])) for n, p in ref["refuted_p"].items()
               if n in ("nominal", "inertia")), ref["refuted_p"]
    assert "Refitted on the earlier recordings and the designed one" in out["note"]


def test_rig_fits_inputs_are_taken_as_they_are(tmp_path, capsys):
    """A balance table beside a recording (what rig fit takes) is accepted: the design replays the
    recording and takes its default command limit from the table too (a free decay alone, command
    0, would leave no command to design with); a table alone is refused by name."""
    rig = load_rig("thesis_sim")
    n = 300
    traj = simulate(rig, np.zeros(n), dt=DT, x0=np.array([0.5, 0.0, 0.0, 0.0, 0.0]))
    theta = traj.true["theta"] + np.random.default_rng(1).normal(0.0, 2e-3, n)
    decay = tmp_path / "decay_bag"
    write_bag(Recording(t=np.arange(n) * DT, duty=np.zeros(n), channels={"theta": theta}, source="decay"),
              decay)
    table = tmp_path / "balance.csv"
    table.write_text("command,angle_rad,angle_std_rad\n0.2,0.21,0.002\n0.35,0.52,0.002\n0.5,0.93,0.002\n")
    out = tmp_path / "design"
    code = main(["--design-for", str(RIG), str(table), str(decay), "--parameters", "pendulum.c_over_J",
                 "--duration", "6", "--budget", "4", "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "balance.csv: static table(s), read by rig fit and gap; the design replays the recordings" in err
    doc = json.loads((out / "design.json").read_text())
    assert doc["limits"]["duty_max"] == pytest.approx(0.5)  # the table's largest command
    duty = np.loadtxt(out / "design.csv", delimiter=",", skiprows=1)[:, 1]
    assert duty.max() > 0.05 and duty.max() <= 0.5 + 1e-12
    assert main(["--design-for", str(RIG), str(table), "--parameters", "pendulum.c_over_J",
                 "-o", str(tmp_path / "y")]) == 2
    assert "static tables alone hold no command sequence" in capsys.readouterr().err


def test_an_earlier_design_is_replaced_only_with_overwrite(tmp_path, step_log, capsys):
    """-o is checked before the search: a folder with a lab's files is refused (with or without
    --overwrite); an earlier design is refused without --overwrite and left byte for byte as it was,
    and replaced with it (no stale file of the earlier design stays)."""
    args = ["--design-for", str(RIG), str(step_log), "--parameters", "pendulum.c_over_J", "--duration", "3",
            "--max-evaluations", "4", "--budget", "4"]
    lab = tmp_path / "lab"
    lab.mkdir()
    (lab / "notes.txt").write_text("mine")
    for extra in ([], ["--overwrite"]):
        assert main([*args, "-o", str(lab), *extra]) == 2
        assert "notes.txt" in capsys.readouterr().err and (lab / "notes.txt").read_text() == "mine"
    out = tmp_path / "design"
    assert main([*args, "-o", str(out)]) == 0
    capsys.readouterr()
    earlier = {p.name: p.read_bytes() for p in out.iterdir()}
    (out / "candidates").mkdir()  # as a discrimination design leaves it
    assert main([*args, "--seed", "1", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "exists and is not empty" in err and "--overwrite" in err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == earlier
    assert main([*args, "--seed", "1", "-o", str(out), "--overwrite"]) == 0
    assert json.loads((out / "design.json").read_text())["seed"] == 1
    assert sorted(p.name for p in out.iterdir()) == ["design.csv", "design.json", "design.md"]
    # a design folder that holds one of the inputs is never emptied, even with --overwrite
    import shutil

    inside = out / "step_bag"
    shutil.copytree(step_log, inside)
    held = ["--design-for", str(RIG), str(inside), *args[3:]]
    assert main([*held, "-o", str(out), "--overwrite"]) == 2
    assert "holds the input" in capsys.readouterr().err and inside.is_dir() and (out / "design.json").exists()


def test_a_reference_design_of_a_gap_report_writes_the_controllers_steps(tmp_path, capsys):
    """``--mode reference`` (closed loop): set points for the controller node, its parameters file,
    the prediction made with the lab's controller on every candidate."""
    import yaml

    from aeropend_control.controller_core import parse_steps
    from aeropend_ident.gap.effects import apply_effects

    rig = load_rig("thesis_sim")
    lagged, _ = apply_effects(rig, {"actuator_lag": {"lag_time_constant": 0.03}})
    duty = np.concatenate([np.zeros(25), np.full(120, 0.45), np.full(120, 0.3), np.full(120, 0.5)])
    traj = simulate(lagged, duty, dt=DT)
    theta = traj.true["theta"] + np.random.default_rng(1).normal(0.0, 2e-3, duty.size)
    log = tmp_path / "closed_bag"
    write_bag(Recording(t=np.arange(duty.size) * DT, duty=duty, channels={"theta": theta}, source="x"), log)
    report = tmp_path / "gap_report"
    report.mkdir()
    report.joinpath("report.json").write_text(json.dumps({
        "tool": "aeropend_ident gap", "inputs": {"rig": {"ref": str(RIG)}},
        "which": {"significant": True, "chosen": ["actuator_lag"],
                  "ranking": [{"effect": "actuator_lag", "ambiguous_with": ["input_delay"]},
                              {"effect": "input_delay", "ambiguous_with": ["actuator_lag"]}]}}))
    lab = tmp_path / "lab_controller.yaml"
    lab.write_text("/**/aeropend_controller:\n  ros__parameters:\n    strategy: fl_pid\n")
    out = tmp_path / "design"
    code = main(["--design-for", str(report), str(log), "--mode", "reference", "--controller", str(lab),
                 "--duration", "10", "--max-evaluations", "12", "--max-effects", "1", "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    doc = json.loads((out / "design.json").read_text())
    assert doc["mode"] == "reference" and doc["controller"]["strategy"] == "fl_pid"
    assert doc["limits_check"]["ok"] and doc["evaluations"] <= 12 + 12
    assert set(doc["predicted"]["loop"]) == {c["name"] for c in doc["candidates"]}
    params = yaml.safe_load((out / "design_controller.yaml").read_text())["/**/aeropend_controller"]
    steps = parse_steps(params["ros__parameters"]["steps"])
    assert np.allclose(np.array(steps), np.array(doc["steps"]), atol=1e-9)
    head = (out / "design.csv").read_text().splitlines()
    assert head[0] == "t,reference" and len(head) == 1 + round(10 / DT)
    ref_col = np.array([float(x.split(",")[1]) for x in head[1:]])
    assert ref_col.min() >= 0.0 and ref_col.max() <= doc["limits"]["theta_max"]
    md = (out / "design.md").read_text()
    assert "closed loop" in md and "design_controller.yaml" in md
    # set points are never played as commands
    from aeropend_sim.excitation import ExcitationError

    with pytest.raises(ExcitationError, match="an angle"):
        make_signal("file", file=str(out / "design.csv"))
    # the controller options belong to a reference design
    y = tmp_path / "y"
    assert main(["--design-for", str(report), str(log), "--strategy", "fl_pid", "-o", str(y)]) == 2
    assert "--mode reference" in capsys.readouterr().err
