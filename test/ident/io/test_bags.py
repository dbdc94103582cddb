"""Contract bags: Recording -> bag -> Recording round trips, decoding paths and error reporting."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from aeropend_ident.errors import BagError
from aeropend_ident.io import bag_codec, bag_reader, bags
from aeropend_ident.io.bag_writer import write_bag
from aeropend_ident.io.bags import read_bag
from aeropend_sim.contract import (
    TOPIC_ARMATURE,
    TOPIC_DUTY_CYCLE,
    TOPIC_JOINT_STATES,
    TYPE_ARMATURE,
    TYPE_JOINT_STATES,
)
from aeropend_sim.recording import Recording

STORAGES = ["mcap", "sqlite3"]
STAMP0 = 1_700_000_000_123_456_789


def _recording(n: int = 600, channels: tuple[str, ...] | None = None, seed: int = 3) -> Recording:
    """Thesis-rate (2.048 ms) run with irregular values in every channel (full float64 mantissas)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 2.048e-3
    duty = np.clip(0.43 + 0.2 * np.sin(2 * np.pi * 0.7 * t) + 0.01 * rng.standard_normal(n), 0, 1)
    theta = 0.5 * np.sin(2 * np.pi * 0.4 * t) + 1e-3 * rng.standard_normal(n)
    all_ch = {
        "theta": theta,
        "theta_dot": np.gradient(theta, t),
        "omega_rotor": 300 + 20 * rng.standard_normal(n),
        "omega_prop": 50 + 3 * rng.standard_normal(n),
        "i_a": 0.8 + 0.05 * rng.standard_normal(n),
        "v_a": 1.4 + 0.3 * rng.standard_normal(n),
    }
    names = tuple(all_ch) if channels is None else channels
    return Recording(t=t, duty=duty, channels={k: all_ch[k] for k in names}, source="synthetic",
                     stamp0_ns=STAMP0, meta={"rig": "test", "licence": "CC0", "gain": 1.5})


def _f32(x: np.ndarray) -> np.ndarray:
    return x.astype(np.float32).astype(float)


def _messages(path: Path) -> dict[str, list[tuple[int, object]]]:
    """topic -> [(log time, message)] read with rosbags' own deserialiser."""
    out: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([path], default_typestore=bag_codec.typestore()) as reader:
        for conn, logtime, raw in reader.messages():
            out.setdefault(conn.topic, []).append((logtime, reader.deserialize(raw, conn.msgtype)))
    return out


@pytest.mark.parametrize("storage", STORAGES)
def test_round_trip_exact(tmp_path: Path, storage: str) -> None:
    rec = _recording()
    path = write_bag(rec, tmp_path / "run", storage=storage, rig_name="bench_rig")
    back = read_bag(path)
    n = len(rec)
    assert len(back) == n
    assert back.stamp0_ns == STAMP0
    assert np.max(np.abs(back.t - rec.t)) <= 0.5e-9
    assert np.array_equal(back.duty, rec.duty)  # last duty comes from the command topic
    for name in ("theta", "theta_dot", "omega_rotor", "omega_prop"):
        assert np.array_equal(back.channels[name], rec.channels[name]), name
    assert np.array_equal(back.channels["i_a"], _f32(rec.channels["i_a"]))  # float32 on the wire
    assert np.array_equal(back.channels["v_a"][:-1], _f32(rec.channels["v_a"][:-1]))
    assert back.channels["v_a"][-1] == back.channels["v_a"][-2]  # not on the wire: held
    assert back.meta["held_tail"] == ["v_a"]
    assert back.meta["rig_name"] == "bench_rig"
    assert back.meta["gain"] == 1.5 and back.meta["licence"] == "CC0"
    assert back.meta["storage"] == storage
    assert back.meta["unmatched_joint_states"] == 0 and back.meta["orphan_armature"] == 0
    assert back.meta["cdr_fallback_messages"] == 0

    msgs = _messages(path)
    counts = {t: len(v) for t, v in msgs.items()}
    assert counts == {TOPIC_JOINT_STATES: n, TOPIC_ARMATURE: n, TOPIC_DUTY_CYCLE: n}
    js_stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in msgs[TOPIC_JOINT_STATES]]
    arm_stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in msgs[TOPIC_ARMATURE]]
    assert js_stamps == arm_stamps
    assert js_stamps == [log for log, _ in msgs[TOPIC_JOINT_STATES]]  # log time = header stamp
    assert js_stamps[1] - js_stamps[0] == 2_048_000
    # wire convention: sample k+1 carries duty[k]; sample 0 carries NaN (duty before start unknown)
    efforts = np.array([m.effort[1] for _, m in msgs[TOPIC_JOINT_STATES]])
    assert math.isnan(efforts[0]) and np.array_equal(efforts[1:], rec.duty[:-1])
    assert list(msgs[TOPIC_JOINT_STATES][0][1].name) == ["pendulum", "motor", "propeller"]
    arm0 = msgs[TOPIC_ARMATURE][5][1]
    assert arm0.present and math.isnan(arm0.temperature) and math.isnan(arm0.percentage)
    assert arm0.voltage == np.float32(rec.channels["v_a"][4])
    cmds = np.array([m.data for _, m in msgs[TOPIC_DUTY_CYCLE]])
    assert np.array_equal(cmds, rec.duty)


