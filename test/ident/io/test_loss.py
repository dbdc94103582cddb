"""Message loss counted while recording and checked by readers (issue 62 item 2)."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.errors import BagLossWarning
from aeropend_ident.io.bag_codec import encode_armature, encode_float64, encode_joint_states
from aeropend_ident.io.bag_writer import BagSink
from aeropend_ident.io.bags import read_bag
from aeropend_ident.io.integrity.loss import LOSS_KEY, LossCounter, loss_text, loss_warning
from aeropend_sim.contract import (
    TOPIC_ARMATURE,
    TOPIC_DUTY_CYCLE,
    TOPIC_JOINT_STATES,
    TYPE_ARMATURE,
    TYPE_DUTY_CYCLE,
    TYPE_JOINT_STATES,
)

T0 = 1_700_000_000_000_000_000
PERIOD = 20_000_000  # 50 Hz


def _stamped(k: int) -> bytes:
    return b"\x00\x01\x00\x00" + struct.pack("<iI", *divmod(T0 + k * PERIOD, 1_000_000_000)) + b"\x00" * 8


def test_stamps_and_sequence_counted() -> None:
    c = LossCounter(stamped=lambda t: t in ("js", "arm"))
    dropped = {300, 301, 302, 303, 304, 700, 701, 702, 703, 704, 900, 901, 902, 903, 904}  # 3 gaps of 5
    for k in range(1000):
        if k not in dropped:  # lost on the way: stamps and publisher sequence both jump
            c.add("js", T0 + k * PERIOD + 1000, _stamped(k), sequence=k + 1, publisher=b"p")
    for k in range(400):  # commands: no header; 40 lost (every 10th), counted by sequence only
        if k % 10 != 5:
            c.add("cmd", T0 + k * 50_000_000, b"\x00\x01\x00\x00" + b"\x00" * 8, sequence=k + 1)
    seq = 0
    for k in range(600):  # a publisher that skipped samples itself (an overrun): stamps only
        if not 300 <= k < 360:
            seq += 1
            c.add("arm", T0 + k * PERIOD, _stamped(k), sequence=seq)
    r = c.report()
    assert r["js"] == {"received": 985, "lost": 15, "expected": 1000, "lost_by_sequence": 15,
                       "lost_by_stamps": 15, "fraction": 0.015, "method": "sequence", "period_s": 0.02,
                       "gaps": 3,
                       "first_gaps": [[5.98, 6.1, 5], [13.98, 14.1, 5], [17.98, 18.1, 5]]}
    cmd = r["cmd"]
    assert (cmd["lost"], cmd["expected"], cmd["method"], cmd["gaps"]) == (40, 400, "sequence", 40)
    assert (r["arm"]["lost"], r["arm"]["lost_by_sequence"], r["arm"]["method"]) == (60, 0, "stamps")
    assert r["arm"]["first_gaps"] == [[5.98, 7.2, 60]]
    assert loss_text({"js": r["js"]}) == "js 15 of 1000 lost (1.50 %, sequence)"
    text = loss_warning("bag 'x'", r)
    assert text is not None
    assert text.startswith("bag 'x': message loss above 1 %: js lost 15 of 1000 (1.5 %, ")
    assert "cmd lost 40 of 400 (10.0 %, counted by sequence) in 40 gap(s) at 0.200-0.300 s (1)" in text
    assert "and 35 more" in text
    assert loss_warning("bag 'x'", {"js": {**r["js"], "fraction": 0.005}}) is None


def _recorded(tmp_path: Path, drop: set[int], loss: dict | None) -> Path:
    """A bag as ``record`` writes it (no aeropend.meta), 500 samples at 50 Hz minus ``drop``."""
    sink = BagSink(tmp_path / "rec", custom_data={"aeropend.recorder": "test"})
    for topic, typ in ((TOPIC_JOINT_STATES, TYPE_JOINT_STATES), (TOPIC_ARMATURE, TYPE_ARMATURE),
                       (TOPIC_DUTY_CYCLE, TYPE_DUTY_CYCLE)):
        sink.add_topic(topic, typ)
    keep = np.array([k for k in range(500) if k not in drop])
    stamps = T0 + keep * PERIOD
    nan = np.full((len(keep), 3), np.nan)
    js = encode_joint_states(stamps, np.column_stack([np.sin(keep / 50), nan[:, :2]]), nan, nan)
    arm = encode_armature(stamps, np.full(len(keep), 1.0), np.full(len(keep), 0.5))
    cmd = encode_float64(np.full(len(keep), 0.4))
    for k, s in enumerate(stamps.tolist()):
        sink.write(TOPIC_JOINT_STATES, s, js[k])
        sink.write(TOPIC_ARMATURE, s, arm[k])
        sink.write(TOPIC_DUTY_CYCLE, s, cmd[k])
    if loss is not None:
        sink.set_custom_data(LOSS_KEY, json.dumps(loss))
    sink.close()
    return tmp_path / "rec"


def test_reader_warns_with_the_recorded_loss(tmp_path: Path) -> None:
    report = {TOPIC_DUTY_CYCLE: {"received": 500, "lost": 25, "expected": 525, "fraction": 25 / 525,
                                 "method": "sequence", "gaps": 2,
                                 "first_gaps": [[1.0, 1.5, 20], [4.0, 4.2, 5]]}}
    with pytest.warns(BagLossWarning) as w:
        rec = read_bag(_recorded(tmp_path, set(), report))
    assert str(w[0].message) == (
        f"bag '{tmp_path / 'rec'}': message loss above 1 %: {TOPIC_DUTY_CYCLE} lost 25 of 525 (4.8 %, "
        "counted by sequence) in 2 gap(s) at 1.000-1.500 s (20), 4.000-4.200 s (5); the model sees these "
        "stretches without data")
    assert rec.meta["loss"] == report


def test_reader_counts_stamp_gaps_of_a_recording_without_count(tmp_path: Path) -> None:
    drop = set(range(200, 210)) | {400}  # 11 of 500 samples
    with pytest.warns(BagLossWarning, match=r"joint_states lost 11 of 500 \(2\.2 %, counted by stamps\) in 2 "
                                            r"gap\(s\) at 3\.980-4\.200 s \(10\), 7\.980-8\.020 s \(1\)"):
        rec = read_bag(_recorded(tmp_path, drop, None))
    assert len(rec) == 489 and rec.meta["loss"][TOPIC_JOINT_STATES]["lost"] == 11


def test_no_warning_below_threshold(tmp_path: Path, recwarn: pytest.WarningsRecorder) -> None:
    rec = read_bag(_recorded(tmp_path, {250}, None))  # 1 of 500: 0.2 %
    assert rec.meta["loss"][TOPIC_JOINT_STATES]["lost"] == 1
    assert not [w for w in recwarn if issubclass(w.category, BagLossWarning)]
