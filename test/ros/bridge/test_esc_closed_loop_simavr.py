"""End to end, closed loop: the ESC + encoder firmware in simavr against the all-simulated graph (issue 61).

Hardware path: the plant of an ESC rig file (:mod:`aeropend_bridge.simavr_plant`, the simulator
``sim_node`` steps, driven by the pulse width the firmware puts on its ESC pin, every 1 ms of MCU
time) ↔ the simavr harness (``-P``: the real firmware ELF; its emulated quadrature encoder follows
the plant's angle) ↔ the ``bridge`` node on the harness's pty ↔ the ``controller`` node (the default
strategy, real-time mode). All-simulated graph: ``sim_node`` with the same rig file ↔ the same
controller, both in lock-step (below). Both take the same set-point step; the controllers' traces
(θ as received on ``joint_states``, the reference, the sample time) are compared.

The two graphs are one rig. The rig file describes the whole rig, ESC included; the hardware path
adds on its own the latency of the ESC's servo protocol and of the emulation, which the
all-simulated graph (``sim_node`` applies τ from the sample period's start) does not have:

* the firmware takes the answer to sample k at tick k + 1 (one T_s = 2.04 ms; ``sim_node`` applies
  it from sample k's instant), the pin takes the new width at the next 490 Hz frame start (0 to
  one frame after the tick: T_frame/2 on average), the ESC (the plant process) knows the width at
  the pulse's falling edge (the width itself, pulse_offset + τ·pulse_span: 1.26 ms at the set
  point's τ_eq = 0.258), and reads it at its next 1 ms exchange (0.5 ms on average); the angle the
  encoder follows is up to 1 ms old (0.5 ms on average): 5.32 ms in all.

A lab's fitted rig file of such hardware carries that latency in its input delay. So the stand-in
plant behind the firmware (:func:`_stand_in`) is the rig file with those 5.32 ms taken out of its
input delay: the whole hardware path then has the rig file's 50 ms, as the simulated graph has.
Before this (one rig file for both, the hardware path 3.3 ms slower) the trajectories differed by
2.0-4.5 q during the rise (4 runs at dc05bfe; the shift that minimised the difference was 2-4 ms);
with 3.28 ms taken out (the tick's T_s forgotten) the hardware trace still came 1.75 ms late
(2026-11-30, the run that failed CI at 849e9d3 by 3 q); with 5.32 ms, 0.25-1.0 ms (4 runs).

The simulated graph runs in lock-step: each sample waits for the controller's command, as a
real-time ``sim_node`` behaves when every reply comes within the sample period. In real time a
reply later than one period adds a period to that graph's loop, so the reference itself moved with
the host's load. In lock-step it is the same in every run (0.00 q between two runs); both modes
gave the hardware trace the same best-fit shift against it (1.0 ms, 3 runs each).

The host answers in the emulated MCU's time as a host that is never late (harness ``-H``): from 0.5
ms after each sample frame's last byte (1.0 ms after the tick) MCU time stands still until the
host's DUTY/PULSE answer has come, so the firmware takes every answer at the next tick, as the lock-
step graph does. The host itself is the 2-core machine's, and its answer to a 490 Hz sample (the
frame on the UART, the bridge, the controller, the command back) took 1.3-4 ms of wall-clock time:
without ``-H`` some answers missed their tick and the pulse before stayed on the pin for a second
frame (the plant's exchange trace shows it; a quarter of them in the rise of one run), a different
loop delay in every run. The trajectories, tick by tick, then differed by 1-5 q (14 runs,
2026-11-30: 3 and 5 q in two). The host's real-time latency is the bridge's and the controller's to
report (their traces, ``bench/bench_control_latency.py``), not this comparison's. With ``-H``, in 10
runs, the step's distinct commands reached the plant in order from the first on, until the first
tick that the 490 Hz frame slips (one in 2041: 30 to 1300 commands after the step; without ``-H``
the order broke at the 1st and the 4th, 2 runs); of the waits over the harness's 10 ms cap, one per run is the
sample after the controller's last, and one run had one more; a host that does not answer within
that cap lets the MCU run on, and a step that then misses a tolerance is withheld (a skip naming the
waits), not failed. What varies from run to run is then the ESC frame's phase to the tick (up to one
frame: when the command reaches the pin) and the 1 ms exchange (when the plant sees the width and
the encoder the angle): the largest difference, tick by tick (:func:`_trace`), was 1 q in 7 runs and
2 q in 3.

The emulated encoder's disk is mounted with its counts centred on the rod's angles (harness ``-M
0.5``: count = round(θ/q)), as aeropend's quantisation effect reads a sensor (q·round(θ/q)); a
disk mounted at a count edge would read up to one count lower than the simulated sensor for one
angle (floor against round), a constant offset that says nothing about the two paths.

Tolerances (q = 2π/4000 = 1.57 mrad, T_s = 2.040 ms):

* the trajectories, aligned on the step instant, sample by sample (both on the encoder's lattice):
  issue 61's bar, the encoder's quantisation, 2 q: one count for the two readings of one angle
  on either side of a count edge, one for the remaining run-to-run latency (the frame's phase to
  the tick drifts 1 µs a frame, 2.041 ms against 2.040 ms; the 1 ms exchange). Measured with
  ``-H`` on the idle host (2026-11-30): max |Δθ| sample by sample 1 q in 7 runs, 2 q in 3 (from
  1.5 s on 1 q in every run); rise times 636.5-642.6 ms against 640.6 ms, settling times
  1187-1200 ms against 1199.5 ms, M_p 0.22 % in all (interpolating between two counts would be off
  the lattice, hence the sample-by-sample comparison);
* the step metrics: final value 2 q; rise and settling time 1.5 L + 2 T_s (``LATENCY``, the
  hardware path's worst-case extra latency, + the metric's sample grid), the settling time also
  the time a 2 q difference moves a crossing of the ±2 % band; the peak (M_p × step) 3 q.
"""

