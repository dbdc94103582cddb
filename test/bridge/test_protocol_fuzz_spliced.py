"""Fuzz of the frame decoder, part 2: corrupted streams with valid frames spliced in.

``AEROPEND_FUZZ_INPUTS // 2`` plain random inputs fed whole (default 500 000) and
``AEROPEND_FUZZ_EXAMPLES // 2`` hypothesis examples (default 5 000; see ``test_protocol_fuzz.py``).
Random bytes with encoded frames inserted at random places and random bytes overwritten:
no exception escapes, every output is a frame dataclass, and the counters account for all
input bytes.
"""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aeropend_bridge import protocol as proto
from bench.bench_bridge_decode import FRAME_TYPES, fuzz

FUZZ_INPUTS = int(os.environ.get("AEROPEND_FUZZ_INPUTS", "1000000")) // 2
FUZZ_EXAMPLES = int(os.environ.get("AEROPEND_FUZZ_EXAMPLES", "10000")) // 2
WIRES = [proto.encode(f) for f in (proto.SampleFrame(1, 2048, 100, -50, 512, 15000, 110, 1),
                                   proto.StatusFrame(1, 2, 3, 4, 5), proto.Duty(32768), proto.Rate(2),
                                   proto.Calibrate(2, -300), proto.Enable(True))]

pytestmark = pytest.mark.slow


def test_random_streams_with_a_frame_spliced_in_never_raise() -> None:
    res = fuzz(FUZZ_INPUTS, seed=2)  # raises on an exception or a bad output
    assert res["inputs"] == FUZZ_INPUTS
    assert 0.19 * FUZZ_INPUTS < res["frames"] < 0.21 * FUZZ_INPUTS, res


@settings(max_examples=FUZZ_EXAMPLES, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(st.binary(max_size=96), st.integers(0, 2**32 - 1))
def test_fuzz_spliced_corrupted_streams_never_raise(noise: bytes, knobs: int) -> None:
    data = bytearray(noise)
    wire = WIRES[knobs % len(WIRES)]
    pos = (knobs >> 3) % (len(data) + 1)
    data[pos:pos] = wire
    if knobs & 0x100 and data:  # overwrite one byte
        data[(knobs >> 9) % len(data)] = (knobs >> 20) & 0xFF
    dec = proto.FrameDecoder()
    frames = dec.feed(bytes(data))
    assert all(isinstance(f, FRAME_TYPES) for f in frames)
    assert dec.stats.bytes == len(data)
