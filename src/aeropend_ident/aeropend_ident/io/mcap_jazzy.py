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

from io import BytesIO
from typing import TYPE_CHECKING, ClassVar, cast

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.storage_mcap import Channel, McapWriter, write_channel, write_string

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


class JazzyWriter(Writer):
    """rosbags :class:`~rosbags.rosbag2.Writer` with :class:`JazzyMcapWriter` for MCAP storage."""

    STORAGE_PLUGINS: ClassVar[Mapping[StoragePlugin, type]] = {
        **Writer.STORAGE_PLUGINS,
        StoragePlugin.MCAP: JazzyMcapWriter,
    }