@pytest.mark.parametrize("storage", STORAGES)
def test_metadata_has_qos_for_each_topic(tmp_path: Path, storage: str) -> None:
    path = write_bag(_recording(50), tmp_path / "q", storage=storage)
    info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9
    assert info["storage_identifier"] == storage
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert set(topics) == {TOPIC_JOINT_STATES, TOPIC_ARMATURE, TOPIC_DUTY_CYCLE}
    for name, entry in topics.items():
        assert entry["message_count"] == 50
        (qos,) = entry["topic_metadata"]["offered_qos_profiles"]
        assert qos["history"] == "keep_last" and qos["durability"] == "volatile"
        if name == TOPIC_DUTY_CYCLE:
            assert (qos["reliability"], qos["depth"]) == ("reliable", 10)
        else:
            assert (qos["reliability"], qos["depth"]) == ("best_effort", 5)
        assert qos["deadline"] == {"sec": 9223372036, "nsec": 854775807}


def test_lockstep_qos_is_reliable(tmp_path: Path) -> None:
    path = write_bag(_recording(20), tmp_path / "ls", lockstep_qos=True)
    info = bag_reader.bag_metadata(path)
    qos = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"][0]["reliability"]
           for t in info["topics_with_message_count"]}
    assert qos == {TOPIC_JOINT_STATES: "reliable", TOPIC_ARMATURE: "reliable", TOPIC_DUTY_CYCLE: "reliable"}


def test_missing_channels_absent_after_read(tmp_path: Path) -> None:
    rec = _recording(200, channels=("theta",))
    back = read_bag(write_bag(rec, tmp_path / "theta_only", storage="sqlite3"))
    assert sorted(back.channels) == ["theta"]
    assert np.array_equal(back.channels["theta"], rec.channels["theta"])
    assert np.array_equal(back.duty, rec.duty)
    assert back.meta["held_tail"] == []


def test_encoders_and_decoders_agree(tmp_path: Path) -> None:
    rec = _recording(300)
    fast = write_bag(rec, tmp_path / "vec")
    ref = write_bag(rec, tmp_path / "ts", encoder="typestore")
    raw = {}
    for p in (fast, ref):
        with AnyReader([p]) as reader:
            raw[p] = [(c.topic, t, bytes(r)) for c, t, r in reader.messages()]
    assert raw[fast] == raw[ref]  # Sample.joint_state_fields() path gives identical bytes
    a, b = read_bag(fast), read_bag(fast, decoder="typestore")
    assert np.array_equal(a.duty, b.duty) and np.array_equal(a.t, b.t)
    for name in a.channels:
        assert np.array_equal(a.channels[name], b.channels[name], equal_nan=True)


def test_duty_before_start_survives(tmp_path: Path) -> None:
    rec = _recording(40)
    rec.meta["duty_before_start"] = 0.125
    msgs = _messages(write_bag(rec, tmp_path / "b"))
    assert msgs[TOPIC_JOINT_STATES][0][1].effort[1] == 0.125
    assert read_bag(tmp_path / "b").meta["duty_before_start"] == 0.125


def test_reads_bare_mcap_file(tmp_path: Path) -> None:
    rec = _recording(100)
    path = write_bag(rec, tmp_path / "bare")
    (mcap,) = path.glob("*.mcap")
    back = read_bag(mcap)
    assert np.array_equal(back.channels["theta"], rec.channels["theta"])


