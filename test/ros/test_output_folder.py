"""The output-folder rule for the commands that run ROS: ``record`` and the main job ``pipeline``.

``record`` refuses an existing non-empty bag folder (rosbag2 would refuse it too, with a
traceback-free message naming ``--overwrite``) and with ``--overwrite`` replaces an earlier bag;
``pipeline --overwrite`` (what ``scripts/run_main.sh`` passes) replaces its earlier run, so README
command 1 works twice in a row.
"""

from __future__ import annotations

import contextlib
import io
import subprocess
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from aeropend_ident.io.bags import read_bag
from aeropend_sim.contract import CONTRACT_TOPICS
from aeropend_sim.ros.harness import isolate_process, isolated_env, node_command, random_domain

pytestmark = [pytest.mark.ros, pytest.mark.timeout(180)]
RECORD = node_command("record", "aeropend_ident.nodes.record")
STALE = "stale_from_an_earlier_run.txt"


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_record_refuses_an_earlier_bag_then_replaces_it_with_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "metadata.yaml").write_text("rosbag2_bagfile_information: {}  # an earlier bag\n")
    (out / STALE).write_text("stale")
    before = _tree(out)
    env = isolated_env(random_domain())
    cmd = [*RECORD, "-o", str(out), "--duration", "0.5"]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 1
    assert (f"record: error: bag folder {out}/ exists and is not empty (metadata.yaml, {STALE}); pass "
            "--overwrite to replace it or choose another -o") in proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr
    assert _tree(out) == before
    proc = subprocess.run([*cmd, "--overwrite"], env=env, capture_output=True, text=True, timeout=60,
                          check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert sorted(p.suffix for p in out.iterdir()) == [".mcap", ".yaml"]  # the new bag only
    with AnyReader([out]) as reader:  # a valid bag of the contract topics (nothing published here)
        assert {c.topic for c in reader.connections} == set(CONTRACT_TOPICS)


def test_pipeline_overwrite_replaces_its_earlier_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from aeropend_ident.cli.pipeline import main
    from aeropend_ident.pipeline import OUTPUTS

    isolate_process(monkeypatch, random_domain(101, 200))
    out = tmp_path / "main"
    (out / "run_bag").mkdir(parents=True)
    (out / "run_bag" / "metadata.yaml").write_text("an earlier run's bag\n")
    (out / "summary.json").write_text("{}\n")
    (out / STALE).write_text("stale")
    signal = ["signal:=lhs", "n:=6", "tau_min:=0.35", "tau_max:=0.7", "hold_min:=0.4", "hold_max:=0.6"]
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["--out", str(out), "--overwrite", "--signal", *signal]) == 0
    assert {p.name for p in out.iterdir()} == set(OUTPUTS.values())
    assert len(read_bag(out / OUTPUTS["bag"])) > 100


def test_a_failing_pipeline_run_keeps_the_earlier_run_whole(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """``pipeline --overwrite`` writes into a partial folder that replaces the earlier run only at the
    end (issue 62): a run that fails (here the plant node, on a rig that does not exist) leaves the
    earlier run as it was, byte for byte, and its own logs in the partial folder it names."""
    from aeropend_ident.cli.pipeline import main

    isolate_process(monkeypatch, random_domain(101, 200))
    out = tmp_path / "main"
    (out / "run_bag").mkdir(parents=True)
    (out / "run_bag" / "metadata.yaml").write_text("an earlier run's bag\n")
    (out / "summary.json").write_text('{"earlier": true}\n')
    before = _tree(out)
    rc = main(["--out", str(out), "--overwrite", "--plant-rig", "no_such_rig"])
    err = capsys.readouterr().err
    assert rc == 1
    assert _tree(out) == before
    partial = tmp_path / ".main.partial-run" / "main"
    assert f"pipeline: {out} is as it was; this run's bag and logs are in {partial}" in err
    assert (partial / "logs").is_dir() and any((partial / "logs").iterdir())
