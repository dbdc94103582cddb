"""Benchmark / fuzz driver of the bridge's frame decoder (pure Python, no ROS).

Usage::

    python -m bench.bench_bridge_decode                # decode throughput of valid sample frames
    python -m bench.bench_bridge_decode --fuzz 1000000 # 1e6 random inputs: no exception escapes

Writes ``bench/results/bridge_decode.json`` with ``--save``.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import time
import typing
from pathlib import Path

from aeropend_bridge import protocol as proto


def throughput(n_frames: int = 200_000) -> dict[str, float]:
    """Decode ``n_frames`` sample frames fed in 64-byte chunks; return frames/s and MB/s."""
    wire = b"".join(proto.encode(proto.SampleFrame(k & 0xFFFF, 2048 * k, 150, 280, 512, 15000, 110, 1))
                    for k in range(1000))
    stream = wire * (n_frames // 1000)
    dec = proto.FrameDecoder()
    t0, c0 = time.perf_counter(), time.process_time()
    got = 0
    for i in range(0, len(stream), 64):
        got += len(dec.feed(stream[i:i + 64]))
    dt, dc = time.perf_counter() - t0, time.process_time() - c0
    assert got == n_frames and dec.stats.errors == 0
    # frames per CPU second does not depend on other load on the machine; per wall second does
    return {"frames": n_frames, "seconds": dt, "frames_per_s": n_frames / dt,
            "MB_per_s": len(stream) / dt / 1e6, "realtime_factor_at_488Hz": n_frames / dt / 488.28,
            "cpu_seconds": dc, "frames_per_cpu_s": n_frames / dc}


#: Every frame type the decoder can return (:data:`aeropend_bridge.protocol.Frame`).
FRAME_TYPES = typing.get_args(proto.Frame)


def fuzz(n_inputs: int, seed: int = 0, chunked: bool = False) -> dict[str, float]:
    """Feed ``n_inputs`` random byte strings (0..128 bytes, some with valid frames spliced in).

    Each input goes to a fresh :class:`~aeropend_bridge.protocol.FrameDecoder`, whole or (``chunked``)
    in random pieces of 1-48 bytes so that frames cross ``feed`` calls. An exception from the decoder
    ends the run (that is the failure the fuzz looks for); so does an output that is not a frame
    dataclass or byte counters that do not account for the input (``AssertionError`` naming the
    input's index and bytes).

    Returns
    -------
    dict
        ``inputs``, ``seconds`` (wall), ``frames`` found and ``errors`` counted over all inputs.
    """
    rng = random.Random(seed)
    valid = proto.encode(proto.SampleFrame(1, 2, 3, 4, 5, 6, 7, 0))
    t0 = time.perf_counter()
    frames = errors = 0
    for k in range(n_inputs):
        data = rng.randbytes(rng.randint(0, 128))
        if rng.random() < 0.2:
            cut = rng.randint(0, len(data))
            data = data[:cut] + b"\x00" + valid + data[cut:]
        dec = proto.FrameDecoder()
        step = rng.randint(1, 48) if chunked else max(len(data), 1)
        got = [f for i in range(0, len(data), step) for f in dec.feed(data[i:i + step])]
        bad = [f for f in got if not isinstance(f, FRAME_TYPES)]
        if bad or dec.stats.bytes != len(data):
            raise AssertionError(f"input {k} ({data.hex()}): outputs {bad!r}, {dec.stats.bytes} bytes "
                                 f"counted of {len(data)}")
        frames += len(got)
        errors += dec.stats.errors
    return {"inputs": n_inputs, "seconds": time.perf_counter() - t0, "frames": frames, "errors": errors}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fuzz", type=int, default=0, help="number of random inputs (e.g. 1000000)")
    ap.add_argument("--save", action="store_true", help="write bench/results/bridge_decode.json")
    a = ap.parse_args()
    res: dict[str, object] = {"throughput": throughput()}
    if a.fuzz:
        res["fuzz"] = fuzz(a.fuzz)
    res["host_load_avg_1min"] = os.getloadavg()[0]  # other processes on the machine skew the rates
    res["host_cpus"] = os.cpu_count()
    print(json.dumps(res, indent=1))
    if a.save:
        out = Path(__file__).parent / "results" / "bridge_decode.json"
        out.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
