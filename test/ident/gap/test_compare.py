"""``compare``: rig files replayed on recordings; per-file CSV presets for every recording argument.

Truth for the replay is the independent plant of ``bench/fixtures/truth_plant.py`` (no aeropend code), so a
rig file equal to its nominal physics must reproduce its recordings and a rig with a wrong
thrust coefficient must not; the scores are checked against closed forms; ``compare`` runs on
every real recording of ``../shared/data/real`` that has an input and an angle, with per-file
presets mixed in one call.
"""

from __future__ import annotations

import fnmatch
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.cli.compare import main
from aeropend_ident.errors import CompareError, RecordingInputError
from aeropend_ident.gap.compare import channel_scores, compare, load_model, step_metrics
from aeropend_ident.io.csv_import import PRESETS
from aeropend_ident.io.recording_input import load_recording, split_preset
from aeropend_ident.io.resampling import uniform_recording
from aeropend_sim.recording import Recording
from bench.fixtures import truth_plant as tp
from bench.fixtures.truth_rig import lab_rig_doc, write_rig

ROOT = Path(__file__).resolve().parents[3]

REAL = ROOT.parent / "shared" / "data" / "real"
DT = tp.DT


def _lab_rig(tmp_path: Path, **frame: float) -> Path:
    """The lab's rig file for the truth plant: thesis_sim with an ideal 2.32 V drive."""
    rig = lab_rig_doc()
    if frame:
        rig["recording_frame"] = {
            k: {"value": v, "unit": "rad" if k == "theta_offset" else "1", "source": "test"}
            for k, v in frame.items()
        }
    return write_rig(rig, tmp_path / ("lab_rig_frame.yaml" if frame else "lab_rig.yaml"))


def _recording(tr: tp.TruthRecording, name: str) -> Recording:
    return Recording(t=tr.t, duty=tr.duty, channels=dict(tr.channels), source=name)


# ------------------------------------------------------------------ recording arguments
def test_split_preset_per_file(tmp_path: Path) -> None:
    assert split_preset("runs/Identification_Data2.csv:aeroshield_ident2") == (
        Path("runs/Identification_Data2.csv"), "aeroshield_ident2")
    assert split_preset("a.csv:auto") == (Path("a.csv"), "auto")
    assert split_preset("bag_dir") == (Path("bag_dir"), None)
    odd = tmp_path / "log:2024.csv"  # an existing file whose name holds a colon stays whole
    odd.write_text("t,x\n", encoding="utf-8")
    assert split_preset(odd) == (odd, None)
    with pytest.raises(RecordingInputError, match="unknown preset 'nope'"):
        split_preset("a.csv:nope")


def test_load_recording_errors_name_the_problem(tmp_path: Path) -> None:
    with pytest.raises(RecordingInputError, match="does not exist"):
        load_recording(tmp_path / "missing.csv")
    unknown = tmp_path / "log.csv"
    unknown.write_text("t,x\n0,1\n", encoding="utf-8")
    with pytest.raises(RecordingInputError, match="no preset matches"):
        load_recording(unknown)
    weird = tmp_path / "log.xyz"
    weird.write_text("", encoding="utf-8")
    with pytest.raises(RecordingInputError, match="unknown kind"):
        load_recording(weird)


def test_uniform_recording_resamples_and_keeps_a_constant_input() -> None:
    t = np.array([0.0, 0.01, 0.02, 0.035, 0.04, 0.05])
    rec = Recording(t=t, duty=np.full(6, 0.5), channels={"theta": 2.0 * t}, source="x")
    u = uniform_recording(rec)
    assert np.allclose(np.diff(u.t), 0.01) and np.allclose(u.channels["theta"], 2.0 * u.t)
    assert np.all(u.duty == 0.5)  # a step from rest (constant input) is valid for compare
    with pytest.raises(RecordingInputError, match="theta"):
        uniform_recording(Recording(t=t, duty=np.full(6, 0.5), channels={"i_a": t}, source="y"))


