"""Atomic results under faults (issue 62, item 5): every command keeps the earlier result.

Each command writes its result under ``.NAME.partial-XXXX/NAME`` beside the output and renames it
into place when complete (:mod:`aeropend_sim.output_folder`). Here each one is run with
``--overwrite`` over an earlier result while a fault hits it *mid-write*: the fault is injected
where the project's files are opened for writing inside the temporary result (the second file of
a folder, so one file is already written; the first file of a one-file result, left empty), as

* ENOSPC (a full disk), EROFS (a read-only folder), EACCES (no permission): ``OSError``;
* Ctrl-C: ``KeyboardInterrupt``.

Every case must end with exit status ≠ 0 (130 after Ctrl-C), one line on stderr naming the
cause and the output, no traceback, the earlier result byte for byte and no partial result left.
Where the machine allows a private mount namespace (``unshare -rm``), ``csv_import`` also runs on
a real 2 MB tmpfs (a real ENOSPC) and on a real read-only mount (a real EROFS).
"""

from __future__ import annotations

import builtins
import contextlib
import errno
import io
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.io.bag_writer import write_bag
from aeropend_sim.excitation import aprbs
from aeropend_sim.output_folder import PARTIAL, fault_message, staged_path, write_file_atomically
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import simulate

DT = 0.01
STALE = "stale_from_an_earlier_run.png"

#: fault name -> (exception raised, the words the one line must hold, exit status)
FAULT_CASES: dict[str, tuple[Callable[[str], BaseException], str, int]] = {
    "ENOSPC": (lambda f: OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), f),
               "no space left on the device (ENOSPC)", 1),
    "EROFS": (lambda f: OSError(errno.EROFS, os.strerror(errno.EROFS), f),
              "read-only file system (EROFS)", 1),
    "EACCES": (lambda f: PermissionError(errno.EACCES, os.strerror(errno.EACCES), f),
               "permission denied (EACCES)", 1),
    "Ctrl-C": (lambda f: KeyboardInterrupt(), "interrupted (Ctrl-C)", 130),
}


def _tree(folder: Path) -> dict[str, bytes]:
    if folder.is_file():
        return {folder.name: folder.read_bytes()}
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _partials(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if PARTIAL in p.name)


@contextlib.contextmanager
def fault_mid_write(fault: str, nth: int):
    """Raise ``fault`` at the ``nth`` file opened for writing inside a temporary result.

    The file is created first (then the fault comes, as when a disk fills during a write), so a
    partial file is on disk for the command to remove. Yields a list: the paths hit.
    """
    make = FAULT_CASES[fault][0]
    real_open = builtins.open
    opened: list[str] = []
    hit: list[str] = []

    def open_(file, mode="r", *args, **kwargs):
        fh = real_open(file, mode, *args, **kwargs)
        name = os.fspath(file) if isinstance(file, (str, bytes, os.PathLike)) else ""
        name = name.decode() if isinstance(name, bytes) else name
        if any(c in mode for c in "wax+") and PARTIAL in name:
            opened.append(name)
            if len(opened) == nth and not hit:
                hit.append(name)
                fh.close()
                raise make(name)
        return fh

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(builtins, "open", open_)
        mp.setattr(io, "open", open_)
        yield hit


# ------------------------------------------------------------------------- the one helper
def test_staged_folder_replaces_the_earlier_one_only_when_complete(tmp_path):
    out = tmp_path / "rep"
    out.mkdir()
    (out / "a.json").write_text("earlier")
    with staged_path(out, folder=True) as tmp:
        assert tmp.name == "rep" and tmp.parent.name.startswith(f".rep{PARTIAL}") and tmp.is_dir()
        (tmp / "a.json").write_text("new")
        assert (out / "a.json").read_text() == "earlier"  # untouched while the new one is written
    assert _tree(out) == {"a.json": b"new"} and _partials(tmp_path) == []
    for exc in (OSError(errno.ENOSPC, "full"), KeyboardInterrupt(), ValueError("a bug")):
        with pytest.raises(type(exc)), staged_path(out, folder=True) as tmp:
            (tmp / "a.json").write_text("partial")
            raise exc
        assert _tree(out) == {"a.json": b"new"} and _partials(tmp_path) == []
    assert fault_message(ValueError("x")) is None
    assert fault_message(OSError(errno.ENOENT, "missing")) is None


def test_the_working_folder_is_written_into_never_renamed(tmp_path, monkeypatch):
    """``-o .`` in an empty working folder: the entries move in; the folder itself stays."""
    from aeropend_sim.output_folder import claim_output_folder

    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    inode = work.stat().st_ino
    out = claim_output_folder(".", False, own=["report.json"], looks_like="a report")
    written = out.write(lambda d: [(d / "report.json").write_text("{}"), d / "report.json"][1])
    assert written == Path("report.json") and work.stat().st_ino == inode
    assert _tree(work) == {"report.json": b"{}"} and _partials(tmp_path) == []


