"""Record → play → record across processes, on bags the project's own recorder writes (issue 34).

Each test records or builds a bag, replays it with ``play`` to a second ``record`` process and
requires every message of every topic to arrive with the same payload: the same count per topic,
byte-identical CDR in the same order, and the same decoded header stamps / clock values / duty
cycles. Before issue 34 ``play`` failed on every bag ``record`` wrote (``history: unknown`` in
the offered QoS -> ``RCLError: ... failed setting topic QoS``).

The graphs run in lock-step (reliable, keep-all samples, commands and /clock; the recorders with
``--reliable``), so nothing may be lost on the way and the comparison demands equality; a
real-time graph's best-effort samples may be dropped by design (``test_record_play_ros`` allows
1 %). Each test uses its own ROS domain (localhost discovery); processes are killed in ``finally``.
"""

from __future__ import annotations

import signal
import struct
import subprocess
import time
from dataclasses import fields, is_dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml

from aeropend_sim.ros.harness import (
    isolate_process,
    isolated_env,
    node_command,
    random_domain,
    reap,
    stop,
    summary_count,
)

pytest.importorskip("rclpy")

from aeropend_ident.io.bag_codec import typestore
from aeropend_ident.io.bag_reader import RawBagReader
from aeropend_ident.io.bag_writer import BagSink, write_bag
from aeropend_ident.nodes.qos import INFINITE_TIME
from aeropend_ident.pipeline import check_recording, run_graph
from aeropend_sim.contract import TOPIC_CLOCK, TOPIC_DUTY_CYCLE, TOPIC_JOINT_STATES
from aeropend_sim.recording import Recording

pytestmark = [pytest.mark.ros, pytest.mark.timeout(180)]

RECORD = node_command("record", "aeropend_ident.nodes.record")
PLAY = node_command("play", "aeropend_ident.nodes.play")


def _raw(bag: Path) -> dict[str, list[bytes]]:
    """Every message of every topic of ``bag``, serialised, in log-time order."""
    with RawBagReader(bag) as reader:
        out: dict[str, list[bytes]] = {t: [] for t in reader.topics}
        for topic, _, raw in reader.messages():
            out[topic].append(raw)
    return out


def _plain(value: object) -> object:
    """A decoded message as nested tuples that compare by value (floats and arrays bitwise, NaN too)."""
    if is_dataclass(value):
        return tuple((f.name, _plain(getattr(value, f.name))) for f in fields(value))
    if isinstance(value, np.ndarray):
        return value.dtype.str, value.tobytes()
    if isinstance(value, float):
        return struct.pack("<d", value)
    if isinstance(value, (list, tuple)):
        return tuple(_plain(v) for v in value)
    return value


def _decoded(msgtype: str, raws: list[bytes]) -> tuple[list[object], np.ndarray]:
    """Every message decoded, and the value that names each: header stamp / clock [ns] or duty."""
    ts = typestore()
    msgs, keys = [], []
    for raw in raws:
        msg = ts.deserialize_cdr(raw, msgtype)
        msgs.append(_plain(msg))
        if hasattr(msg, "header"):
            keys.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
        elif hasattr(msg, "clock"):
            keys.append(msg.clock.sec * 10**9 + msg.clock.nanosec)
        else:
            keys.append(msg.data)
    return msgs, np.array(keys)


def _assert_same_messages(original: Path, replayed: Path) -> dict[str, int]:
    """Every topic of ``original`` is in ``replayed`` with the same messages; returns the counts.

    Messages are compared decoded, every field (the CDR bytes may differ in trailing alignment
    padding, which the middleware does not carry: a bag written by ``write_bag`` pads the end).
    """
    a, b = _raw(original), _raw(replayed)
    assert set(b) == set(a), f"topics {sorted(b)} re-recorded, {sorted(a)} in the bag"
    with RawBagReader(original) as reader:
        types = {t: info.msgtype for t, info in reader.topics.items()}
    for topic in a:
        assert len(b[topic]) == len(a[topic]), f"{topic}: {len(b[topic])} re-recorded of {len(a[topic])}"
        (ma, ka), (mb, kb) = _decoded(types[topic], a[topic]), _decoded(types[topic], b[topic])
        assert np.array_equal(ka, kb), f"{topic}: stamps/values differ first at {np.flatnonzero(ka != kb)[0]}"
        diff = [k for k, (x, y) in enumerate(zip(ma, mb, strict=True)) if x != y]
        assert not diff, f"{topic}: {len(diff)} messages differ in a field, the first at {diff[0]}"
    return {t: len(v) for t, v in a.items()}


def _offered(bag: Path) -> dict[str, dict[str, object]]:
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"][0]
            for t in info["topics_with_message_count"]}


