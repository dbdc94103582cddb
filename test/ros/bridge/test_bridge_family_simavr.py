"""The ``bridge`` node on the ESC + encoder firmware in simavr, and its refusal of a mismatch (issue 61).

The emulator build ``ACTUATOR=esc ESC_HZ=50 ANGLE=encoder ENC_CPR=4000 SPEED=none`` runs in
``firmware/sim/harness.c``; the harness's encoder raises the rod to 0.5 rad (count 318) in 0.8 s
and holds it there. An ESC rig file from ``rig new`` with a ``hardware`` block (encoder, 4000
counts, ESC 1.0–2.0 ms) drives it through the bridge:

* configure reads the firmware's HELLO and accepts it; ``joint_states`` carries θ = 318·2π/4000,
  the applied τ computed back from the firmware's applied pulse (0 while the ESC arms, then 0.5
  for a τ = 0.5 command), ω₁ = ω₂ = NaN (no speed sensor in the build) and ``armature`` NaN
  (an ESC has no armature channels) — never 0;
* controller silence: τ 0 (the zero-throttle pulse) on the topic, held, after one trip of the
  bridge's watchdog; a τ 0 between τ 0.5 samples (the firmware's own 61 ms watchdog, on a host
  too loaded to send a frame in time) is reported by the bridge, never silent;
* the thesis rig (H-bridge) against the same firmware: the bridge exits with status 1 and a
  message naming both actuators, before activating anything.
"""

from __future__ import annotations

import itertools
import math
import shutil
import signal
import subprocess
import time
from contextlib import ExitStack
from pathlib import Path

import pytest
import yaml

pytest.importorskip("rclpy")

from sensor_msgs.msg import BatteryState, JointState
from std_msgs.msg import Float64

from aeropend_bridge.simavr_harness import build_emulator, encoder_event_lines, read_pty_path
from aeropend_ident.cli.rig import main as rig_main
from aeropend_sim.contract import TOPIC_ARMATURE, TOPIC_DUTY_CYCLE, TOPIC_JOINT_STATES
from aeropend_sim.ros.harness import isolated_env, node_command, private_node, random_domain, reap, stop
from aeropend_sim.ros.ros_contract import COMMAND_QOS, SAMPLE_SUB_QOS

ROOT = Path(__file__).resolve().parents[3]
FW = ROOT / "firmware"
CPR = 4000
THETA_HOLD = 0.5

pytestmark = [
    pytest.mark.ros,
    pytest.mark.timeout(120),
    pytest.mark.skipif(
        shutil.which("avr-gcc") is None or not Path("/usr/include/simavr/sim_avr.h").is_file(),
        reason="needs avr-gcc + libsimavr-dev/libsimavrparts1 (scripts/setup_env.sh installs them as root)"),
]
BRIDGE = node_command("bridge", "aeropend_bridge.bridge_node")


@pytest.fixture(scope="module")
def firmware(tmp_path_factory: pytest.TempPathFactory) -> Path:
    build = build_emulator(FW, tmp_path_factory.mktemp("escfw"),
                           ("ACTUATOR=esc", "ESC_HZ=50", "ANGLE=encoder", f"ENC_CPR={CPR}", "SPEED=none"))
    # the rod rises smoothly (peak 1 rad/s) to THETA_HOLD at t = 0.1 s + π/4 s and stays there
    t1_us = 100_000 + math.pi / 4 * 1e6
    swing = (0.1, t1_us * 1e-6, 0.0, THETA_HOLD, 2.0)
    (build / "events.txt").write_text("\n".join(encoder_event_lines([swing], CPR)) + "\n")
    return build