def test_rclpy_serialized_messages_decode_vectorized() -> None:
    """Fast-CDR (rclpy) leaves garbage in alignment padding: the vectorised decoder must accept it."""
    serialization = pytest.importorskip("rclpy.serialization")
    from aeropend_sim.contract import Sample
    from aeropend_sim.ros.ros_contract import sample_to_msgs

    samples = [Sample(stamp_ns=STAMP0 + k * 2_048_000, theta=0.01 * k, theta_dot=-0.5, omega_rotor=310.0 + k,
                      i_a=0.75, v_a=1.5, duty=0.4) for k in range(50)]
    pairs = [sample_to_msgs(s) for s in samples]
    js = bag_codec.decode_joint_states([serialization.serialize_message(p[0]) for p in pairs])
    arm = bag_codec.decode_armature([serialization.serialize_message(p[1]) for p in pairs])
    assert js.fallback == 0 and arm.fallback == 0
    assert np.array_equal(js.columns["theta"], [s.theta for s in samples])
    assert np.array_equal(js.columns["omega_rotor"], [s.omega_rotor for s in samples])
    assert np.array_equal(js.columns["stamp"], [s.stamp_ns for s in samples])
    assert np.all(np.isnan(js.columns["omega_prop"]))
    assert np.array_equal(arm.columns["v_a"], np.full(50, 1.5))


def _raw_bag(path: Path, js: list[tuple[int, bytes]], arm: list[tuple[int, bytes]] = (),
             cmd: list[tuple[int, bytes]] = ()) -> Path:
    """Hand-built bag with arbitrary message lists (log time, raw CDR)."""
    ts = bag_codec.typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for topic, typ, items in ((TOPIC_JOINT_STATES, TYPE_JOINT_STATES, js),
                                  (TOPIC_ARMATURE, TYPE_ARMATURE, arm),
                                  (TOPIC_DUTY_CYCLE, "std_msgs/msg/Float64", cmd)):
            if items:
                conn = w.add_connection(topic, typ, typestore=ts,
                                        offered_qos_profiles=[bags.qos_for_topic(topic)])
                for logtime, raw in items:
                    w.write(conn, logtime, raw)
    return path


def _js(stamps: np.ndarray, theta: np.ndarray, effort: np.ndarray) -> list[bytes]:
    n = len(stamps)
    nan = np.full(n, np.nan)
    return bag_codec.encode_joint_states(stamps, np.column_stack([theta, nan, nan]),
                                    np.column_stack([nan, nan, nan]), np.column_stack([nan, effort, nan]))


def test_unmatched_armature_kept_with_nan_and_counted(tmp_path: Path) -> None:
    n = 20
    stamps = STAMP0 + np.arange(n, dtype=np.int64) * 10_000_000
    theta = np.linspace(0.0, 0.2, n)
    js = _js(stamps, theta, np.full(n, 0.3))
    keep = [k for k in range(n) if k not in (4, 9, 10)]
    arm_stamps = np.concatenate([stamps[keep], [stamps[-1] + 5]])  # plus one armature with no sample
    volts = np.concatenate([1.0 + 0.1 * np.array(keep), [9.0]])
    arm = bag_codec.encode_armature(arm_stamps, volts, np.full(len(arm_stamps), 0.5))
    path = _raw_bag(tmp_path / "gap", list(zip(stamps.tolist(), js, strict=True)),
                    list(zip(arm_stamps.tolist(), arm, strict=True)))
    rec = read_bag(path)
    assert len(rec) == n
    assert rec.meta["unmatched_joint_states"] == 3
    assert rec.meta["orphan_armature"] == 1
    i_a = rec.channels["i_a"]
    assert np.flatnonzero(np.isnan(i_a)).tolist() == [4, 9, 10]
    # v_a[k] comes from sample k+1 (interval that ends there): NaN where sample k+1 has no armature
    assert np.flatnonzero(np.isnan(rec.channels["v_a"])).tolist() == [3, 8, 9]
    assert rec.channels["v_a"][0] == np.float32(1.1)


def test_duty_from_commands_only(tmp_path: Path) -> None:
    """Bags whose joint_states carry no effort: duty is the command in force at each stamp."""
    n = 10
    stamps = STAMP0 + np.arange(n, dtype=np.int64) * 20_000_000
    js = _js(stamps, np.zeros(n), np.full(n, np.nan))
    cmd_times = [STAMP0 - 1, STAMP0 + 45_000_000, STAMP0 + 100_000_000]  # before s0, between s2/s3, at s5
    cmds = bag_codec.encode_float64(np.array([0.1, 0.2, 0.3]))
    path = _raw_bag(tmp_path / "cmd", list(zip(stamps.tolist(), js, strict=True)),
                    cmd=list(zip(cmd_times, cmds, strict=True)))
    rec = read_bag(path)
    # a command received within (t_k, t_k+1) drives the interval starting at t_k (as the plant reports it)
    assert rec.duty.tolist() == [0.1, 0.1, 0.2, 0.2, 0.2, 0.3, 0.3, 0.3, 0.3, 0.3]
    assert rec.meta["duty_source"] == {"effort": 0, "command": 10, "effort_after_gap": 0, "missing": 0}