def _replay_and_record(bag: Path, out: Path, env: dict[str, str]) -> tuple[str, str]:
    """``play bag`` to a ``record --reliable`` of the bag's topics; returns both outputs."""
    with RawBagReader(bag) as reader:
        topics = list(reader.topics)
    rec = subprocess.Popen([*RECORD, "-o", str(out), "--reliable", "--topics", *topics], env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    play = None
    try:
        play = subprocess.Popen([*PLAY, str(bag), "--wait-for-subscribers", "30"], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        play_out = play.communicate(timeout=120)[0]
        assert play.returncode == 0, play_out
        assert "no subscriber" not in play_out, play_out
        rec_out = stop(rec, signal.SIGINT, timeout=30).stdout
        assert rec.returncode == 0, rec_out
    finally:
        reap(play, rec)
    return play_out, rec_out


@pytest.mark.exclusive  # real time, as the record/play tests of test_record_play.py: beside the parallel
# suite (fresh-clone CI of 3d2308b) the recorder re-recorded 912 of 979 replayed duty_cycle messages, its
# keep-last queue overflowing while it was starved
def test_sim_node_and_controller_recorded_replayed_rerecorded(tmp_path: Path) -> None:
    """(a) the recorder records a running lock-step ``sim_node`` + ``controller`` graph; ``play``
    replays that bag to a second recorder, which receives every message unchanged."""
    t0 = time.monotonic()
    env = isolated_env(random_domain())
    first, second = tmp_path / "graph", tmp_path / "replayed"
    rec = subprocess.Popen([*RECORD, "-o", str(first), "--reliable", "--clock"], env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    sim = ctl = None
    try:
        # sample 0 waits for both sample consumers (controller and recorder) and the recorder's /clock
        # reader, the controller's first command for both command readers (plant and recorder): the
        # recording starts at sample 0
        sim = subprocess.Popen([*node_command("sim_node"), "--ros-args", "-p", "mode:=lockstep",
                                "-p", "rig:=thesis_rig", "-p", "min_subscribers:=2",
                                "-p", "min_clock_subscribers:=1"],
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        ctl = subprocess.Popen([*node_command("controller"), "--ros-args", "-p", "mode:=lockstep",
                                "-p", "strategy:=fl_pid", "-p", "steps:=[0.0, 0.4]", "-p", "duration:=2.0",
                                "-p", "min_subscribers:=2"],
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        ctl_out = ctl.communicate(timeout=90)[0]
        assert ctl.returncode == 0, ctl_out
        sim_out = stop(sim, signal.SIGTERM, timeout=15).stdout
        rec_out = stop(rec, signal.SIGINT, timeout=30).stdout
        assert rec.returncode == 0, rec_out
    finally:
        reap(ctl, sim, rec)
    t_graph = time.monotonic() - t0

    # the first recording is complete: every sample (re-published ones included), tick and command
    published = summary_count(sim_out, "samples") + summary_count(sim_out, "republished")
    counts = {t: len(v) for t, v in _raw(first).items()}
    assert counts[TOPIC_JOINT_STATES] == counts[TOPIC_CLOCK] == published
    assert counts[TOPIC_DUTY_CYCLE] == summary_count(sim_out, "commands")
    assert published >= 2.0 / 2.048e-3
    # ... with concrete offered QoS: the lock-step writers' reliable keep-all, the controller's commands
    qos = _offered(first)
    assert {q["history"] for q in qos.values()} <= {"keep_last", "keep_all"}
    assert qos[TOPIC_JOINT_STATES]["history"] == qos[TOPIC_CLOCK]["history"] == "keep_all"
    assert qos[TOPIC_JOINT_STATES]["reliability"] == "reliable"

    play_out, _ = _replay_and_record(first, second, env)
    assert f"published {sum(counts.values())} messages" in play_out
    same = _assert_same_messages(first, second)
    print(f"\n(a) sim_node + controller: recorded {counts}, replayed {sum(counts.values())} messages, "
          f"re-recorded {same}; graph {t_graph:.1f} s, total {time.monotonic() - t0:.1f} s")


def test_the_main_jobs_bag_replays(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """(b) a bag of the main job's node graph (``pipeline.run_graph``: recorder, lock-step plant and
    excitation, shortened to two steps) replays to a second recorder message for message."""
    t0 = time.monotonic()
    domain = random_domain()
    isolate_process(monkeypatch, domain)
    signal_params = ["signal:=lhs", "n:=2", "tau_min:=0.35", "tau_max:=0.7", "hold_min:=1.0", "hold_max:=1.2"]
    bag = run_graph(tmp_path / "main", "thesis_rig", "lockstep", 1, signal_params, noise=True)
    completeness = check_recording(bag, tmp_path / "main" / "logs" / "sim_node.log", "lockstep")
    assert completeness["complete"], completeness
    assert {q["history"] for q in _offered(bag).values()} <= {"keep_last", "keep_all"}
    t_graph = time.monotonic() - t0

    _replay_and_record(bag, tmp_path / "replayed", isolated_env(domain))
    same = _assert_same_messages(bag, tmp_path / "replayed")
    assert set(same) == {TOPIC_CLOCK, TOPIC_DUTY_CYCLE, TOPIC_JOINT_STATES, "/aeropend/armature"}
    # every sample message (re-published ones too) and one /clock tick each
    assert same[TOPIC_CLOCK] == same[TOPIC_JOINT_STATES] >= completeness["published"]
    print(f"\n(b) main-job graph: recorded and re-recorded {same}; graph {t_graph:.1f} s, "
          f"total {time.monotonic() - t0:.1f} s")


def test_a_bag_with_history_unknown_replays(tmp_path: Path) -> None:
    """(c) a bag whose offered QoS is what ``ros2 bag record`` writes for a discovered publisher
    (``history: unknown``, ``depth: 0``; sqlite3 storage) replays message for message."""
    t0 = time.monotonic()
    n, dt = 600, 2.048e-3
    t = np.arange(n) * dt
    rng = np.random.default_rng(5)
    rec = Recording(t=t, duty=0.4 + 0.1 * rng.random(n),
                    channels={"theta": 0.3 * np.sin(3 * t), "theta_dot": 0.9 * np.cos(3 * t),
                              "omega_rotor": 300 + rng.standard_normal(n), "i_a": np.full(n, 0.7),
                              "v_a": np.full(n, 1.4)},
                    source="test_history_unknown", stamp0_ns=1_700_000_000_000_000_000)
    source = write_bag(rec, tmp_path / "source")
    # as ros2 bag record writes it (rmw reports no history for a discovered writer): every topic
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability

    unknown = Qos(history=QosHistory.UNKNOWN, depth=0, reliability=QosReliability.RELIABLE,
                  durability=QosDurability.VOLATILE, deadline=INFINITE_TIME, lifespan=INFINITE_TIME,
                  liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=INFINITE_TIME,
                  avoid_ros_namespace_conventions=False)
    bag = tmp_path / "ros2_bag_record"
    sink = BagSink(bag, storage="sqlite3")
    with RawBagReader(source) as reader:
        for topic, info in reader.topics.items():
            sink.add_topic(topic, info.msgtype, [unknown])
        for topic, logtime, raw in reader.messages():
            sink.write(topic, logtime, raw)
    sink.close()
    qos = _offered(bag)
    assert {(q["history"], q["depth"]) for q in qos.values()} == {("unknown", 0)}  # the case under test

    _replay_and_record(bag, tmp_path / "replayed", isolated_env(random_domain()))
    same = _assert_same_messages(bag, tmp_path / "replayed")
    assert same == {t: len(v) for t, v in _raw(source).items()} and same[TOPIC_JOINT_STATES] == n
    print(f"\n(c) history unknown (sqlite3): replayed and re-recorded {same}; {time.monotonic() - t0:.1f} s")


def test_extra_channels_replay_and_read_back(tmp_path: Path) -> None:
    """(d) an imported 2-DOF closed-loop log (a second joint phi, the reference on /aeropend/reference,
    a thrust and a lab channel on /aeropend/extra_channels) replays to a recorder message for message,
    and the re-recorded bag reads back the same extra channels with their units (the array's label
    carries them: the recorder's bag has no aeropend metadata)."""
    from aeropend_ident.io.bags import read_bag

    t0 = time.monotonic()
    n, dt = 400, 0.01
    t = np.arange(n) * dt
    rec = Recording(t=t, duty=0.3 + 0.1 * (t > 2.0), channels={"theta": 0.4 * np.sin(2 * t)},
                    source="test_extra", stamp0_ns=1_700_000_000_000_000_000,
                    extra={"phi": 0.1 * np.cos(t), "phi_dot": -0.1 * np.sin(t),
                           "theta_ref": 0.2 + 0.2 * (t > 2.0),
                           "thrust": 0.1 + 0.01 * np.sin(t), "x_acc": 9.81 * np.cos(0.4 * np.sin(2 * t))},
                    extra_units={"x_acc": "m/s^2"})
    bag = write_bag(rec, tmp_path / "source", lockstep_qos=True)
    _replay_and_record(bag, tmp_path / "replayed", isolated_env(random_domain()))
    same = _assert_same_messages(bag, tmp_path / "replayed")
    assert same == {TOPIC_JOINT_STATES: n, "/aeropend/armature": n, TOPIC_DUTY_CYCLE: n,
                    "/aeropend/reference": n, "/aeropend/extra_channels": n}
    back = read_bag(tmp_path / "replayed")
    assert back.extra_units == {"phi": "rad", "phi_dot": "rad/s", "theta_ref": "rad", "thrust": "N",
                                "x_acc": "m/s^2"}
    for name, values in rec.extra.items():
        assert np.array_equal(back.extra[name], values), name
    print(f"\n(d) extra channels: replayed and re-recorded {same}; {time.monotonic() - t0:.1f} s")
