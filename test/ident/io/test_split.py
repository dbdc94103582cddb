"""Held-out designs of the gap diagnosis (aeropend_ident.io.split): block assignment, the
information rule, runs split at a label column, time-ordered split, and their errors."""

from __future__ import annotations

import numpy as np
import pytest

from aeropend_ident.io.split import informative, interleaved_blocks, split_runs, time_ordered
from aeropend_sim.recording import Recording

DT = 0.01


def _rec(duty: np.ndarray, theta: np.ndarray, source: str = "r") -> Recording:
    return Recording(t=np.arange(duty.size) * DT, duty=duty, channels={"theta": theta}, source=source)


def _staircase(n_blocks: int, block: int = 100) -> Recording:
    """A new duty level every half block, the angle following it (0.05 rad per level)."""
    levels = np.repeat(np.arange(2 * n_blocks) % 7 / 10.0, block // 2)
    return _rec(levels, 0.5 * levels)


def test_every_third_block_from_the_second_is_held_out():
    rec = _staircase(10)  # 10 blocks of 1 s
    fit, held, rule = interleaved_blocks([rec], 1.0)
    assert [h.source for h in held] == ["r[100:200]", "r[400:500]", "r[700:800]"]
    assert len(fit) == 7 and all(len(p) == 100 for p in (*fit, *held))
    assert not {p.source for p in fit} & {p.source for p in held}
    assert held[0].t[0] == 0.0 and held[0].duty[0] == rec.duty[100]  # re-based, same samples
    assert rule == "interleaved blocks of 1 s: every 3rd block (from the 2nd) held out, the others fit"
    _fit2, held2, rule2 = interleaved_blocks([rec], 1.0, every=2)
    assert len(held2) == 5 and "every 2nd block" in rule2


def test_block_folds_hold_out_every_block_exactly_once():
    """offset 0, 1, 2 of every 3rd block: the folds of a cross-validation over blocks."""
    rec = _staircase(10)
    folds = [interleaved_blocks([rec], 1.0, offset=k) for k in range(3)]
    held = [h.source for _f, hs, _r in folds for h in hs]
    assert sorted(held) == sorted(f"r[{100 * j}:{100 * (j + 1)}]" for j in range(10))  # each once
    assert [h.source for h in folds[0][1]] == ["r[0:100]", "r[300:400]", "r[600:700]", "r[900:1000]"]
    for fit, hs, _rule in folds:  # fit and held out are complementary within a fold
        assert len(fit) + len(hs) == 10 and not {p.source for p in fit} & {h.source for h in hs}
    assert [r for _f, _h, r in folds] == [
        f"interleaved blocks of 1 s: every 3rd block (from the {k}) held out, the others fit"
        for k in ("1st", "2nd", "3rd")
    ]
    default = interleaved_blocks([rec], 1.0)[1]  # offset 1: from the 2nd block
    assert [h.source for h in default] == [h.source for h in folds[1][1]]
    with pytest.raises(ValueError, match="offset 3: expected a block index in \\[0, 3\\)"):
        interleaved_blocks([rec], 1.0, offset=3)
    with pytest.raises(ValueError, match="offset -1"):
        interleaved_blocks([rec], 1.0, offset=-1)


def test_blocks_without_information_are_dropped_and_counted():
    rec = _staircase(6)
    rec.duty[200:300] = 0.3  # block 2: constant input -> dropped silently
    rec.channels["theta"][300:400] = 0.1 + 0.001 * np.sin(np.arange(100))  # block 3: rod on a stop
    fit, held, rule = interleaved_blocks([rec], 1.0, min_range=0.02)
    sources = {p.source for p in (*fit, *held)}
    assert "r[200:300]" not in sources and "r[300:400]" not in sources
    assert [h.source for h in held] == ["r[100:200]", "r[400:500]"]  # assignment by block index
    assert "1 block(s) with a recorded angle range below 0.02 rad" in rule
    # without the angle rule the resting block stays
    fit0, _held0, _ = interleaved_blocks([rec], 1.0)
    assert "r[300:400]" in {p.source for p in fit0}


def test_short_last_block_dropped_and_several_recordings():
    a, b = _staircase(3), _staircase(2)
    b.source = "s"
    a_long = _rec(np.concatenate([a.duty, a.duty[:40]]), np.concatenate([a.channels["theta"], np.zeros(40)]))
    fit, held, _ = interleaved_blocks([a_long, b], 1.0)
    assert len(fit) + len(held) == 5  # 40-sample tail (< half a block) dropped
    assert [h.source for h in held] == ["r[100:200]", "s[100:200]"]


def test_informative():
    flat = _rec(np.full(50, 0.4), np.linspace(0, 1, 50))
    assert not informative(flat)
    still = _rec(np.r_[np.zeros(25), np.ones(25)], np.full(50, 0.2))
    assert informative(still) and not informative(still, 0.02)


def test_split_runs_at_label_changes():
    rec = _staircase(3)
    labels = np.repeat([1, 1, 2, 7, 7, 7], 50)
    runs = split_runs(rec, labels)
    assert [len(r) for r in runs] == [100, 50, 150]
    assert np.array_equal(runs[2].duty, rec.duty[150:])
    assert [len(r) for r in split_runs(rec, labels, min_samples=60)] == [100, 150]
    with pytest.raises(ValueError, match=r"\(299,\) run labels for 300 samples"):
        split_runs(rec, labels[:-1])
    with pytest.raises(ValueError, match="min_samples 1: expected >= 2"):
        split_runs(rec, labels, min_samples=1)


def test_time_ordered_and_errors():
    rec = _staircase(5)
    fit, held, rule = time_ordered([rec], 0.7)
    assert (len(fit[0]), len(held[0])) == (350, 150) and rule.startswith("time-ordered split: first 70%")
    with pytest.raises(ValueError, match=r"1\.2: expected a fraction in"):
        time_ordered([rec], 1.2)
    with pytest.raises(ValueError, match="block length -1"):
        interleaved_blocks([rec], -1.0)
    with pytest.raises(ValueError, match="every 1"):
        interleaved_blocks([rec], 1.0, every=1)
    with pytest.raises(ValueError, match=r"min_range -0\.1"):
        interleaved_blocks([rec], 1.0, min_range=-0.1)
