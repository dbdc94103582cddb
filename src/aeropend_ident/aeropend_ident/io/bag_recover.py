"""What is readable of a rosbag2 storage file, complete or truncated, and ``metadata.yaml`` rebuilt from it.

A recording cut short (the recorder killed, a disk full, a copy interrupted) leaves a storage
file that rosbags refuses whole: an MCAP file without its summary and footer ("File end magic is
invalid"), an SQLite3 file shorter than its header says ("database disk image is malformed").
:func:`scan_storage` reads such a file record by record and keeps every message that is
complete on disk:

* **MCAP** (``.mcap``): the top-level records are walked by their length prefix (opcode u8 +
  length u64, MCAP specification) up to the last record that ends inside the file; those are
  parsed by the ``mcap`` package's :class:`mcap.stream_reader.StreamReader`, which needs no
  summary section. A chunk cut by the end of the file is decompressed as far as its data goes
  (none, zstd or lz4; a compressed chunk yields its complete compression blocks) and its
  complete inner records are parsed the same way. A message is thus recovered exactly when its
  whole record lies before the cut (for uncompressed chunks, which rosbags and aeropend write).
* **SQLite3** (``.db3``): the file is opened through an apsw VFS that shows SQLite only the
  whole pages present (a page cut in the middle would be read zero-filled and could yield a
  wrong row), with ``PRAGMA writable_schema=ON`` so SQLite accepts a file shorter than its
  header's page count; the ``messages`` table is read in rowid order up to the first page that
  is missing. Rows are appended in rowid order and SQLite allocates their leaf pages in that
  order, so this is the recording up to the cut.

:func:`rebuild_metadata` / :func:`reindex` write a bag directory's ``metadata.yaml`` from its
storage files (like ``ros2 bag reindex``): topics, offered QoS, type hashes and message counts
as found in storage, ``custom_data`` from the rosbag2 metadata stored inside the file when it
is readable (rosbag2 and rosbags both embed it: an MCAP ``rosbag2`` metadata record, the
SQLite3 ``metadata`` table).
"""

from __future__ import annotations

import io
import itertools
import json
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from aeropend_ident.errors import BagError
from aeropend_ident.io.bag_storage import (
    _MCAP_MAGIC,
    _OP_CHUNK,
    _SUFFIX_STORAGE,
    METADATA_FILE,
    SKIPPED_KEY,
    SkippedChunk,
    StorageScan,
    StorageTopic,
    _parse_qos,
    _parse_stored_metadata,
    _sqlite_pages,
    is_truncated,
    storage_files,
)
from aeropend_ident.io.integrity.loss import LOSS_KEY, RECORDER_KEY, LossCounter
from aeropend_sim.contract import TYPE_ARMATURE, TYPE_JOINT_STATES

__all__ = [
    "rebuild_metadata",
    "reindex",
    "scan_storage",
    "stored_metadata",
]

#: rosbag2 metadata version :func:`rebuild_metadata` writes (Jazzy).
METADATA_VERSION = 9


def scan_storage(path: str | Path, keep_messages: bool = True, validate: bool = False) -> StorageScan:
    """Read every complete message of an MCAP or SQLite3 storage file, even a truncated one.

    Parameters
    ----------
    path : str or Path
        ``.mcap`` or ``.db3`` file.
    keep_messages : bool
        Keep the raw messages (False: count them only, e.g. for :func:`rebuild_metadata`).
    validate : bool
        SQLite3 (no checksums): deserialise every message and leave out (as a :class:`SkippedChunk`)
        the rows whose bytes are not a message of their topic's type.

    Returns
    -------
    StorageScan
        Topics, messages (log-time order), counts, whether and where the file is cut.

    Raises
    ------
    BagError
        The file is not an MCAP / SQLite3 rosbag2 storage file, or its readable part is corrupt.
    """
    path = Path(path)
    if path.suffix not in _SUFFIX_STORAGE:
        raise BagError(f"'{path}': unknown storage file suffix {path.suffix!r}; expected .mcap or .db3")
    try:
        scan = _scan_mcap(path, keep_messages) if path.suffix == ".mcap" else \
            _scan_sqlite3(path, keep_messages, validate)
    except OSError as exc:
        raise BagError(f"'{path}': cannot read ({exc.strerror or exc})") from exc
    scan.messages.sort(key=lambda m: m[1])
    return scan


