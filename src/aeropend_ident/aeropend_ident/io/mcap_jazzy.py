"""rosbag2 writer whose MCAP channels carry the type hash as ROS 2 Jazzy writes it.

rosbag2 Jazzy's ``rosbag2_storage_mcap`` stores two keys in every MCAP channel's metadata map:
``offered_qos_profiles`` (the YAML QoS list) and ``topic_type_hash`` (the message type's RIHS01
type-description hash, e.g. ``RIHS01_d5e8...``), and it reads the hash back from there into
``TopicMetadata.type_description_hash``. rosbags 0.11 writes the hash into ``metadata.yaml`` only;
:class:`JazzyWriter` is rosbags' :class:`~rosbags.rosbag2.Writer` with an MCAP storage that writes
the channel key too (sqlite3 bags are unchanged: their hash lives in ``metadata.yaml``, as in
Jazzy). The hash is the one rosbags computes from the typestore (``Typestore.hash_rihs01``), so
the channel and ``metadata.yaml`` always agree.
"""

from __future__ import annotations

import os
import zlib
from collections import defaultdict
from collections.abc import Sequence
from io import BytesIO
from typing import TYPE_CHECKING, ClassVar, cast

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.storage_mcap import (
    Channel,
    McapWriter,
    PendingChunk,
    write_channel,
    write_record,
    write_string,
    write_uint16,
    write_uint32,
    write_uint64,
)

if TYPE_CHECKING:
    from collections.abc import Mapping

    from rosbags.interfaces import Connection, ConnectionExtRosbag2

#: MCAP channel-metadata key of the RIHS01 type hash (rosbag2_storage_mcap, Jazzy).
TOPIC_TYPE_HASH_KEY = "topic_type_hash"
#: MCAP channel-metadata key of the offered QoS profiles (YAML list).
OFFERED_QOS_KEY = "offered_qos_profiles"