def _esc_rig(path: Path) -> Path:
    assert rig_main(["new", "--actuator", "esc", "-o", str(path)]) == 0
    data = yaml.safe_load(path.read_text())
    q = {"unit": "s", "source": "ESC calibrated to 1.0-2.0 ms (test)"}
    data["hardware"] = {"angle_sensor": "encoder",
                        "counts_per_rev": {"value": CPR, "unit": "1", "source": "1000 lines x 4 (test)"},
                        "pulse_offset": {"value": 1.0e-3, **q}, "pulse_span": {"value": 1.0e-3, **q}}
    path.write_text(yaml.safe_dump(data))
    return path


def _harness(build: Path) -> subprocess.Popen:
    return subprocess.Popen([str(build / "harness"), str(build / "aeropend.elf"), "0", "-e",
                             str(build / "events.txt")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def test_bridge_drives_the_esc_encoder_firmware(firmware: Path, tmp_path: Path) -> None:
    rig = _esc_rig(tmp_path / "esc_encoder_rig.yaml")
    sim = _harness(firmware)
    env = isolated_env(random_domain(201, 215))
    bridge = None
    client = ExitStack()
    try:
        node, ex = client.enter_context(private_node("esc_client", int(env["ROS_DOMAIN_ID"])))
        js: list[JointState] = []
        arm: list[BatteryState] = []
        node.create_subscription(JointState, TOPIC_JOINT_STATES, js.append, SAMPLE_SUB_QOS)
        node.create_subscription(BatteryState, TOPIC_ARMATURE, arm.append, SAMPLE_SUB_QOS)
        pub = node.create_publisher(Float64, TOPIC_DUTY_CYCLE, COMMAND_QOS)

        def spin(seconds: float, duty: float | None = None) -> None:
            end, nxt = time.monotonic() + seconds, 0.0
            while time.monotonic() < end:
                if duty is not None and time.monotonic() >= nxt:
                    pub.publish(Float64(data=duty))
                    nxt = time.monotonic() + 0.02
                ex.spin_once(timeout_sec=0.005)

        bridge = subprocess.Popen([*BRIDGE, "--ros-args", "-p", f"port:={read_pty_path(sim)}", "-p",
                                   f"rig:={rig}"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True)
        end = time.monotonic() + 30
        while len(js) < 200 and time.monotonic() < end and bridge.poll() is None:
            ex.spin_once(timeout_sec=0.01)
        assert len(js) >= 200, f"no samples from the bridge (exit status {bridge.poll()})"
        # commands flow while the ESC arms (2 s after reset): τ stays 0 until arming ends. On a loaded
        # host the firmware's own watchdog (61 ms without a frame) may cut a few samples to τ 0 after
        # that; the bridge reports each cut (asserted below), so the loop waits for a steady τ 0.5
        end = time.monotonic() + 30
        while time.monotonic() < end and not all(abs(m.effort[1] - 0.5) < 1e-9 for m in js[-5:]):
            spin(0.2, duty=0.5)
        on = [m.effort[1] for m in js[-20:]]
        assert all(abs(t - 0.5) < 1e-9 for t in on[-5:]), on  # 1500 µs applied = τ 0.5 exactly
        assert js[0].effort[1] == 0.0  # arming: the zero-throttle pulse
        first_on = next(i for i, m in enumerate(js) if m.effort[1] != 0.0)
        m, b = js[-1], arm[-1]
        count = math.floor(THETA_HOLD * CPR / (2 * math.pi))  # 318
        assert m.position[0] == pytest.approx(count * 2 * math.pi / CPR, abs=1e-12)
        assert math.isnan(m.velocity[1]) and math.isnan(m.velocity[2]), list(m.velocity)
        assert math.isnan(b.voltage) and math.isnan(b.current), (b.voltage, b.current)
        n_on = len(js)
        # controller silent: the bridge sends the zero-throttle pulse. The silence lasts 1 s of host time
        # and 300 samples (0.6 s of the MCU's): beside the parallel suite the emulated MCU ran at an
        # eighth of real time (65 samples in the 1 s; fresh-clone CI of f40fd9a)
        end = time.monotonic() + 30
        spin(1.0)
        while len(js) - n_on < 300 and time.monotonic() < end:
            spin(0.1)
        off = [x.effort[1] for x in js[n_on:]]
        # the bridge's cut holds: the last 0.2 s of samples (490 Hz) at the zero-throttle pulse
        assert len(off) > 100 and all(t == 0.0 for t in off[-100:]), off[-100:]
        last_on = max((i for i, t in enumerate(off) if t != 0.0), default=-1)
        assert all(abs(t - 0.5) < 1e-9 for t in off if t != 0.0)  # only τ 0.5 or the zero-throttle pulse
        dt = (js[n_on + last_on + 1].header.stamp.sec + js[n_on + last_on + 1].header.stamp.nanosec * 1e-9
              - (js[n_on + last_on].header.stamp.sec + js[n_on + last_on].header.stamp.nanosec * 1e-9)
              if last_on >= 0 else math.nan)
        # a τ 0 between τ 0.5 samples, after arming, is a cut by the firmware's own watchdog
        stream = js[first_on:n_on + last_on + 1]
        cuts = sum(1 for a, b in itertools.pairwise(stream) if a.effort[1] != 0.0 and b.effort[1] == 0.0)
        err = stop(bridge, signal.SIGINT, timeout=10).stderr
        assert bridge.returncode == 0, err
        assert "firmware (announced): actuator esc, angle encoder (4000 counts/rev)" in err, err
        # the bridge's own watchdog tripped once, at the silence; a firmware cut is reported, never silent
        summary = next(x for x in err.splitlines() if "summary:" in x)
        assert " watchdog_trips=1 " in summary, summary
        assert not cuts or "the firmware's own watchdog cut the output" in err, (cuts, summary)
        print(f"ESC bridge: tau 0 {dt * 1e3:.1f} ms (stamps) after the last τ 0.5 sample; {cuts} cut(s) "
              f"by the firmware's own watchdog on the way ({summary.split('summary: ')[1]})")
    finally:
        reap(bridge)
        client.close()
        sim.kill()
        sim.communicate()


def test_bridge_refuses_a_rig_of_another_family(firmware: Path) -> None:
    sim = _harness(firmware)
    env = isolated_env(random_domain(216, 230))
    try:
        r = subprocess.run([*BRIDGE, "--ros-args", "-p", f"port:={read_pty_path(sim)}", "-p",
                            "rig:=thesis_rig"], env=env, capture_output=True, text=True, timeout=60)
    finally:
        sim.kill()
        sim.communicate()
    print(r.stderr[-600:])
    assert r.returncode == 1, r.stderr
    assert ("rig 'thesis_rig' is a dc_hbridge rig (firmware actuator 'hbridge') but the firmware on the port "
            "drives 'esc' and reads 'encoder'") in r.stderr
    assert "active: duty output enabled" not in r.stderr  # refused at configure, nothing armed


# ---------------------------------------------------------------------------------------- index
#: The index build: the encoder's index lies INDEX_AT counts from the rod's rest; the rig is powered up
#: with the rod REST_DISK counts from its rest (the harness's disk count 0 is the power-up position).
INDEX_DISK, REST_DISK = 100, -200
INDEX_AT = INDEX_DISK - REST_DISK
T_SWING = 5.0  # [s of MCU time] the rod rests at its power-up position until then (ESC armed at 2 s)


@pytest.fixture(scope="module")
def index_firmware(tmp_path_factory: pytest.TempPathFactory) -> Path:
    build = build_emulator(FW, tmp_path_factory.mktemp("escfwindex"),
                           ("ACTUATOR=esc", "ESC_HZ=50", "ANGLE=encoder", f"ENC_CPR={CPR}", "SPEED=none",
                            f"ENC_INDEX={INDEX_AT}"))
    # at T_SWING the rod rises smoothly (peak 1 rad/s) through the index (disk count 100, 0.157 rad) to
    # THETA_HOLD from the power-up position (disk count 318) and stays there
    t0_us, t1_us = T_SWING * 1e6, T_SWING * 1e6 + math.pi / 4 * 1e6
    swing = (t0_us * 1e-6, t1_us * 1e-6, 0.0, THETA_HOLD, 2.0)
    (build / "events.txt").write_text("\n".join(encoder_event_lines([swing], CPR, index=INDEX_DISK)) + "\n")
    return build


# real time: the emulated MCU must turn the rod to the index within 40 s; beside the parallel suite on the
# slower machine of 2026-11-30 it ran at a tenth of real time (1 781 samples in 40 s) and never got there
@pytest.mark.exclusive
def test_bridge_holds_the_output_until_the_encoder_is_homed(index_firmware: Path, tmp_path: Path) -> None:
    """Until the encoder's index is seen θ is unknown: NaN on ``joint_states`` and τ held at 0 whatever
    the controller sends; from the index on θ is the angle from the rod's rest and τ flows."""
    rig = _esc_rig(tmp_path / "esc_index_rig.yaml")
    data = yaml.safe_load(rig.read_text())
    data["hardware"]["encoder_index"] = True
    rig.write_text(yaml.safe_dump(data))
    sim = _harness(index_firmware)
    env = isolated_env(random_domain(201, 215))
    bridge = None
    client = ExitStack()
    try:
        node, ex = client.enter_context(private_node("esc_index_client", int(env["ROS_DOMAIN_ID"])))
        js: list[JointState] = []
        node.create_subscription(JointState, TOPIC_JOINT_STATES, js.append, SAMPLE_SUB_QOS)
        pub = node.create_publisher(Float64, TOPIC_DUTY_CYCLE, COMMAND_QOS)
        bridge = subprocess.Popen([*BRIDGE, "--ros-args", "-p", f"port:={read_pty_path(sim)}", "-p",
                                   f"rig:={rig}"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True)
        end, nxt = time.monotonic() + 40, 0.0
        homed_at = None
        while time.monotonic() < end and bridge.poll() is None:
            if time.monotonic() >= nxt:
                pub.publish(Float64(data=0.5))  # the controller asks for τ 0.5 throughout
                nxt = time.monotonic() + 0.02
            ex.spin_once(timeout_sec=0.005)
            if homed_at is None and js and math.isfinite(js[-1].position[0]):
                homed_at = len(js) - 1
            # the rod reaches THETA_HOLD π/4 s after it starts: 1 s of samples (490 Hz) after the index
            if homed_at is not None and len(js) > homed_at + 490 and abs(js[-1].effort[1] - 0.5) < 1e-9:
                break
        assert homed_at is not None, f"the bridge never published a finite angle ({len(js)} samples)"
        before, after = js[:homed_at], js[homed_at:]
        assert len(before) > 50 and all(math.isnan(m.position[0]) for m in before)
        # armed at 2 s, commanded τ 0.5 from the first sample on: held at the zero-throttle pulse
        assert all(m.effort[1] == 0.0 for m in before), sorted({m.effort[1] for m in before})
        assert all(math.isfinite(m.position[0]) for m in after)
        rest = math.floor(THETA_HOLD * CPR / (2 * math.pi)) - REST_DISK  # 518 counts from the rod's rest
        assert after[-1].position[0] == pytest.approx(rest * 2 * math.pi / CPR, abs=1e-12)
        assert abs(after[-1].effort[1] - 0.5) < 1e-9, after[-1].effort[1]
        err = stop(bridge, signal.SIGINT, timeout=10).stderr
        assert bridge.returncode == 0, err
        assert "held at 0: the encoder has not seen its index" in err, err[-2000:]
        print(f"index: {len(before)} samples NaN and τ 0 before the index, then θ "
              f"{after[-1].position[0]:.6f} rad, τ 0.5")
    finally:
        reap(bridge)
        client.close()
        sim.kill()
        sim.communicate()
