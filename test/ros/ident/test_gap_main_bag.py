"""``gap`` on the main job's own bag (issue 34, item 7 and its bar line).

The bag is written exactly as ``scripts/run_main.sh`` writes it: the node graph of the main job
(record + sim_node with the thesis rig, sensor noise and 10-bit ADC quantisation on, + excitation
with the default signal) as separate ROS 2 processes, recorded by the project's recorder
(:func:`aeropend_ident.pipeline.run_graph`). The gap command, as a user types it
(``gap BAG --rig thesis_sim -o DIR``), must then write its whole report, with the angle quantum
reported as detected from the data (2π/1024 rad) and every optional section computed.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import time

import pytest

from aeropend_ident.cli.gap import main as gap_main
from aeropend_ident.pipeline import DEFAULT_SIGNAL, run_graph
from aeropend_sim.params import load_rig
from aeropend_sim.ros.harness import isolate_process, random_domain

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_gap_writes_its_report_on_the_main_jobs_bag(tmp_path, monkeypatch):
    isolate_process(monkeypatch, random_domain(101, 200))
    bag = run_graph(tmp_path / "main", "thesis_rig", "lockstep", 1, DEFAULT_SIGNAL, True)
    assert (bag / "metadata.yaml").is_file()
    out = tmp_path / "gap"
    buf = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf):
        rc = gap_main([str(bag), "--rig", "thesis_sim", "-o", str(out), "-q"])
    elapsed = time.perf_counter() - t0
    assert rc == 0, buf.getvalue()
    for name in ("report.json", "report.html", "corrected_rig.yaml"):
        assert (out / name).is_file()
    rep = json.loads((out / "report.json").read_text())
    q = 2.0 * math.pi / 1024.0  # the thesis rig's AS5040 angle through a 10-bit ADC
    assert rep["headline"]["detected"]["quantisation"]["theta_quantum"] == pytest.approx(q, rel=1e-4)
    assert rep["which"]["detected"] == rep["headline"]["detected"]
    assert "quantisation" not in rep["which"]["chosen"]
    assert rep["not_computed"] == {}
    att = rep["after"]["attainable"]
    assert att and all("oracle_drift_error" not in a and "oracle_best_error" not in a for a in att)
    assert att[0]["noise_floor"] > 0.0
    assert rep["prediction"] is not None
    assert load_rig(out / "corrected_rig.yaml").sensors.theta_quantum == pytest.approx(q, rel=1e-4)
    text = buf.getvalue()
    assert "detected from the recorded values (not fitted): quantisation" in text
    assert "ATTAINABLE on" in text
    print(f"gap on the main job's bag: {elapsed:.1f} s wall")
