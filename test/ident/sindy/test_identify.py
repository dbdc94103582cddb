"""The identification command on contract bags and CSV logs (simulated runs written to disk)."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import yaml

from aeropend_ident.cli.identify import main
from aeropend_ident.io.bag_writer import write_bag
from aeropend_sim.excitation import aprbs, density_modulated_prbs
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import simulate
from bench.fixtures.sindy_case import TRUTH

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def noisy_run():
    rig = load_rig("thesis_sim").with_effects(sensor_noise=True).with_params("sensors", snr_db=50)
    return simulate(rig, aprbs(20.0, lo=0.2, hi=0.9, min_hold=0.02, max_hold=0.3, seed=1).duty, seed=3)


@pytest.fixture(scope="module")
def rig_runs():
    """Two 20 s APRBS runs of thesis_rig at 100 Hz, 50 dB (angle-only logs)."""
    rig = load_rig("thesis_rig").with_effects(sensor_noise=True).with_params("sensors", snr_db=50)
    return [simulate(rig, aprbs(20.0, lo=0.35, hi=0.65, min_hold=0.3, max_hold=3.0, seed=s, dt=0.01).duty,
                     seed=s, dt=0.01) for s in (4, 5)]


@pytest.mark.slow
def test_identify_bag_50db(noisy_run, tmp_path, capsys) -> None:
    bag = write_bag(Recording.from_trajectory(noisy_run), tmp_path / "run")
    out = tmp_path / "res"
    t0 = time.perf_counter()
    assert main([str(bag), "--rig", "thesis_sim", "--out", str(out)]) == 0
    wall = time.perf_counter() - t0
    doc = yaml.safe_load((out / "model.yaml").read_text(encoding="utf-8"))
    assert set(doc["equations"]) == {"theta_dot", "i_a", "omega_rotor"}
    assert set(doc["equations"]["theta_dot"]["terms"]) >= {"θ̇", "sin(θ)", "ω₁²"}
    assert doc["derived_parameters"]["K_q"]["value"] == pytest.approx(1e-4, rel=0.02)
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["not_identified"] == {} and summary["heldout"][0]["nrmse_range"] < 0.05
    for name in ("coefficients.png", "derivatives.png", "free_run.png"):
        assert (out / name).read_bytes()[:8] == PNG, name
    cap = capsys.readouterr()
    assert "θ̈ =" in cap.out and "held-out free-run NRMSE" in cap.out
    assert "[identify" in cap.err and "sweeping λ" in cap.err  # progress on stderr
    assert wall < 40.0


def test_identify_angle_only_bag_and_errors(noisy_run, tmp_path, capsys) -> None:
    rec = Recording.from_trajectory(noisy_run, channels=("theta",))
    bag = write_bag(rec, tmp_path / "theta_only")
    assert main([str(bag), "--out", str(tmp_path / "r1"), "--thrust-map", "static", "--quiet"]) == 0
    doc = yaml.safe_load((tmp_path / "r1" / "model.yaml").read_text(encoding="utf-8"))
    assert list(doc["equations"]) == ["theta_dot"]  # no current or rotor equation without i_a, ω₁
    summary = json.loads((tmp_path / "r1" / "summary.json").read_text(encoding="utf-8"))
    assert set(summary["not_identified"]) == {"i_a", "omega_rotor"}
    assert "armature current i_a was not recorded" in summary["not_identified"]["i_a"]
    assert summary["thrust_map"]["time_constant_s"] == 0.0
    assert "not identified (i_a)" in capsys.readouterr().out
    assert main([str(tmp_path / "missing_bag"), "--out", str(tmp_path / "r2")]) == 2
    assert "missing_bag does not exist" in capsys.readouterr().err


@pytest.mark.slow
def test_identify_weak_iv_output_error_on_the_design(tmp_path, capsys) -> None:
    """``--method weak-iv --output-error`` (the issue-4 estimator) through the command: 30 s of the
    identifiability design, noise-free, recovers all three equations; fixed λ in the summary."""
    rig = load_rig("thesis_sim")
    bag = write_bag(Recording.from_trajectory(simulate(rig, density_modulated_prbs(30.0, seed=1).duty)),
                    tmp_path / "design")
    out = tmp_path / "res"
    assert main([str(bag), "--rig", "thesis_sim", "--method", "weak-iv", "--library", "physics",
                 "--output-error", "--no-plots", "--quiet", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["threshold"] == 0.1 and summary["threshold_selection"] == "fixed"
    assert summary["method"] == "weak+oe" and "sweep" not in summary
    doc = yaml.safe_load((out / "model.yaml").read_text(encoding="utf-8"))
    assert "std" in doc["equations"]["i_a"]["terms"]["i_a"]  # output-error standard errors
    assert "std" not in doc["equations"]["theta_dot"]["terms"]["θ̇"]  # θ̈ not refined: no spread
    assert list(doc["equations"]) == ["theta_dot", "i_a", "omega_rotor"]  # dθ/dt = θ̇ is not identified
    for tg in doc["equations"]:
        terms = TRUTH[tg]
        coefs = {name: c["coefficient"] for name, c in doc["equations"][tg]["terms"].items()}
        assert set(coefs) == set(terms), (tg, coefs)
        for name, c in terms.items():
            assert coefs[name] == pytest.approx(c, rel=2e-3), (tg, name)
    capsys.readouterr()
    # weak-iv / output error need the full state; a λ must be finite and >= 0
    bag = write_bag(Recording.from_trajectory(simulate(rig, density_modulated_prbs(5.0, seed=1).duty),
                                              channels=("theta",)), tmp_path / "theta_only")
    assert main([str(bag), "--method", "weak-iv", "--quiet", "--out", str(tmp_path / "x")]) == 2
    assert "need the full state" in capsys.readouterr().err
    assert main([str(bag), "--threshold", "-1", "--quiet", "--out", str(tmp_path / "y")]) == 2
    assert "threshold = -1.0" in capsys.readouterr().err


def test_identify_refuses_bad_recordings(noisy_run, tmp_path, capsys) -> None:
    n = 2000
    tr_t = noisy_run.t[:n]
    # a bag without an angle: nothing to identify
    no_theta = Recording(t=tr_t, duty=noisy_run.duty[:n], channels={"i_a": noisy_run.channels()["i_a"][:n]})
    bag = write_bag(no_theta, tmp_path / "no_theta")
    assert main([str(bag), "--out", str(tmp_path / "a"), "--quiet"]) == 2
    assert "the angle must be measured" in capsys.readouterr().err
    # NaNs in the angle
    th = noisy_run.channels()["theta"][:n].copy()
    th[700:705] = np.nan
    bag = write_bag(Recording(t=tr_t, duty=noisy_run.duty[:n], channels={"theta": th}), tmp_path / "nan")
    assert main([str(bag), "--out", str(tmp_path / "b"), "--quiet", "--thrust-map", "static"]) == 2
    err = capsys.readouterr().err
    assert "NaN/inf in 5 of 2000 samples" in err and "theta" in err
    # unexcited: a constant duty with θ at rest (noise only) -> nothing is identifiable
    flat = simulate(load_rig("thesis_rig"), np.full(1500, 0.5), dt=0.01)
    still = 0.3 + 1e-3 * np.random.default_rng(0).standard_normal(1500)
    rest = Recording(t=flat.t, duty=flat.duty, channels={"theta": still})
    bag = write_bag(rest, tmp_path / "rest")
    assert main([str(bag), "--out", str(tmp_path / "c"), "--quiet", "--thrust-map", "static"]) == 2
    assert "nothing excites the rig" in capsys.readouterr().err
    # a step from rest under that constant duty is a step test: accepted (one level, no thrust terms),
    # and its held-out part, a hold at the final angle, is scored in the recording's range
    bag = write_bag(Recording.from_trajectory(flat, channels=("theta",)), tmp_path / "step")
    assert main([str(bag), "--out", str(tmp_path / "c2"), "--quiet", "--thrust-map", "static"]) == 0
    (score,) = json.loads((tmp_path / "c2" / "summary.json").read_text())["heldout"]
    assert score["nrmse_range"] < 0.05 and "diverges" not in score
    # too short for the derivative estimate / library
    short = Recording(t=tr_t[:6], duty=noisy_run.duty[:6],
                      channels={"theta": noisy_run.channels()["theta"][:6]})
    bag = write_bag(short, tmp_path / "short")
    assert main([str(bag), "--out", str(tmp_path / "d"), "--quiet", "--thrust-map", "static"]) == 2
    assert "6 samples" in capsys.readouterr().err


@pytest.mark.slow
def test_identify_csv_logs_several_recordings(rig_runs, tmp_path, capsys) -> None:
    """Two angle-only CSV logs (PWM counts, degrees) through a custom-preset-free path: the
    etchepareborda preset's layout (t, pwm, theta [rad]); training parts stacked, each held-out
    part scored; thesis_rig's c/J 2.2343 and mgd/J 15.472 recovered within 10 %."""
    paths = []
    for k, tr in enumerate(rig_runs):
        pwm = np.round(tr.duty * 255.0)
        rows = "\n".join(f"{t:.2f},{int(p)},{th:.6f}" for t, p, th in zip(tr.t, pwm, tr.channels()["theta"],
                                                                           strict=True))
        p = tmp_path / f"openloop_sim_{k}.csv"
        p.write_text("t [s],pwm [0-255],theta [rad]\n" + rows + "\n", encoding="utf-8")
        paths.append(str(p))
    out = tmp_path / "multi"
    # the duty is quantised to 1/255 like a real analogWrite log; v_a from thesis_rig's map
    assert main([*paths, "--rig", "thesis_rig", "--out", str(out), "--method", "ensemble",
                 "--train-fraction", "0.7"]) == 0
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert len(summary["heldout"]) == 2 and all(h["nrmse_range"] < 0.05 for h in summary["heldout"])
    p = summary["derived_parameters"]
    assert p["c_over_J"]["value"] == pytest.approx(2.2343, rel=0.10)
    assert p["mgd_over_J"]["value"] == pytest.approx(15.472, rel=0.10)
    assert p["thrust_time_constant"]["unit"] == "s" and p["thrust_time_constant"]["value"] <= 0.05
    doc = yaml.safe_load((out / "model.yaml").read_text(encoding="utf-8"))
    assert all("std" in v for v in doc["equations"]["theta_dot"]["terms"].values())
    assert doc["provenance"]["thrust_map"]["time_constant_s"] >= 0.0
    assert (out / "free_run.png").read_bytes()[:8] == PNG
    # the weak form is refused for stacked recordings
    assert main([*paths, "--out", str(tmp_path / "w"), "--method", "weak", "--quiet"]) == 2
    assert "weak form" in capsys.readouterr().err