@pytest.mark.parametrize("with_commands", [True, False])
def test_lost_samples(tmp_path: Path, with_commands: bool) -> None:
    """Samples lost in transit (best-effort QoS): before a gap the duty is the next received effort."""
    rec = _recording(200)
    full = write_bag(rec, tmp_path / "full")
    lost = {50, 51, 120}
    kept = np.array([k for k in range(len(rec)) if k not in lost])
    topics = [TOPIC_JOINT_STATES, TOPIC_ARMATURE] + ([TOPIC_DUTY_CYCLE] if with_commands else [])
    with AnyReader([full]) as reader:
        msgs = {t: [] for t in topics}
        for conn, logtime, raw in reader.messages():
            if conn.topic in msgs:
                msgs[conn.topic].append((logtime, bytes(raw)))
    drop = lambda items: [items[k] for k in kept]  # noqa: E731
    path = _raw_bag(tmp_path / "lossy", drop(msgs[TOPIC_JOINT_STATES]), drop(msgs[TOPIC_ARMATURE]),
                    msgs.get(TOPIC_DUTY_CYCLE, []))
    back = read_bag(path)
    assert len(back) == len(kept) and back.meta["gaps"] == 2
    assert np.array_equal(back.channels["theta"], rec.channels["theta"][kept])
    gap_k = np.flatnonzero(np.diff(kept) > 1)
    assert gap_k.tolist() == [49, 117]
    # the duty applied just before the next received sample (samples 52 and 121)
    assert back.duty[gap_k].tolist() == [rec.duty[51], rec.duty[120]]
    assert back.meta["duty_source"]["effort_after_gap"] == 2
    rest = np.setdiff1d(np.arange(len(kept) - 1), gap_k)
    assert np.array_equal(back.duty[rest], rec.duty[kept][rest])
    if with_commands:  # the last sample's duty comes from its command
        assert back.duty[-1] == rec.duty[-1] and back.meta["duty_source"]["command"] == 1
        assert back.meta["held_tail"] == ["v_a"]
    else:
        assert back.duty[-1] == back.duty[-2] and back.meta["held_tail"] == ["duty", "v_a"]


def test_no_duty_at_all_is_an_error(tmp_path: Path) -> None:
    stamps = STAMP0 + np.arange(5, dtype=np.int64) * 20_000_000
    path = _raw_bag(tmp_path / "nod", list(zip(stamps.tolist(), _js(stamps, np.zeros(5), np.full(5, np.nan)),
                                               strict=True)))
    with pytest.raises(BagError, match="no duty information"):
        read_bag(path)
    assert read_bag(path, require_duty=False).meta["duty_source"]["missing"] == 5


def test_nan_theta_is_an_error(tmp_path: Path) -> None:
    stamps = STAMP0 + np.arange(6, dtype=np.int64) * 20_000_000
    theta = np.array([0.0, 0.1, np.nan, 0.3, np.nan, 0.5])
    js = _js(stamps, theta, np.full(6, 0.2))
    path = _raw_bag(tmp_path / "nan", list(zip(stamps.tolist(), js, strict=True)))
    with pytest.raises(BagError, match=r"theta .* NaN/inf in 2 of 6 samples, first at sample 2") as err:
        read_bag(path)
    assert str(path) in str(err.value)


def test_conflicting_duplicate_stamps_are_an_error(tmp_path: Path) -> None:
    stamps = STAMP0 + np.array([0, 10, 10, 20], dtype=np.int64)
    theta = np.array([0.0, 0.1, 0.2, 0.3])
    path = _raw_bag(tmp_path / "dup", list(zip(stamps.tolist(), _js(stamps, theta, np.full(4, 0.2)),
                                               strict=True)))
    with pytest.raises(BagError, match=r"two different .* samples share the stamp"):
        read_bag(path)


def test_republished_identical_samples_are_dropped(tmp_path: Path) -> None:
    """A lock-step plant re-publishes its waiting sample: identical copies count once."""
    stamps = STAMP0 + np.array([0, 0, 0, 10, 20], dtype=np.int64)
    theta = np.array([0.0, 0.0, 0.0, 0.1, 0.2])
    path = _raw_bag(tmp_path / "rep", list(zip(stamps.tolist(), _js(stamps, theta, np.full(5, 0.2)),
                                               strict=True)))
    rec = read_bag(path)
    assert len(rec) == 3
    assert np.array_equal(rec.channels["theta"], [0.0, 0.1, 0.2])
    assert rec.meta["republished_samples_dropped"] == 2