# --------------------------------------------------------------------------------------------
# MCAP
# --------------------------------------------------------------------------------------------


def _complete_records(buf: Any, start: int, size: int) -> tuple[int, tuple[int, int] | None]:
    """Walk MCAP records (opcode u8, length u64 LE) from ``start``: the end of the last record that
    lies inside ``size`` bytes, and (opcode, offset) of the record the end cuts, if any.

    ``buf`` is a seekable binary file or bytes.
    """
    pos = start
    while pos + 9 <= size:
        if isinstance(buf, (bytes, bytearray, memoryview)):
            head = bytes(buf[pos:pos + 9])
        else:
            buf.seek(pos)
            head = buf.read(9)
        opcode, length = struct.unpack("<BQ", head)
        if pos + 9 + length > size:
            return pos, (opcode, pos)
        pos += 9 + length
    return pos, ((-1, pos) if pos < size else None)


def _partial_chunk_records(chunk: Any) -> bytes:
    """The complete records at the start of a chunk whose data the end of the file cut."""
    data = chunk.data
    if chunk.compression == "zstd":
        import zstandard

        data = zstandard.ZstdDecompressor().decompressobj().decompress(data)
    elif chunk.compression == "lz4":
        import lz4.frame

        try:
            data = lz4.frame.LZ4FrameDecompressor().decompress(data)
        except RuntimeError:
            data = b""
    elif chunk.compression:
        return b""
    end, _ = _complete_records(data, 0, len(data))
    return data[:end]


