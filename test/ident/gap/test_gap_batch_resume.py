"""``gap-batch`` keeps finished sessions, resumes, and replaces an earlier batch only when complete.

Two short sessions of the thesis rig (12 s, θ only), one ``gap`` run each in this process
(``--workers 1``). Each ``gap`` run is counted through ``diagnose_session`` (the real one runs),
and a session taken as it was keeps its report's modification time (a copy keeps it, a new run
cannot).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from aeropend_ident.cli import gap_batch
from aeropend_ident.gap.batch import SESSION_FILE, write_batch
from aeropend_ident.io.bag_writer import write_bag
from aeropend_sim.output_folder import PARTIAL
from bench.fixtures.sessions import thesis_session

OPTIONS = ["--rig", "thesis_rig", "--workers", "1", "-q", "--max-effects", "1", "--no-oracle"]


def _archive(root: Path) -> Path:
    for name, seed in (("mon", 21), ("tue", 22)):
        write_bag(thesis_session(seed, duration=12.0), root / name, rig_name="thesis_rig")
    return root


@pytest.fixture
def gap_runs(monkeypatch) -> dict[str, Any]:
    """The sessions ``gap`` runs on (the real command behind a counter); ``interrupt``: sessions
    during which Ctrl-C comes."""
    seen: dict[str, Any] = {"runs": [], "interrupt": set()}
    real = gap_batch.gap_main.__wrapped__

    def run(argv):
        name = Path(argv[argv.index("-o") + 1]).name
        if name in seen["interrupt"]:
            raise KeyboardInterrupt
        seen["runs"].append(name)
        return real(argv)

    monkeypatch.setattr(gap_batch, "gap_main", SimpleNamespace(__wrapped__=run))
    return seen


def _mtimes(out: Path) -> dict[str, int]:
    return {s: (out / s / "report.json").stat().st_mtime_ns for s in ("mon", "tue")}


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.slow
def test_resume_recomputes_nothing_unchanged_and_the_session_whose_input_changed(tmp_path, gap_runs, capsys):
    counted = gap_runs["runs"]
    archive = _archive(tmp_path / "archive")
    out = tmp_path / "batch"
    stale = tmp_path / f".batch{PARTIAL}batch" / "batch" / "mon"  # an unfinished batch of another run
    stale.mkdir(parents=True)
    (stale / SESSION_FILE).write_text('{"key": "of other inputs", "row": {"exit": 0}}')
    assert gap_batch.main([str(archive), "-o", str(out), *OPTIONS]) == 0
    assert counted == ["mon", "tue"]
    assert f"note: the unfinished batch in {stale.parents[1]} is discarded" in capsys.readouterr().err
    first = json.loads((out / "batch.json").read_text())
    stamps = _mtimes(out)
    assert [r["report"] for r in first["rows"]] == [str(out.absolute() / "mon"), str(out.absolute() / "tue")]
    assert all((out / s / SESSION_FILE).is_file() for s in ("mon", "tue"))
    capsys.readouterr()
    # unchanged inputs: nothing computed, not even the drift table; the same rows
    t0 = time.perf_counter()
    assert gap_batch.main([str(archive), "-o", str(out), "--resume", *OPTIONS]) == 0
    elapsed = time.perf_counter() - t0
    assert counted == ["mon", "tue"] and elapsed < 2.0
    printed = capsys.readouterr().out
    assert "resumed: 2 of 2 session(s) taken as they were (inputs unchanged), 0 computed" in printed
    second = json.loads((out / "batch.json").read_text())
    assert second["rows"] == first["rows"] and second["drift"] == first["drift"]
    assert _mtimes(out) == stamps
    # tuesday's recording replaced by another run: only tuesday is diagnosed again
    write_bag(thesis_session(23, duration=12.0), archive / "tue", rig_name="thesis_rig", overwrite=True)
    assert gap_batch.main([str(archive), "-o", str(out), "--resume", *OPTIONS]) == 0
    assert counted == ["mon", "tue", "tue"]
    third = json.loads((out / "batch.json").read_text())
    now = _mtimes(out)
    assert now["mon"] == stamps["mon"] and now["tue"] != stamps["tue"]
    assert third["rows"][0] == first["rows"][0]
    assert third["rows"][1]["nrmse_before"] != first["rows"][1]["nrmse_before"]
    assert [p.name for p in tmp_path.iterdir() if PARTIAL in p.name] == []


@pytest.mark.slow
def test_ctrl_c_and_a_full_disk_keep_the_earlier_batch_and_finished_sessions(tmp_path, gap_runs, monkeypatch,
                                                                                capsys):
    counted = gap_runs["runs"]
    archive = _archive(tmp_path / "archive")
    out = tmp_path / "batch"
    out.mkdir()  # an earlier batch (its own files), kept byte for byte until the new one is complete
    (out / "batch.json").write_text('{"rows": "earlier"}\n')
    (out / "drift.md").write_text("# earlier drift table\n")
    (out / "mon").mkdir()
    (out / "mon" / "report.json").write_text("{}\n")
    before = _tree(out)
    gap_runs["interrupt"].add("tue")  # Ctrl-C while the second session runs
    assert gap_batch.main([str(archive), "-o", str(out), "--overwrite", *OPTIONS]) == 130
    err = capsys.readouterr().err
    stage = tmp_path / f".batch{PARTIAL}batch"
    assert err == (f"gap-batch: error: interrupted (Ctrl-C); {out} unchanged (the earlier result is kept), "
                   f"the finished part kept in {stage} (--resume continues from it)\n")
    assert _tree(out) == before
    assert (stage / "batch" / "mon" / SESSION_FILE).is_file() and not (stage / "batch" / "tue").exists()
    monday = (stage / "batch" / "mon" / "report.json").stat().st_mtime_ns
    # a full disk while the batch files are written at the end: the two sessions are kept
    gap_runs["interrupt"].clear()

    def full(out_dir, *args, **kwargs):
        raise OSError(28, "No space left on device", str(out_dir / "batch.json"))

    monkeypatch.setattr(gap_batch, "write_batch", full)
    assert gap_batch.main([str(archive), "-o", str(out), "--resume", *OPTIONS]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"gap-batch: error: no space left on the device (ENOSPC) on {out}/batch.json; "
                          f"{out} unchanged (the earlier result is kept), the finished part kept in")
    assert err.count("\n") == 1 and "Traceback" not in err
    assert counted == ["mon", "tue"] and _tree(out) == before
    # the disk has room again: nothing is diagnosed again, the batch replaces the earlier one
    monkeypatch.setattr(gap_batch, "write_batch", write_batch)
    assert gap_batch.main([str(archive), "-o", str(out), "--resume", *OPTIONS]) == 0
    assert counted == ["mon", "tue"]
    doc = json.loads((out / "batch.json").read_text())
    assert [r["session"] for r in doc["rows"]] == ["mon", "tue"] and all(r["exit"] == 0 for r in doc["rows"])
    assert doc["meta"]["reused"] == ["mon", "tue"]
    assert (out / "mon" / "report.json").stat().st_mtime_ns == monday
    assert not stage.exists()



def test_a_real_sigint_on_a_local_cluster_is_one_line(tmp_path):
    """Ctrl-C (a real SIGINT to the process group, as a terminal sends it) while two Dask workers
    diagnose: one line, the earlier batch intact."""
    archive = _archive(tmp_path / "archive")
    out = tmp_path / "batch"
    out.mkdir()
    (out / "batch.json").write_text('{"rows": "earlier"}\n')
    before = _tree(out)
    stage = tmp_path / f".batch{PARTIAL}batch"
    argv = [sys.executable, "-m", "aeropend_ident.cli.gap_batch", str(archive), "-o", str(out), "--overwrite",
            *OPTIONS]
    argv[argv.index("--workers") + 1] = "2"
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    t0 = time.perf_counter()
    while not stage.exists() and proc.poll() is None and time.perf_counter() - t0 < 60:
        time.sleep(0.05)
    time.sleep(2.0)  # the cluster starts or its sessions run: either way one line
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert err == (f"gap-batch: error: interrupted (Ctrl-C); {out} unchanged (the earlier result is kept), "
                   f"the finished part kept in {stage} (--resume continues from it)\n")
    assert _tree(out) == before
