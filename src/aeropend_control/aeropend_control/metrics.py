"""Step-response metrics (python-control definitions) and the thesis' Table 6.1 check (no rclpy).

Definitions are those of :func:`control.step_info`: rise time 10-90 % of the step, peak time =
instant of the largest response, settling time = last exit from the ±2 % band around the final
value, overshoot in % of the step. Here the final value is the **reference** (not the last
sample), so a response with a steady-state error larger than 2 % never settles (``nan``), and
the steady-state error e_ss = r − mean(θ over the last ``final_window`` seconds) is reported.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

# python-control is imported inside the functions that use it: importing it costs ~2 s
# (scipy.signal, matplotlib.pyplot), which `controller --help` and every importer would pay.


class MetricsError(ValueError):
    """Unusable response data (mismatched arrays, no step, step outside the record)."""


@dataclass(frozen=True)
class Requirements:
    """Time-domain requirements; ``nan`` = no requirement.

    Attributes
    ----------
    rise_time, peak_time, settling_time : float
        Upper bounds [s].
    overshoot : float
        Upper bound [%].
    steady_state_error : float
        Upper bound on |e_ss| [rad].
    """

    rise_time: float = math.nan
    peak_time: float = math.nan
    settling_time: float = math.nan
    overshoot: float = math.nan
    steady_state_error: float = math.nan


#: Thesis Table 6.1: tr ≤ 0.5 s, tp ≤ 0.9 s, ts ≤ 3.6 s, Mp ≤ 20 %.
TABLE_6_1 = Requirements(rise_time=0.5, peak_time=0.9, settling_time=3.6, overshoot=20.0)
#: Goal of issue 6 beyond the thesis: ts ≤ 1 s, Mp ≤ 5 %, zero steady-state error (|e_ss| ≤ 1 mrad).
GOAL = Requirements(rise_time=0.5, peak_time=0.9, settling_time=1.0, overshoot=5.0, steady_state_error=1e-3)


@dataclass(frozen=True)
class StepMetrics:
    """Metrics of one step response (SI: s, rad; overshoot in %)."""

    step: float
    rise_time: float
    peak_time: float
    settling_time: float
    overshoot: float
    steady_state_error: float

    def failures(self, req: Requirements = TABLE_6_1) -> list[str]:
        """Names of the requirements not met (``nan`` metrics fail a set requirement)."""
        out = []
        for name in ("rise_time", "peak_time", "settling_time", "overshoot"):
            bound = getattr(req, name)
            val = getattr(self, name)
            if not math.isnan(bound) and not (val <= bound):
                out.append(f"{name} {val:.4g} > {bound:g}")
        if not math.isnan(req.steady_state_error) and not (
            abs(self.steady_state_error) <= req.steady_state_error
        ):
            out.append(f"steady_state_error {self.steady_state_error:.3g} > {req.steady_state_error:g}")
        return out

    def meets(self, req: Requirements = TABLE_6_1) -> bool:
        """True if every set requirement is met."""
        return not self.failures(req)

    def as_dict(self) -> dict[str, float]:
        """Plain dict (for JSON)."""
        return asdict(self)


def step_metrics(
    t: np.ndarray, y: np.ndarray, r: float, t_step: float = 0.0, final_window: float = 0.2
) -> StepMetrics:
    """Metrics of a step of the reference to ``r`` at ``t_step`` from the value y(t_step).

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample instants [s], increasing.
    y : ndarray, shape (N,)
        Response (e.g. θ [rad]).
    r : float
        Reference after the step.
    t_step : float
        Instant of the step [s]; the response before it is ignored.
    final_window : float
        Length [s] of the record end averaged for the steady-state error.

    Raises
    ------
    MetricsError
        If the arrays mismatch, ``t_step`` is outside the record or the step is zero.
    """
    import control
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.ndim != 1 or t.shape != y.shape or t.size < 3:
        raise MetricsError(f"t and y must be 1-D of equal length >= 3, got {t.shape} and {y.shape}")
    k0 = int(np.searchsorted(t, t_step - 1e-12))
    if k0 >= t.size - 2:
        raise MetricsError(f"step instant t_step = {t_step!r} s is not inside the record [{t[0]}, {t[-1]}] s")
    tt, yy = t[k0:] - t[k0], y[k0:]
    y0 = float(yy[0])
    step = float(r) - y0
    if step == 0.0 or not math.isfinite(step):
        raise MetricsError(f"step size r − y(t_step) = {step!r} must be finite and non-zero")
    tail = yy[tt >= tt[-1] - final_window]
    try:
        info = control.step_info(yy - y0, T=tt, yfinal=step, SettlingTimeThreshold=0.02,
                                 RiseTimeLimits=(0.1, 0.9))
    except IndexError:  # never reached 90 % of the step: python-control has no rise time
        k = int(np.argmax(np.sign(step) * (yy - y0)))
        info = {"RiseTime": math.nan, "PeakTime": tt[k], "SettlingTime": math.nan, "Overshoot": 0.0}
    return StepMetrics(
        step=step,
        rise_time=float(info["RiseTime"]),
        peak_time=float(info["PeakTime"]),
        settling_time=float(info["SettlingTime"]),
        overshoot=float(info["Overshoot"]),
        steady_state_error=float(r - np.mean(tail)),
    )
