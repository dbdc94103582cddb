"""Truncated bags (MCAP and SQLite3 cut at byte offsets), bags without metadata.yaml, ``reindex``.

The expected counts are computed independently of the reader under test: for MCAP, the end
offset of every message record in the complete file (found by searching its exact record bytes,
MCAP specification: opcode 0x05, u64 length, u16 channel, u32 sequence, u64 log and publish
time, data; messages listed by the ``mcap`` package's seeking reader in file order); for SQLite3,
SQLite's own page accounting of the messages table (``dbstat``, stdlib ``sqlite3``): the rows of
the leaf pages that lie whole before the cut, in b-tree order up to the first page that does not.
"""

from __future__ import annotations

import json
import shutil
import sqlite3
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml

from aeropend_ident.cli import reindex as reindex_cli
from aeropend_ident.errors import BagError, BagTruncatedWarning
from aeropend_ident.io.bag_reader import RawBagReader, bag_metadata
from aeropend_ident.io.bag_recover import reindex, scan_storage, stored_metadata
from aeropend_ident.io.bag_writer import write_bag
from aeropend_ident.io.bags import read_bag
from aeropend_sim.contract import TOPIC_ARMATURE, TOPIC_DUTY_CYCLE, TOPIC_JOINT_STATES
from aeropend_sim.recording import Recording

#: Samples of the test bag: 3 × 6000 messages, ≈ 2.5 MB, so the MCAP file has 3 chunks
#: (rosbags closes a chunk past 1 MiB) and the SQLite3 file a two-level b-tree.
N_SAMPLES = 6000
STAMP0 = 1_700_000_000_000_000_000
STORAGES = ("mcap", "sqlite3")
SUFFIX = {"mcap": ".mcap", "sqlite3": ".db3"}