def test_missing_joint_states_topic_named(tmp_path: Path) -> None:
    stamps = STAMP0 + np.arange(5, dtype=np.int64)
    arm = bag_codec.encode_armature(stamps, np.ones(5), np.ones(5))
    ts = bag_codec.typestore()
    path = tmp_path / "armonly"
    with Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        conn = w.add_connection(TOPIC_ARMATURE, TYPE_ARMATURE, typestore=ts)
        for s, raw in zip(stamps.tolist(), arm, strict=True):
            w.write(conn, s, raw)
    expected = r"has no /aeropend/joint_states topic \(topics present: \['/aeropend/armature'\]\)"
    with pytest.raises(BagError, match=expected):
        read_bag(path)


def test_namespaced_topics(tmp_path: Path) -> None:
    rec = _recording(30)
    path = write_bag(rec, tmp_path / "ns", namespace="/rig1")
    with pytest.raises(BagError, match="no /aeropend/joint_states topic"):
        read_bag(path)
    assert np.array_equal(read_bag(path, namespace="/rig1").channels["theta"], rec.channels["theta"])


@pytest.mark.parametrize("storage", STORAGES)
def test_corrupt_bag(tmp_path: Path, storage: str) -> None:
    path = write_bag(_recording(2000), tmp_path / "corrupt", storage=storage)
    (data,) = [p for p in path.iterdir() if p.suffix in (".mcap", ".db3")]
    blob = bytearray(data.read_bytes())
    rng = np.random.default_rng(0)
    start = len(blob) // 3
    blob[start:start + 4096] = rng.integers(0, 256, 4096, dtype=np.uint8).tobytes()
    data.write_bytes(bytes(blob))
    with pytest.raises(BagError) as err:
        read_bag(path)
    assert str(path) in str(err.value)


def test_not_a_bag(tmp_path: Path) -> None:
    text = tmp_path / "notes.txt"
    text.write_text("hello\n")
    with pytest.raises(BagError, match=r"notes\.txt'? is not a readable rosbag2 bag"):
        read_bag(text)
    empty = tmp_path / "emptydir"
    empty.mkdir()
    with pytest.raises(BagError, match=r"no metadata\.yaml"):
        read_bag(empty)
    with pytest.raises(BagError, match="does not exist"):
        read_bag(tmp_path / "nowhere")
    fake = tmp_path / "fake"
    fake.mkdir()
    (fake / "metadata.yaml").write_text("just: text\n")
    with pytest.raises(BagError, match="fake"):
        read_bag(fake)


def test_write_refuses_to_clobber(tmp_path: Path) -> None:
    rec = _recording(10)
    write_bag(rec, tmp_path / "x")
    with pytest.raises(BagError, match=r"exists and is not empty \(metadata.yaml, x.mcap\); pass "
                                       r"overwrite=True to replace it"):
        write_bag(rec, tmp_path / "x")
    write_bag(rec, tmp_path / "x", overwrite=True, storage="sqlite3")
    assert read_bag(tmp_path / "x").meta["storage"] == "sqlite3"
    assert sorted(p.suffix for p in (tmp_path / "x").iterdir()) == [".db3", ".yaml"]  # no stale .mcap
    (tmp_path / "plain").mkdir()
    (tmp_path / "plain" / "keep.txt").write_text("precious")
    with pytest.raises(BagError, match="does not look like a rosbag2 bag"):
        write_bag(rec, tmp_path / "plain", overwrite=True)
    assert (tmp_path / "plain" / "keep.txt").read_text() == "precious"
    (tmp_path / "empty").mkdir()  # an empty folder is no result: used without overwrite
    assert read_bag(write_bag(rec, tmp_path / "empty")).meta["storage"] == "mcap"


def test_dds_padded_payloads_decode_vectorized() -> None:
    """Messages recorded from DDS are padded to a multiple of 4 bytes; the fast path must accept them."""
    stamps = STAMP0 + np.arange(30, dtype=np.int64) * 2_048_000
    raws = bag_codec.encode_armature(stamps, np.linspace(1.0, 2.0, 30), np.full(30, 0.5))
    assert len(raws[0]) % 4 != 0
    padded = [r + b"\x00" * (-len(r) % 4) for r in raws]
    dec = bag_codec.decode_armature(padded)
    assert dec.fallback == 0
    assert np.array_equal(dec.columns["v_a"], np.linspace(1.0, 2.0, 30).astype(np.float32).astype(float))
    assert np.array_equal(dec.columns["stamp"], stamps)
