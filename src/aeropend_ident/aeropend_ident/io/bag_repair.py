"""A clean copy of a damaged bag: every recoverable message, nothing of the damage (``reindex --repair``).

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rosbags.rosbag2 import StoragePlugin

from aeropend_ident.errors import BagError
from aeropend_ident.io.bag_codec import typestore
from aeropend_ident.io.bag_recover import rebuild_metadata
from aeropend_ident.io.bag_storage import SKIPPED_KEY, StorageScan
from aeropend_ident.io.mcap_jazzy import JazzyWriter

#: ``custom_data`` key of a repaired bag: the parts of the original that were left out (JSON, as the
#: original's rebuilt metadata listed them under ``aeropend.skipped``).
REPAIRED_KEY = "aeropend.repaired_from"


def repair(bag: str | Path, out: str | Path, rebuilt: tuple[dict[str, Any], list[StorageScan]] | None = None
           ) -> tuple[Path, int, list[StorageScan]]:
    """Write a new bag at ``out`` holding every message recoverable from ``bag`` (``reindex --repair``).

    ``reindex`` leaves the storage file as it is: our readers skip a corrupt part it lists, but
    another tool (``ros2 bag play``) stops at it. The repaired bag is a clean copy: every recovered
    message of every topic (its type, serialisation and offered QoS kept, log times kept), written
    by rosbags' writer in the storage kind of the original, with the original's custom data and the
    loss count (:func:`rebuild_metadata`); the parts left out are recorded under
    :data:`REPAIRED_KEY`, not as parts to skip. The original is not changed.

    Parameters
    ----------
    bag : str or Path
        The damaged bag directory.
    out : str or Path
        The new bag directory (must not exist).
    rebuilt : (dict, list of StorageScan), optional
        What :func:`rebuild_metadata` (or ``reindex(..., keep_messages=True)``) already returned for
        ``bag`` with the messages kept; None reads the files here (once, validated).

    Returns
    -------
    (Path, int, list of StorageScan)
        The repaired bag, the messages written and the scans of the original's files (what was
        left out is in their ``skipped`` and ``truncated``).

    Raises
    ------
    BagError
        ``out`` exists, ``bag`` is not a bag directory, or a topic's type is unknown to the writer.
    """
    bag, out = Path(bag), Path(out)
    if out.exists():
        raise BagError(f"'{out}' exists; reindex --repair writes a new bag directory (choose another name)")
    # one validated read of every file serves the metadata, the loss count and the copy (a SQLite3
    # row that is not a message of its topic's type is left out of the copy, as readers skip it)
    info, scans = rebuild_metadata(bag, keep_messages=True) if rebuilt is None else rebuilt
    topics = {n: t for s in scans for n, t in s.topics.items()}
    plugin = StoragePlugin.MCAP if info["storage_identifier"] == "mcap" else StoragePlugin.SQLITE3
    writer = JazzyWriter(out, version=9, storage_plugin=plugin)
    ts = typestore()
    written = 0
    try:
        writer.open()
        conns = {}
        for name, t in topics.items():
            try:
                conns[name] = writer.add_connection(name, t.msgtype, typestore=ts,
                                                    serialization_format=t.serialization_format,
                                                    offered_qos_profiles=list(t.qos))
            except KeyError as exc:
                raise BagError(f"'{bag}': topic {name} has type {t.msgtype}, which the repair's writer "
                               f"does not know ({exc})") from None
        custom = dict(info.get("custom_data") or {})
        skipped = custom.pop(SKIPPED_KEY, None)  # the new file holds no damage to skip
        if skipped is not None:
            custom[REPAIRED_KEY] = skipped  # what the original lost, kept as a record
        for key, value in custom.items():
            writer.set_custom_data(key, value)
        for topic, log_ns, data in sorted((m for s in scans for m in s.messages), key=lambda m: m[1]):
            writer.write(conns[topic], log_ns, data)
            written += 1
    finally:
        writer.close()
    return out, written, scans
