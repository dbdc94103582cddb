"""Hypothesis fuzz of the frame decoder: random byte streams never make it raise.

Runs ``AEROPEND_FUZZ_EXAMPLES`` examples (default 100 000, ≈ 45 s). For 1e6:
``AEROPEND_FUZZ_EXAMPLES=1000000 pytest test/test_protocol_fuzz.py`` (≈ 8 min), or
``python bench/bench_bridge_decode.py --fuzz 1000000`` (plain random inputs, no hypothesis
overhead, ≈ 1 min).
"""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from aeropend_bridge import protocol as proto

FUZZ_EXAMPLES = int(os.environ.get("AEROPEND_FUZZ_EXAMPLES", "100000"))
FRAME_TYPES = (proto.SampleFrame, proto.StatusFrame, proto.Duty, proto.Enable, proto.Rate, proto.Calibrate)

pytestmark = pytest.mark.slow

_FUZZ = settings(max_examples=FUZZ_EXAMPLES, deadline=None, database=None,
                 suppress_health_check=list(HealthCheck))


@_FUZZ
@given(st.binary(max_size=128), st.integers(1, 48))
def test_fuzz_random_streams_never_raise(data: bytes, chunk: int) -> None:
    dec = proto.FrameDecoder()
    # Feed in chunks so that frame boundaries cross feed() calls.
    for i in range(0, len(data), chunk):
        for fr in dec.feed(data[i:i + chunk]):
            assert isinstance(fr, FRAME_TYPES)
    assert dec.stats.bytes == len(data)
