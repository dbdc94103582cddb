"""The ``topics`` command's text (``aeropend_ident.nodes.topic_view``): no ROS graph, no rclpy.

Messages are real generated ROS 2 classes (importing them needs no running ROS); the expected
text is what ``ros2 topic echo`` prints for them.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

pytest.importorskip("sensor_msgs")

from sensor_msgs.msg import BatteryState, Image, Imu, JointState
from std_msgs.msg import Float64, Float64MultiArray

from aeropend_ident.nodes.topic_view import (
    DEFAULT_TRUNCATE,
    RateStats,
    TopicRow,
    format_rate,
    message_to_dict,
    message_to_yaml,
    rate_stats,
    topic_table,
)


def _joint_state() -> JointState:
    msg = JointState(name=["pendulum", "motor", "propeller"], position=[0.25, math.nan, -1.5],
                     velocity=[0.0, 12.5, 0.0], effort=[0.4])
    msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id = 3, 6_144_000, "aeropend"
    return msg


def test_joint_state_prints_as_ros2_topic_echo() -> None:
    assert message_to_yaml(_joint_state()) == (
        "header:\n"
        "  stamp:\n"
        "    sec: 3\n"
        "    nanosec: 6144000\n"
        "  frame_id: aeropend\n"
        "name:\n"
        "- pendulum\n"
        "- motor\n"
        "- propeller\n"
        "position:\n"
        "- 0.25\n"
        "- .nan\n"
        "- -1.5\n"
        "velocity:\n"
        "- 0.0\n"
        "- 12.5\n"
        "- 0.0\n"
        "effort:\n"
        "- 0.4\n"
    )
    assert message_to_yaml(Float64(data=0.43)) == "data: 0.43\n"
    flow = message_to_yaml(_joint_state(), flow_style=True)
    assert flow.startswith("{header: {stamp: {sec: 3, nanosec: 6144000}, frame_id: aeropend}, name: [")


def test_yaml_reads_back_the_values() -> None:
    msg = BatteryState(voltage=1.25, current=0.7, temperature=math.nan, present=True,
                       cell_voltage=[3.5, 3.25])
    msg.header.frame_id = "aeropend"
    back = yaml.safe_load(message_to_yaml(msg))
    assert list(back) == list(BatteryState.get_fields_and_field_types())  # field order kept
    assert back["voltage"] == 1.25 and back["present"] is True and back["cell_voltage"] == [3.5, 3.25]
    assert back["current"] == pytest.approx(0.7, rel=1e-7)  # float32 on the wire
    assert math.isnan(back["temperature"])  # the contract's "not measured" NaN, as .nan
    assert back["header"] == {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": "aeropend"}


def test_long_sequences_and_strings_are_cut_like_ros2() -> None:
    msg = Float64MultiArray(data=[float(k) for k in range(200)])
    data = message_to_dict(msg)["data"]
    assert len(data) == DEFAULT_TRUNCATE + 1 and data[-1] == "..." and data[127] == 127.0
    assert len(message_to_dict(msg, truncate=None)["data"]) == 200
    assert message_to_dict(msg, no_arr=True)["data"] == "<sequence type: double, length: 200>"
    js = JointState()
    js.header.frame_id = "x" * 300
    assert message_to_dict(js, truncate=10)["header"]["frame_id"] == "x" * 10 + "..."
    assert message_to_dict(js, no_str=True)["header"]["frame_id"] == "<string length: 300>"


def test_fixed_arrays_and_bytes_become_plain_lists() -> None:
    imu = Imu()
    imu.orientation_covariance = np.arange(9, dtype=float)
    d = message_to_dict(imu)
    assert d["orientation_covariance"] == [float(k) for k in range(9)]
    assert all(type(v) is float for v in d["orientation_covariance"])  # no NumPy scalars in the YAML
    assert message_to_dict(imu, no_arr=True)["orientation_covariance"] == "<sequence type: double, length: 9>"
    img = Image(height=1, width=3, encoding="mono8", step=3, data=[0, 128, 255])
    assert message_to_dict(img)["data"] == [0, 128, 255]
    assert yaml.safe_load(message_to_yaml(img))["data"] == [0, 128, 255]


def test_not_a_message() -> None:
    with pytest.raises(TypeError, match="dict is not a ROS 2 message"):
        message_to_dict({"data": 1.0})


def test_rate_of_the_thesis_sample_period() -> None:
    t = np.arange(489) * 2_048_000 + 5_000_000_000
    s = rate_stats(t)
    assert s.count == 489 and s.rate_hz == pytest.approx(1 / 2.048e-3, rel=1e-12)
    assert s.min_s == s.max_s == pytest.approx(2.048e-3) and s.std_s == pytest.approx(0.0, abs=1e-15)


def test_rate_with_a_lost_message_and_jitter() -> None:
    # 10 Hz with message 5 lost and 1 ms of jitter on message 2: 9 intervals over 1.0 s
    t = [k * 100_000_000 for k in range(11) if k != 5]
    t[2] += 1_000_000
    s = rate_stats(t)
    assert s.count == 10 and s.rate_hz == pytest.approx(9.0)
    assert s.min_s == pytest.approx(0.099) and s.max_s == pytest.approx(0.2)
    assert s.std_s == pytest.approx(np.std(np.diff(t) / 1e9))


def test_rate_of_too_few_messages_and_bad_times() -> None:
    assert rate_stats([]) == RateStats(0, None)
    assert rate_stats([7]) == RateStats(1, None)
    with pytest.raises(ValueError, match="must not decrease"):
        rate_stats([3, 2])


def test_rate_text() -> None:
    assert format_rate(None) == "-"
    assert format_rate(RateStats(0, None)) == "no messages"
    assert format_rate(RateStats(1, None)) == "1 msg"
    assert format_rate(rate_stats(np.arange(100) * 2_048_000)) == "488.3 Hz"


def test_topic_table() -> None:
    rows = [TopicRow("/aeropend/joint_states", ("sensor_msgs/msg/JointState",), 1, 2,
                     rate_stats(np.arange(50) * 2_048_000)),
            TopicRow("/aeropend/duty_cycle", ("std_msgs/msg/Float64",), 0, 1, RateStats(0, None)),
            TopicRow("/x", ("a/msg/B", "c/msg/D"), 2, 0, None)]
    assert topic_table(rows) == (
        "topic                   type                        rate         pub  sub\n"
        "/aeropend/joint_states  sensor_msgs/msg/JointState  488.3 Hz     1    2\n"
        "/aeropend/duty_cycle    std_msgs/msg/Float64        no messages  0    1\n"
        "/x                      a/msg/B, c/msg/D            -            2    0\n")
    assert topic_table(rows[1:2], with_rate=False) == (
        "topic                 type                  pub  sub\n"
        "/aeropend/duty_cycle  std_msgs/msg/Float64  0    1\n")
    assert topic_table([]) == ""