def test_one_file_is_replaced_in_one_rename(tmp_path):
    f = tmp_path / "gains.yaml"
    write_file_atomically(f, "kp: 1\n")
    with pytest.raises(OSError) as info, staged_path(f, folder=False) as tmp:
        tmp.write_text("kp: 2\n")
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp))
    assert f.read_text() == "kp: 1\n" and _partials(tmp_path) == []
    assert fault_message(info.value) == (f"no space left on the device (ENOSPC) on {f}; {f} unchanged (the "
                                         "earlier result is kept), the partial result removed")


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
    import aeropend_sim

    rig_file = Path(aeropend_sim.__file__).parent / "rigs" / "thesis_rig.yaml"
    return {"thesis_rig_file": rig_file, "bag": write_bag(_recording(1, 12.0), root / "fit"),
            "held": write_bag(_recording(2, 8.0), root / "held"), "csv": csv, **_rig_fit_inputs(root)}


def _rig_fit_inputs(root: Path) -> dict[str, Path]:
    """An ESC rig file from ``rig new`` and a balance table of its own equilibrium (``rig fit``)."""
    from aeropend_ident.cli.rig import main as rig
    from aeropend_ident.greybox.rig_problem import BalanceBlock, apply_values

    template = root / "esc_rig.yaml"
    assert rig(["new", "--actuator", "esc", "--stated", "pendulum.mass=120g", "pendulum.com_distance=18cm",
                "pendulum.thrust_arm=0.15m", "motor.gear_ratio=1", "actuator.omega_max=1085rad/s", "-o",
                str(template)]) == 0
    geo = {"pendulum.mass": 0.12, "pendulum.com_distance": 0.18, "pendulum.thrust_arm": 0.15}
    truth = {"actuator.idle_duty": 0.08, "actuator.curve_exponent": 1.0, "thrust.K_q": 8e-7}
    levels = np.linspace(0.15, 0.9, 8)
    block = BalanceBlock(source="t", label="", command=levels, angle=np.zeros(levels.size))
    theta = block.residual(apply_values(load_rig(template), geo, truth), [])
    table = root / "balance.csv"
    rows = (f"{c},{a},0.0001\n" for c, a in zip(levels, theta, strict=True))
    table.write_text("command,angle_rad,angle_std_rad\n" + "".join(rows))
    return {"rig_template": template, "balance": table}


def _main(name: str) -> Callable[[list[str]], int]:
    from aeropend_control.design_gains import main as design_gains
    from aeropend_ident.cli import baseline, compare, csv_import, gap, identify
    from aeropend_ident.cli.rig import main as rig
    from aeropend_ident.design.cli import main as excitation_design

    return {"baseline": baseline.main, "compare": compare.main, "identify": identify.main, "gap": gap.main,
            "csv_import": csv_import.main, "design_gains": design_gains, "rig new": rig, "rig fit": rig,
            "excitation_design": excitation_design}[name]


#: command -> (its arguments before the output, output option, its own file, result is a folder)
COMMANDS: dict[str, tuple[Callable[[dict[str, Path]], list[str]], str, str, bool]] = {
    "baseline": (lambda d: [str(d["bag"]), "--rig", "thesis_rig", "--decimate", "4", "--init-horizon", "0"],
                 "-o", "report.json", True),
    "compare": (lambda d: [str(d["bag"]), "--rig", "thesis_rig"], "-o", "compare.json", True),
    "identify": (lambda d: [str(d["bag"]), "--rig", "thesis_rig", "--quiet", "--no-plots"], "-o",
                 "model.yaml", True),
    "gap": (lambda d: [str(d["bag"]), "--held-out", str(d["held"]), "--rig", "thesis_rig", "-q",
                       "--max-effects", "1", "--no-oracle"], "-o", "report.json", True),
    "csv_import": (lambda d: [str(d["csv"]), "--time-col", "t", "--duty-col", "duty", "--angle-col", "angle"],
                   "-o", "metadata.yaml", True),
    "rig new": (lambda d: ["new", "--actuator", "esc"], "-o", "", False),
    "rig fit": (lambda d: ["fit", str(d["rig_template"]), str(d["balance"]), "-q"], "-o", "", False),
    "design_gains": (lambda d: ["--rig", "thesis_rig", "--no-tune", "--steps", "0.4"], "-o", "", False),
    "excitation_design": (lambda d: ["--design-for", str(d["thesis_rig_file"]), str(d["bag"]), "--parameters",
                                     "pendulum.c_over_J", "--duration", "3", "--max-evaluations", "4"],
                          "-o", "design.json", True),
}
#: (command, fault) cases: every command under a full disk, a read-only folder and Ctrl-C; EACCES
#: on two; design_gains (a 10 s closed-loop check before it writes) under a full disk only (its
#: write is the same helper as rig new's, tried under every fault).
CASES = [pytest.param(c, f, marks=pytest.mark.slow if c == "gap" else ())  # a whole diagnosis: 8 s each
         for c in COMMANDS if c != "design_gains" for f in ("ENOSPC", "EROFS", "Ctrl-C")]
CASES += [("csv_import", "EACCES"), ("rig new", "EACCES"), ("design_gains", "ENOSPC")]