from __future__ import annotations

import csv
import math
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("rclpy")

from aeropend_bridge.simavr_harness import build_emulator, read_pty_path
from aeropend_control.metrics import StepMetrics, step_metrics
from aeropend_ident.cli.rig import main as rig_main
from aeropend_sim.model import plant_model
from aeropend_sim.params import load_rig
from aeropend_sim.ros.harness import isolated_env, node_command, random_domain, reap, stop

ROOT = Path(__file__).resolve().parents[3]
FW = ROOT / "firmware"
CPR = 4000
Q = 2 * math.pi / CPR          # encoder quantum [rad]
TS = 2.040e-3                  # firmware sample period (TOV1: 510 × 4 µs) [s]
EXCHANGE_US = 1000             # plant exchange interval of the harness (-Q) [µs]; 250 starved the 2-core host
HOLD_US = 500                  # harness -H: MCU time waits for the answer from 0.5 ms after a sample [µs]
STEP = 0.5                     # set point after the step [rad]
T_STEP = 2.5                   # step instant after the controller's first sample [s]; > ESC arming (2 s)
AFTER = 3.5                    # record after the step [s]
LATENCY = 2 * TS + 2e-3 + 2e-3  # the hardware path's extra latency, at most [s] (module docstring)
FRAME_S = 4082 * 0.5e-6        # the 490 Hz build's ESC frame: Timer3 TOP 4081 at 0.5 µs [s]
HOLD_MAX_S = 10e-3             # the harness's LINK_HOLD_MAX_US: the longest MCU time waits for one answer [s]
PULSE_OFFSET, PULSE_SPAN = 1.0e-3, 1.0e-3  # the rig's ESC map: pulse = offset + τ·span [s]

