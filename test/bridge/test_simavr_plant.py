"""The pulse plant behind the simavr harness's ``-P`` socket (aeropend_bridge.simavr_plant, issue 61)."""

from __future__ import annotations

import csv
import io
import math
import socket
import tempfile
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from aeropend_bridge.family import CommandMap, read_rig_hardware
from aeropend_bridge.simavr_plant import (
    REPLY,
    REQUEST,
    TRACE_COLUMNS,
    PlantProtocolError,
    PulsePlant,
    main,
    serve,
)
from aeropend_ident.cli.rig import main as rig_main
from aeropend_sim.params import load_rig
from aeropend_sim.simulation import PlantStepper


@pytest.fixture(scope="module")
def esc_rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("escrig") / "esc.yaml"
    assert rig_main(["new", "--actuator", "esc", "-o", str(path)]) == 0
    data = yaml.safe_load(path.read_text())
    q = {"unit": "s", "source": "test"}
    data["hardware"] = {"pulse_offset": {"value": 1.1e-3, **q}, "pulse_span": {"value": 0.8e-3, **q}}
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_pulse_map_is_the_bridges(esc_rig: Path) -> None:
    rig = load_rig(esc_rig)
    cmap = CommandMap.for_rig(read_rig_hardware(esc_rig, rig.family))
    assert cmap.tau_of_pulse(1.1e-3 + 0.25 * 0.8e-3) == pytest.approx(0.25)
    assert cmap.tau_of_pulse(0.0) == 0.0 and cmap.tau_of_pulse(2.5e-3) == 1.0
    # applied() of a sample frame goes through the same map
    assert cmap.applied(type("F", (), {"pulse": 2 * 1500, "duty": 0})()) == pytest.approx(0.5)


def test_plant_holds_each_pulse_until_the_next_exchange_like_the_stepper(esc_rig: Path) -> None:
    plant = PulsePlant(esc_rig, 1e-3)
    rig = load_rig(esc_rig).with_effects(sensor_noise=False, quantisation=False)
    ref = PlantStepper(replace(rig, sample_period=1e-3))
    taus = [0.0] * 5 + [0.7] * 300 + [0.2] * 200
    tau_prev = 0.0
    for k, tau in enumerate(taus, start=1):
        theta = plant.exchange(k * 1e-3, 1.1e-3 + tau * 0.8e-3)
        ref.step(tau_prev)  # the pulse read at the last exchange was held until this one
        tau_prev = tau
        assert theta == pytest.approx(float(ref.x[0]), abs=1e-9)  # τ through the map: last-bit rounding
    assert plant.tau_max == pytest.approx(0.7) and plant.exchanges == len(taus)
    assert plant.theta > 0.01  # it moved: τ 0.7 lifts the rod after the 50 ms input delay


def test_plant_refuses_time_going_back_and_non_finite_values(esc_rig: Path) -> None:
    plant = PulsePlant(esc_rig, 1e-3)
    plant.exchange(0.010, 1.5e-3)
    assert plant.t == pytest.approx(0.010)
    with pytest.raises(PlantProtocolError, match="time went back"):
        plant.exchange(0.005, 1.5e-3)
    with pytest.raises(PlantProtocolError, match="non-finite"):
        plant.exchange(0.011, math.nan)
    with pytest.raises(ValueError, match="dc_hbridge rig"):
        PulsePlant("thesis_rig")


def test_serve_answers_a_harness_over_the_socket(esc_rig: Path) -> None:
    sock_dir = Path(tempfile.mkdtemp(prefix="ap-plant-t-"))
    path = sock_dir / "p.sock"
    plant = PulsePlant(esc_rig, 1e-3)
    ready = threading.Event()
    result: list[int] = []
    trace = io.StringIO()
    th = threading.Thread(target=lambda: result.append(serve(path, plant, lambda _: ready.set(), 10.0,
                                                             trace)))
    th.start()
    assert ready.wait(10)
    thetas = []
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as c:
        c.connect(str(path))
        for k in range(1, 401):
            c.sendall(REQUEST.pack(k * 1e-3, 1.9e-3))
            buf = b""
            while len(buf) < REPLY.size:
                buf += c.recv(REPLY.size - len(buf))
            thetas.append(REPLY.unpack(buf)[0])
    th.join(10)
    assert result == [400] and not path.exists()
    assert np.all(np.diff(thetas[100:]) >= 0) and thetas[-1] > 0.01
    # the trace: one row per exchange, what the harness sent and what went back
    rows = list(csv.reader(io.StringIO(trace.getvalue())))
    assert tuple(rows[0]) == TRACE_COLUMNS and len(rows) == 401
    data = np.array(rows[1:], dtype=float)
    assert np.array_equal(data[:, 0], np.arange(1, 401) * 1e-3) and np.all(data[:, 1] == 1.9e-3)
    assert np.allclose(data[:, 2], (1.9e-3 - 1.1e-3) / 0.8e-3) and np.array_equal(data[:, 3], thetas)


def test_main_never_overwrites_a_trace(esc_rig: Path, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    mine = tmp_path / "trace.csv"
    mine.write_text("my run\n")
    sock = str(tmp_path / "p.sock")
    assert main([str(esc_rig), sock, "--trace", str(mine), "--accept-timeout", "0.1"]) == 2
    assert f"cannot create the trace {mine}: File exists" in capsys.readouterr().err
    assert mine.read_text() == "my run\n"


def test_main_refuses_a_rig_without_an_esc(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["thesis_rig", "/tmp/unused.sock"]) == 2
    assert "is a dc_hbridge rig; the pulse plant drives an ESC rig" in capsys.readouterr().err


def test_serve_never_replaces_a_file_that_is_not_a_socket(esc_rig: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """A socket path that names a user's file is refused; the file is left as it was."""
    mine = tmp_path / "results.csv"
    mine.write_text("t,theta\n0,0\n")
    with pytest.raises(FileExistsError, match="is not a socket"):
        serve(mine, PulsePlant(esc_rig), accept_timeout_s=0.1)
    assert mine.read_text() == "t,theta\n0,0\n"
    assert main([str(esc_rig), str(mine), "--accept-timeout", "0.1"]) == 1
    assert f"{mine} exists and is not a socket" in capsys.readouterr().err
    assert mine.read_text() == "t,theta\n0,0\n"