def _earlier(out: Path, own: str, folder: bool) -> dict[str, bytes]:
    if not folder:
        out.write_text("# an earlier result, kept byte for byte\nname: earlier\n")
        return _tree(out)
    out.mkdir()
    (out / own).write_text("earlier run\n")
    (out / STALE).write_bytes(b"\x89PNG stale")
    return _tree(out)


@pytest.mark.parametrize(("name", "fault"), CASES)
def test_a_fault_mid_write_keeps_the_earlier_result(name, fault, inputs, tmp_path, capsys):
    args, option, own, folder = COMMANDS[name]
    out = tmp_path / ("out" if folder else "out.yaml")
    before = _earlier(out, own, folder)
    with fault_mid_write(fault, nth=2 if folder else 1) as hit, contextlib.redirect_stdout(io.StringIO()):
        status = _main(name)([*args(inputs), option, str(out), "--overwrite"])
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip() and not x.startswith("design_gains: checking")]
    assert hit, f"{name} wrote no file under a temporary name"
    _, words, code = FAULT_CASES[fault]
    assert status == code, err
    assert "Traceback" not in err and len(lines) == 1, err
    assert lines[0].startswith(f"{name.split()[0]}: error: {words}"), lines[0]
    assert f"{out} unchanged (the earlier result is kept), the partial result removed" in lines[0]
    if fault != "Ctrl-C":  # the file the disk filled on, by its final name
        assert f" on {out}" in lines[0] and PARTIAL not in lines[0]
    assert _tree(out) == before
    assert _partials(tmp_path) == []


def test_a_read_only_output_folder_is_one_line(inputs, tmp_path, capsys):
    """A real read-only folder (chmod; root ignores it, so there the test is skipped)."""
    if os.geteuid() == 0:
        pytest.skip("root writes into a chmod 555 folder; the injected EROFS/EACCES cases cover it")
    parent = tmp_path / "ro"
    parent.mkdir()
    out = parent / "bag"
    before = _earlier(out, "metadata.yaml", True)
    parent.chmod(0o555)
    try:
        status = _main("csv_import")([*COMMANDS["csv_import"][0](inputs), "-o", str(out), "--overwrite"])
    finally:
        parent.chmod(0o755)
    err = capsys.readouterr().err
    assert status == 1 and err.count("\n") == 1 and "permission denied (EACCES)" in err
    assert _tree(out) == before and _partials(parent) == []


def _unshare_ok() -> bool:
    if shutil.which("unshare") is None or sys.platform != "linux":
        return False
    return subprocess.run(["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt || exit 1"],
                          capture_output=True, cwd="/").returncode == 0


@pytest.mark.skipif(not _unshare_ok(), reason="no private mount namespace (unshare -rm) for a real tmpfs")
@pytest.mark.parametrize("fault", ["ENOSPC", "EROFS"])
def test_csv_import_on_a_real_full_or_read_only_tmpfs(fault, tmp_path):
    """A 2 MB tmpfs that a 4 MB file filled (ENOSPC), or remounted read-only (EROFS), real faults."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    csv = tmp_path / "log.csv"
    t = np.arange(60000) * 0.002
    rows = (f"{a:.3f},{0.3 + 0.2 * (k // 500 % 2):.3f},{0.1 * np.sin(a):.6f}\n" for k, a in enumerate(t))
    csv.write_text("t,duty,angle\n" + "".join(rows))
    fill = f"head -c 1800000 /dev/zero > {mnt}/filler" if fault == "ENOSPC" else f"mount -o remount,ro {mnt}"
    script = f"""
set -e
mount -t tmpfs -o size=2m tmpfs {mnt}
mkdir {mnt}/out && printf 'earlier run\\n' > {mnt}/out/metadata.yaml
{fill}
set +e
{sys.executable} -m aeropend_ident.cli.csv_import {csv} --time-col t --duty-col duty --angle-col angle \
  -o {mnt}/out --overwrite
echo "status=$?"
cat {mnt}/out/metadata.yaml
ls -a {mnt}
"""
    t0 = time.perf_counter()
    proc = subprocess.run(["unshare", "-rm", "sh", "-c", script], capture_output=True, text=True, timeout=120)
    assert time.perf_counter() - t0 < 60
    words = FAULT_CASES[fault][1]
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.startswith(f"csv_import: error: {words}"), proc.stderr
    assert f"{mnt}/out unchanged (the earlier result is kept)" in proc.stderr
    assert "status=1\nearlier run\n" in proc.stdout, proc.stdout
    assert PARTIAL not in proc.stdout  # nothing partial left on the full / read-only disk


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full (a device that is always full)")
def test_a_full_standard_output_is_one_line():
    """``excitation --print > /dev/full``: a real ENOSPC on standard output, one line, exit 1."""
    argv = [sys.executable, "-m", "aeropend_sim.ros.excitation_node", "--print", "--signal", "lhs"]
    with open("/dev/full", "w") as full:
        proc = subprocess.run(argv, stdout=full, stderr=subprocess.PIPE, text=True, timeout=120)
    assert proc.returncode == 1
    assert proc.stderr == "excitation: error: no space left on the device (ENOSPC)\n"
