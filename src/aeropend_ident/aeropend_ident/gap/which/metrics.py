"""Which, the validation figures: NRMSE per channel, step metrics, per-segment errors (:func:`gap_metrics`).

Part of the effect diagnosis of :mod:`aeropend_ident.gap.which` (step 6 of its pipeline); no rclpy.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from aeropend_ident.errors import GapError, IdentificationError
from aeropend_ident.gap.effects import (
    MeasurementMap,
)
from aeropend_ident.gap.which.data import Prepared, replay
from aeropend_ident.greybox.replay import FreeRun, free_run
from aeropend_sim.params import Rig

#: Segment length [s] of the bootstraps.
SEGMENT = 1.0


def duty_holds(duty: np.ndarray, dt: float, min_hold: float = 0.5) -> list[tuple[int, int]]:
    """[start, stop) sample spans of every constant-duty stretch of at least ``min_hold`` seconds."""
    edges = np.concatenate(([0], np.flatnonzero(np.diff(duty) != 0.0) + 1, [duty.size]))
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges) if (b - a) * dt >= min_hold]


def step_info(y: np.ndarray, t: np.ndarray, yfinal: float | None = None) -> dict[str, float]:
    """python-control ``step_info`` of a response y(t) (from 0): ``rise_time`` (10-90 %),
    ``settling_time`` (2 %), ``peak_time`` [s] and ``overshoot`` M_p [%], relative to ``yfinal``
    (default: the last value)."""
    import control  # python-control: field-standard step metrics

    info = control.step_info(y, timepts=t, final_output=yfinal)
    return {"rise_time": float(info["RiseTime"]), "settling_time": float(info["SettlingTime"]),
            "overshoot": float(info["Overshoot"]), "peak_time": float(info["PeakTime"])}


def gap_metrics(rig: Rig, meas: MeasurementMap, preps: Sequence[Prepared]) -> dict[str, Any]:
    """Free-run θ gap of a rig on recordings.

    Returns
    -------
    dict
        Every θ figure comes from the one free run of every command
        (:func:`aeropend_ident.greybox.replay.free_run`: its start, divergence rule and NRMSE; one
        ``free_run`` summary per recording), so ``gap``'s held-out figures equal ``compare``'s.
        ``nrmse`` (mean over recordings of RMS(θ_sim − θ_rec)/range(θ_rec)), ``max_error`` [rad],
        ``steady_state_error`` (RMS over holds ≥ 0.5 s of the difference of the mean angles over
        each hold's last quarter [rad]), ``step_metrics`` (python-control ``step_info`` of the
        recorded and simulated response to the largest duty step of the first recording with one),
        ``noise_floor_nrmse`` (the same mean with the recorded θ's measurement noise σ in place of
        the error: the NRMSE of a perfect model; a held-out recording whose θ barely moves, a decay
        come to rest, has a floor near 1/(its range in noise σ)), ``per_recording`` θ NRMSEs,
        ``channel_nrmse`` (mean NRMSE of every compared channel),
        ``nrmse_channels`` (RMS over the compared channels of their NRMSEs: the gauge of a gap
        that lies in i_a, v_a or ω₁ rather than in θ), ``diverges`` (per recording whose free run
        diverges, :func:`aeropend_ident.io.overlay_axes.diverges`: its source and the reason; then
        the NRMSE only measures how far the run went, and the report gives no shrink).
    """
    nrmse, maxe, ss, gone, runs = [], 0.0, [], [], []
    per_channel: dict[str, list[float]] = {}
    step: dict[str, Any] = {}
    floor = []
    for p in preps:
        run = one_free_run(rig, meas, p)
        floor.append(p.theta_noise_sd / p.scale["theta"])
        runs.append({"recording": p.rec.source, **run.as_dict(), "noise_sd": p.theta_noise_sd,
                     "noise_floor_nrmse": floor[-1]})
        th = run.theta
        y = p.y["theta"]
        for c, yc in p.y.items():
            sc = th if c == "theta" else run.channels.get(c, np.full(p.n, np.nan))
            per_channel.setdefault(c, []).append(float(np.sqrt(np.mean((sc - yc) ** 2)) / p.scale[c]))
        e = th - y
        nrmse.append(float(np.sqrt(np.mean(e**2)) / p.scale["theta"]))
        maxe = max(maxe, float(np.max(np.abs(e))))
        if run.divergence is not None:
            gone.append(f"{p.rec.source or 'recording'}: {run.divergence}")
        holds = duty_holds(p.duty, p.dt)
        for a, b in holds:
            q = a + 3 * (b - a) // 4
            ss.append(float(np.mean(th[q:b]) - np.mean(y[q:b])))
        if not step and len(holds) >= 2:
            best = None
            for (a0, _b0), (a, b) in itertools.pairwise(holds):
                if a0 < a and a == _b0:
                    jump = abs(p.duty[a] - p.duty[a - 1])
                    if best is None or jump > best[0]:
                        best = (jump, a, b)
            if best is not None:
                _, a, b = best
                t = np.arange(b - a) * p.dt
                try:
                    rec = step_info(y[a:b] - y[a], t)
                    sim = step_info(th[a:b] - th[a], t)
                    step = {"recorded": rec, "simulated": sim, "t_start": float(a * p.dt),
                            "abs_error": {k: abs(sim[k] - rec[k]) for k in rec}}
                except Exception:
                    step = {}
    ch_nrmse = {c: float(np.mean(v)) for c, v in per_channel.items()}
    return {
        "nrmse": float(np.mean(nrmse)),
        "noise_floor_nrmse": float(np.mean(floor)),
        "nrmse_channels": float(np.sqrt(np.mean(np.square(list(ch_nrmse.values()))))),
        "max_error": maxe,
        "steady_state_error": float(np.sqrt(np.mean(np.square(ss)))) if ss else math.nan,
        "step_metrics": step,
        "per_recording": nrmse,
        "channel_nrmse": ch_nrmse,
        "diverges": gone,
        "free_run": runs,
    }


def one_free_run(rig: Rig, meas: MeasurementMap, p: Prepared) -> FreeRun:
    """The one free run of every command (:func:`aeropend_ident.greybox.replay.free_run`) of ``rig``
    seen through ``meas`` on the recording ``p``: the figures a diagnosis reports come from it. A
    recording that continues a run (a carved validation stretch) starts the rig's own effect states
    where its replay of the commands before ends, as the diagnosis' ranking replays do.

    Raises
    ------
    GapError
        If the replay fails for this rig (naming the recording and the rig).
    """
    try:
        return free_run(rig, np.arange(p.n) * p.dt, p.duty, p.y["theta"], theta_offset=meas.theta_offset,
                        theta_scale=meas.theta_scale, source=p.rec.source or "a recording",
                        duty_before=p.rec.duty_before)
    except IdentificationError as exc:
        raise GapError(str(exc)) from exc


def validation_errors(rig: Rig, meas: MeasurementMap, preps: Sequence[Prepared],
                      segment: float = SEGMENT) -> tuple[np.ndarray, dict[str, float]]:
    """Normalised squared output error per time segment (for bootstraps) and per channel.

    Each channel's error is divided by its range and each recording's by its length, as in
    :func:`residuals`; the segments of every recording are concatenated, the channel sums are
    totals over recordings. One replay per recording.
    """
    segs, per_channel = [], {}
    for p in preps:
        sim = replay(rig, meas, p)
        w = max(round(segment / p.dt), 1)
        e2 = np.zeros(p.n)
        for c, y in p.y.items():
            ec = ((sim[c] - y) / p.scale[c]) ** 2 / p.n
            per_channel[c] = per_channel.get(c, 0.0) + float(ec.sum())
            e2 += ec
        k = p.n // w
        if k == 0:
            segs.append(np.array([e2.sum()]))
            continue
        segs.append(np.add.reduceat(e2[: k * w], np.arange(0, k * w, w)))
        segs[-1][-1] += e2[k * w:].sum()
    return np.concatenate(segs), per_channel


def segment_sse(rig: Rig, meas: MeasurementMap, preps: Sequence[Prepared],
                segment: float = SEGMENT) -> np.ndarray:
    """Normalised squared output error per time segment of every recording (for bootstraps)."""
    return validation_errors(rig, meas, preps, segment)[0]


def channel_sse(rig: Rig, meas: MeasurementMap, preps: Sequence[Prepared]) -> dict[str, float]:
    """Normalised squared output error per channel, summed over recordings (as :func:`segment_sse`)."""
    return validation_errors(rig, meas, preps)[1]