class JazzyMcapWriter(McapWriter):
    """rosbags' MCAP storage writer plus the ``topic_type_hash`` channel metadata of Jazzy."""

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        """Register a channel with its offered QoS profiles and RIHS01 type hash.

        Parameters
        ----------
        connection
            rosbags connection; ``connection.digest`` is the RIHS01 hash of its message type.
        offered_qos_profiles
            Serialised (YAML) offered QoS profiles.
        """
        metadata = BytesIO()
        for key, value in ((OFFERED_QOS_KEY, offered_qos_profiles),
                           (TOPIC_TYPE_HASH_KEY, connection.digest)):
            write_string(metadata, key)
            write_string(metadata, value)
        self.channels.append(
            Channel(
                connection.id,
                connection.msgtype,
                connection.topic,
                cast("ConnectionExtRosbag2", connection.ext).serialization_format,
                metadata.getvalue(),
            )
        )
        self.channel_stats[connection.id] = 0
        write_channel(self.chunk.bio, self.channels[-1], self.schemas)

    def write_rows(self, ids: Sequence[int], stamps: np.ndarray, rows: Sequence[np.ndarray]) -> None:
        """Append fixed-size messages of several channels, one of each per stamp, as whole chunks.

        The records are built with NumPy (about 100x faster than one :meth:`write` per message);
        the chunks, message indexes and chunk indexes are those :meth:`close_chunk` writes.

        Parameters
        ----------
        ids : sequence of int
            Channel ids (connection ids), one per message of a sample, in write order.
        stamps : ndarray of int64, shape (N,)
            Log (and publish) time of each sample's messages [ns], non-decreasing.
        rows : sequence of ndarray of uint8, shape (N, size_i)
            The serialised messages of each channel.
        """
        n = len(stamps)
        if not n:
            return
        fields = []
        for i, r in enumerate(rows):
            fields += [(f"op{i}", "u1"), (f"len{i}", "<u8"), (f"cid{i}", "<u2"), (f"seq{i}", "<u4"),
                       (f"log{i}", "<u8"), (f"pub{i}", "<u8"), (f"data{i}", "u1", (r.shape[1],))]
        dtype = np.dtype(fields)
        rec_offsets = [dtype.fields[f"op{i}"][1] for i in range(len(rows))]
        per_chunk = max(1, (1 << 20) // dtype.itemsize)
        if self.chunk.msgs:  # messages written one by one before: their chunk first
            self.close_chunk()
        for a in range(0, n, per_chunk):
            b = min(n, a + per_chunk)
            arr = np.zeros(b - a, dtype)
            ts = np.asarray(stamps[a:b], dtype=np.uint64)
            for i, (cid, r) in enumerate(zip(ids, rows, strict=True)):
                arr[f"op{i}"] = 0x05
                arr[f"len{i}"] = 22 + r.shape[1]
                arr[f"cid{i}"] = cid
                arr[f"log{i}"] = ts
                arr[f"pub{i}"] = ts
                arr[f"data{i}"] = r[a:b]
            pre = self.chunk.bio.getvalue()  # schema and channel records not yet in a chunk
            self.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))
            self._write_chunk(pre, arr.tobytes(), ids, ts, dtype.itemsize, rec_offsets)
            for cid in ids:
                self.channel_stats[cid] += b - a
            self.message_start_time = min(int(ts[0]), self.message_start_time)
            self.message_end_time = max(int(ts[-1]), self.message_end_time)

    def _write_chunk(self, pre: bytes, body: bytes, ids: Sequence[int], ts: np.ndarray, row_size: int,
                     rec_offsets: Sequence[int]) -> None:
        """One chunk of :meth:`write_rows` (records after ``pre``, ``row_size`` bytes per sample)."""
        base = len(pre) + np.arange(len(ts), dtype=np.uint64) * np.uint64(row_size)
        index = {}
        for cid, off in zip(ids, rec_offsets, strict=True):
            pairs = np.empty((len(ts), 2), dtype="<u8")
            pairs[:, 0] = ts
            pairs[:, 1] = base + np.uint64(off)
            index[cid] = pairs
        self._emit_chunk(pre + body, int(ts[0]), int(ts[-1]), index)

    def close_chunk(self) -> None:
        """Write the pending chunk (as rosbags does, plus the CRC-32 of its records)."""
        index = {cid: np.asarray(msgs, dtype="<u8").reshape(-1, 2) for cid, msgs in self.chunk.msgs.items()}
        self._emit_chunk(self.chunk.bio.getvalue(), self.chunk.message_start_time,
                         self.chunk.message_end_time, index)
        self.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))

    def _emit_chunk(self, data: bytes, start: int, end: int, index: dict[int, np.ndarray]) -> None:
        """A chunk record holding ``data`` (its records; CRC-32 stored so a reader can tell a
        corrupt chunk), its message index records (``index``: channel -> (log time, offset) rows)
        and its chunk index for the summary."""
        rec = BytesIO()
        write_uint64(rec, start)
        write_uint64(rec, end)
        write_uint64(rec, len(data))
        write_uint32(rec, zlib.crc32(data))
        compressed = self.compressor(data)
        write_string(rec, self.compression)
        write_uint64(rec, len(compressed))
        rec.write(compressed)
        chunk_start = self.bio.tell()
        write_record(self.bio, 0x06, rec)
        chunk_end = self.bio.tell()
        offsets: list[tuple[int, int]] = []
        for cid, pairs in index.items():
            offsets.append((cid, self.bio.tell()))
            rec = BytesIO()
            write_uint16(rec, cid)
            write_uint32(rec, pairs.nbytes)
            rec.write(pairs.tobytes())
            write_record(self.bio, 0x07, rec)
        rec = BytesIO()
        write_uint64(rec, start)
        write_uint64(rec, end)
        write_uint64(rec, chunk_start)
        write_uint64(rec, chunk_end - chunk_start)
        write_uint32(rec, len(offsets) * 10)
        for cid, offset in offsets:
            write_uint16(rec, cid)
            write_uint64(rec, offset)
        write_uint64(rec, self.bio.tell() - chunk_end)
        write_string(rec, self.compression)
        write_uint64(rec, len(compressed))
        write_uint64(rec, len(data))
        self.chunks.append(rec)

    def flush(self) -> None:
        """Close the pending chunk if it holds messages and push the file to disk (``fsync``): what
        was written so far survives the process being killed or the power going."""
        if self.chunk.msgs:
            self.close_chunk()
        self.bio.flush()
        os.fsync(self.bio.fileno())


class JazzyWriter(Writer):
    """rosbags :class:`~rosbags.rosbag2.Writer` with :class:`JazzyMcapWriter` for MCAP storage."""

    STORAGE_PLUGINS: ClassVar[Mapping[StoragePlugin, type]] = {
        **Writer.STORAGE_PLUGINS,
        StoragePlugin.MCAP: JazzyMcapWriter,
    }

    def write_rows(self, connections: Sequence[Connection], stamps: np.ndarray,
                   rows: Sequence[np.ndarray]) -> None:
        """Write one message of each connection per stamp (fixed-size serialised messages).

        MCAP storage takes them as whole chunks (:meth:`JazzyMcapWriter.write_rows`); any other
        storage one by one through :meth:`write`.

        Parameters
        ----------
        connections : sequence of Connection
            One per message of a sample, in write order.
        stamps : ndarray of int64, shape (N,)
            Log time of each sample's messages [ns].
        rows : sequence of ndarray of uint8, shape (N, size_i)
            The serialised messages of each connection.
        """
        if not len(stamps):
            return
        if isinstance(self.storage, JazzyMcapWriter) and self.compression_mode.name != "MESSAGE":
            self.storage.write_rows([c.id for c in connections], stamps, rows)
            for c in connections:
                self.counts[c.id] += len(stamps)
            self.min_timestamp = min(int(stamps[0]), self.min_timestamp)
            self.max_timestamp = max(int(stamps[-1]), self.max_timestamp)
            return
        datas = [[r[k].tobytes() for k in range(len(r))] for r in rows]
        for k, stamp in enumerate(np.asarray(stamps).tolist()):
            for c, d in zip(connections, datas, strict=True):
                self.write(c, stamp, d[k])
