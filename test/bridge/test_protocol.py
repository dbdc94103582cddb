"""Python codec of the serial protocol: golden vectors, round trips, decoder fuzzing.

The no-exception fuzz (1e6 plain random inputs and 1e4 hypothesis examples) is in
``test_protocol_fuzz.py`` and ``test_protocol_fuzz_spliced.py``; the frames-in-noise property here
runs ``AEROPEND_FUZZ_EXAMPLES // 2`` hypothesis examples (default 5000).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aeropend_bridge import protocol as proto

ROOT = Path(__file__).resolve().parents[2]
VECTORS = json.loads((ROOT / "firmware" / "test_vectors.json").read_text())
FUZZ_EXAMPLES = int(os.environ.get("AEROPEND_FUZZ_EXAMPLES", "10000"))
CLASSES = {c.__name__: c for c in (proto.SampleFrame, proto.StatusFrame, proto.Duty, proto.Enable,
                                   proto.Rate, proto.Calibrate)}


def test_crc_check_value_and_vectors() -> None:
    assert proto.crc16(b"123456789") == 0x29B1
    for v in VECTORS["crc16"]:
        assert proto.crc16(bytes.fromhex(v["data"])) == v["crc"], v
    # continuing from a previous result equals checking the concatenation (streaming use)
    assert proto.crc16(b"56789", proto.crc16(b"1234")) == 0x29B1


def test_cobs_vectors_round_trip() -> None:
    for v in VECTORS["cobs"]:
        raw, enc = bytes.fromhex(v["raw"]), bytes.fromhex(v["encoded"])
        assert proto.cobs_encode(raw) == enc
        assert proto.cobs_decode(enc) == raw
        assert 0 not in enc


@pytest.mark.parametrize("vec", VECTORS["frames"], ids=lambda v: v["name"])
def test_frame_vectors(vec: dict) -> None:
    frame = CLASSES[vec["type"]](**vec["fields"])
    assert frame.payload().hex() == vec["payload"]
    assert proto.encode(frame).hex() == vec["wire"]
    dec = proto.FrameDecoder()
    assert dec.feed(bytes.fromhex(vec["wire"])) == [frame]
    assert asdict(proto.parse_payload(bytes.fromhex(vec["payload"]))) == vec["fields"]


@pytest.mark.parametrize("vec", VECTORS["invalid"], ids=lambda v: v["name"])
def test_invalid_vectors_counted(vec: dict) -> None:
    dec = proto.FrameDecoder()
    assert dec.feed(bytes.fromhex(vec["wire"])) == []
    s = dec.stats
    got = {"crc": s.crc_errors, "cobs": s.cobs_errors, "length": s.length_errors, "type": s.type_errors}
    assert got[vec["error"]] == 1 and s.errors == 1, (got, s.last_error)
    assert s.last_error


def test_sample_field_range_and_duty_validation() -> None:
    with pytest.raises(proto.ProtocolError, match="out of range"):
        proto.SampleFrame(1, 2, 3, 4, 5, 2**32, 0).payload()
    for bad in (math.nan, math.inf, -0.01, 1.5):
        with pytest.raises(proto.ProtocolError, match=repr(bad)):
            proto.Duty.from_fraction(bad)
    assert proto.Duty.from_fraction(1.0).value == 65535
    with pytest.raises(proto.ProtocolError, match="divider 0"):
        proto.Rate(0).payload()
    with pytest.raises(proto.ProtocolError, match="item 9"):
        proto.Calibrate(9, 0).payload()


def test_oversize_and_split_feeding() -> None:
    dec = proto.FrameDecoder()
    f = proto.SampleFrame(7, 123, 1, -2, 3, 4, 5, 1)
    wire = proto.encode(f)
    stream = b"\x01" * 500 + b"\x00" + wire + wire
    out = []
    for i in range(len(stream)):  # byte by byte
        out += dec.feed(stream[i:i + 1])
    assert out == [f, f]
    assert dec.stats.oversize == 1


def test_corruption_single_byte_always_detected() -> None:
    """Every single-byte corruption of a frame (any position, any value) is rejected."""
    wire = proto.encode(proto.SampleFrame(513, 99999, 100, -100, 700, 12345, 200, 1))
    for pos in range(len(wire) - 1):
        for val in range(256):
            if val == wire[pos]:
                continue
            bad = bytearray(wire)
            bad[pos] = val
            dec = proto.FrameDecoder()
            assert dec.feed(bytes(bad)) == [], (pos, val)
            assert dec.stats.errors >= 1


_sample = st.builds(proto.SampleFrame, st.integers(0, 0xFFFF), st.integers(0, 2**32 - 1),
                    st.integers(-1023, 1023), st.integers(-512, 511), st.integers(0, 1023),
                    st.integers(0, 2**32 - 1), st.integers(0, 255), st.integers(0, 15))


@pytest.mark.slow
@settings(max_examples=max(FUZZ_EXAMPLES // 2, 200), deadline=None, database=None,
          suppress_health_check=list(HealthCheck))
@given(st.lists(st.tuples(st.binary(max_size=60), _sample), min_size=1, max_size=8), st.binary(max_size=60))
def test_fuzz_frames_in_noise_all_recovered(
    parts: list[tuple[bytes, proto.SampleFrame]], tail: bytes
) -> None:
    stream = bytearray()
    for noise, frame in parts:
        stream += noise + b"\x00" + proto.encode(frame)
    stream += tail
    dec = proto.FrameDecoder()
    got = dec.feed(bytes(stream))
    it = iter(got)
    for _, frame in parts:  # every embedded frame comes out, in order (noise may add frames)
        assert any(g == frame for g in it), frame
