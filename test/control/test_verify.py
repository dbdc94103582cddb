"""The closed-loop check's judgement (aeropend_control.verify.closed_loop): a slow creep is "not
settled", not a limit cycle; a slow pattern runs long enough to show its settling; when no pattern
settles with M_p ≤ 5 %, one whose every step ends in the band ranks before one that diverges (it
gives design_gains' attainable figures)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aeropend_control.design import PoleSpec
from aeropend_control.metrics import step_metrics
from aeropend_control.verify.closed_loop import DURATION, SETTLE_RAD, StepRun, Verdict, _judge, duration_for


def _run(status: str, ts: float, mp: float) -> StepRun:
    t = np.arange(0.0, 4.0, 0.01)
    m = step_metrics(t, 0.4 * (1.0 - np.exp(-t)), 0.4) if status != "diverged" else None
    if m is not None:
        m = type(m)(**{**m.as_dict(), "settling_time": ts, "overshoot": mp})
    return StepRun("fl_pid", 0.4, 0.4, t, np.zeros_like(t), np.zeros_like(t), m, status)


def test_a_slow_creep_is_not_a_limit_cycle_a_swing_is() -> None:
    t = np.arange(0.0, 4.0, 0.01)
    creep = 0.3 + 0.05 * t / 4.0  # rises 12 mrad over the last second, never turns back
    assert _judge(t, creep, 0.4, 0.0)[0] == "ok"  # run_step then calls it "not settled"
    swing = 0.4 + 0.02 * np.sin(2.0 * math.pi * 2.0 * t)
    status, detail = _judge(t, swing, 0.4, 0.0)
    assert status == "limit cycle" and "≈ 2 Hz" in detail  # 4 mean crossings in the last second


def test_a_slow_pattern_runs_long_enough_to_settle() -> None:
    assert duration_for(PoleSpec(9.5, 0.7, 1.0)) == DURATION
    assert math.isclose(duration_for(PoleSpec(1.6, 0.9, 1.0)), SETTLE_RAD / 1.6)


def test_ending_in_the_band_ranks_before_diverging() -> None:
    spec = PoleSpec(1.5, 0.9, 1.0)
    overshoots = Verdict("fl_pid", spec, [_run("ok", 9.0, 10.8), _run("ok", 9.6, 5.2)])
    diverges = Verdict("fl_pid", spec, [_run("diverged", math.nan, math.nan)])
    settles = Verdict("fl_pid", spec, [_run("ok", 12.0, 2.0)])
    assert not overshoots.settles and overshoots.ends_in_band and not diverges.ends_in_band
    assert settles.cost() < overshoots.cost() < diverges.cost()
    assert overshoots.cost() == (1, 9.6)


def _run_figures(r: StepRun) -> tuple:
    return r.reference, r.status, r.metrics.as_dict() if r.metrics is not None else None


@pytest.mark.slow
def test_design_gains_checks_strategies_in_worker_processes_with_the_same_verdicts(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``design_gains`` checks each strategy in a worker process of its own (spawned); the verdicts
    (every step's status and metrics, the tuned pattern) equal those checked one after the other in
    this process: each closed loop is deterministic."""
    from aeropend_control.design_gains import WORKERS_ENV, check
    from aeropend_control.strategies.fl_pid import FeedbackLinearizationPID
    from aeropend_control.strategies.small_signal import SmallSignalPID
    from aeropend_sim.params import load_rig

    rig = load_rig("thesis_rig")
    specs = {cls.name: cls.default_spec_for(rig) for cls in (FeedbackLinearizationPID, SmallSignalPID)}

    def verdicts(workers: str) -> dict:
        monkeypatch.setenv(WORKERS_ENV, workers)
        out = check(rig, specs, (0.2, 0.4), tune_specs=True)
        flat = {}
        for kind, table in out.items():
            for name, value in table.items():
                pair = value if isinstance(value, tuple) else (value,)
                flat[(kind, name)] = [v if isinstance(v, str) else (v.spec, [_run_figures(r) for r in v.runs])
                                      for v in pair]
        return flat

    here, pooled = verdicts("1"), verdicts("2")
    assert set(here) == {("tuned", "fl_pid"), ("tuned", "small_signal"), ("others", "cascade"),
                         ("others", "fl_cascade")}
    assert pooled == here
