"""A rosbag2 storage file (``.mcap``, ``.db3``): its kinds and magic bytes, whether it is cut short, and
what a scan of it finds (:class:`StorageScan`: topics, messages, the parts left out).

The scan itself (record by record, also of a truncated or corrupt file) is
:func:`aeropend_ident.io.bag_recover.scan_storage`.
"""

from __future__ import annotations

import io
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

#: Name of a rosbag2 bag directory's metadata file.
METADATA_FILE = "metadata.yaml"
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_OP_CHUNK = 0x06
_SQLITE_MAGIC = b"SQLite format 3\x00"
_SUFFIX_STORAGE = {".mcap": "mcap", ".db3": "sqlite3"}
#: ``custom_data`` key of ``metadata.yaml`` listing the corrupt parts that
#: :func:`~aeropend_ident.io.bag_recover.reindex` left out (JSON).
SKIPPED_KEY = "aeropend.skipped"


@dataclass(frozen=True)
class StorageTopic:
    """A topic as a storage file declares it.

    Attributes
    ----------
    name, msgtype, serialization_format : str
        Topic name, message type (``sensor_msgs/msg/JointState``) and serialisation (``cdr``).
    qos : tuple of rosbags.interfaces.Qos
        Offered QoS profiles stored with the topic (may be empty).
    type_hash : str
        RIHS01 type-description hash (empty when the storage has none).
    """

    name: str
    msgtype: str
    serialization_format: str
    qos: tuple[Any, ...]
    type_hash: str


@dataclass
class SkippedChunk:
    """A part of a storage file that cannot be read and was left out
    (:func:`~aeropend_ident.io.bag_recover.scan_storage`).

    Attributes
    ----------
    start, end : int
        Byte range in the file (MCAP: the chunk record; SQLite3: the rows' page range is unknown,
        both 0).
    reason : str
        Why it cannot be read (CRC mismatch, unreadable record, ...).
    counts : dict of str -> int
        Messages it held per topic, as far as the file tells (MCAP message indexes; SQLite3 the
        missing row ids); empty when unknown.
    first_ns, last_ns : int or None
        Log time range of those messages [ns], when known.
    """

    start: int
    end: int
    reason: str
    counts: dict[str, int] = field(default_factory=dict)
    first_ns: int | None = None
    last_ns: int | None = None

    @property
    def total(self) -> int:
        """Messages it held (0: unknown or none)."""
        return sum(self.counts.values())

    def describe(self, t0_ns: int | None = None) -> str:
        """One line: where, what it held and why, e.g. ``bytes 4096-1052672 (log time 2.000-3.000 s
        after the first message): 1470 message(s) (/aeropend/joint_states 490, ...): CRC mismatch``."""
        where = f"bytes {self.start}-{self.end}" if self.end else self.reason
        if self.first_ns is not None and self.last_ns is not None:
            base = self.first_ns if t0_ns is None else t0_ns
            where += (f" (log time {(self.first_ns - base) / 1e9:.3f}-{(self.last_ns - base) / 1e9:.3f} s "
                      "after the first message)")
        held = (f"{self.total} message(s) ({', '.join(f'{t} {n}' for t, n in self.counts.items())})"
                if self.counts else "an unknown number of messages")
        return f"{where}: {held}" + (f": {self.reason}" if self.end else "")