# ------------------------------------------------------------------ scores: closed forms
def test_channel_scores_closed_form() -> None:
    n = 4000
    duty = np.repeat([0.3, 0.6, 0.4, 0.7], n // 4)
    y = np.repeat([0.0, 1.0, 0.5, 1.5], n // 4) + 0.01 * np.sin(np.arange(n) * 0.01)
    sc = channel_scores(y, y + 0.05, duty, DT, min_hold=1.0)
    assert sc["rms_error"] == pytest.approx(0.05) and sc["max_abs_error"] == pytest.approx(0.05)
    assert sc["nrmse"] == pytest.approx(0.05 / np.ptp(y))
    spread = np.linalg.norm(y - y.mean())
    assert sc["fit_percent"] == pytest.approx(100.0 * (1.0 - 0.05 * math.sqrt(n) / spread))
    assert sc["steady_state_error"]["holds"] == 4
    assert sc["steady_state_error"]["mean"] == pytest.approx(0.05) and sc["steady_state_error"]["rms"] == (
        pytest.approx(0.05))
    rng = np.random.default_rng(3)
    white = channel_scores(y, y + rng.normal(0.0, 0.01, n), duty, DT)["whiteness"]
    assert white["white"] and not white["input_correlated"]
    # a residual that is a lagged copy of the input is neither white nor independent of it
    follows = channel_scores(y, y + 0.2 * np.roll(duty, 10), duty, DT)["whiteness"]
    assert not follows["white"] and follows["input_correlated"]


def test_step_metrics_of_a_first_order_response() -> None:
    """Rise time of 1 − exp(−t/T) is T·ln 9, settling time (2 %) T·ln 50, no overshoot."""
    T, hold = 0.2, 2.0
    m = round(hold / DT)
    duty = np.repeat([0.4, 0.7], m)
    t = np.arange(m) * DT
    y = np.concatenate([np.zeros(m), 0.3 * (1.0 - np.exp(-t / T))])
    steps = step_metrics(y, y, duty, DT)
    assert len(steps) == 1
    rec = steps[0]["recorded"]
    assert rec["rise_time"] == pytest.approx(T * math.log(9.0), abs=3 * DT)
    assert rec["settling_time"] == pytest.approx(T * math.log(50.0), abs=3 * DT)
    assert rec["overshoot"] == pytest.approx(0.0, abs=0.1)
    assert steps[0]["duty_from"] == 0.4 and steps[0]["duty_to"] == 0.7
    assert max(steps[0]["abs_error"].values()) <= 3 * DT  # smoothing the recorded side only


# ------------------------------------------------------------------ replay against an independent plant
def test_lab_rig_reproduces_the_independent_plant_and_a_thrust_error_does_not(tmp_path: Path) -> None:
    duty = tp.lhs_steps(24.0, seed=11)
    exact = _recording(tp.record(tp.TruthPlant(), duty, 60.0, seed=1), "nominal.csv")
    weak = _recording(tp.record(tp.TruthPlant(effects={"thrust_coefficient": 0.8}), duty, 60.0, seed=2),
                      "weak_thrust.csv")
    lab = load_model(str(_lab_rig(tmp_path)), "lab")
    res = compare([lab], [exact, weak])
    good = res.scores["lab"]["nominal.csv"]
    bad = res.scores["lab"]["weak_thrust.csv"]
    for c in ("theta", "i_a", "v_a", "omega_rotor"):  # the noise at 60 dB is 0.1 % of the RMS
        assert good["channels"][c]["nrmse"] < 0.003, c
    assert good["channels"]["theta"]["fit_percent"] > 99.0
    assert bad["channels"]["theta"]["nrmse"] > 20 * good["channels"]["theta"]["nrmse"]
    # 20 % less thrust: the rod hangs lower at every hold; the model predicts it too high
    assert bad["channels"]["theta"]["steady_state_error"]["mean"] > 0.02
    assert bad["channels"]["theta"]["whiteness"]["input_correlated"]
    # the motor is unchanged: i_a and ω₁ still match
    assert bad["channels"]["omega_rotor"]["nrmse"] < 0.003
    assert good["steps"] and good["step_summary"]["rise_time"] < 0.02


def test_recording_frame_of_the_rig_file_is_applied(tmp_path: Path) -> None:
    """A sensor with gain 1.1 and offset −0.05 rad: the rig file's recording_frame reproduces it."""
    tr = tp.record(tp.TruthPlant(), tp.lhs_steps(16.0, seed=4), 60.0, seed=5)
    s, delta = 1.1, -0.05  # θ_rec = s·θ + δ = s·(θ − (−δ/s))
    rec = Recording(t=tr.t, duty=tr.duty, channels={"theta": s * tr.true["theta"] + delta}, source="scaled")
    plain = load_model(str(_lab_rig(tmp_path)), "plain")
    framed = load_model(str(_lab_rig(tmp_path, theta_offset=-delta / s, theta_scale=s)), "framed")
    assert framed.measurement.theta_scale == s
    res = compare([plain, framed], [rec])
    assert res.scores["framed"]["scaled"]["channels"]["theta"]["nrmse"] < 1e-3
    assert res.scores["plain"]["scaled"]["channels"]["theta"]["nrmse"] > 0.02


def test_a_diverging_replay_is_reported_as_divergence_not_a_figure(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], truth_csv_preset: Callable[..., str]) -> None:
    """A rig with 30× the thrust spins the rod over the top (θ leaves the recorded range): no NRMSE.

    Before the fix compare printed and stored an NRMSE of such a run (matheusbucater's sawtooth
    under a rig fitted on it alone: 21.3 with θ → 93 rad), as if it were a figure of fit.
    """
    doc = lab_rig_doc()
    doc["thrust"]["K_q"]["value"] *= 30.0
    strong = write_rig(doc, tmp_path / "strong.yaml")
    tr = tp.record(tp.TruthPlant(), tp.lhs_steps(16.0, seed=7), 30.0, seed=8)
    tr.to_csv(tmp_path / "log.csv")
    res = compare([load_model(str(_lab_rig(tmp_path)), "lab"), load_model(str(strong), "strong")],
                  [_recording(tr, "log.csv")])
    bad = res.scores["strong"]["log.csv"]["channels"]["theta"]
    assert bad["nrmse"] is None and bad["diverges"].startswith("diverges at t = ")
    good = res.scores["lab"]["log.csv"]["channels"]["theta"]
    assert "diverges" not in good and good["nrmse"] < 0.05
    preset = truth_csv_preset("_compare_div", ())
    assert main([f"{tmp_path / 'log.csv'}:{preset}", "--rig", str(strong), "--label", "strong",
                 "-o", str(tmp_path / "out")]) == 0
    row = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("log.csv"))
    assert "DIVERGES: diverges at t = " in row
    doc = json.loads((tmp_path / "out" / "compare.json").read_text(encoding="utf-8"))
    assert doc["scores"]["strong"]["log.csv"]["channels"]["theta"]["nrmse"] is None


