"""Replay rig files on recordings and score the simulated responses: ``compare`` for aeropend.

The System Identification Toolbox's ``compare`` for rig files: each rig (nominal, fitted by
``baseline``, corrected by ``gap``) is driven by a recording's duty cycle in a free run (no later
correction from the measurements): the one replay of every command,
:func:`aeropend_ident.greybox.replay.free_run` (its start, divergence rule and θ NRMSE; each score
carries it as ``free_run``), and each recorded channel (θ, i_a, v_a, ω₁, whichever the recording
has) is compared with the simulated one:

* ``nrmse``: RMS(y_sim − y)/range(y) [1] (θ's: the figure every command reports; None when the
  free run diverges);
* ``fit_percent``: 100·(1 − ‖y_sim − y‖/‖y − mean y‖) [%] (the toolbox's NRMSE fit);
* ``rms_error``, ``max_abs_error`` (channel units);
* ``steady_state_error``: over every constant-duty hold of at least ``min_hold`` seconds, the
  mean of y_sim − y over the hold's last quarter; reported as its RMS and mean (bias) over holds;
* ``whiteness``: Ljung-Box test of the residual y − y_sim
  (:func:`aeropend_ident.gap.residual_tests.ljung_box`)
  and the prewhitened input-residual cross-correlation
  (:func:`aeropend_ident.gap.residual_tests.input_cross_correlation`; "correlated" = the residual still
  follows the input: an unmodelled dynamic, not noise).

Step metrics of θ (python-control ``step_info``: rise time 10-90 %, settling time 2 %, overshoot
M_p, peak time) of the recorded and the simulated response for every duty step between two
holds of at least ``min_hold`` seconds; the recorded response is smoothed by a Savitzky-Golay
filter of 50 ms first (measurement noise would otherwise set the settling time).

The rig's angle frame: ``recording_frame`` of the rig file (θ_recorded = theta_scale·(θ_model −
theta_offset), :func:`aeropend_ident.greybox.parameters.rig_theta_offset`), so corrected rigs with a fitted
sensor offset or gain are replayed as ``gap`` replayed them.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.errors import CompareError, GapError, IdentificationError
from aeropend_ident.gap.effects import MeasurementMap
from aeropend_ident.gap.holds import MIN_HOLD
from aeropend_ident.gap.residual_tests import input_cross_correlation, ljung_box
from aeropend_ident.gap.which.data import FIT_CHANNELS, prepare
from aeropend_ident.gap.which.metrics import duty_holds, step_info
from aeropend_ident.greybox.parameters import rig_theta_offset, rig_theta_scale
from aeropend_ident.greybox.replay import FreeRun, free_run
from aeropend_sim.params import Rig, RigFileError, load_rig, shipped_rigs
from aeropend_sim.recording import Recording

#: Savitzky-Golay window smoothing the recorded angle before step metrics [s].
STEP_SMOOTHING = 0.05
#: Units of the compared channels.
UNITS = {"theta": "rad", "i_a": "A", "v_a": "V", "omega_rotor": "rad/s"}


@dataclass(frozen=True)
class RigModel:
    """A rig to replay and its angle-sensor frame.

    Attributes
    ----------
    label : str
        Name in tables, plots and JSON.
    ref : str
        Shipped rig name or rig-file path.
    rig : Rig
    measurement : MeasurementMap
        θ_recorded = theta_scale·(θ_model − theta_offset), from ``recording_frame``.
    """

    label: str
    ref: str
    rig: Rig
    measurement: MeasurementMap


def load_model(ref: str, label: str | None = None) -> RigModel:
    """Load a rig by shipped name or rig-file path with its ``recording_frame``.

    Raises
    ------
    CompareError
        Unknown name, missing or malformed rig file.
    """
    p = Path(ref)
    if p.suffix not in (".yaml", ".yml") and ref not in shipped_rigs():
        raise CompareError(f"unknown rig {ref!r}; expected a rig-file path (.yaml) or one of "
                           f"{shipped_rigs()}")
    if p.suffix in (".yaml", ".yml") and not p.is_file():
        raise CompareError(f"rig file {p} does not exist")
    try:
        rig = load_rig(ref)
        meas = MeasurementMap(theta_offset=rig_theta_offset(ref), theta_scale=rig_theta_scale(ref))
    except (RigFileError, IdentificationError) as exc:
        raise CompareError(f"rig {ref}: {exc}") from exc
    return RigModel(label=label or (p.stem if p.suffix else ref), ref=str(ref), rig=rig, measurement=meas)


def channel_scores(measured: np.ndarray, simulated: np.ndarray, duty: np.ndarray, dt: float,
                   min_hold: float = MIN_HOLD) -> dict[str, Any]:
    """Scores of one simulated channel against the recorded one (module docstring).

    Parameters
    ----------
    measured, simulated : ndarray, shape (N,)
        Recorded and simulated channel on the same uniform grid.
    duty : ndarray, shape (N,)
        Duty cycle τ ∈ [0, 1].
    dt : float
        Sample period [s].
    min_hold : float
        Shortest hold for the steady-state error [s].

    Returns
    -------
    dict
        ``nrmse``, ``fit_percent``, ``rms_error``, ``max_abs_error``, ``range``,
        ``steady_state_error`` (``rms``, ``mean``, ``holds``), ``whiteness`` (``ljung_box_q``,
        ``p_value``, ``white``, ``max_abs_acf``, ``input_correlation`` max |ρ_ue|, its
        ``input_correlation_lag_s``, ``input_correlated``).
    """
    y = np.asarray(measured, dtype=float)
    e = np.asarray(simulated, dtype=float) - y
    rng = float(np.ptp(y))
    rms = float(np.sqrt(np.mean(e**2)))
    spread = float(np.linalg.norm(y - np.mean(y)))
    ss = []
    for a, b in duty_holds(duty, dt, min_hold):
        q = a + 3 * (b - a) // 4
        ss.append(float(np.mean(e[q:b])))
    lb = ljung_box(-e)
    xc = input_cross_correlation(duty, -e, dt)
    return {
        "nrmse": rms / rng if rng > 0.0 else math.inf,
        "fit_percent": 100.0 * (1.0 - float(np.linalg.norm(e)) / spread) if spread > 0.0 else -math.inf,
        "rms_error": rms,
        "max_abs_error": float(np.max(np.abs(e))),
        "range": rng,
        "steady_state_error": {
            "rms": float(np.sqrt(np.mean(np.square(ss)))) if ss else math.nan,
            "mean": float(np.mean(ss)) if ss else math.nan,
            "holds": len(ss),
        },
        "whiteness": {
            "ljung_box_q": lb["q"], "lags": lb["lags"], "p_value": lb["p_value"], "white": lb["white"],
            "max_abs_acf": lb["max_abs_acf"], "input_correlation": xc["max_abs"],
            "input_correlation_lag_s": xc["peak_lag_s"], "input_correlated": xc["correlated"],
        },
    }


def step_metrics(theta: np.ndarray, sim: np.ndarray, duty: np.ndarray, dt: float,
                 min_hold: float = MIN_HOLD) -> list[dict[str, Any]]:
    """Step metrics of the recorded and the simulated θ for every duty step between two holds.

    Each response is taken relative to its mean over the last 10 % of the hold before the step;
    the recorded one is smoothed (:data:`STEP_SMOOTHING`). Steps with a response of zero size
    (e.g. a rod resting on its stop) are skipped.

    Returns
    -------
    list of dict
        ``t_start`` [s], ``duty_from``, ``duty_to``, ``recorded`` and ``simulated`` (``rise_time``,
        ``settling_time``, ``peak_time`` [s], ``overshoot`` [%]), ``abs_error`` per metric.
    """
    from scipy.signal import savgol_filter  # here: importing scipy.signal costs ~1 s (`compare --help`)

    w = round(STEP_SMOOTHING / dt) | 1
    smooth = savgol_filter(theta, w, 2) if w >= 5 and theta.size > w else np.asarray(theta, dtype=float)
    out = []
    holds = duty_holds(duty, dt, min_hold)
    for (a0, b0), (a, b) in itertools.pairwise(holds):
        if b0 != a:
            continue
        pre = max(a0, b0 - max(1, (b0 - a0) // 10))
        t = np.arange(b - a) * dt
        yr = smooth[a:b] - float(np.mean(smooth[pre:b0]))
        ys = sim[a:b] - float(np.mean(sim[pre:b0]))
        if np.ptp(yr) == 0.0 or np.ptp(ys) == 0.0:
            continue
        rec = step_info(yr, t, float(np.mean(yr[-max(1, yr.size // 4):])))
        simm = step_info(ys, t, float(np.mean(ys[-max(1, ys.size // 4):])))
        out.append({"t_start": float(a * dt), "duty_from": float(duty[a - 1]), "duty_to": float(duty[a]),
                    "recorded": rec, "simulated": simm,
                    "abs_error": {k: abs(simm[k] - rec[k]) for k in rec}})
    return out


@dataclass
class CompareResult:
    """Outcome of :func:`compare`.

    Attributes
    ----------
    models : list of RigModel
    recordings : list of dict
        ``label``, ``source``, ``samples``, ``duration_s``, ``channels`` compared.
    scores : dict
        ``scores[model][recording]`` = ``{"channels": {c: channel_scores}, "steps": [...],
        "step_summary": {metric: median abs error}}`` or ``{"error": message}`` if the replay
        failed (the other pairs are kept).
    traces : dict
        ``traces[recording]`` = ``{"t", "duty", "measured": {c: y}, "simulated": {model: {c: y}}}``
        for the plots.
    """

    models: list[RigModel]
    recordings: list[dict[str, Any]]
    scores: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)
    traces: dict[str, dict[str, Any]] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """JSON-able result (without traces)."""
        return {
            "models": [{"label": m.label, "ref": m.ref, "rig": m.rig.name,
                        "theta_offset": m.measurement.theta_offset, "theta_scale": m.measurement.theta_scale}
                       for m in self.models],
            "recordings": self.recordings,
            "scores": self.scores,
            "units": UNITS,
        }


def _unique_labels(labels: Sequence[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for lab in labels:
        n = seen.get(lab, 0)
        seen[lab] = n + 1
        out.append(lab if n == 0 else f"{lab}#{n + 1}")
    return out


def _scores(run: FreeRun, prep: Any, min_hold: float) -> dict[str, Any]:
    """The scores of one rig's free run on one recording: every channel's, θ's figure from ``run``."""
    if not run.channels:  # the replay blew up (a state turned non-finite): nothing to score but that
        theta = {"nrmse": None, "fit_percent": None, "diverges": run.divergence}
        return {"channels": {"theta": theta}, "steps": [], "step_summary": {}, "free_run": run.as_dict()}
    sim = run.channels
    ch = {c: channel_scores(y, sim[c], prep.duty, prep.dt, min_hold) for c, y in prep.y.items() if c in sim}
    ch["theta"]["nrmse"] = run.nrmse  # the one NRMSE (None when diverged)
    if run.diverged:  # the one divergence rule: reported as divergence, not as a figure
        ch["theta"].update(fit_percent=None, diverges=run.divergence)
    steps = step_metrics(prep.y["theta"], sim["theta"], prep.duty, prep.dt, min_hold)
    summ = {k: float(np.median([s["abs_error"][k] for s in steps])) for k in steps[0]["abs_error"]} \
        if steps else {}
    return {"channels": ch, "steps": steps, "step_summary": summ, "free_run": run.as_dict()}


