"""MCAP channels carry the RIHS01 type hash as rosbag2 Jazzy writes it (issue 17, item 7).

The bag is read with the independent ``mcap`` reader (not rosbags), and the hash is compared
with the one rclpy's middleware announces for the same message type on a live publisher, so
the check does not rest on rosbags' own hash computation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from aeropend_ident.io.bag_writer import write_bag
from aeropend_ident.io.mcap_jazzy import OFFERED_QOS_KEY, TOPIC_TYPE_HASH_KEY
from aeropend_sim.contract import TOPIC_ARMATURE, TOPIC_DUTY_CYCLE, TOPIC_JOINT_STATES
from aeropend_sim.recording import Recording
from aeropend_sim.ros.harness import isolate_process, private_node, random_domain


def _bag(tmp_path: Path, storage: str) -> Path:
    n = 50
    t = np.arange(n) * 2.048e-3
    rec = Recording(t=t, duty=np.full(n, 0.4), channels={"theta": np.linspace(0.0, 0.1, n)}, source="test")
    path = tmp_path / f"bag_{storage}"
    write_bag(rec, path, storage=storage)
    return path


def _channel_metadata(bag: Path) -> dict[str, dict[str, str]]:
    (mcap_file,) = bag.glob("*.mcap")
    with mcap_file.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return {c.topic: dict(c.metadata) for c in summary.channels.values()}


def _yaml_hashes(bag: Path) -> dict[str, str]:
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {t["topic_metadata"]["name"]: t["topic_metadata"]["type_description_hash"]
            for t in info["topics_with_message_count"]}


def test_mcap_channels_carry_topic_type_hash_equal_to_metadata_yaml(tmp_path: Path) -> None:
    bag = _bag(tmp_path, "mcap")
    meta = _channel_metadata(bag)
    hashes = _yaml_hashes(bag)
    assert set(meta) == {TOPIC_JOINT_STATES, TOPIC_ARMATURE, TOPIC_DUTY_CYCLE}
    for topic, keys in meta.items():
        assert set(keys) == {OFFERED_QOS_KEY, TOPIC_TYPE_HASH_KEY}
        assert keys[TOPIC_TYPE_HASH_KEY].startswith("RIHS01_")
        assert len(keys[TOPIC_TYPE_HASH_KEY]) == len("RIHS01_") + 64
        assert keys[TOPIC_TYPE_HASH_KEY] == hashes[topic]
        assert "reliability" in keys[OFFERED_QOS_KEY]


@pytest.mark.ros
def test_type_hash_equals_the_one_rclpy_announces(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    from sensor_msgs.msg import BatteryState, JointState
    from std_msgs.msg import Float64

    meta = _channel_metadata(_bag(tmp_path, "mcap"))
    domain = random_domain()
    isolate_process(monkeypatch, domain)
    announced = {}
    with private_node("type_hash_probe", domain) as (node, _):
        for topic, msg_type in ((TOPIC_JOINT_STATES, JointState), (TOPIC_ARMATURE, BatteryState),
                                (TOPIC_DUTY_CYCLE, Float64)):
            node.create_publisher(msg_type, topic, 1)
            (info,) = node.get_publishers_info_by_topic(topic)
            announced[topic] = str(info.topic_type_hash)
    assert {t: m[TOPIC_TYPE_HASH_KEY] for t, m in meta.items()} == announced


def test_sqlite3_bags_keep_the_hash_in_metadata_yaml(tmp_path: Path) -> None:
    hashes = _yaml_hashes(_bag(tmp_path, "sqlite3"))
    assert all(h.startswith("RIHS01_") for h in hashes.values())
    assert len(hashes) == 3
