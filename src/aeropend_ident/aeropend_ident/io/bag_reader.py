"""Raw bag reading (pure Python, no rclpy): the one reader of every tool, and its errors.

:class:`RawBagReader` gives the serialised messages of a rosbag2 bag (MCAP or SQLite3) in log-time
order, through rosbags' ``AnyReader`` or, for a storage file cut short, the recovery scan of
:mod:`aeropend_ident.io.bag_recover`; :func:`bag_metadata` reads ``metadata.yaml``;
:func:`playback_deadlines` times a replay. Decoding the contract topics into a
:class:`~aeropend_sim.recording.Recording` is :func:`aeropend_ident.io.bags.read_bag`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from rosbags.interfaces import Qos

from aeropend_ident.errors import BagError, BagTruncatedWarning
from aeropend_ident.io.bag_codec import typestore
from aeropend_ident.io.bag_recover import scan_storage, stored_metadata
from aeropend_ident.io.bag_storage import METADATA_FILE, SKIPPED_KEY, is_truncated, storage_files

#: Storage plugins of a rosbag2 bag.
Storage = Literal["mcap", "sqlite3"]


def bag_metadata(path: str | Path) -> dict[str, Any]:
    """``rosbag2_bagfile_information`` of a bag directory's ``metadata.yaml``.

    Raises
    ------
    BagError
        If ``path`` has no readable ``metadata.yaml``.
    """
    import yaml

    from aeropend_sim.files.safe_yaml import load_yaml

    path = Path(path)
    meta_file = path / METADATA_FILE
    try:
        doc = load_yaml(meta_file, "a rosbag2 metadata.yaml")
        return dict(doc["rosbag2_bagfile_information"])
    except (OSError, ValueError, yaml.YAMLError, KeyError, TypeError) as exc:
        raise BagError(f"bag '{path}': cannot read {meta_file.name}: {exc}") from exc


def corruption_error(path: Path, what: str, log_ns: int | None = None) -> BagError:
    """A bag that cannot be read: where its storage is corrupt (byte ranges, log times, messages, from
    :func:`~aeropend_ident.io.bag_recover.scan_storage`) and that ``reindex`` recovers the rest.

    Parameters
    ----------
    path : Path
        Bag directory or storage file.
    what : str
        What failed (``a message of /aeropend/joint_states cannot be decoded (...)``).
    log_ns : int, optional
        Log time [ns] of the message that failed: the chunk holding it is named.
    """
    bag = path if path.is_dir() else path.parent
    fix = f"'reindex --overwrite {bag}' leaves the corrupt part(s) out and keeps every intact message"
    parts: list[str] = []
    try:
        files = storage_files(path) if path.is_dir() else [path]
        scans = [scan_storage(p, keep_messages=False, validate=True) for p in files]
    except BagError as exc:
        return BagError(f"bag '{path}' is corrupt: {what}; {exc}")
    for s in scans:
        parts += [f"{s.path.name} {k.describe(s.t0_ns)}" for k in s.skipped]
    if parts:
        return BagError(f"bag '{path}' is corrupt: {what}; {'; '.join(parts)}; {fix}")
    held = [f"bytes {a}-{b} of {s.path.name}" for s in scans for a, b, t0, t1 in s.chunks
            if log_ns is not None and t0 <= log_ns <= t1]
    place = f"; the message lies in {' or '.join(held)}" if held else ""
    return BagError(f"bag '{path}' is corrupt: {what}{place}; its chunks carry no CRC (an older writer), so "
                    "reindex cannot tell which is damaged: cut the bag before that point or record again")


def _open_error(path: Path, exc: BaseException) -> BagError:
    if path.is_dir() or path.suffix in (".mcap", ".db3"):
        return corruption_error(path, f"its storage cannot be opened ({type(exc).__name__}: {exc})")
    return BagError(f"'{path}' is not a readable rosbag2 bag ({type(exc).__name__}: {exc}); expected a bag "
                    "directory with metadata.yaml and .mcap/.db3 storage, or a .mcap/.db3 file")


def _missing_metadata_error(path: Path) -> BagError:
    """What to do with a bag directory without ``metadata.yaml`` (the recorder did not close it)."""
    files = storage_files(path)
    if not files:
        return BagError(f"'{path}' is not a rosbag2 bag: the directory has no {METADATA_FILE} and no "
                        ".mcap/.db3 storage file")
    if len(files) == 1:
        return BagError(f"bag '{path}' has no {METADATA_FILE}: give its storage file instead ({files[0]}) or "
                        f"rebuild the metadata with 'reindex {path}'")
    return BagError(f"bag '{path}' has no {METADATA_FILE}: rebuild it with 'reindex {path}' (the bag has "
                    f"{len(files)} storage files, {files[0].name} ... {files[-1].name}; one given alone "
                    "reads only its part)")


@dataclass(frozen=True)
class BagTopic:
    """A topic of a bag: message type, offered QoS profiles and message count."""

    name: str
    msgtype: str
    qos: tuple[Qos, ...]
    count: int


class RawBagReader:
    """Raw (serialised) messages of a bag in log-time order: the one reader of every tool.

    :func:`aeropend_ident.io.bags.read_bag` (so ``identify``, ``baseline``, ``gap``, ``compare``) and
    the player read bags through it. A bag whose storage is complete is read with rosbags' ``AnyReader``
    (streamed). A storage file cut short (no MCAP footer, an SQLite3 file shorter than its header
    says) is read with :func:`aeropend_ident.io.bag_recover.scan_storage`: every complete message
    is kept, :attr:`recovery` describes what was recovered and where the file ends, and a
    :class:`~aeropend_ident.errors.BagTruncatedWarning` says so.

    Parameters
    ----------
    path : str or Path
        Bag directory (with ``metadata.yaml``) or a ``.mcap`` / ``.db3`` file, read directly.
    topics : sequence of str, optional
        Topics to read (default all).

    Attributes
    ----------
    topics : dict of str -> BagTopic
        The topics read, with type, offered QoS and message count (declared by the bag, or
        recovered from a truncated one).
    storage : {"mcap", "sqlite3"}
        Storage plugin.
    custom_data : dict
        ``custom_data`` of the bag's metadata (``metadata.yaml``, or the metadata stored inside a
        storage file given directly; empty when there is none).
    recovery : dict or None
        For a truncated bag: ``files`` (each with ``file``, ``file_size``, ``readable_bytes``,
        ``declared_bytes``), ``recovered`` (per topic), ``recovered_total``, ``declared_total``
        (``metadata.yaml``'s count, None without it), ``first_log_ns``, ``last_log_ns``;
        None for a complete bag.

    Raises
    ------
    BagError
        ``path`` does not exist, is a directory without ``metadata.yaml`` (the message says to
        give the storage file or run ``reindex``), cannot be opened, has no recoverable message,
        or lacks a requested topic.
    """

    def __init__(self, path: str | Path, topics: Sequence[str] | None = None) -> None:
        from rosbags.highlevel import AnyReader

        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"bag '{self.path}' does not exist")
        if self.path.is_dir() and not (self.path / METADATA_FILE).exists():
            raise _missing_metadata_error(self.path)
        self._reader: Any = None
        self._recovered: list[tuple[str, int, bytes]] | None = None
        self._stored: dict[str, Any] | None = None
        self.recovery: dict[str, Any] | None = None
        files = self._storage_paths()
        self.storage: Storage = "mcap" if any(p.suffix == ".mcap" for p in files) else "sqlite3"
        if any(p.is_file() and is_truncated(p) for p in files) or self._reindexed_skipping():
            # not AnyReader: SQLite would read a page cut in the middle zero-filled
            found = self._recover(files)
        else:
            try:
                reader = AnyReader([self.path], default_typestore=typestore())
                reader.open()
            except Exception as exc:
                raise _open_error(self.path, exc) from exc
            self._reader = reader
            found = {}
            for c in reader.connections:
                qos = tuple(getattr(c.ext, "offered_qos_profiles", ()) or ())
                old = found.get(c.topic)
                found[c.topic] = BagTopic(c.topic, c.msgtype, qos if old is None else old.qos + qos,
                                          int(c.msgcount) + (old.count if old else 0))
        self.custom_data = self._custom_data()
        present = sorted(found)
        if topics:
            missing = [t for t in topics if t not in found]
            if missing:
                self.close()
                raise BagError(f"bag '{self.path}' has no topic(s) {missing} (topics present: {present})")
            found = {t: found[t] for t in topics}
        self.topics: dict[str, BagTopic] = found

    def _reindexed_skipping(self) -> bool:
        """``reindex`` left corrupt parts of this bag out (``metadata.yaml`` lists them)."""
        if not self.path.is_dir():
            return False
        try:
            custom = bag_metadata(self.path).get("custom_data") or {}
        except BagError:
            return False
        return isinstance(custom, dict) and SKIPPED_KEY in custom

    def _storage_paths(self) -> list[Path]:
        """The storage files: the file given, or those metadata.yaml lists."""
        if not self.path.is_dir():
            return [self.path]
        try:
            names = bag_metadata(self.path).get("relative_file_paths") or []
            return [self.path / Path(str(n)).name for n in names]
        except (BagError, AttributeError, TypeError):
            return []

    def _custom_data(self) -> dict[str, Any]:
        """``custom_data`` of metadata.yaml, or of the metadata stored in a storage file given alone."""
        if self.path.is_dir():
            try:
                custom = bag_metadata(self.path).get("custom_data")
            except BagError:
                custom = None
        else:
            stored = self._stored if self._recovered is not None else stored_metadata(self.path)
            custom = (stored or {}).get("custom_data")
        return dict(custom) if isinstance(custom, dict) else {}

    def _recover(self, files: list[Path]) -> dict[str, BagTopic]:
        """Read what is readable of truncated storage files; warn how much and where they end."""
        scans = [scan_storage(p, validate=self._reindexed_skipping()) for p in files]
        self._stored = next((s.stored_metadata for s in scans if s.stored_metadata), None)
        found: dict[str, BagTopic] = {}
        counts: dict[str, int] = {}
        for s in scans:
            for name, t in s.topics.items():
                counts[name] = counts.get(name, 0) + s.counts.get(name, 0)
                found.setdefault(name, BagTopic(name, t.msgtype, t.qos, 0))
        found = {n: BagTopic(n, t.msgtype, t.qos, counts[n]) for n, t in found.items()}
        self._recovered = sorted((m for s in scans for m in s.messages), key=lambda m: m[1])
        total = len(self._recovered)
        declared = None
        if self.path.is_dir():
            try:
                declared = int(bag_metadata(self.path).get("message_count"))
            except (BagError, TypeError, ValueError):
                declared = None
        cut = [s for s in scans if s.truncated]
        where = "; ".join([s.where_it_ends() for s in cut]
                          + [f"{s.path.name} {k.describe(s.t0_ns)}" for s in scans for k in s.skipped])
        state = "is truncated" if cut else "has corrupt parts, left out"
        if total == 0:
            raise BagError(f"bag '{self.path}' {state}: {where}; no complete message could be recovered")
        first, last = self._recovered[0][1], self._recovered[-1][1]
        self.recovery = {
            "files": [{"file": str(s.path), "file_size": s.file_size, "readable_bytes": s.readable_bytes,
                       "declared_bytes": s.declared_bytes} for s in cut],
            "recovered": counts, "recovered_total": total, "declared_total": declared,
            "first_log_ns": first, "last_log_ns": last,
        }
        per_topic = ", ".join(f"{n} {c}" for n, c in counts.items())
        lost = "" if declared is None else f"; {METADATA_FILE} declares {declared}, {declared - total} lost"
        self.recovery["skipped"] = [f"{s.path.name} {k.describe(s.t0_ns)}" for s in scans for k in s.skipped]
        warnings.warn(f"bag '{self.path}' {state}: {where}; recovered {total} message(s) ({per_topic}) "
                      f"up to log time {last} ns ({(last - first) / 1e9:.3f} s after the first){lost}",
                      BagTruncatedWarning, stacklevel=3)
        return found

    def messages(self, topics: Sequence[str] | None = None) -> Any:
        """Yield ``(topic, log_time_ns, raw_bytes)`` in log-time order.

        Parameters
        ----------
        topics : sequence of str, optional
            Only these of :attr:`topics` (default all of them).

        Raises
        ------
        BagError
            If the storage turns out to be corrupt while reading.
        """
        wanted = set(self.topics if topics is None else topics) & set(self.topics)
        if self._recovered is not None:
            for topic, logtime, raw in self._recovered:
                if topic in wanted:
                    yield topic, logtime, raw
            return
        conns = [c for c in self._reader.connections if c.topic in wanted]
        if not conns:
            return
        try:
            for conn, logtime, raw in self._reader.messages(connections=conns):
                yield conn.topic, int(logtime), bytes(raw)
        except BagError:
            raise
        except Exception as exc:
            raise corruption_error(self.path, f"reading failed ({type(exc).__name__}: {exc})") from exc

    def close(self) -> None:
        """Close the underlying reader (the recovered messages stay readable)."""
        if self._reader is not None:
            try:
                self._reader.close()
            except Exception:
                pass
            self._reader = None

    def __enter__(self) -> RawBagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def playback_deadlines(log_times_ns: Sequence[int] | np.ndarray, rate: float) -> np.ndarray:
    """Wall-clock offsets [ns] from the start at which each message is due on replay.

    Parameters
    ----------
    log_times_ns : array of int, shape (M,)
        Log times of the messages, in replay order.
    rate : float
        Playback speed factor (> 0; 2.0 = twice as fast).

    Returns
    -------
    ndarray of int64, shape (M,)
        ``(log_k − log_0) / rate``, rounded to ns. Sleeping until ``start + offset_k`` (absolute
        deadlines) keeps timing errors from accumulating.

    Raises
    ------
    ValueError
        If ``rate`` is not a positive finite number.
    """
    if not (rate > 0 and math.isfinite(rate)):
        raise ValueError(f"playback rate {rate!r} must be a positive finite number")
    t = np.asarray(log_times_ns, dtype=np.int64)
    if t.size == 0:
        return t
    return np.round((t - t[0]) / rate).astype(np.int64)