class _McapState:
    """Schemas, channels and messages of an MCAP file as its records are read."""

    def __init__(self, scan: StorageScan, keep: bool) -> None:
        self.scan, self.keep = scan, keep
        self.schemas: dict[int, str] = {}
        self.channels: dict[int, str] = {}
        self.orphans = 0

    def feed(self, records: Iterator[Any]) -> None:
        from mcap.exceptions import EndOfFile
        from mcap.records import Channel, Message, Metadata, Schema

        try:
            for rec in records:
                if isinstance(rec, Message):
                    topic = self.channels.get(rec.channel_id)
                    if topic is None:
                        self.orphans += 1
                    else:
                        self.scan._add(topic, int(rec.log_time), bytes(rec.data), self.keep)
                elif isinstance(rec, Schema):
                    self.schemas[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    self._channel(rec)
                elif isinstance(rec, Metadata) and rec.name == "rosbag2":
                    text = rec.metadata.get("serialized_metadata")
                    self.scan.stored_metadata = _parse_stored_metadata(text)
        except EndOfFile:
            pass

    def _channel(self, rec: Any) -> None:
        self.channels[rec.id] = rec.topic
        if rec.topic not in self.scan.topics:
            qos = _parse_qos(rec.metadata.get("offered_qos_profiles", ""))
            self.scan.topics[rec.topic] = StorageTopic(
                rec.topic, self.schemas.get(rec.schema_id, ""), rec.message_encoding, qos,
                rec.metadata.get("topic_type_hash", ""))


_OP_FOOTER, _OP_MESSAGE_INDEX, _OP_CHUNK_INDEX = 0x02, 0x07, 0x08


def _records(data: bytes) -> list[Any]:
    """The MCAP records in ``data`` (no magic), all of them or an exception."""
    from mcap.exceptions import EndOfFile
    from mcap.stream_reader import StreamReader

    out: list[Any] = []
    try:
        for rec in StreamReader(io.BytesIO(data), skip_magic=True).records:
            out.append(rec)
    except EndOfFile:
        pass
    return out


def _chunk_content(body: bytes) -> tuple[Any, list[Any]]:
    """A chunk record's header and inner records; raises ValueError saying why it is unreadable."""
    import zlib

    from mcap.data_stream import ReadDataStream
    from mcap.exceptions import McapError
    from mcap.records import Chunk

    try:
        chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
    except (McapError, struct.error, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"unreadable chunk header ({type(exc).__name__})") from exc
    data = chunk.data
    try:
        if chunk.compression == "zstd":
            import zstandard

            data = zstandard.ZstdDecompressor().decompress(data, max_output_size=chunk.uncompressed_size)
        elif chunk.compression == "lz4":
            import lz4.frame

            data = lz4.frame.decompress(data)
        elif chunk.compression:
            raise ValueError(f"unknown compression {chunk.compression!r}")
    except ValueError:
        raise
    except Exception as exc:
        raise ValueError(f"cannot decompress ({type(exc).__name__})") from exc
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError("CRC mismatch: its bytes changed after it was written")
    try:
        return chunk, _records(bytes(data))
    except (McapError, struct.error, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(f"unreadable record inside ({type(exc).__name__}: {exc})") from exc


def _summary(f: Any, size: int) -> tuple[list[int], list[Any]]:
    """Chunk start offsets and the schema and channel records of a complete file's summary section
    (a channel declared only inside a corrupt chunk is still known); ([], []) if unreadable."""
    from mcap.records import Channel, ChunkIndex, Footer, Schema

    try:
        f.seek(size - len(_MCAP_MAGIC) - 29)
        recs = _records(f.read(29))
        footer = recs[0] if recs and isinstance(recs[0], Footer) else None
        if footer is None or not footer.summary_start:
            return [], []
        f.seek(footer.summary_start)
        summary = _records(f.read(size - len(_MCAP_MAGIC) - 29 - footer.summary_start))
        starts = sorted(r.chunk_start_offset for r in summary if isinstance(r, ChunkIndex))
        return starts, [r for r in summary if isinstance(r, (Schema, Channel))]
    except Exception:  # a damaged summary: resynchronise by searching instead
        return [], []


def _next_chunk(f: Any, pos: int, size: int, starts: list[int]) -> int | None:
    """Start of the first readable chunk record after byte ``pos`` (summary index, else a search for a
    chunk opcode whose length fits and whose content checks)."""
    known = [p for p in starts if p > pos]
    if known:
        return known[0]
    f.seek(pos)
    data = f.read()
    i = data.find(bytes([_OP_CHUNK]), 1)
    while i >= 0:
        if i + 9 <= len(data):
            length = struct.unpack("<Q", data[i + 1:i + 9])[0]
            if i + 9 + length <= len(data):
                try:
                    _chunk_content(data[i + 9:i + 9 + length])
                    return pos + i
                except ValueError:
                    pass
        i = data.find(bytes([_OP_CHUNK]), i + 1)
    return None


def _skipped_index(skip: SkippedChunk, rec: Any, channels: dict[int, str]) -> None:
    """Count a skipped chunk's messages from its message index record ``rec``."""
    if not rec.records:
        return
    topic = channels.get(rec.channel_id, f"channel {rec.channel_id}")
    skip.counts[topic] = skip.counts.get(topic, 0) + len(rec.records)
    times = [t for t, _ in rec.records]
    skip.first_ns = min(times) if skip.first_ns is None else min(skip.first_ns, min(times))
    skip.last_ns = max(times) if skip.last_ns is None else max(skip.last_ns, max(times))


def _scan_mcap(path: Path, keep: bool) -> StorageScan:
    """Walk an MCAP file record by record (see :func:`scan_storage`): a chunk that cannot be read
    (CRC mismatch, unreadable header or content) is skipped and reported, the walk goes on after it
    (a damaged record length: at the next chunk the summary or a search finds)."""
    from mcap.data_stream import ReadDataStream
    from mcap.exceptions import McapError
    from mcap.records import Chunk, MessageIndex

    size = path.stat().st_size
    scan = StorageScan(path, "mcap", file_size=size)
    if size == 0:
        raise BagError(f"'{path}' is empty: nothing was written (0 bytes: the recorder stopped or was killed "
                       "before its first flush)")
    state = _McapState(scan, keep)
    with path.open("rb") as f:
        head = f.read(len(_MCAP_MAGIC))
        if head != _MCAP_MAGIC:
            if _MCAP_MAGIC.startswith(head):
                raise BagError(f"'{path}' is empty: nothing was written ({size} byte(s), part of the MCAP "
                               "magic)")
            raise BagError(f"'{path}' is not an MCAP file (it does not start with the MCAP magic)")
        scan.truncated = is_truncated(path)
        starts, defs = ([], []) if scan.truncated else _summary(f, size)
        state.feed(iter(defs))
        pos, skip = len(_MCAP_MAGIC), None
        while pos + 9 <= size:
            f.seek(pos)
            opcode, length = struct.unpack("<BQ", f.read(9))
            end = pos + 9 + length
            if end > size and scan.truncated:
                if opcode == _OP_CHUNK:  # the chunk the end of the file cut: its complete records
                    f.seek(pos + 9)
                    body = io.BytesIO(f.read())
                    try:
                        chunk = Chunk.read(ReadDataStream(body))
                        inner = _partial_chunk_records(chunk)
                        state.feed(iter(_records(inner)))
                        if not chunk.compression and inner:
                            pos = body.tell() - len(chunk.data) + pos + 9 + len(inner)
                    except (McapError, struct.error, ValueError, UnicodeDecodeError):
                        pass
                break
            if opcode == _OP_FOOTER:
                pos = end
                break
            if end > size or opcode == 0:
                nxt = _next_chunk(f, pos, size, starts)
                scan.skipped.append(SkippedChunk(pos, nxt or size, "unreadable record (its length runs past "
                                                 "the end of the file)"))
                if nxt is None:
                    break
                pos, skip = nxt, None
                continue
            body = f.read(length)
            if opcode == _OP_CHUNK:
                skip = None
                try:
                    chunk, inner = _chunk_content(body)
                    state.feed(iter(inner))
                    scan.chunks.append((pos, end, int(chunk.message_start_time), int(chunk.message_end_time)))
                except ValueError as exc:
                    skip = SkippedChunk(pos, end, f"corrupt chunk: {exc}")
                    scan.skipped.append(skip)
            elif opcode == _OP_MESSAGE_INDEX and skip is not None:
                recs = _safe_records(bytes([opcode]) + struct.pack("<Q", length) + body)
                for r in recs or []:
                    if isinstance(r, MessageIndex):
                        _skipped_index(skip, r, state.channels)
            else:
                recs = _safe_records(bytes([opcode]) + struct.pack("<Q", length) + body)
                if recs is None:
                    scan.skipped.append(SkippedChunk(pos, end, f"unreadable record (opcode {opcode:#04x})"))
                else:
                    state.feed(iter(recs))
            pos = end
        scan.readable_bytes = min(pos, size)
    if state.orphans and not scan.skipped:
        raise BagError(f"'{path}' is corrupt: {state.orphans} message(s) on a channel without channel record")
    if state.orphans:  # their channel was declared in a corrupt part only
        scan.skipped.append(SkippedChunk(0, 0, "intact messages on channels declared only in a corrupt "
                                         "part", {"topic unknown": state.orphans}))
    return scan


def _safe_records(data: bytes) -> list[Any] | None:
    """:func:`_records`, or None when they cannot be read."""
    from mcap.exceptions import McapError

    try:
        return _records(data)
    except (McapError, struct.error, UnicodeDecodeError, ValueError):
        return None


# --------------------------------------------------------------------------------------------
# SQLite3
# --------------------------------------------------------------------------------------------

_vfs_ids = itertools.count()


def _open_sqlite(path: Path, vfs: str | None = None) -> Any:
    """Read-only apsw connection (``immutable=1``: no locks, no journal) to an SQLite file."""
    import apsw

    return apsw.Connection(f"file:{path}?immutable=1", flags=apsw.SQLITE_OPEN_READONLY | apsw.SQLITE_OPEN_URI,
                           vfs=vfs)


def _prefix_vfs(limit: int) -> Any:
    """An apsw VFS that shows SQLite only the first ``limit`` bytes of a file (whole pages)."""
    import apsw

    class PrefixFile(apsw.VFSFile):  # type: ignore[misc]
        def __init__(self, filename: Any, flags: list[int]) -> None:
            super().__init__("", filename, flags)

        def xFileSize(self) -> int:
            return min(super().xFileSize(), limit)

        def xRead(self, amount: int, offset: int) -> bytes:
            # fewer bytes than asked: apsw zero-fills and reports a short read, as SQLite expects
            return super().xRead(max(0, min(amount, limit - offset)), offset) if offset < limit else b""

    class PrefixVFS(apsw.VFS):  # type: ignore[misc]
        def __init__(self, name: str) -> None:
            super().__init__(name, "")
            self.name = name

        def xOpen(self, name: Any, flags: list[int]) -> Any:
            return PrefixFile(name, flags)

    return PrefixVFS(f"aeropend-prefix-{next(_vfs_ids)}")


def _scan_sqlite3(path: Path, keep: bool, validate: bool = False) -> StorageScan:
    import apsw

    scan = StorageScan(path, "sqlite3", file_size=path.stat().st_size)
    with path.open("rb") as f:
        head = f.read(100)
    pages = _sqlite_pages(head)
    if pages is None:
        raise BagError(f"'{path}' is not an SQLite3 database (no SQLite header)")
    scan.declared_bytes = pages[0] * pages[1]
    scan.truncated = scan.file_size < scan.declared_bytes
    scan.readable_bytes = scan.file_size // pages[0] * pages[0] if scan.truncated else scan.file_size
    vfs = _prefix_vfs(scan.readable_bytes) if scan.truncated else None
    try:
        conn = _open_sqlite(path, vfs.name if vfs else None)
        try:
            if scan.truncated:
                conn.execute("PRAGMA writable_schema=ON")  # accept a file shorter than its header says
            _read_sqlite3(conn, scan, keep, validate)
        finally:
            conn.close()
    except apsw.Error as exc:
        if scan.truncated:
            raise BagError(f"bag storage '{path}' is truncated: {scan.where_it_ends()}; its tables cannot be "
                           f"read ({type(exc).__name__}: {exc}), no message could be recovered") from exc
        raise BagError(f"'{path}' cannot be read as a rosbag2 SQLite3 file ({type(exc).__name__}: {exc})") \
            from exc
    finally:
        if vfs is not None:
            vfs.unregister()
    return scan


def _read_sqlite3(conn: Any, scan: StorageScan, keep: bool, validate: bool = False) -> None:
    """Topics, stored metadata and messages (rowid order, up to the first missing page)."""
    import apsw

    tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    if not {"topics", "messages"} <= tables:
        raise BagError(f"'{scan.path}': no topics/messages table in the readable part "
                       f"(tables: {sorted(tables) or 'none'})")
    cols = [r[1] for r in conn.execute("PRAGMA table_info(topics)")]
    qos_col = "offered_qos_profiles" if "offered_qos_profiles" in cols else "''"
    hash_col = "type_description_hash" if "type_description_hash" in cols else "''"
    ids: dict[int, str] = {}
    for tid, name, typ, fmt, qos, digest in conn.execute(
            f"SELECT id, name, type, serialization_format, {qos_col}, {hash_col} FROM topics ORDER BY id"):
        ids[tid] = name
        scan.topics.setdefault(name, StorageTopic(name, typ, fmt, _parse_qos(qos), digest or ""))
    if "metadata" in tables:
        try:
            row = conn.execute("SELECT metadata FROM metadata ORDER BY id DESC LIMIT 1").fetchone()
            scan.stored_metadata = _parse_stored_metadata(row[0]) if row else None
        except apsw.Error:
            scan.stored_metadata = None
    last_id = 0
    check = _Validator(scan, ids) if validate else None
    try:
        query = "SELECT id, topic_id, timestamp, data FROM messages ORDER BY id"
        for rid, tid, stamp, data in conn.execute(query):
            if tid in ids and (check is None or check(rid, tid, int(stamp), data)):
                scan._add(ids[tid], int(stamp), bytes(data), keep)
            last_id = rid
    except apsw.CorruptError:
        if not scan.truncated:
            _read_sqlite3_around(conn, scan, keep, ids, last_id)
    if check is not None:
        check.report()


class _Validator:
    """Rows of an SQLite3 bag whose bytes do not deserialise as their topic's type (the file has no
    checksum): called per row, True for a good one; :meth:`report` adds the bad ones, run by run,
    to ``scan.skipped``."""

    def __init__(self, scan: StorageScan, ids: dict[int, str]) -> None:
        from aeropend_ident.io.bag_codec import typestore

        self.scan, self.ids, self.ts = scan, ids, typestore()
        self.types = {tid: scan.topics[name].msgtype for tid, name in ids.items()}
        self.bad: list[tuple[int, int, int, str]] = []  # row id, topic id, stamp, error

    def __call__(self, rid: int, tid: int, stamp: int, data: bytes) -> bool:
        typ = self.types[tid]
        if typ not in self.ts.types:
            return True
        try:
            self.ts.deserialize_cdr(bytes(data), typ)
        except Exception as exc:
            self.bad.append((rid, tid, stamp, f"{type(exc).__name__}: {exc}"))
            return False
        return True

    def report(self) -> None:
        by_id = {b[0]: b for b in self.bad}
        for run in _runs(list(by_id)):
            rows = [by_id[r] for r in run]
            counts: dict[str, int] = {}
            for _, tid, _, _ in rows:
                counts[self.ids[tid]] = counts.get(self.ids[tid], 0) + 1
            self.scan.skipped.append(SkippedChunk(
                0, 0, f"rows {run[0]}-{run[-1]} of the messages table hold bytes that are not a message "
                f"of their topic's type ({rows[0][3]})", counts, min(r[2] for r in rows),
                max(r[2] for r in rows)))


#: Rows read at a time around a corrupt page of an SQLite3 file.
_ROW_BATCH = 4096


def _read_sqlite3_around(conn: Any, scan: StorageScan, keep: bool, ids: dict[int, str], done: int) -> None:
    """The rows after id ``done`` of a file with a corrupt page: read by id ranges, a range that fails
    bisected down to single rows; the unreadable rows are reported as :class:`SkippedChunk` s."""
    import apsw

    try:
        top = conn.execute("SELECT max(id) FROM messages").fetchone()[0] or done
    except apsw.Error:
        top = done
    bad: list[int] = []
    stamps: dict[int, int] = {}
    prev = scan.last_ns  # the last row read before the corrupt page

    def read(a: int, b: int) -> None:
        try:
            rows = list(conn.execute("SELECT id, topic_id, timestamp, data FROM messages "
                                     "WHERE id >= ? AND id < ? ORDER BY id", (a, b)))
        except apsw.Error:
            if b - a <= 1:
                bad.append(a)
                return
            m = (a + b) // 2
            read(a, m)
            read(m, b)
            return
        for rid, tid, stamp, data in rows:
            stamps[rid] = int(stamp)
            if tid in ids:
                scan._add(ids[tid], int(stamp), bytes(data), keep)

    for a in range(done + 1, top + 1, _ROW_BATCH):
        read(a, min(top + 1, a + _ROW_BATCH))
    if top == done:
        scan.skipped.append(SkippedChunk(0, 0, f"the rows after id {done} of the messages table are "
                                         "unreadable (corrupt page)"))
    for run in _runs(bad):
        before = max((stamps[i] for i in stamps if i < run[0]), default=prev)
        after = min((stamps[i] for i in stamps if i > run[-1]), default=None)
        scan.skipped.append(SkippedChunk(0, 0, f"rows {run[0]}-{run[-1]} of the messages table are on a "
                                         "corrupt page", {"topic unknown": len(run)}, before,
                                         after))


def _runs(values: list[int]) -> list[list[int]]:
    """Consecutive runs of sorted integers."""
    out: list[list[int]] = []
    for v in sorted(values):
        if out and v == out[-1][-1] + 1:
            out[-1].append(v)
        else:
            out.append([v])
    return out


def stored_metadata(path: str | Path) -> dict[str, Any] | None:
    """The ``rosbag2_bagfile_information`` a complete storage file carries inside, if any.

    rosbag2 (and rosbags) embed the bag's metadata in the storage file: the MCAP metadata record
    ``rosbag2`` (read through the summary's metadata index by ``mcap``'s reader) and the SQLite3
    ``metadata`` table. None when the file has none or it cannot be read.
    """
    import apsw
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    path = Path(path)
    try:
        if path.suffix == ".mcap":
            with path.open("rb") as f:
                for rec in make_reader(f).iter_metadata():
                    if rec.name == "rosbag2":
                        return _parse_stored_metadata(rec.metadata.get("serialized_metadata"))
            return None
        conn = _open_sqlite(path)
        try:
            row = conn.execute("SELECT metadata FROM metadata ORDER BY id DESC LIMIT 1").fetchone()
        finally:
            conn.close()
        return _parse_stored_metadata(row[0]) if row else None
    except (OSError, ValueError, KeyError, struct.error, McapError, apsw.Error):
        return None


# --------------------------------------------------------------------------------------------
# metadata.yaml from storage (reindex)
# --------------------------------------------------------------------------------------------


def rebuild_metadata(bag: str | Path, keep_messages: bool = False
                     ) -> tuple[dict[str, Any], list[StorageScan]]:
    """``rosbag2_bagfile_information`` of a bag directory rebuilt from its storage files.

    Parameters
    ----------
    bag : str or Path
        Bag directory holding ``.mcap`` or ``.db3`` files (one storage kind).
    keep_messages : bool
        Keep the recovered messages in the returned scans (``reindex --repair`` writes them); the
        loss count, when one is needed, is then made from them instead of a second read.

    Returns
    -------
    (dict, list of StorageScan)
        The metadata (version 9: topics with offered QoS, type hash and message count, per-file
        counts and times; ``custom_data``, ``ros_distro`` and the compression settings from the
        metadata stored in a storage file when readable) and the scans of the files
        (``truncated`` says which are cut).

    Raises
    ------
    BagError
        No storage file, mixed storage kinds, or an unreadable file.
    """
    from rosbags.rosbag2.metadata import dump_qos_v9

    bag = Path(bag)
    files = storage_files(bag) if bag.is_dir() else []
    if not files:
        raise BagError(f"'{bag}' holds no .mcap or .db3 storage file; nothing to index")
    kinds = {_SUFFIX_STORAGE[p.suffix] for p in files}
    if len(kinds) > 1:
        raise BagError(f"'{bag}' mixes storage kinds ({', '.join(p.name for p in files)}); expected one")
    scans = [scan_storage(p, keep_messages=keep_messages, validate=True) for p in files]
    topics: dict[str, StorageTopic] = {}
    counts: dict[str, int] = {}
    for s in scans:
        for name, t in s.topics.items():
            topics.setdefault(name, t)
            counts[name] = counts.get(name, 0) + s.counts.get(name, 0)
    firsts = [s.first_ns for s in scans if s.first_ns is not None]
    lasts = [s.last_ns for s in scans if s.last_ns is not None]
    start = min(firsts) if firsts else 0
    stored = next((s.stored_metadata for s in scans if s.stored_metadata), None) or {}
    info: dict[str, Any] = {
        "version": METADATA_VERSION,
        "storage_identifier": kinds.pop(),
        "relative_file_paths": [p.name for p in files],
        "duration": {"nanoseconds": (max(lasts) - start) if lasts else 0},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": sum(counts.values()),
        "topics_with_message_count": [
            {"topic_metadata": {"name": t.name, "type": t.msgtype,
                                "serialization_format": t.serialization_format,
                                "offered_qos_profiles": dump_qos_v9(list(t.qos)),
                                "type_description_hash": t.type_hash},
             "message_count": counts[t.name]}
            for t in topics.values()
        ],
        "compression_format": stored.get("compression_format") or "",
        "compression_mode": stored.get("compression_mode") or "",
        "files": [
            {"path": s.path.name,
             "starting_time": {"nanoseconds_since_epoch": s.first_ns or 0},
             "duration": {"nanoseconds": (s.last_ns - s.first_ns) if s.first_ns is not None else 0},
             "message_count": s.total}
            for s in scans
        ],
        "custom_data": stored.get("custom_data") or None,
        "ros_distro": stored.get("ros_distro") or "rosbags",
    }
    custom = info["custom_data"] or {}
    # a storage file never closed (its metadata record missing: a killed recorder) or a recorder's
    # file without its count: the loss is counted here, from the stamps
    if LOSS_KEY not in custom and (not stored or RECORDER_KEY in custom):
        loss = _loss_from_stamps(scans, topics, keep_messages)
        info["custom_data"] = {**custom, LOSS_KEY: json.dumps(loss)}
    skipped = [{"file": s.path.name, "start": k.start, "end": k.end, "reason": k.reason, "counts": k.counts,
                "first_ns": k.first_ns, "last_ns": k.last_ns} for s in scans for k in s.skipped]
    if skipped:  # readers then read the recovered messages (and say what was left out)
        info["custom_data"] = {**(info["custom_data"] or {}), SKIPPED_KEY: json.dumps(skipped)}
    return info, scans


#: ``note`` of a loss count made by ``reindex`` (the recorder stored none: it was killed).
REINDEX_LOSS_NOTE = ("counted by reindex from the header stamps (the recorder stored no count, e.g. it was "
                     "killed); topics without a header are not countable, and messages of a corrupt part "
                     "left out count as lost")


def _loss_from_stamps(scans: list[StorageScan], topics: dict[str, StorageTopic],
                      have_messages: bool) -> dict[str, dict[str, Any]]:
    """Per-topic loss of the recovered messages, from the header stamps against the sample period
    (:class:`aeropend_ident.io.integrity.loss.LossCounter` without sequence numbers: a storage file
    does not keep them), each topic's entry marked with :data:`REINDEX_LOSS_NOTE`. The messages are
    the scans' own when ``have_messages``, else each file is read again (validated, like the scan)."""
    stamped = {n for n, t in topics.items() if t.msgtype in (TYPE_JOINT_STATES, TYPE_ARMATURE)}
    counter = LossCounter(stamped=lambda topic: topic in stamped)
    for scan in scans:
        messages = scan.messages if have_messages else \
            scan_storage(scan.path, keep_messages=True, validate=True).messages  # log-time order
        for topic, log_ns, data in messages:
            counter.add(topic, log_ns, data)
    return {name: {**r, "note": REINDEX_LOSS_NOTE} for name, r in counter.report().items()}


def reindex(bag: str | Path, overwrite: bool = False, keep_messages: bool = False
            ) -> tuple[Path, dict[str, Any], list[StorageScan]]:
    """Write ``metadata.yaml`` of a bag directory from its storage files (``ros2 bag reindex``).

    Parameters
    ----------
    bag : str or Path
        Bag directory.
    overwrite : bool
        Replace an existing ``metadata.yaml`` (refused otherwise).
    keep_messages : bool
        Keep the recovered messages in the returned scans (:func:`rebuild_metadata`), e.g. for
        :func:`aeropend_ident.io.bag_repair.repair` to copy without reading the files again.

    Returns
    -------
    (Path, dict, list of StorageScan)
        The metadata file written, its ``rosbag2_bagfile_information`` and the file scans.

    Raises
    ------
    BagError
        ``bag`` is not a directory, ``metadata.yaml`` exists and ``overwrite`` is False, or
        :func:`rebuild_metadata` fails.
    """
    import yaml

    bag = Path(bag)
    if not bag.is_dir():
        raise BagError(f"'{bag}' is not a bag directory" + (" (it does not exist)" if not bag.exists() else
                       "; reindex takes the directory that holds the .mcap/.db3 file(s)"))
    target = bag / METADATA_FILE
    if target.exists() and not overwrite:
        raise BagError(f"'{target}' already exists; reindex --overwrite replaces it")
    info, scans = rebuild_metadata(bag, keep_messages)
    tmp = target.with_name(METADATA_FILE + ".tmp")
    tmp.write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False), encoding="utf-8")
    tmp.replace(target)
    return target, info, scans