def test_compare_refuses_unusable_input(tmp_path: Path) -> None:
    with pytest.raises(CompareError, match="unknown rig"):
        load_model("no_such_rig")
    lab = load_model(str(_lab_rig(tmp_path)))
    rec = Recording(t=np.arange(100) * DT, duty=np.full(100, 0.5), channels={"theta": np.zeros(100)})
    with pytest.raises(CompareError, match="unknown channel"):
        compare([lab], [rec], channels=["pressure"])
    with pytest.raises(CompareError, match="at least one rig"):
        compare([], [rec])


def test_cli_writes_json_and_overlays(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                      truth_csv_preset: Callable[..., str]) -> None:
    plant = tp.TruthPlant(effects={"thrust_coefficient": 0.8})
    tr = tp.record(plant, tp.lhs_steps(16.0, seed=7), 50.0, seed=8)
    tr.to_csv(tmp_path / "log.csv")
    preset = truth_csv_preset("_compare_test", ("i_a", "omega_rotor"))
    rc = main([f"{tmp_path / 'log.csv'}:{preset}", "--rig", str(_lab_rig(tmp_path)), "thesis_rig",
               "--label", "lab", "thesis", "-o", str(tmp_path / "out")])
    assert rc == 0
    out = capsys.readouterr().out
    assert "log.csv" in out and "lab" in out and "thesis" in out
    doc = json.loads((tmp_path / "out" / "compare.json").read_text(encoding="utf-8"))
    assert [m["label"] for m in doc["models"]] == ["lab", "thesis"]
    assert set(doc["scores"]["lab"]["log.csv"]["channels"]) == {"theta", "i_a", "omega_rotor"}
    assert (tmp_path / "out" / "overlay_log.csv.png").stat().st_size > 10_000
    assert main(["log.csv:nope", "--rig", "thesis_rig", "-o", str(tmp_path / "o2")]) == 2
    assert "unknown preset 'nope'" in capsys.readouterr().err
    assert main([str(tmp_path / "log.csv"), "--rig", "thesis_rig", "--label", "a", "b",
                 "-o", str(tmp_path / "o3")]) == 2


# ------------------------------------------------------------------ every real recording
def _real_recordings() -> list[tuple[Path, str]]:
    out = []
    for f in sorted(REAL.rglob("*.csv*")):
        name = f.name[:-3] if f.name.endswith(".gz") else f.name
        for key, spec in PRESETS.items():
            if any(fnmatch.fnmatch(name, pat) for pat in spec.meta.get("files", [])):
                out.append((f, key))
    return out


@pytest.mark.slow
@pytest.mark.real_data
@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/real not present")
def test_compare_runs_on_every_real_recording_with_an_input_and_an_angle(tmp_path: Path) -> None:
    found = _real_recordings()
    presets = {k for _, k in found}
    # every preset's recordings are present; mixed formats in one call (per-file presets)
    assert presets == set(PRESETS), sorted(set(PRESETS) - presets)
    args = [f"{f}:{k}" for f, k in found]
    rigs = ["--rig", "thesis_rig", "aeroshield_rig"]
    assert main([*args, *rigs, "-o", str(tmp_path / "out"), "--no-plots"]) == 0
    doc = json.loads((tmp_path / "out" / "compare.json").read_text(encoding="utf-8"))
    assert len(doc["recordings"]) == len(found)
    for rig in ("thesis_rig", "aeroshield_rig"):
        for rec in doc["recordings"]:
            sc = doc["scores"][rig][rec["label"]]
            if "error" in sc:  # a replay may fail on a foreign rig; it must say why, never vanish
                assert sc["error"]
                continue
            assert sc["channels"]["theta"]["rms_error"] >= 0.0
    # the AeroShield rig on its own sessions: a usable model on both formats
    shield = {r["label"]: doc["scores"]["aeroshield_rig"][r["label"]] for r in doc["recordings"]
              if r["label"].startswith("Identification_Data")}
    assert len(shield) == 2
    assert all(s["channels"]["theta"]["nrmse"] < 0.15 for s in shield.values())
