"""Loop-latency bookkeeping: the plant's CommandTiming and the benchmark's command matching (no ROS)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aeropend_control.controller_core import SIGNALS
from aeropend_sim.sim_core import CommandTiming, SimConfigError
from bench.bench_control_latency import analyse, match_commands

T = 2_048_000  # ns


def test_command_timing_attribution_and_unanswered(tmp_path: Path) -> None:
    tm = CommandTiming(capacity=8)
    for k in range(6):
        tm.on_sample(10_000 + k * T, 1_000_000 + k * T)
    # sample 0 answered after 0.3 ms, sample 1 never, sample 2 late (after sample 3), 3 and 4 answered
    for recv, duty in ((1_300_000, 0.1), (1_000_000 + 3 * T + 100_000, 0.2),
                       (1_000_000 + 3 * T + 400_000, 0.3), (1_000_000 + 4 * T + 500_000, 0.4)):
        tm.on_command(recv, duty)
    s = tm.summary()
    assert s["commands_timed"] == 4 and s["unanswered"] == 2  # samples 1 and 2 got no command in their period
    assert s["lat_p50_ms"] == pytest.approx(np.percentile([0.3, 0.1, 0.4, 0.5], 50))
    assert s["lat_max_ms"] == pytest.approx(0.5)
    for _ in range(5):
        tm.on_sample(0, 0)
    assert tm.n_samples == 8 and tm.overflow == 3  # capacity respected, the rest only counted
    tm.write(str(tmp_path / "t.npz"))
    d = np.load(tmp_path / "t.npz")
    assert d["recv_ns"].size == 4 and d["duty"].tolist() == [0.1, 0.2, 0.3, 0.4]
    with pytest.raises(SimConfigError, match="capacity = 0"):
        CommandTiming(0)


def test_match_commands_by_duty_with_a_lost_command() -> None:
    ctl = np.array([0.1, 0.2, 0.2, 0.3, 0.4])
    assert match_commands(ctl, np.array([0.1, 0.2, 0.2, 0.3, 0.4])).tolist() == [0, 1, 2, 3, 4]
    assert match_commands(ctl, np.array([0.1, 0.3, 0.4, 0.0])).tolist() == [0, 3, 4, -1]
    # a lost command between equal duties: the earlier row is taken (latency over-estimated)
    assert match_commands(ctl, np.array([0.1, 0.2, 0.3])).tolist() == [0, 1, 3]


def test_analyse_latency_and_missed_samples() -> None:
    n = 10
    stamps = 5_000_000_000 + np.arange(n + 2, dtype=np.int64) * T
    taken = 1_000_000_000 + np.arange(n + 2, dtype=np.int64) * T
    duty = np.linspace(0.1, 0.5, n)
    rows = np.full((n, len(SIGNALS)), np.nan)
    rows[:, SIGNALS.index("stamp_s")] = stamps[:n] * 1e-9
    rows[:, SIGNALS.index("duty")] = duty
    rows[:, SIGNALS.index("recv_latency")] = 1e-4
    rows[:, SIGNALS.index("pub_latency")] = 3e-4
    lat = np.full(n, 400_000)
    lat[4] = T + 100_000  # sample 4 answered after sample 5 was taken
    keep = np.arange(n) != 7  # command of sample 7 lost
    timing = {"stamp_ns": stamps, "taken_ns": taken, "recv_ns": (taken[:n] + lat)[keep], "duty": duty[keep]}
    res, misses = analyse(rows, timing)
    assert res["commands_matched"] == n - 1 and res["lost_commands"] == 1
    assert res["late_commands"] == 1 and res["missed_samples"] == 2 and res["dropped_samples"] == 0
    assert res["loop_latency_sample_to_command_receipt"]["max_ms"] == pytest.approx(2.148)
    assert res["loop_latency_sample_to_command_receipt"]["p50_ms"] == pytest.approx(0.4)
    assert res["controller_compute_receipt_to_publish"]["p50_ms"] == pytest.approx(0.2)
    # each miss with its cause, window and latency split (plant on time here: lateness 0)
    assert [(m["k"], m["cause"]) for m in misses] == [(4, "late"), (7, "lost")]
    late = misses[0]
    assert late["window_ns"] == [int(taken[4]), int(taken[4] + T + 100_000)]
    assert late["latency_ms"] == pytest.approx(2.148)
    assert late["split_ms"] == pytest.approx({"plant_late": 0.0, "to_controller": 0.1,
                                              "controller_compute": 0.2, "to_plant": 2.148 - 0.3})
    assert misses[1]["window_ns"] == [int(taken[7]), int(taken[8])]


def test_misses_are_attributed_to_stalls_of_all_or_some_cpus() -> None:
    from bench.bench_control_latency import attribute, stall_intervals

    ms = 1_000_000
    misses = [{"window_ns": [a * ms, (a + 3) * ms]} for a in (0, 10, 20)]
    cpu0 = {"deadline_ns": np.array([1 * ms, 11 * ms, 30 * ms]),
            "late_ns": np.array([1 * ms, 1 * ms, 5 * ms])}
    cpu1 = {"deadline_ns": np.array([int(1.5 * ms), 50 * ms]), "late_ns": np.array([1 * ms, 200_000])}
    stalls = [stall_intervals(cpu0, 0.5), stall_intervals(cpu1, 0.5)]
    assert stalls[1].tolist() == [[int(1.5 * ms), int(2.5 * ms)]]  # the 0.2 ms wake-up is no stall
    counts = attribute(misses, stalls)
    assert counts == {"all_cpus": 1, "some_cpus": 1, "none": 1}
    assert [m["machine_stall"] for m in misses] == ["all_cpus", "some_cpus", "none"]
    assert misses[0]["longest_overlapping_stall_ms"] == pytest.approx(1.0)