def _recording(n: int = N_SAMPLES) -> Recording:
    rng = np.random.default_rng(11)
    t = np.arange(n) * 2.048e-3
    duty = np.clip(0.4 + 0.2 * np.sin(2 * np.pi * 0.5 * t) + 0.01 * rng.standard_normal(n), 0, 1)
    theta = 0.4 * np.sin(2 * np.pi * 0.3 * t) + 1e-3 * rng.standard_normal(n)
    i_a = 0.7 + 0.05 * rng.standard_normal(n)
    return Recording(t=t, duty=duty, channels={"theta": theta, "i_a": i_a}, source="synthetic",
                     stamp0_ns=STAMP0, meta={"rig": "test"})


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The complete test bag in each storage (read-only: tests copy it)."""
    root = tmp_path_factory.mktemp("bags")
    rec = _recording()
    return {st: write_bag(rec, root / f"run_{st}", storage=st, rig_name="bench_rig") for st in STORAGES}


def _storage_file(bag: Path) -> Path:
    (f,) = [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")]
    return f


def _cut_copy(bag: Path, dest: Path, nbytes: int) -> Path:
    """A copy of ``bag`` (metadata.yaml kept) whose storage file keeps its first ``nbytes``."""
    dest.mkdir()
    shutil.copy(bag / "metadata.yaml", dest)
    src = _storage_file(bag)
    (dest / src.name).write_bytes(src.read_bytes()[:nbytes])
    return dest


def _mcap_records(path: Path) -> list[tuple[str, int, bytes, int]]:
    """(topic, log time, data, end offset of its record) of every message, in file order."""
    from mcap.reader import make_reader

    blob = path.read_bytes()
    out: list[tuple[str, int, bytes, int]] = []
    pos = 0
    with path.open("rb") as f:
        for _, channel, msg in make_reader(f).iter_messages(log_time_order=False):
            record = struct.pack("<BQHIQQ", 0x05, 22 + len(msg.data), msg.channel_id, msg.sequence,
                                 msg.log_time, msg.publish_time) + msg.data
            pos = blob.find(record, pos)
            assert pos >= 0, "message record not found in the file"
            out.append((channel.topic, msg.log_time, bytes(msg.data), pos + len(record)))
            pos += len(record)
    return out


def _expected_mcap(records: list[tuple[str, int, bytes, int]], cut: int) -> list[tuple[str, int, bytes]]:
    """The messages whose whole record lies before the cut."""
    return [(t, log, data) for t, log, data, end in records if end <= cut]


def _sqlite_rows(path: Path) -> tuple[list[tuple[str, int, bytes]], list[tuple[int, str, int]], int]:
    """Rows (topic, timestamp, data) in id order; pages of the messages b-tree in traversal order
    (page number, type, cells); page size."""
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        rows = con.execute("SELECT topics.name, timestamp, data FROM messages JOIN topics "
                           "ON topics.id = messages.topic_id ORDER BY messages.id").fetchall()
        pages = con.execute("SELECT pageno, pagetype, ncell FROM dbstat WHERE name = 'messages' "
                            "ORDER BY path").fetchall()
        page_size = con.execute("PRAGMA page_size").fetchone()[0]
    finally:
        con.close()
    return [(t, s, bytes(d)) for t, s, d in rows], pages, page_size


def _expected_sqlite(rows: list[tuple[str, int, bytes]], pages: list[tuple[int, str, int]], page_size: int,
                     cut: int) -> list[tuple[str, int, bytes]]:
    """The rows of the leaf pages read in b-tree order until the first page not whole before the cut."""
    n = 0
    for pageno, kind, ncell in pages:
        if pageno * page_size > cut:
            break
        if kind == "leaf":
            n += ncell
    return rows[:n]


def _sorted(msgs: list[tuple[str, int, bytes]]) -> list[tuple[str, int, bytes]]:
    return sorted(msgs, key=lambda m: m[1])  # stable: file order within one log time


#: Cut offsets: fractions of the file, plus named places (see each test).
FRACTIONS = (0.05, 0.25, 0.5, 0.75, 0.9)


def _mcap_cuts(path: Path) -> list[int]:
    from mcap.reader import make_reader

    size = path.stat().st_size
    with path.open("rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    first_end = chunks[0].chunk_start_offset + chunks[0].chunk_length
    # in the header, just past the first chunk's start, at and just before the first chunk's end,
    # fractions, and the footer's last byte (every message is in the data section)
    return sorted([20, chunks[0].chunk_start_offset + 200, first_end - 1, first_end,
                   *(int(size * f) for f in FRACTIONS), size - 1])


@pytest.mark.slow
def test_truncated_mcap_recovers_every_message_written_before_the_cut(
        written: dict[str, Path], tmp_path: Path) -> None:
    src = _storage_file(written["mcap"])
    records = _mcap_records(src)
    assert len(records) == 3 * N_SAMPLES
    figures = []
    for cut in _mcap_cuts(src):
        bag = _cut_copy(written["mcap"], tmp_path / f"cut_{cut}", cut)
        expected = _expected_mcap(records, cut)
        scan = scan_storage(_storage_file(bag))
        assert scan.truncated and scan.file_size == cut
        assert scan.total == len(expected), cut
        assert max((end for *_, end in records if end <= cut), default=0) <= scan.readable_bytes <= cut
        assert scan.messages == _sorted(expected), cut
        figures.append((cut, scan.total))
        if not expected:
            with pytest.raises(BagError, match=r"is truncated: .* no complete message could be recovered"):
                RawBagReader(bag)
            continue
        with pytest.warns(BagTruncatedWarning) as warned:
            reader = RawBagReader(bag)
        text = str(warned[0].message)
        assert f"run_mcap.mcap ends at byte {cut} without its MCAP footer" in text
        assert f"recovered {len(expected)} message(s)" in text
        assert f"up to log time {max(m[1] for m in expected)} ns" in text
        assert text.endswith(f"metadata.yaml declares {3 * N_SAMPLES}, {3 * N_SAMPLES - len(expected)} lost")
        assert list(reader.messages()) == _sorted(expected)
    # the cut points recover 0 (header), a few, ..., all 18000 messages (only the footer is cut)
    assert figures[0][1] == 0 and figures[-1][1] == 3 * N_SAMPLES
    assert [c for _, c in figures] == sorted(c for _, c in figures)


def test_truncated_sqlite3_recovers_the_rows_of_whole_pages(written: dict[str, Path], tmp_path: Path) -> None:
    src = _storage_file(written["sqlite3"])
    rows, pages, page_size = _sqlite_rows(src)
    assert len(rows) == 3 * N_SAMPLES and len(pages) > 100
    size = src.stat().st_size
    first_leaf = min(p for p, kind, _ in pages if kind == "leaf")
    cuts = [first_leaf * page_size - 1, *(int(size * f) for f in FRACTIONS),
            int(size * 0.5) // page_size * page_size + 1000, size - 100]  # mid-page cuts too
    counts = []
    for cut in cuts:
        bag = _cut_copy(written["sqlite3"], tmp_path / f"cut_{cut}", cut)
        expected = _expected_sqlite(rows, pages, page_size, cut)
        scan = scan_storage(_storage_file(bag))
        assert scan.truncated and scan.readable_bytes == cut // page_size * page_size
        assert scan.total == len(expected), cut
        assert scan.messages == _sorted(expected), cut
        counts.append(scan.total)
        if not expected:
            with pytest.raises(BagError, match="no complete message could be recovered"):
                RawBagReader(bag)
            continue
        pattern = (rf"run_sqlite3\.db3 has {cut} bytes but its SQLite header declares {size} "
                   rf".*recovered {len(expected)} message\(s\)")
        with pytest.warns(BagTruncatedWarning, match=pattern):
            reader = RawBagReader(bag)
        assert list(reader.messages()) == _sorted(expected)
    assert counts[0] == 0 and 0 < counts[-1] < 3 * N_SAMPLES


@pytest.mark.parametrize("storage", STORAGES)
def test_read_bag_of_a_cut_bag_is_the_start_of_the_recording(written: dict[str, Path], tmp_path: Path,
                                                             storage: str) -> None:
    full = read_bag(written[storage])
    src = _storage_file(written[storage])
    bag = _cut_copy(written[storage], tmp_path / "half", src.stat().st_size // 2)
    recovered = scan_storage(_storage_file(bag))
    n_js = recovered.counts[TOPIC_JOINT_STATES]
    n_arm = recovered.counts[TOPIC_ARMATURE]
    with pytest.warns(BagTruncatedWarning):
        rec = read_bag(bag)
    # samples whose armature message the cut took are dropped (the writer puts it after the sample)
    assert len(rec) == min(n_js, n_arm) == n_js - rec.meta["truncated"].get("incomplete_samples_dropped", 0)
    n = len(rec)
    assert np.array_equal(rec.channels["theta"], full.channels["theta"][:n])
    assert np.array_equal(rec.channels["i_a"], full.channels["i_a"][:n])
    assert np.array_equal(rec.duty[:-1], full.duty[:n - 1])
    assert rec.stamp0_ns == STAMP0 and rec.meta["rig_name"] == "bench_rig"
    info = rec.meta["truncated"]
    assert info["recovered_total"] == recovered.total and info["declared_total"] == 3 * N_SAMPLES
    assert info["recovered"] == {TOPIC_JOINT_STATES: n_js, TOPIC_ARMATURE: n_arm,
                                 TOPIC_DUTY_CYCLE: recovered.counts[TOPIC_DUTY_CYCLE]}


def test_zstd_chunks_of_another_writer_recover_a_prefix(written: dict[str, Path], tmp_path: Path) -> None:
    """MCAP with zstd chunks (rosbag2's default), written with the mcap package: a cut keeps the
    messages of the whole chunks and what its zstd blocks give of the cut one, in order."""
    from mcap.reader import make_reader
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk
    from mcap.writer import CompressionType, Writer

    with RawBagReader(written["mcap"]) as reader:
        msgs = list(reader.messages())
        topics = reader.topics
    path = tmp_path / "zstd.mcap"
    with path.open("wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD, chunk_size=256 * 1024)
        w.start(profile="ros2", library="test")
        ids = {}
        for name, t in topics.items():
            sid = w.register_schema(name=t.msgtype, encoding="ros2msg", data=b"")
            ids[name] = w.register_channel(topic=name, message_encoding="cdr", schema_id=sid)
        for k, (topic, log, data) in enumerate(msgs):
            w.add_message(channel_id=ids[topic], log_time=log, publish_time=log, data=data, sequence=k)
        w.finish()
    with path.open("rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) >= 3 and all(c.compression == "zstd" for c in chunks)
    cut = (chunks[1].chunk_start_offset + chunks[2].chunk_start_offset) // 2  # inside the second chunk
    short = tmp_path / "short.mcap"
    short.write_bytes(path.read_bytes()[:cut])
    scan = scan_storage(short)
    with path.open("rb") as f:
        first = next(r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk))
    in_first = sum(isinstance(r, Message) for r in breakup_chunk(first))
    assert in_first <= scan.total < len(msgs)
    assert scan.messages == msgs[:scan.total]


# ------------------------------------------------------------------ missing metadata.yaml


@pytest.mark.parametrize("storage", STORAGES)
def test_missing_metadata_says_how_to_proceed(written: dict[str, Path], tmp_path: Path, storage: str) -> None:
    bag = tmp_path / "crashed"
    shutil.copytree(written[storage], bag)
    (bag / "metadata.yaml").unlink()
    data = _storage_file(bag)
    with pytest.raises(BagError) as err:
        read_bag(bag)
    assert str(err.value) == (f"bag '{bag}' has no metadata.yaml: give its storage file instead ({data}) or "
                              f"rebuild the metadata with 'reindex {bag}'")
    with pytest.raises(BagError, match=r"has no metadata\.yaml"):
        RawBagReader(bag)  # play's reader says the same
    # the storage file itself reads like the bag, metadata stored inside it included
    full, direct = read_bag(written[storage]), read_bag(data)
    for name, y in full.channels.items():
        assert np.array_equal(direct.channels[name], y)
    assert np.array_equal(direct.duty, full.duty, equal_nan=True)
    assert direct.meta["rig_name"] == "bench_rig" and direct.meta["rig"] == "test"
    assert stored_metadata(data)["custom_data"]["aeropend.rig_name"] == "bench_rig"
    # two storage files: one alone is only part of the bag
    shutil.copy(data, bag / f"crashed_1{SUFFIX[storage]}")
    with pytest.raises(BagError, match=rf"rebuild it with 'reindex {bag}' \(the bag has 2 storage files"):
        read_bag(bag)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(BagError, match=r"no metadata\.yaml and no \.mcap/\.db3 storage file"):
        read_bag(empty)


# ------------------------------------------------------------------ reindex


@pytest.mark.parametrize("storage", STORAGES)
def test_reindex_round_trip(written: dict[str, Path], tmp_path: Path, storage: str,
                            capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "bag"
    shutil.copytree(written[storage], bag)
    original = bag_metadata(bag)
    (bag / "metadata.yaml").unlink()
    assert reindex_cli.main([str(bag)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"reindex: wrote {bag / 'metadata.yaml'}: {3 * N_SAMPLES} message(s) in 1 "
                          f"{storage} file(s)")
    # the same metadata the writer wrote (topics, QoS, type hashes, counts, times, custom data)
    assert bag_metadata(bag) == original
    full, again = read_bag(written[storage]), read_bag(bag)
    for name, y in full.channels.items():
        assert np.array_equal(again.channels[name], y)
    assert {**again.meta, "bag": None} == {**full.meta, "bag": None}
    # play's reader accepts it: same topics, QoS and messages as the original
    with RawBagReader(written[storage]) as a, RawBagReader(bag) as b:
        assert b.recovery is None and b.topics == a.topics
        assert list(b.messages()) == list(a.messages())
    # an existing metadata.yaml is not replaced without --overwrite
    assert reindex_cli.main([str(bag)]) == 1
    err = capsys.readouterr().err
    assert err == (f"reindex: error: '{bag / 'metadata.yaml'}' already exists; reindex --overwrite "
                   "replaces it\n")
    assert reindex_cli.main([str(bag), "--overwrite"]) == 0


def test_reindex_of_a_cut_bag_counts_what_is_recovered(written: dict[str, Path], tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    src = _storage_file(written["mcap"])
    bag = _cut_copy(written["mcap"], tmp_path / "cut", int(src.stat().st_size * 0.6))
    (bag / "metadata.yaml").unlink()
    expected = _expected_mcap(_mcap_records(src), int(src.stat().st_size * 0.6))
    assert reindex_cli.main([str(bag)]) == 0
    cap = capsys.readouterr()
    assert cap.err.startswith(f"reindex: warning: {_storage_file(bag)} is truncated: run_mcap.mcap ends "
                              "at byte")
    assert f"indexed the {len(expected)} message(s) that can be recovered" in cap.err
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["message_count"] == len(expected)
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]}
    assert counts == {t: sum(1 for m in expected if m[0] == t)
                      for t in (TOPIC_JOINT_STATES, TOPIC_ARMATURE, TOPIC_DUTY_CYCLE)}
    # the metadata record is written at close: cut away; reindex counted the loss from the stamps
    # (none inside the recovered stretch; the duty commands carry no header: not countable)
    assert set(info["custom_data"]) == {"aeropend.loss"}
    loss = json.loads(info["custom_data"]["aeropend.loss"])
    assert {t: (r["lost"], r["method"]) for t, r in loss.items()} == {
        TOPIC_JOINT_STATES: (0, "stamps"), TOPIC_ARMATURE: (0, "stamps"), TOPIC_DUTY_CYCLE: (0, "none")}
    assert "reindex: loss: /aeropend/joint_states 0 of" in cap.out
    with pytest.warns(BagTruncatedWarning, match=rf"declares {len(expected)}, 0 lost$"):
        read_bag(bag)


def test_reindex_counts_the_loss_a_killed_recorder_never_stored(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """A bag whose storage file was never closed (a killed recorder) has no loss count; reindex counts
    it from the header stamps: 300 samples missing in the middle of the log are 300 lost on each
    stamped topic, stored in the metadata, printed, and warned about by the reader."""
    full = _recording()
    keep = np.ones(N_SAMPLES, bool)
    keep[2000:2300] = False
    rec = Recording(t=full.t[keep], duty=full.duty[keep],
                    channels={k: v[keep] for k, v in full.channels.items()}, source="gappy", stamp0_ns=STAMP0,
                    meta={"rig": "test"})
    bag = write_bag(rec, tmp_path / "written", storage="mcap", rig_name="bench_rig")
    src = _storage_file(bag)
    cut = _cut_copy(bag, tmp_path / "killed", int(src.stat().st_size * 0.97))
    (cut / "metadata.yaml").unlink()
    assert reindex_cli.main([str(cut)]) == 0
    out = capsys.readouterr().out
    info = yaml.safe_load((cut / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    loss = json.loads(info["custom_data"]["aeropend.loss"])
    for topic in (TOPIC_JOINT_STATES, TOPIC_ARMATURE):
        assert loss[topic]["lost"] == 300 and loss[topic]["method"] == "stamps" and loss[topic]["gaps"] == 1
        assert loss[topic]["note"].startswith("counted by reindex from the header stamps")
    assert f"{TOPIC_JOINT_STATES} 300 of" in out
    with pytest.warns(UserWarning, match=r"joint_states lost 300 of .* counted by stamps\) in 1 gap"):
        read_bag(cut)


def test_reindex_refuses_what_is_not_a_bag_directory(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="does not exist"):
        reindex(tmp_path / "nowhere")
    (tmp_path / "notes").mkdir()
    with pytest.raises(BagError, match=r"holds no \.mcap or \.db3 storage file; nothing to index"):
        reindex(tmp_path / "notes")
