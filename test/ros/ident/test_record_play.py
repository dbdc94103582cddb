"""Multi-process ROS 2 test: ``play`` a contract bag, ``record`` it in another process, compare.

Each test uses its own random ROS_DOMAIN_ID (and localhost-only discovery) so parallel runs do
not cross-talk. Sample topics are best effort, so up to 1 % of the samples may be lost; every
sample that arrives must carry exactly the original values and stamps.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from aeropend_ident.io.bag_writer import write_bag
from aeropend_ident.io.bags import read_bag
from aeropend_sim.contract import TOPIC_ARMATURE, TOPIC_DUTY_CYCLE, TOPIC_JOINT_STATES
from aeropend_sim.recording import Recording
from aeropend_sim.ros.harness import isolated_env, node_command, private_node, random_domain, stop

pytest.importorskip("rclpy")
pytestmark = pytest.mark.ros

N = 1225  # 2.5 s at the thesis rate
DT = 2.048e-3
RECORD = node_command("record", "aeropend_ident.nodes.record")


def _source(tmp_path: Path) -> tuple[Recording, Path]:
    rng = np.random.default_rng(11)
    t = np.arange(N) * DT
    rec = Recording(
        t=t,
        duty=np.clip(0.45 + 0.1 * np.sign(np.sin(2 * np.pi * 1.3 * t)) + 0.01 * rng.standard_normal(N), 0, 1),
        channels={
            "theta": 0.4 * np.sin(2 * np.pi * 0.5 * t) + 1e-3 * rng.standard_normal(N),
            "theta_dot": rng.standard_normal(N),
            "omega_rotor": 300 + rng.standard_normal(N),
            "i_a": 0.7 + 0.01 * rng.standard_normal(N),
            "v_a": 1.4 + 0.01 * rng.standard_normal(N),
        },
        source="test_record_play", stamp0_ns=1_700_000_000_000_000_000,
    )
    return rec, write_bag(rec, tmp_path / "source")


def _run(tmp_path: Path, record_args: list[str], play_args: list[str], stop_sig: int | None
         ) -> tuple[subprocess.CompletedProcess[str], str, str]:
    """Start the recorder, play the source bag, then stop the recorder (or let it stop itself)."""
    env = isolated_env(random_domain())
    rec_proc = subprocess.Popen([*RECORD, *record_args], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    play_proc: subprocess.Popen[str] | None = None
    try:
        play_proc = subprocess.Popen([sys.executable, "-m", "aeropend_ident.nodes.play", *play_args,
                                      "--wait-for-subscribers", "20"], env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        play_out, _ = play_proc.communicate(timeout=40)
        assert play_proc.returncode == 0, play_out
        if stop_sig is not None:
            time.sleep(0.3)
            rec_proc.send_signal(stop_sig)
        rec_out, _ = rec_proc.communicate(timeout=15)
        return subprocess.CompletedProcess(rec_proc.args, rec_proc.returncode), rec_out, play_out
    finally:
        if play_proc is not None:
            stop(play_proc, signal.SIGINT, kill_on_timeout=True)
        stop(rec_proc, signal.SIGINT, kill_on_timeout=True)


def _compare(src: Recording, got: Recording) -> np.ndarray:
    """Indices of the received samples in ``src``; asserts values/stamps identical, loss <= 1 %."""
    s_src = src.stamp0_ns + np.round(src.t * 1e9).astype(np.int64)
    s_got = got.stamp0_ns + np.round(got.t * 1e9).astype(np.int64)
    idx = np.searchsorted(s_src, s_got)
    assert np.all(idx < len(src)) and np.array_equal(s_src[idx], s_got), "recorded stamps not in the source"
    assert len(got) >= 0.99 * len(src), f"lost {len(src) - len(got)} of {len(src)} samples"
    for name in ("theta", "theta_dot", "omega_rotor"):
        assert np.array_equal(got.channels[name], src.channels[name][idx]), name
    assert "omega_prop" not in got.channels  # NaN on the wire -> absent, as in the source
    # duty[k] is the effort of the next received sample: exact, except before a gap where it is the
    # duty applied just before that next sample (wire convention, see read_bag)
    gap = np.flatnonzero(np.diff(idx) > 1)
    assert got.meta["gaps"] == gap.size
    assert np.array_equal(np.delete(got.duty, gap), np.delete(src.duty[idx], gap))
    assert np.array_equal(got.duty[gap], src.duty[idx[gap + 1] - 1])
    ok = np.isfinite(got.channels["i_a"])
    assert (~ok).sum() <= 0.01 * len(src)
    assert np.array_equal(got.channels["i_a"][ok], src.channels["i_a"][idx][ok].astype(np.float32))
    assert got.meta["unmatched_joint_states"] <= 0.01 * len(src)
    return idx


def _check_pacing(bag: Path, src: Recording, idx: np.ndarray, rate: float) -> None:
    """The replay is paced at ``rate``: the recorded span of receive times (bag log times) is the
    original span / rate within 10 % (a wrong rate is off by 50 % or more, an unpaced dump spans
    ~0). How *precisely* the messages arrive on time depends on the machine's load (p95 27 ms at
    load 5 on 2 cores, under 10 ms when quiet): measured by ``bench/bench_play_timing.py``, not
    asserted here."""
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == TOPIC_JOINT_STATES]
        log = np.array([t for _, t, _ in reader.messages(connections=conns)], dtype=np.int64)
    expected = (src.t[idx[-1]] - src.t[idx[0]]) / rate
    assert (log[-1] - log[0]) / 1e9 == pytest.approx(expected, rel=0.10)


def _qos(bag: Path) -> dict[str, dict[str, object]]:
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"][0]
            for t in info["topics_with_message_count"]}


@pytest.mark.exclusive  # real time: beside the parallel suite (clean-clone CI of 83d8c14, load 4 on 2 cores)
# the 2.5 s replay reached the recorder over 5.26 s, its rate's 10 % missed by both processes' starvation
def test_play_then_record_mcap_ros_args_sigint(tmp_path: Path) -> None:
    src, source_bag = _source(tmp_path)
    out = tmp_path / "recorded"
    done, rec_out, play_out = _run(
        tmp_path, ["--ros-args", "-p", f"output:={out}"], [str(source_bag)], signal.SIGINT)
    assert done.returncode == 0, rec_out
    assert f"published {3 * N} messages" in play_out
    assert (out / "metadata.yaml").exists()
    got = read_bag(out)
    assert got.meta["storage"] == "mcap"
    idx = _compare(src, got)
    _check_pacing(out, src, idx, rate=1.0)
    span = (got.t[-1]) / (src.t[idx[-1]] - src.t[idx[0]])
    assert span == pytest.approx(1.0, abs=1e-9)  # stamps are the original ones
    qos = _qos(out)  # offered QoS of the player's publishers, which took them from the source bag
    assert qos[TOPIC_JOINT_STATES]["reliability"] == "best_effort"
    assert qos[TOPIC_ARMATURE]["reliability"] == "best_effort"
    assert qos[TOPIC_DUTY_CYCLE]["reliability"] == "reliable"


@pytest.mark.exclusive  # real time, as its sibling above: beside the parallel suite (fresh-clone CI of
# 19b7580, the suite's CPU time cut by a third and so denser) the 1.25 s replay at rate 2 reached the
# recorder over 1.51 s; the player keeps absolute deadlines, so only starved processes lag that far
def test_play_twice_as_fast_record_sqlite3_friendly_flags_sigterm(tmp_path: Path) -> None:
    src, source_bag = _source(tmp_path)
    out = tmp_path / "recorded_sqlite"
    done, rec_out, _ = _run(tmp_path, ["-o", str(out), "--storage", "sqlite3"],
                            [str(source_bag), "--rate", "2.0"], signal.SIGTERM)
    assert done.returncode == 0, rec_out
    got = read_bag(out)
    assert got.meta["storage"] == "sqlite3"
    idx = _compare(src, got)
    _check_pacing(out, src, idx, rate=2.0)


def test_recorder_stops_itself(tmp_path: Path) -> None:
    src, source_bag = _source(tmp_path)
    out = tmp_path / "first300"
    t0 = time.monotonic()
    done, rec_out, _ = _run(tmp_path, ["-o", str(out), "--max-samples", "300"], [str(source_bag)], None)
    assert done.returncode == 0, rec_out
    assert "300 samples recorded" in rec_out
    got = read_bag(out)
    assert len(got) == 300
    s_src = src.stamp0_ns + np.round(src.t * 1e9).astype(np.int64)
    assert np.isin(got.stamp0_ns + np.round(got.t * 1e9).astype(np.int64), s_src).all()

    # duration limit with nobody publishing: a valid, empty bag listing the contract topics
    empty = tmp_path / "empty"
    env = isolated_env(random_domain())
    args = [*RECORD, "--ros-args", "-p", f"output:={empty}",
            "-p", "duration:=1.0"]
    proc = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        text, _ = proc.communicate(timeout=20)
    finally:
        stop(proc, signal.SIGINT, kill_on_timeout=True)
    assert proc.returncode == 0, text
    assert "duration 1 s reached" in text
    assert set(_qos(empty)) == {TOPIC_JOINT_STATES, TOPIC_ARMATURE, TOPIC_DUTY_CYCLE}
    assert time.monotonic() - t0 < 40


def test_play_clock_publishes_the_bag_time(tmp_path: Path) -> None:
    """``play --clock 100``: /clock carries log_0 + (now − start)·rate, non-decreasing, inside the
    bag's time span, about 100 ticks per second of playback."""
    from rosgraph_msgs.msg import Clock

    from aeropend_sim.contract import TOPIC_CLOCK

    src, bag = _source(tmp_path)
    domain = random_domain()
    ticks: list[int] = []
    with private_node("test_play_clock", domain) as (node, ex):
        node.create_subscription(Clock, TOPIC_CLOCK,
                                 lambda m: ticks.append(m.clock.sec * 10**9 + m.clock.nanosec), 10)
        play = subprocess.Popen([sys.executable, "-m", "aeropend_ident.nodes.play", str(bag),
                                 "--clock", "100", "--wait-for-subscribers", "20"], env=isolated_env(domain),
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            deadline = time.monotonic() + 60.0
            while play.poll() is None and time.monotonic() < deadline:
                ex.spin_once(timeout_sec=0.01)
            ex.spin_once(timeout_sec=0.2)
            out = play.communicate(timeout=10)[0]
            assert play.returncode == 0, out
        finally:
            stop(play, signal.SIGINT, kill_on_timeout=True)
    t = np.array(ticks)
    span = src.t[-1]
    assert t.size >= 0.8 * 100 * span, f"{t.size} clock ticks for {span:.2f} s"
    assert np.all(np.diff(t) > 0)
    assert t[0] >= src.stamp0_ns and t[-1] <= src.stamp0_ns + round(span * 1e9) + 1
    assert np.median(np.diff(t)) == pytest.approx(1e7, rel=1e-6)  # 10 ms of bag time per tick at rate 1
