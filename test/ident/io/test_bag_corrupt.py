"""Corrupt and empty bags (issue 62 item 1): ``reindex`` tells an empty file, a file without footer
and a file with corrupt chunks apart, keeps every intact chunk around a corrupt one and reports
exactly what it left out; readers name where the storage is corrupt and point to ``reindex``."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.cli.reindex import main as reindex_main
from aeropend_ident.errors import BagError, BagTruncatedWarning
from aeropend_ident.io.bag_recover import scan_storage
from aeropend_ident.io.bag_writer import write_bag
from aeropend_ident.io.bags import read_bag
from aeropend_sim.recording import Recording

N = 20000  # 40 s at 500 Hz: about 9 MB of MCAP, 9 chunks
STAMP0 = 1_700_000_000_000_000_000


def _bag(tmp_path: Path, storage: str) -> tuple[Recording, Path, Path]:
    t = np.arange(N) * 0.002
    rec = Recording(t=t, duty=0.4 + 0.1 * np.sin(t), channels={"theta": np.sin(t)}, source="corrupt-test",
                    stamp0_ns=STAMP0)
    bag = write_bag(rec, tmp_path / storage, storage=storage)  # type: ignore[arg-type]
    return rec, bag, next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))


def _flip(path: Path, at: int, n: int = 64) -> None:
    data = bytearray(path.read_bytes())
    data[at:at + n] = bytes(b ^ 0xFF for b in data[at:at + n])
    path.write_bytes(bytes(data))


def test_empty_storage_file_is_nothing_written(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "killed"
    bag.mkdir()
    (bag / "killed_0.mcap").write_bytes(b"")
    assert reindex_main([str(bag)]) == 1
    err = capsys.readouterr().err.strip()
    assert err == (f"reindex: error: '{bag / 'killed_0.mcap'}' is empty: nothing was written (0 bytes: the "
                   "recorder stopped or was killed before its first flush)")


@pytest.mark.slow
def test_corrupt_mcap_chunk_skipped_and_reported(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    rec, bag, f = _bag(tmp_path, "mcap")
    whole = scan_storage(f, keep_messages=False)
    assert whole.total == 3 * N and not whole.skipped and len(whole.chunks) >= 5
    start, end, t0, t1 = whole.chunks[len(whole.chunks) // 2]
    _flip(f, (start + end) // 2)  # 64 bytes in the middle of the middle chunk
    with pytest.raises(BagError) as err:  # a reader names the byte range and points to reindex
        read_bag(bag)
    msg = str(err.value)
    assert f"{f.name} bytes {start}-{end}" in msg and "CRC mismatch" in msg
    assert f"'reindex --overwrite {bag}'" in msg
    assert reindex_main([str(bag), "--overwrite"]) == 0
    out = capsys.readouterr()
    lost = re.search(r"left out a corrupt part, bytes (\d+)-(\d+) \(log time ([\d.]+)-([\d.]+) s after the "
                     r"first message\): (\d+) message\(s\)", out.err)
    assert lost is not None, out.err
    assert (int(lost[1]), int(lost[2])) == (start, end)
    n_lost = int(lost[5])
    assert float(lost[3]) == pytest.approx((t0 - STAMP0) / 1e9, abs=1e-3)
    assert float(lost[4]) == pytest.approx((t1 - STAMP0) / 1e9, abs=1e-3)
    assert f"{3 * N - n_lost} message(s)" in out.out and n_lost % 3 == 0 and n_lost > 1000
    with pytest.warns(BagTruncatedWarning,
                      match=f"has corrupt parts, left out: {f.name} bytes {start}-{end}"):
        got = read_bag(bag)
    assert len(got) == N - n_lost // 3  # every intact chunk, before and after the corrupt one
    idx = np.round(got.t / 0.002).astype(int)
    assert np.array_equal(got.channels["theta"], rec.channels["theta"][idx])
    gap = np.diff(got.t).max()
    # the chunk's span is what is missing (its first and last sample may have messages in a neighbour)
    assert (t1 - t0) / 1e9 <= gap <= (t1 - t0) / 1e9 + 0.0041


@pytest.mark.slow
def test_repair_writes_a_clean_copy_any_reader_takes_whole(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """``reindex --repair NEW`` (issue 62): after 64 bytes flipped in a middle chunk, the new bag holds
    every intact message (the same bytes and log times as the original's intact parts) and no
    damage: scanned chunk by chunk nothing is left out, and the strict reader (the one that stops at
    a corrupt chunk, as ``ros2 bag play`` does) reads it without a recovery. The original is as it was."""
    from aeropend_ident.io.bag_reader import RawBagReader

    _, bag, f = _bag(tmp_path, "mcap")
    whole = scan_storage(f, keep_messages=False)
    start, end, _, _ = whole.chunks[len(whole.chunks) // 2]
    _flip(f, (start + end) // 2)
    damaged = f.read_bytes()
    kept = scan_storage(f)
    assert kept.skipped and kept.total < 3 * N
    new = tmp_path / "repaired"
    assert reindex_main([str(bag), "--overwrite", "--repair", str(new)]) == 0
    assert f"reindex: wrote the repaired bag {new}: {kept.total} message(s)" in capsys.readouterr().out
    assert f.read_bytes() == damaged
    (g,) = [p for p in new.iterdir() if p.suffix == ".mcap"]
    clean = scan_storage(g)
    assert not clean.skipped and not clean.truncated and clean.total == kept.total
    assert sorted(clean.messages, key=lambda m: m[1]) == sorted(kept.messages, key=lambda m: m[1])
    with RawBagReader(new) as reader:
        assert reader.recovery is None
        assert sum(1 for _ in reader.messages()) == kept.total
    assert reindex_main([str(bag), "--overwrite", "--repair", str(new)]) == 1  # never over a bag
    assert f"'{new}' exists" in capsys.readouterr().err


@pytest.mark.slow
def test_repair_of_a_sqlite3_bag_leaves_the_corrupt_rows_out(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """SQLite3 has no checksums: a flipped message blob is found by deserialising it. The repaired copy
    holds exactly the rows the validated scan kept (not the undeserialisable one, which a reader of
    the copy would then fail on) and reads whole."""
    rec, bag, f = _bag(tmp_path, "sqlite3")
    _flip(f, f.stat().st_size // 2)
    kept = scan_storage(f, keep_messages=True, validate=True)
    assert kept.skipped and kept.total < 3 * N
    new = tmp_path / "repaired"
    assert reindex_main([str(bag), "--overwrite", "--repair", str(new)]) == 0
    assert f"reindex: wrote the repaired bag {new}: {kept.total} message(s)" in capsys.readouterr().out
    (g,) = [p for p in new.iterdir() if p.suffix == ".db3"]
    clean = scan_storage(g, keep_messages=True, validate=True)
    assert not clean.skipped and clean.total == kept.total
    assert clean.messages == kept.messages
    with warnings.catch_warnings():
        warnings.simplefilter("error", BagTruncatedWarning)  # nothing left to skip in the copy
        got = read_bag(new)
    idx = np.round(got.t / 0.002).astype(int)
    assert len(got) < N and np.array_equal(got.channels["theta"], rec.channels["theta"][idx])


def test_corrupt_mcap_record_length_resynchronised(tmp_path: Path) -> None:
    f = _bag(tmp_path, "mcap")[2]
    whole = scan_storage(f, keep_messages=False)
    start = whole.chunks[3][0]
    _flip(f, start + 1, 8)  # the chunk record's length: the walk finds the next chunk
    scan = scan_storage(f, keep_messages=False)
    assert [(k.start, k.end) for k in scan.skipped] == [(start, whole.chunks[4][0])]
    assert scan.chunks == whole.chunks[:3] + whole.chunks[4:]


@pytest.mark.parametrize("where", ["message", "page"])
def test_corrupt_sqlite3_rows_skipped_and_reported(tmp_path: Path, where: str,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    rec, bag, f = _bag(tmp_path, "sqlite3")
    size = f.stat().st_size
    page = int.from_bytes(f.read_bytes()[16:18], "big")
    if where == "message":
        _flip(f, size // 2)  # inside a message blob: no checksum, found by deserialising
    else:
        at = size // page // 2 * page
        data = bytearray(f.read_bytes())
        data[at:at + 12] = b"\xff" * 12  # a b-tree page header
        f.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"is corrupt: .*rows \d+-\d+ of the messages table .*'reindex "
                                       r"--overwrite"):
        read_bag(bag)
    assert reindex_main([str(bag), "--overwrite"]) == 0
    err = capsys.readouterr().err
    lost = re.findall(r"left out a corrupt part, rows (\d+)-(\d+) of the messages table", err)
    assert len(lost) == 1, err
    n_rows = int(lost[0][1]) - int(lost[0][0]) + 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BagTruncatedWarning)
        got = read_bag(bag)
    assert N - n_rows <= len(got) < N
    idx = np.round(got.t / 0.002).astype(int)
    assert np.array_equal(got.channels["theta"], rec.channels["theta"][idx])


def test_corrupt_first_chunk_channels_from_the_summary(tmp_path: Path) -> None:
    """The first chunk declares the channels; corrupt, the summary section still names them, so every
    later chunk's messages keep their topic."""
    f = _bag(tmp_path, "mcap")[2]
    whole = scan_storage(f, keep_messages=False)
    start, end = whole.chunks[0][:2]
    _flip(f, (start + end) // 2)
    scan = scan_storage(f, keep_messages=False)
    assert len(scan.skipped) == 1 and (scan.skipped[0].start, scan.skipped[0].end) == (start, end)
    assert scan.skipped[0].describe(scan.t0_ns).startswith(f"bytes {start}-{end} (log time 0.000-")
    assert scan.total + scan.skipped[0].total == 3 * N
    assert set(scan.counts) == set(whole.counts)