def compare(models: Sequence[RigModel], recordings: Sequence[Recording],
            channels: Sequence[str] | None = None, min_hold: float = MIN_HOLD) -> CompareResult:
    """Replay every rig on every recording and score the channels (module docstring).

    Parameters
    ----------
    models : sequence of RigModel
    recordings : sequence of Recording
        Uniform time grid (:func:`aeropend_ident.io.resampling.uniform_recording`), θ required.
    channels : sequence of str, optional
        Channels compared (of ``theta``, ``i_a``, ``v_a``, ``omega_rotor``); default every one a
        recording has. θ is always compared.
    min_hold : float
        Shortest constant-duty hold for steady-state errors and step metrics [s].

    Returns
    -------
    CompareResult

    Raises
    ------
    CompareError
        No rig or recording, an unknown channel, a recording without θ.
    """
    if not models or not recordings:
        raise CompareError(
            f"need at least one rig and one recording (got {len(models)} and {len(recordings)})")
    wanted = set(FIT_CHANNELS if channels is None else channels) | {"theta"}
    unknown = wanted - set(FIT_CHANNELS)
    if unknown:
        raise CompareError(f"unknown channel(s) {sorted(unknown)}; expected some of {list(FIT_CHANNELS)}")
    labels = _unique_labels([Path(r.source).name if r.source else f"recording{k}"
                             for k, r in enumerate(recordings)])
    res = CompareResult(models=list(models), recordings=[])
    mlabels = _unique_labels([m.label for m in models])
    for label, rec in zip(labels, recordings, strict=True):
        if "theta" not in rec.channels:
            raise CompareError(f"{rec.source or label}: no θ channel (has {sorted(rec.channels)})")
        chans = frozenset(c for c in wanted if c in rec.channels)
        prep = prepare([rec], chans)[0]
        res.recordings.append({"label": label, "source": rec.source, "samples": prep.n,
                               "duration_s": prep.n * prep.dt, "channels": sorted(prep.y)})
        tr: dict[str, Any] = {"t": np.arange(prep.n) * prep.dt, "duty": prep.duty, "measured": prep.y,
                              "simulated": {}}
        for mlabel, m in zip(mlabels, models, strict=True):
            try:  # the one free-run replay of every command (start, divergence, NRMSE)
                meas = m.measurement
                run = free_run(m.rig, tr["t"], prep.duty, prep.y["theta"], theta_offset=meas.theta_offset,
                               theta_scale=meas.theta_scale, source=rec.source or label,
                               duty_before=rec.duty_before)
            except (GapError, IdentificationError) as exc:
                res.scores.setdefault(mlabel, {})[label] = {"error": str(exc)}
                continue
            res.scores.setdefault(mlabel, {})[label] = _scores(run, prep, min_hold)
            gone = np.full(prep.n, np.nan)  # a channel the rig does not give, or a blown-up replay
            tr["simulated"][mlabel] = {c: run.channels.get(c, run.theta if c == "theta" else gone)
                                       for c in prep.y}
        res.traces[label] = tr
    return res
