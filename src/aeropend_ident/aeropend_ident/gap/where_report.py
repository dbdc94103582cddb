"""What the where-analysis finds: per equation (:class:`EquationCheck`), per recording
(:class:`RecordingWhere`) and over the recordings (:class:`WhereReport`), with their verdicts and JSON.

The analysis that fills them is :func:`aeropend_ident.gap.where.locate_gap`. No rclpy import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeropend_ident.gap.residual_tests import ALPHA, timing_lag_seen
from aeropend_ident.io.jsonutil import jsonable

#: Smallest free-run NRMSE called a gap (below it the model is as good as the range resolution).
MIN_NRMSE = 0.01
#: Smallest relative equation residual (residual RMS / driving-term RMS) flagged.
MIN_RELATIVE = 0.01


@dataclass
class EquationCheck:
    """Equation error of one state equation on one recording (see module doc, step 3).

    Attributes
    ----------
    equation : str
        One of :data:`EQUATIONS`.
    subsystem : str
        Subsystem of the equation.
    checked : bool
        False when the recording lacks a channel it needs (then ``note`` says which).
    note : str
        What was used (e.g. "ω₁ from the nominal simulation") or why it was not checked.
    unit : str
        Unit of the residual.
    rms : float
        RMS of the residual.
    mean : float
        Mean of the residual.
    driving_rms : float
        RMS of the equation's driving term (same unit).
    relative : float
        rms / driving_rms.
    noise_floor : float
        RMS the residual would have from measurement noise alone (same unit).
    method_floor : float
        RMS of the same equation error computed on the nominal model's own simulation of this
        input (what the derivative filters leave on a perfect model).
    flagged : bool
        see :func:`aeropend_ident.gap.where._flag` (above the noise floor and 1.5× the method floor).
    groups : dict[str, float]
        R² of the residual on each term group alone (0..1).
    residual : ndarray, shape (N,)
        The residual time series (not serialised).
    """

    equation: str
    subsystem: str
    checked: bool
    note: str
    unit: str = ""
    rms: float = math.nan
    mean: float = math.nan
    driving_rms: float = math.nan
    relative: float = math.nan
    noise_floor: float = math.nan
    method_floor: float = math.nan
    flagged: bool = False
    groups: dict[str, float] = field(default_factory=dict)
    group_subsystems: dict[str, str] = field(default_factory=dict)
    residual: np.ndarray | None = None

    @property
    def top_group(self) -> str | None:
        """Term group with the largest R² (None when nothing was regressed)."""
        return max(self.groups, key=self.groups.__getitem__) if self.groups else None

    def as_dict(self) -> dict[str, Any]:
        d = {
            k: getattr(self, k)
            for k in (
                "equation",
                "subsystem",
                "checked",
                "note",
                "unit",
                "rms",
                "mean",
                "driving_rms",
                "relative",
                "noise_floor",
                "method_floor",
                "flagged",
                "groups",
            )
        }
        d["top_group"] = self.top_group
        d["top_group_subsystem"] = self.group_subsystems.get(self.top_group or "", None)
        return d


@dataclass
class RecordingWhere:
    """Where-analysis of one recording (arrays on its uniform grid; θ in the recording's frame)."""

    source: str
    dt: float
    channels: list[str]
    t: np.ndarray
    duty: np.ndarray
    theta: np.ndarray
    theta_free: np.ndarray
    theta_short: np.ndarray
    free_run: dict[str, float]
    short_horizon: dict[str, float]
    horizon: float
    equations: list[EquationCheck]
    regions: dict[str, Any]
    holds: list[dict[str, Any]]
    bands: list[dict[str, Any]]
    whiteness: dict[str, Any]
    input_xcorr: dict[str, Any]
    alignment: dict[str, Any]
    noise_rms: float
    significant: bool
    repeats: list[dict[str, Any]] = field(default_factory=list)

    def equation(self, name: str) -> EquationCheck:
        """The :class:`EquationCheck` of ``name``."""
        return next(e for e in self.equations if e.equation == name)

    def as_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "dt_s": self.dt,
            "n_samples": int(self.t.size),
            "duration_s": float(self.t[-1]) if self.t.size else 0.0,
            "channels": self.channels,
            "free_run": self.free_run,
            "short_horizon": {**self.short_horizon, "horizon_s": self.horizon},
            "equations": [e.as_dict() for e in self.equations],
            "regions": self.regions,
            "holds": self.holds,
            "repeatability": self.repeats,
            "bands": self.bands,
            "whiteness": self.whiteness,
            "input_xcorr": self.input_xcorr,
            "alignment": self.alignment,
            "noise_rms_rad": self.noise_rms,
            "significant": self.significant,
        }