pytestmark = [
    pytest.mark.ros,
    # the emulator, the plant, the bridge and the real-time controller need the 2 cores: beside the
    # parallel suite the controller fell silent for over 0.1 s seven times in 4 s (CI at 328f23b), the
    # bridge's watchdog cut the ESC each time and the rod overshot by 49 %
    pytest.mark.exclusive,
    pytest.mark.timeout(150),
    pytest.mark.xdist_group("test_esc_closed_loop_simavr"),
    pytest.mark.skipif(
        shutil.which("avr-gcc") is None or not Path("/usr/include/simavr/sim_avr.h").is_file(),
        reason="needs avr-gcc + libsimavr-dev/libsimavrparts1 (scripts/setup_env.sh installs them as root)"),
]
BRIDGE = node_command("bridge", "aeropend_bridge.bridge_node")
CONTROLLER = node_command("controller", "aeropend_control.controller_node")
SIM = node_command("sim_node", "aeropend_sim.ros.sim_node")


@pytest.fixture(scope="module")
def firmware(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_emulator(FW, tmp_path_factory.mktemp("escfw490"),
                          ("ACTUATOR=esc", "ESC_HZ=490", "ANGLE=encoder", f"ENC_CPR={CPR}", "SPEED=none"))


def _esc_rig(path: Path) -> Path:
    """``rig new --actuator esc`` (its starting values: ω_max 1000 rad/s, input delay 50 ms, T_m 0.1 s;
    reach π/2) with the firmware's sample period, the encoder's quantum and a hardware block."""
    assert rig_main(["new", "--actuator", "esc", "-o", str(path)]) == 0
    data = yaml.safe_load(path.read_text())
    q = {"unit": "s", "source": "ESC calibrated to 1.0-2.0 ms (test)"}
    data["sample_period"] = {"value": TS, "unit": "s", "source": "firmware Timer1 tick: 510 x 4 us"}
    data["sensors"] = {"theta_quantum": {"value": Q, "unit": "rad", "source": f"encoder, {CPR} counts/rev"}}
    data["hardware"] = {"angle_sensor": "encoder",
                        "counts_per_rev": {"value": CPR, "unit": "1", "source": "1000 lines x 4 (test)"},
                        "pulse_offset": {"value": PULSE_OFFSET, **q},
                        "pulse_span": {"value": PULSE_SPAN, **q}}
    path.write_text(yaml.safe_dump(data))
    return path


def _stand_in(rig: Path, path: Path) -> tuple[Path, float]:
    """The hardware stand-in's plant: the rig file with the mean latency the ESC protocol and the
    emulation add taken out of its input delay, so that the whole hardware path is the rig the file
    describes (module docstring). Returns (its rig file, the latency taken out [s])."""
    data = yaml.safe_load(rig.read_text())
    tau_eq = plant_model(load_rig(rig)).equilibrium(STEP)[1]
    width = PULSE_OFFSET + tau_eq * PULSE_SPAN
    # the reply to sample k reaches the timer at tick k + 1 (one T_s), the pin at the next frame start
    # (half a frame on average), the plant after the width and half an exchange; the angle is half an
    # exchange old
    latency = TS + FRAME_S / 2 + width + EXCHANGE_US * 1e-6
    delay = data["actuator"]["input_delay"]
    delay["value"] = float(delay["value"]) - latency
    delay["source"] = f"the rig file's less {latency * 1e3:.2f} ms: the ESC protocol's and the emulation's"
    path.write_text(yaml.safe_dump(data))
    return path, latency


def _controller(rig: Path, trace: Path, env: dict[str, str], log: Path,
                mode: str = "realtime") -> subprocess.Popen:
    """The controller node, default strategy, in ``mode``: reference 0, then STEP at T_STEP."""
    return subprocess.Popen(
        [*CONTROLLER, "--ros-args", "-p", f"rig:={rig}", "-p", f"steps:=[0.0, 0.0, {T_STEP}, {STEP}]",
         "-p", f"duration:={T_STEP + AFTER}", "-p", f"trace:={trace}", "-p", f"mode:={mode}"],
        env=env, stdout=log.open("w"), stderr=subprocess.STDOUT, text=True)


def _trace(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(t − t_step [s], θ [rad]) of a controller trace from its sample count: row i is the MCU's
    (or ``sim_node``'s) tick i, t = (i − i_step)·T_s; i_step: the first sample at the new reference.

    The tick count, not the stamps: the bridge stamps a sample with the MCU's time mapped to the
    host's (a drift line through each second's least delay), and the emulated MCU is paced to the
    host's clock only roughly, so its mapped periods came out 2.032-2.036 ms with jumps of 4-7 ms at
    each second's re-fit (2 of 6 runs, 2026-11-30): matching samples by stamp paired a sample with
    one 2-3 ticks away (4 q during the rise). Every tick has its row here: the bridge counts the
    frames lost on the serial link (asserted 0); a sample lost between the bridge and the controller
    (best-effort QoS) would shift the rest of the trace by a tick, a departure the comparison shows."""
    rows = list(csv.reader(path.open()))
    head, data = rows[0], np.array(rows[1:], dtype=float)
    ref, theta = (data[:, head.index(k)] for k in ("reference", "theta"))
    k_step = int(np.argmax(ref >= STEP - 1e-12))
    assert ref[-1] == pytest.approx(STEP) and k_step > 0, "the step did not happen"
    return (np.arange(ref.size) - k_step) * TS, theta


def _tail(path: Path, n: int = 1500) -> str:
    return path.read_text(errors="replace")[-n:] if path.is_file() else ""


def _hardware_graph(firmware: Path, rig: Path, tmp: Path) -> tuple[np.ndarray, np.ndarray, str]:
    env = isolated_env(random_domain(150, 230))
    sock_dir = Path(tempfile.mkdtemp(prefix="ap-plant-"))  # a short path: sun_path holds 108 bytes
    sock = sock_dir / "plant.sock"
    trace = tmp / "hw_trace.csv"
    stand_in, _ = _stand_in(rig, tmp / "stand_in_rig.yaml")
    logs = {k: tmp / f"hw_{k}.log" for k in ("plant", "harness", "bridge", "controller")}
    plant = harness = bridge = ctl = None
    try:
        plant = subprocess.Popen([sys.executable, "-m", "aeropend_bridge.simavr_plant", str(stand_in),
                                  str(sock), "--interval", f"{EXCHANGE_US * 1e-6}", "--trace",
                                  str(tmp / "hw_plant_trace.csv")],
                                 env=env, stdout=subprocess.PIPE, stderr=logs["plant"].open("w"), text=True)
        ready = plant.stdout.readline() if plant.stdout is not None else ""
        assert ready.startswith("LISTENING"), _tail(logs["plant"])
        harness = subprocess.Popen([str(firmware / "harness"), str(firmware / "aeropend.elf"), "0", "-P",
                                    str(sock), "-Q", str(EXCHANGE_US), "-M", "0.5", "-H", str(HOLD_US)],
                                   stdout=subprocess.PIPE, stderr=logs["harness"].open("w"), text=True)
        port = read_pty_path(harness)
        # the controller designs (seconds) while the bridge connects and the ESC arms (2 s of MCU time)
        ctl = _controller(rig, trace, env, logs["controller"])
        bridge = subprocess.Popen([*BRIDGE, "--ros-args", "-p", f"port:={port}", "-p", f"rig:={rig}"],
                                  env=env, stdout=logs["bridge"].open("w"), stderr=subprocess.STDOUT,
                                  text=True)
        try:
            ctl.wait(timeout=90)
        except subprocess.TimeoutExpired:
            pytest.fail(f"controller did not finish: {_tail(logs['controller'])}\n"
                        f"bridge: {_tail(logs['bridge'])}")
        assert ctl.returncode == 0, _tail(logs["controller"])
        stop(bridge, signal.SIGINT, timeout=10)
        assert bridge.returncode == 0, _tail(logs["bridge"])
        lost = re.findall(r"\blost=(\d+)", logs["bridge"].read_text(errors="replace"))
        assert lost and int(lost[-1]) == 0, f"the bridge lost sample frames: {_tail(logs['bridge'])}"
        # one trip is the end of the run: the controller stops commanding at its duration, the bridge
        # stays active until it is stopped; more are the controller falling silent during the run
        trips = re.findall(r"\bwatchdog_trips=(\d+)", logs["bridge"].read_text(errors="replace"))
        assert trips and int(trips[-1]) <= 1, (
            f"the controller fell silent for over the bridge's command timeout {int(trips[-1]) - 1} time(s) "
            f"during the run: the real-time loop was starved (the test needs the machine to itself: "
            f"-m exclusive)\n{_tail(logs['bridge'])}")
        # the harness's unread frames after the bridge left are no concern here (LINKLOST)
        out = stop(harness, signal.SIGTERM, timeout=20).stdout
        plant_out, _ = plant.communicate(timeout=10)  # the harness closed the socket: it reports, exits
        assert "PLANTLOST" not in out and plant.returncode == 0, (out, plant_out, _tail(logs["plant"]))
    finally:
        reap(bridge, ctl, harness, plant)
        shutil.rmtree(sock_dir, ignore_errors=True)
    t, theta = _trace(trace)
    return t, theta, f"{out.strip()} | {plant_out.strip()}"


def _sim_graph(rig: Path, tmp: Path) -> tuple[np.ndarray, np.ndarray]:
    """The all-simulated graph: ``sim_node`` and the controller with the rig file, in lock-step."""
    env = isolated_env(random_domain(150, 230))
    trace = tmp / "sim_trace.csv"
    logs = {k: tmp / f"sim_{k}.log" for k in ("sim", "controller")}
    sim = ctl = None
    try:
        sim = subprocess.Popen([*SIM, "--ros-args", "-p", f"rig:={rig}", "-p",
                                "effects:=[sensor_noise=false]", "-p", "mode:=lockstep"],
                               env=env, stdout=logs["sim"].open("w"), stderr=subprocess.STDOUT, text=True)
        ctl = _controller(rig, trace, env, logs["controller"], "lockstep")
        try:
            ctl.wait(timeout=90)
        except subprocess.TimeoutExpired:
            pytest.fail(f"controller did not finish: {_tail(logs['controller'])}\nsim: {_tail(logs['sim'])}")
        assert ctl.returncode == 0, _tail(logs["controller"])
        stop(sim, signal.SIGTERM, timeout=10)
    finally:
        reap(ctl, sim)
    return _trace(trace)


def _slope_at(t: np.ndarray, y: np.ndarray, at: float, half: float = 0.01) -> float:
    """|dy/dt| [rad/s] around ``at``, over ±``half`` seconds."""
    k0, k1 = np.searchsorted(t, at - half), np.searchsorted(t, at + half)
    k1 = min(k1, t.size - 1)
    return abs(float(y[k1] - y[k0]) / float(t[k1] - t[k0])) if k1 > k0 else 0.0


def _figures(name: str, m: StepMetrics) -> str:
    return (f"{name}: final {STEP - m.steady_state_error:.5f} rad, rise {m.rise_time * 1e3:.1f} ms, "
            f"settling {m.settling_time * 1e3:.1f} ms, M_p {m.overshoot:.2f} % (peak "
            f"{m.overshoot / 100 * STEP * 1e3:.2f} mrad over)")


def test_esc_firmware_closed_loop_matches_the_simulated_graph(firmware: Path, tmp_path: Path) -> None:
    rig = _esc_rig(tmp_path / "esc_encoder_rig.yaml")
    t0 = time.monotonic()
    th_t, th_hw, counts = _hardware_graph(firmware, rig, tmp_path)
    t1 = time.monotonic()
    holds, timeouts = (int(v) for v in re.search(r"HOLDS (\d+) (\d+)", counts).groups())
    ts_t, th_sim = _sim_graph(rig, tmp_path)
    t2 = time.monotonic()
    hw, sim = step_metrics(th_t, th_hw, STEP), step_metrics(ts_t, th_sim, STEP)
    # sample by sample from the step on: both traces on the same 2.040 ms tick, aligned on the step
    n = min(int(np.sum(th_t >= 0)), int(np.sum(ts_t >= 0)))
    grid = np.flatnonzero(th_t >= 0)[:n]
    diff = np.abs(th_hw[grid] - th_sim[np.flatnonzero(ts_t >= 0)[:n]])
    k_max = int(np.argmax(diff))
    print(f"\nhardware path ({t1 - t0:.1f} s wall; harness/plant: {counts})")
    print(_figures("  firmware + bridge", hw))
    print(_figures("  sim_node         ", sim))
    print(f"  max |dtheta| {diff.max() * 1e3:.2f} mrad = {diff.max() / Q:.2f} q at t - t_step = "
          f"{th_t[grid][k_max] * 1e3:.0f} ms; after 1.5 s {diff[th_t[grid] >= 1.5].max() / Q:.2f} q "
          f"(q = {Q * 1e3:.3f} mrad); sim graph {t2 - t1:.1f} s wall; MCU time waited for the host's "
          f"answer {holds} times, {timeouts} over {HOLD_MAX_S * 1e3:.0f} ms; the plant's exchanges "
          f"(t, pulse, τ, θ): {tmp_path / 'hw_plant_trace.csv'}")
    failed = _departures(hw, sim, ts_t, th_sim, diff, th_t[grid][k_max])
    # one wait over the cap is the end of the run (the sample after the controller's last answer); more
    # are samples of the run the host did not answer in time
    late = timeouts - 1
    if failed and late > 0:
        pytest.skip(f"verdict withheld: the host did not answer {late} sample(s) within "
                    f"{HOLD_MAX_S * 1e3:.0f} ms of wall-clock time, so the MCU ran on without the answer "
                    f"(harness -H): the loop this comparison assumes did not run; {'; '.join(failed)}")
    assert not failed, "; ".join(failed)


def _departures(hw: StepMetrics, sim: StepMetrics, ts_t: np.ndarray, th_sim: np.ndarray, diff: np.ndarray,
                t_max: float) -> list[str]:
    """Every tolerance of the module docstring the hardware path's step misses, each named."""
    out = []
    final = abs(hw.steady_state_error - sim.steady_state_error)
    if final > 2 * Q:
        out.append(f"final values {final / Q:.2f} q apart (2 q)")
    if abs(hw.rise_time - sim.rise_time) > 1.5 * LATENCY + 2 * TS:
        out.append(f"rise times {abs(hw.rise_time - sim.rise_time) * 1e3:.1f} ms apart")
    slope = max(_slope_at(ts_t, th_sim, sim.settling_time), 1e-3)
    if abs(hw.settling_time - sim.settling_time) > 1.5 * LATENCY + 2 * TS + 2 * Q / slope:
        out.append(f"settling times {abs(hw.settling_time - sim.settling_time) * 1e3:.1f} ms apart")
    if abs(hw.overshoot - sim.overshoot) / 100 * STEP > 3 * Q:  # StepMetrics.overshoot is in %
        out.append(f"peaks {abs(hw.overshoot - sim.overshoot) / 100 * STEP / Q:.2f} q apart (3 q)")
    # issue 61's bar: the step response within the encoder's quantisation (module docstring), 2 q
    if diff.max() > 2 * Q + 1e-9:
        out.append(f"max |dtheta| {diff.max() / Q:.2f} q at t - t_step = {t_max * 1e3:.0f} ms (2 q)")
    return out