@pytest.mark.slow
def test_identify_plots_in_child_process_equal_in_process(noisy_run, tmp_path, monkeypatch) -> None:
    """The forked plotting child (training-tail free run sent back through a pipe, then
    coefficients.png / derivatives.png) gives the same pictures as drawing everything in-process;
    a child that dies before sending anything falls back to doing it all in-process."""
    import multiprocessing

    import matplotlib.image as mpimg

    from aeropend_ident.sindy import identify as ident

    n = 3906  # 8 s at 490 Hz
    rec = Recording.from_trajectory(noisy_run)
    rec = Recording(t=rec.t[:n], duty=rec.duty[:n], channels={k: v[:n] for k, v in rec.channels.items()})
    bag = write_bag(rec, tmp_path / "run8s")
    rig = load_rig("thesis_sim")
    names = ["coefficients.png", "derivatives.png", "free_run.png"]
    started = []
    real_start = ident._start_plot_child

    def spy(*a):
        child = real_start(*a)
        started.append(child)
        return child

    monkeypatch.setattr(ident, "_start_plot_child", spy)
    s_child = ident.identify(bag, tmp_path / "child", rig)
    assert started and started[0] is not None and started[0].proc.exitcode == 0  # the child did its part

    def failing(out, model, held, train):
        ctx = multiprocessing.get_context("fork")
        recv, send = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=lambda: 1 / 0, daemon=True)
        proc.start()
        send.close()
        return ident._PlotChild(proc, recv)

    monkeypatch.setattr(ident, "_start_plot_child", failing)
    s_fallback = ident.identify(bag, tmp_path / "fallback", rig)
    assert s_child["files"] == s_fallback["files"] == ["model.yaml", "summary.json", *names]
    assert s_child["equations"] == s_fallback["equations"]
    for name in names:  # the fallback drew everything in this process (the same path as without fork)
        ref = mpimg.imread(tmp_path / "fallback" / name)
        assert ref.shape[0] > 100
        np.testing.assert_array_equal(mpimg.imread(tmp_path / "child" / name), ref, err_msg=name)