@dataclass
class WhereReport:
    """Result of :func:`aeropend_ident.gap.where.locate_gap` over several recordings.

    Attributes
    ----------
    rig : str
        Nominal rig name.
    theta_offset : float
        θ_model − θ_recorded [rad] used.
    recordings : list[RecordingWhere]
    significant : bool
        Any recording shows a significant gap.
    located : list[dict]
        Checked equations ranked by their pooled relative residual (the residual's mean square
        over the driving term's, sample-weighted over the recordings), each
        ``{equation, subsystem, relative, flagged, top_group, top_group_subsystem, groups}``.
    not_checked : list[dict]
        ``{equation, reason}`` for equations no recording could check.
    """

    rig: str
    theta_offset: float
    recordings: list[RecordingWhere]
    significant: bool
    located: list[dict[str, Any]]
    not_checked: list[dict[str, str]]

    @property
    def subsystem(self) -> str | None:
        """Most likely subsystem of the gap (None when no equation is flagged).

        The most upstream flagged equation's subsystem (causal order actuator → armature → rotor
        → pendulum), refined by its dominant term group when that group belongs to another
        subsystem (e.g. the pendulum equation's "thrust" group points to the aerodynamic /
        actuator side).
        """
        for row in self.located:
            if row["flagged"]:
                return row["top_group_subsystem"] or row["subsystem"]
        return None

    def verdict(self) -> list[str]:
        """Plain-language findings (a few lines)."""
        out = []
        if not self.significant:
            out.append(
                "no significant gap: the free-run residual is white or within the noise/resolution floor"
            )
        for row in self.located:
            if row["flagged"]:
                grp = row["top_group"]
                out.append(
                    f"{row['equation']} equation ({row['subsystem']}) misses {row['relative']:.0%} of its "
                    f"driving term; residual best explained by the '{grp}' terms "
                    f"(R² {row['groups'].get(grp, math.nan):.2f}, {row['top_group_subsystem']})"
                )
        for r in self.recordings:
            if r.free_run.get("diverged"):
                out.append(
                    f"{r.source}: the nominal free run flips over the pivot (leaves the measured angle range "
                    f"by more than π); its NRMSE is meaningless, the {r.horizon:g} s-ahead NRMSE is "
                    f"{r.short_horizon['nrmse']:.3f}"
                )
            for rp in r.repeats:
                if rp["measured_spread"] > 3.0 * rp["simulated_spread"] + 0.02:
                    out.append(
                        f"{r.source}: at duty {rp['duty']:.3f} the recorded steady angle varies by "
                        f"{rp['measured_spread']:.3f} rad over {rp['count']} repeats "
                        f"({rp['measured_drift_per_min']:+.3f} rad/min), the model by "
                        f"{rp['simulated_spread']:.3f} rad: a time-varying effect (drift) no constant "
                        "parameter removes"
                    )
            a = r.alignment
            if timing_lag_seen(a):
                out.append(
                    f"{r.source}: simulated θ̇ best aligns with the measured one when delayed by "
                    f"{a['lag_s']:.3f} s ({a['lag_samples']} samples)"
                )
        for nc in self.not_checked:
            out.append(f"not checked: {nc['equation']} equation ({nc['reason']})")
        return out

    def as_dict(self) -> dict[str, Any]:
        return jsonable(
            {
                "rig": self.rig,
                "theta_offset_rad": self.theta_offset,
                "significant": self.significant,
                "subsystem": self.subsystem,
                "located": self.located,
                "not_checked": self.not_checked,
                "verdict": self.verdict(),
                "recordings": [r.as_dict() for r in self.recordings],
                "definitions": {
                    "residual": "theta_sim - theta_meas [rad] (recording frame)",
                    "nrmse": "RMS(residual) / (max theta_meas - min theta_meas)",
                    "relative": "RMS(equation residual) / RMS(equation driving term)",
                    "significant": f"Ljung-Box p < {ALPHA} on the free-run residual and RMS > 3 x noise and "
                    f"NRMSE > {MIN_NRMSE}",
                    "flagged": f"relative > {MIN_RELATIVE}, RMS above the noise floor (3 standard "
                    "errors) and sqrt(RMS^2 - noise^2) > 1.5 x method floor",
                },
            }
        )