@dataclass
class StorageScan:
    """The readable content of one storage file (:func:`~aeropend_ident.io.bag_recover.scan_storage`).

    Attributes
    ----------
    path : Path
        The storage file.
    storage : {"mcap", "sqlite3"}
        Storage plugin.
    topics : dict of str -> StorageTopic
        Topics declared in the readable part, by name.
    messages : list of (topic, log_time_ns, bytes)
        Recovered messages in log-time order (empty when scanned with ``keep_messages=False``).
    counts : dict of str -> int
        Messages recovered per topic.
    first_ns, last_ns : int or None
        Smallest and largest log time recovered [ns since the epoch].
    truncated : bool
        The file is cut short (no MCAP footer / fewer bytes than the SQLite header declares).
    file_size : int
        Size of the file [bytes].
    readable_bytes : int
        MCAP: end of the last complete record read; SQLite3: bytes in the whole pages read.
    declared_bytes : int or None
        SQLite3: size the header declares (page count × page size); None for MCAP.
    stored_metadata : dict or None
        The ``rosbag2_bagfile_information`` embedded in the storage file, when readable.
    skipped : list of SkippedChunk
        Corrupt parts left out (the messages around them are recovered).
    chunks : list of (int, int, int, int)
        MCAP: (start byte, end byte, first log time, last log time) of each chunk read.
    """

    path: Path
    storage: Literal["mcap", "sqlite3"]
    topics: dict[str, StorageTopic] = field(default_factory=dict)
    messages: list[tuple[str, int, bytes]] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    first_ns: int | None = None
    last_ns: int | None = None
    truncated: bool = False
    file_size: int = 0
    readable_bytes: int = 0
    declared_bytes: int | None = None
    stored_metadata: dict[str, Any] | None = None
    skipped: list[SkippedChunk] = field(default_factory=list)
    chunks: list[tuple[int, int, int, int]] = field(default_factory=list)

    @property
    def t0_ns(self) -> int | None:
        """Earliest log time in the file [ns]: recovered or left out (the base of the log times
        :meth:`SkippedChunk.describe` gives)."""
        times = [t for t in (self.first_ns, *(k.first_ns for k in self.skipped)) if t is not None]
        return min(times) if times else None

    @property
    def total(self) -> int:
        """Messages recovered in all topics."""
        return sum(self.counts.values())

    def _add(self, topic: str, log_ns: int, data: bytes, keep: bool) -> None:
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self.first_ns = log_ns if self.first_ns is None else min(self.first_ns, log_ns)
        self.last_ns = log_ns if self.last_ns is None else max(self.last_ns, log_ns)
        if keep:
            self.messages.append((topic, log_ns, data))

    def where_it_ends(self) -> str:
        """Where the file ends, for a warning: e.g. ``run_0.mcap ends at byte 411011 without its
        footer (last complete record ends at byte 409876)``."""
        if self.storage == "mcap":
            return (f"{self.path.name} ends at byte {self.file_size} without its MCAP footer (complete "
                    f"records up to byte {self.readable_bytes})")
        return (f"{self.path.name} has {self.file_size} bytes but its SQLite header declares "
                f"{self.declared_bytes} (read {self.readable_bytes} bytes of whole pages)")


def storage_files(bag: Path) -> list[Path]:
    """The ``.mcap`` / ``.db3`` files of a bag directory, in split order (``name_0``, ``name_1``, ...)."""

    def order(p: Path) -> tuple[int, str]:
        m = re.search(r"_(\d+)$", p.stem)
        return (int(m.group(1)) if m else -1, p.name)

    return sorted((p for p in bag.iterdir() if p.suffix in _SUFFIX_STORAGE and p.is_file()), key=order)


def is_truncated(path: Path) -> bool:
    """Whether a storage file is cut short: an MCAP file not ending in the MCAP magic, an SQLite
    file shorter than its header's page count × page size. Cheap (reads at most 100 bytes)."""
    size = path.stat().st_size
    with path.open("rb") as f:
        head = f.read(100)
        if path.suffix == ".mcap":
            if size < 2 * len(_MCAP_MAGIC) or not head.startswith(_MCAP_MAGIC):
                return head.startswith(_MCAP_MAGIC[:size]) and size > 0
            f.seek(-len(_MCAP_MAGIC), io.SEEK_END)
            return f.read() != _MCAP_MAGIC
    pages = _sqlite_pages(head)
    return pages is not None and size < pages[0] * pages[1]


def _sqlite_pages(head: bytes) -> tuple[int, int] | None:
    """(page size [bytes], page count) of an SQLite header; None when it is not an SQLite header."""
    if len(head) < 32 or not head.startswith(_SQLITE_MAGIC):
        return None
    page = struct.unpack(">H", head[16:18])[0]
    return (65536 if page == 1 else page), struct.unpack(">I", head[28:32])[0]


def _parse_qos(text: str) -> tuple[Any, ...]:
    """Offered QoS profiles stored with a topic (YAML), parsed by rosbags; () when absent or unreadable."""
    from rosbags.rosbag2 import ReaderError
    from rosbags.rosbag2.metadata import parse_qos

    try:
        return tuple(parse_qos(text)) if text else ()
    except (ReaderError, KeyError, ValueError, TypeError, AttributeError):
        return ()


def _parse_stored_metadata(text: str | None) -> dict[str, Any] | None:
    import yaml

    from aeropend_sim.files.safe_yaml import parse_yaml

    if not text:
        return None
    try:
        doc = parse_yaml(text, "the metadata stored in the bag", "a rosbag2 metadata record")
    except (yaml.YAMLError, ValueError):  # unreadable stored metadata: recovered from the messages
        return None
    if isinstance(doc, dict) and "rosbag2_bagfile_information" in doc:
        doc = doc["rosbag2_bagfile_information"]
    return doc if isinstance(doc, dict) else None
