"""No command replaces a result without ``--overwrite`` (issue 34, item 3).

The rule (:mod:`aeropend_sim.output_folder`): a non-empty output folder is refused before any
computation, naming the folder, what it holds and the flag, and left byte-identical; with
``--overwrite`` the earlier run's files go (a stale file of an earlier run included), but only from
a folder that looks like the command's own output and is no protected place. Every command that
writes a result folder or file is run here on the smallest input it accepts.
"""

from __future__ import annotations

import contextlib
import io
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.io.bag_writer import write_bag
from aeropend_sim.excitation import aprbs
from aeropend_sim.output_folder import OutputFolderError, check_output_file, claim_output_folder
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import simulate

DT = 0.01
#: The refusal comes before any computation: well under this [s] (imports already done).
REFUSAL_S = 1.0
STALE = "stale_from_an_earlier_run.png"


# ------------------------------------------------------------------------- the rule itself
def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _earlier_run(folder: Path, own: str) -> dict[str, bytes]:
    """A folder as an earlier run left it: one of the command's own files and a stale one."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / own).write_text("earlier run\n")
    (folder / STALE).write_bytes(b"\x89PNG stale")
    return _tree(folder)


def test_missing_or_empty_folder_is_used(tmp_path: Path) -> None:
    out = claim_output_folder(tmp_path / "a" / "b", False, own=["report.json"], looks_like="a report")
    assert out.prepare() == tmp_path / "a" / "b" and (tmp_path / "a" / "b").is_dir()
    (tmp_path / "empty").mkdir()
    assert claim_output_folder(tmp_path / "empty", False, own=["x"], looks_like="x").prepare().is_dir()
    bag = claim_output_folder(tmp_path / "empty", False, own=["x"], looks_like="x").prepare(create=False)
    assert not bag.exists()  # a writer that must create the folder itself (rosbag2) gets none


def test_non_empty_folder_is_refused_without_overwrite(tmp_path: Path) -> None:
    before = _earlier_run(tmp_path / "g", "report.json")
    for name in ("report.html", "corrected_rig.yaml", "notes.txt"):
        (tmp_path / "g" / name).write_text(name)
    (tmp_path / "g" / "figures").mkdir()
    before = _tree(tmp_path / "g")
    with pytest.raises(OutputFolderError) as err:
        claim_output_folder(tmp_path / "g", False, own=["report.json"], looks_like="a gap report")
    assert str(err.value) == (
        f"output folder {tmp_path / 'g'}/ exists and is not empty (corrected_rig.yaml, figures/, notes.txt, "
        "report.html and 2 more); pass --overwrite to replace it or choose another -o")
    assert _tree(tmp_path / "g") == before


def test_overwrite_removes_the_earlier_run_when_the_new_one_is_written(tmp_path: Path) -> None:
    _earlier_run(tmp_path / "g", "report.json")
    (tmp_path / "g" / "figures").mkdir()
    (tmp_path / "g" / "figures" / "old.png").write_bytes(b"old")
    out = claim_output_folder(tmp_path / "g", True, own=["report.json", "figures"], looks_like="a gap report")
    assert (tmp_path / "g" / STALE).exists()  # the claim only checks: a failed run keeps the result
    assert out.prepare() == tmp_path / "g"
    assert list((tmp_path / "g").iterdir()) == []


def test_overwrite_never_empties_a_folder_of_other_files(tmp_path: Path) -> None:
    data = tmp_path / "recordings"
    data.mkdir()
    (data / "run1.mcap").write_bytes(b"irreplaceable")
    with pytest.raises(OutputFolderError, match=r"does not look like a gap report \(it holds run1.mcap, none "
                                                r"of report.json, figures\); --overwrite replaces only"):
        claim_output_folder(data, True, own=["report.json", "figures"], looks_like="a gap report")
    assert (data / "run1.mcap").read_bytes() == b"irreplaceable"


@pytest.mark.parametrize("where", ["working folder", "above the working folder", "home", "git repository",
                                   "holds the input", "symbolic link"])
def test_overwrite_never_empties_a_protected_folder(where: str, tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    folder = tmp_path / "f"
    folder.mkdir()
    (folder / "report.json").write_text("own-looking")
    inputs: list[Path] = []
    target = folder
    if where == "working folder":
        monkeypatch.chdir(folder)
        target, reason = Path("."), "it is the working folder"
    elif where == "above the working folder":
        (folder / "sub").mkdir()
        monkeypatch.chdir(folder / "sub")
        target, reason = Path(".."), "it holds the working folder"
    elif where == "home":
        monkeypatch.setenv("HOME", str(folder))
        reason = "it is the home folder"
    elif where == "git repository":
        (folder / ".git").mkdir()
        reason = "it is a git repository"
    elif where == "holds the input":
        (folder / "run_bag").mkdir()
        inputs = [folder / "run_bag"]
        reason = f"it holds the input {folder / 'run_bag'}"
    else:
        target = tmp_path / "link"
        target.symlink_to(folder)
        reason = "it is a symbolic link"
    before = _tree(folder)
    with pytest.raises(OutputFolderError, match=f"is not emptied even with --overwrite: {reason}"):
        claim_output_folder(target, True, own=["report.json"], looks_like="a report", inputs=inputs)
    assert _tree(folder) == before


def test_output_file(tmp_path: Path) -> None:
    gains = tmp_path / "gains.yaml"
    assert check_output_file(gains, False) == gains
    gains.write_text("kp: 1\n")
    with pytest.raises(OutputFolderError, match=f"output file {gains} exists; pass --overwrite to replace"):
        check_output_file(gains, False)
    assert check_output_file(gains, True) == gains
    with pytest.raises(OutputFolderError, match="is a folder"):
        check_output_file(tmp_path, True)


# ------------------------------------------------------------------------- every command
def _recording(seed: int, duration: float) -> Recording:
    real = load_rig("thesis_rig").with_effects(coulomb_friction=True, sensor_noise=True).with_params(
        "pendulum", coulomb_over_J=0.5)
    d = aprbs(duration, lo=0.3, hi=0.8, min_hold=0.3, max_hold=1.5, seed=seed, dt=DT).duty.copy()
    d[:50] = 0.0
    return Recording.from_trajectory(simulate(real, d, dt=DT, seed=seed), channels=("theta",),
                                     source=f"synthetic seed {seed}")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("inputs")
    csv = root / "log.csv"
    t = np.arange(200) * DT
    rows = [f"{a:.2f},{0.3 + 0.2 * (k // 50 % 2):.3f},{0.1 * np.sin(a):.5f}" for k, a in enumerate(t)]
    csv.write_text("t,duty,angle\n" + "\n".join(rows) + "\n")
    return {"bag": write_bag(_recording(1, 12.0), root / "fit"),
            "held": write_bag(_recording(2, 8.0), root / "held"), "csv": csv}


def _main(name: str) -> Callable[[list[str]], int]:
    from aeropend_control.design_gains import main as design_gains
    from aeropend_ident.cli import baseline, compare, csv_import, gap, identify, pipeline

    return {"baseline": baseline.main, "compare": compare.main, "identify": identify.main, "gap": gap.main,
            "csv_import": csv_import.main, "pipeline": pipeline.main, "design_gains": design_gains}[name]


#: command -> (arguments before the output option, output option, exit status of a refusal,
#:             one of its own files, what a new run leaves in the folder)
COMMANDS: dict[str, tuple[Callable[[dict[str, Path]], list[str]], str, int, str, set[str]]] = {
    "baseline": (lambda d: [str(d["bag"]), "--rig", "thesis_rig", "--decimate", "4", "--init-horizon", "0"],
                 "-o", 2, "report.json", {"report.json", "overlay.png", "fitted_rig.yaml"}),
    "compare": (lambda d: [str(d["bag"]), "--rig", "thesis_rig"], "-o", 2, "compare.json",
                {"compare.json", "overlay_fit.png"}),
    "identify": (lambda d: [str(d["bag"]), "--rig", "thesis_rig", "--quiet", "--no-plots"], "-o", 2,
                 "model.yaml", {"model.yaml", "summary.json"}),
    "gap": (lambda d: [str(d["bag"]), "--held-out", str(d["held"]), "--rig", "thesis_rig", "-q",
                       "--max-effects", "1", "--no-oracle"], "-o", 2, "report.json",
            {"report.json", "report.html", "corrected_rig.yaml", "figures"}),
    "csv_import": (lambda d: [str(d["csv"]), "--time-col", "t", "--duty-col", "duty", "--angle-col", "angle"],
                   "-o", 1, "metadata.yaml", {"metadata.yaml", "out.mcap"}),
}


def _call(name: str, argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, float]:
    main = _main(name)
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        rc = main(argv)
    return rc, capsys.readouterr().err, time.perf_counter() - t0


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow if n == "gap" else ())  # a diagnosis
                                  for n in sorted(COMMANDS)])
def test_command_refuses_then_overwrites(name: str, inputs: dict[str, Path], tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    args, option, refusal, own, new_files = COMMANDS[name]
    out = tmp_path / "out"
    before = _earlier_run(out, own)
    rc, err, elapsed = _call(name, [*args(inputs), option, str(out)], capsys)
    kind = "bag folder" if name == "csv_import" else "output folder"
    assert rc == refusal, err
    assert err.startswith(f"{name}: error: {kind} {out}/ exists and is not empty ({own}, {STALE}); "
                          f"pass --overwrite to replace it or choose another {option}\n")
    assert err.count("\n") == 1 and "Traceback" not in err
    assert elapsed < REFUSAL_S, f"{name} refused only after {elapsed:.2f} s"
    assert _tree(out) == before
    # with --overwrite: only the new run's files, the stale one gone
    rc, err, _ = _call(name, [*args(inputs), option, str(out), "--overwrite"], capsys)
    assert rc == 0, err
    assert {p.name for p in out.iterdir()} == new_files
    assert (out / own).read_bytes() != before[own]


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_overwrite_refuses_a_folder_that_is_not_the_commands_output(
        name: str, inputs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args, option, refusal, _, _ = COMMANDS[name]
    out = tmp_path / "mydata"
    out.mkdir()
    (out / "notes.txt").write_text("a lab notebook")
    rc, err, elapsed = _call(name, [*args(inputs), option, str(out), "--overwrite"], capsys)
    assert rc == refusal and "does not look like" in err and f"choose another {option}" in err
    assert elapsed < REFUSAL_S
    assert _tree(out) == {"notes.txt": b"a lab notebook"}


def test_overwrite_never_deletes_the_input(inputs: dict[str, Path], tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """``gap reports/run/run_bag -o reports/run --overwrite`` must not delete the recording it reads."""
    run = tmp_path / "run"
    run.mkdir()
    bag = write_bag(_recording(3, 12.0), run / "run_bag")
    (run / "report.json").write_text("earlier")
    before = _tree(run)
    rc, err, _ = _call("gap", [str(bag), "--rig", "thesis_rig", "-o", str(run), "--overwrite"], capsys)
    assert rc == 2 and f"it holds the input {bag}" in err
    assert _tree(run) == before


def test_pipeline_refuses_before_starting_the_graph(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "main"
    before = _earlier_run(out, "summary.json")
    rc, err, elapsed = _call("pipeline", ["-o", str(out)], capsys)
    assert rc == 2 and elapsed < REFUSAL_S
    assert err == (f"pipeline: error: output folder {out}/ exists and is not empty ({STALE}, summary.json); "
                   "pass --overwrite to replace it or choose another -o\n")
    assert _tree(out) == before


def test_design_gains_refuses_an_existing_file_before_designing(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    gains = tmp_path / "gains.yaml"
    gains.write_text("earlier: gains\n")
    rc, err, elapsed = _call("design_gains", ["--rig", "thesis_rig", "-o", str(gains)], capsys)
    assert rc == 2 and elapsed < REFUSAL_S
    assert err == (f"design_gains: error: output file {gains} exists; pass --overwrite to replace it or "
                   "choose another -o\n")
    assert gains.read_text() == "earlier: gains\n"
