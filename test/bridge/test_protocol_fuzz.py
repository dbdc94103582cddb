"""Fuzz of the frame decoder, part 1: random byte streams never make it raise.

The no-exception fuzz is split over two files so each stays well under a minute, and over two
engines:

- **plain random inputs** (``bench.bench_bridge_decode.fuzz``): ``AEROPEND_FUZZ_INPUTS`` in all
  (default 1 000 000, the bar of issue 7), half here fed in random pieces so that frames cross
  ``feed`` calls, half in ``test_protocol_fuzz_spliced.py`` fed whole; about 10 µs each;
- **hypothesis** (its edge-case search and shrinking): ``AEROPEND_FUZZ_EXAMPLES`` in all (default
  10 000), half here on random streams, half on corrupted streams with valid frames spliced in.
  Hypothesis spends about 2 ms of its own per example (the decoder about 6 µs), which is why the
  million inputs are plain ones. ``AEROPEND_FUZZ_EXAMPLES=1000000 pytest test/bridge/test_protocol_fuzz*.py``
  runs a million of its examples (about an hour).
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

pytestmark = pytest.mark.slow


def test_random_streams_fed_in_pieces_never_raise() -> None:
    res = fuzz(FUZZ_INPUTS, seed=1, chunked=True)  # raises on an exception or a bad output
    assert res["inputs"] == FUZZ_INPUTS
    # a fifth of the inputs carry a valid sample frame: nearly all of them come out
    assert 0.19 * FUZZ_INPUTS < res["frames"] < 0.21 * FUZZ_INPUTS, res
    assert res["errors"] > FUZZ_INPUTS // 4, res  # random bytes are mostly reported as errors


@settings(max_examples=FUZZ_EXAMPLES, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(st.binary(max_size=128), st.integers(1, 48))
def test_fuzz_random_streams_never_raise(data: bytes, chunk: int) -> None:
    dec = proto.FrameDecoder()
    # Feed in chunks so that frame boundaries cross feed() calls.
    for i in range(0, len(data), chunk):
        for fr in dec.feed(data[i:i + chunk]):
            assert isinstance(fr, FRAME_TYPES)
    assert dec.stats.bytes == len(data)
