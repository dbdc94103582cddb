"""Hypothesis fuzz of the frame decoder, part 1: random byte streams never make it raise.

The decoder fuzz is split over two files so each stays well under a minute:
this one runs ``AEROPEND_FUZZ_EXAMPLES // 2`` examples (default 50 000, ≈ 25 s) of plain
random streams, ``test_protocol_fuzz_spliced.py`` the other half on corrupted streams with
valid frames spliced in — 100 000 hypothesis examples in total. For 1e6:
``AEROPEND_FUZZ_EXAMPLES=1000000 pytest test/test_protocol_fuzz*.py`` (≈ 8 min), or
``python -m bench.bench_bridge_decode --fuzz 1000000`` (plain random inputs, no hypothesis
overhead, ≈ 5 s).
"""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aeropend_bridge import protocol as proto

FUZZ_EXAMPLES = int(os.environ.get("AEROPEND_FUZZ_EXAMPLES", "100000")) // 2
FRAME_TYPES = (proto.SampleFrame, proto.StatusFrame, proto.Duty, proto.Enable, proto.Rate, proto.Calibrate)

pytestmark = pytest.mark.slow


@settings(max_examples=FUZZ_EXAMPLES, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(st.binary(max_size=128), st.integers(1, 48))
def test_fuzz_random_streams_never_raise(data: bytes, chunk: int) -> None:
    dec = proto.FrameDecoder()
    # Feed in chunks so that frame boundaries cross feed() calls.
    for i in range(0, len(data), chunk):
        for fr in dec.feed(data[i:i + chunk]):
            assert isinstance(fr, FRAME_TYPES)
    assert dec.stats.bytes == len(data)
