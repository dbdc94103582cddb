"""What ``baseline`` finds (:class:`BaselineResult`): the nominal and the fitted rig on the fit and the
held-out recordings, their NRMSE per part and operating region, the fitted parameters, the
warnings, and the report's JSON.

The run is :func:`aeropend_ident.greybox.baseline.run_baseline`. No rclpy import.
"""

from __future__ import annotations

import datetime as _dt
import math
import platform
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy

from aeropend_ident.greybox.fit_result import GreyBoxResult
from aeropend_ident.greybox.replay import START_RULE
from aeropend_ident.greybox.uniform import UniformData
from aeropend_ident.io.jsonutil import jsonable
from aeropend_ident.io.recording_input import TimingRange
from aeropend_ident.io.resampling import resampling_notes
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording

#: Definition of the NRMSE used throughout the report.
NRMSE_DEFINITION = ("NRMSE = RMS(theta_sim - theta_meas) / (max(theta_meas) - min(theta_meas)) over the part "
                    "(over all recordings when the part's own range is below HOLD_RANGE_SHARE of theirs); "
                    "null when the model diverges (see 'divergence')")
#: The timing parameters whose search range comes from the data
#: (:func:`aeropend_ident.greybox.baseline.timing_range`).
TIMING_PARAMS = ("actuator.input_delay", "actuator.lag_time_constant")


@dataclass(frozen=True)
class BaselineResult:
    """Everything the baseline computed (arrays in the recordings' angle frame, SI units).

    Attributes
    ----------
    fit : GreyBoxResult
        The fit on the fit data (fitted rig, parameters, standard errors, cost, ...).
    nominal_rig : Rig
        The rig as loaded (the nominal model).
    nominal_theta_offset : float
        The rig's recording-frame offset [rad] (θ_model = θ_recorded + offset).
    rig_ref : str
        The rig name or path given (provenance).
    recordings : tuple of Recording
        The fit recordings as given (whole, before any split).
    held_out_recordings : tuple of Recording
        Separate held-out recordings (empty for a time-ordered split).
    train_fraction : float or None
        Share of each recording fitted in a time-ordered split; None with held-out recordings.
    train, heldout : UniformData
        The fit and held-out data on one grid, one segment per recording (time re-based).
    t_split : float or None
        Start of the held-out part [s] of a single recording split in time order, else None.
    theta : dict
        ``theta[part][model]`` simulated angle [rad] (segments concatenated), part ∈ {"train",
        "heldout"}, model ∈ {"nominal", "fitted"}.
    metrics : dict
        ``metrics[part][model]``: :func:`aeropend_ident.greybox.fit.error_metrics` over the part
        (NRMSE as :data:`NRMSE_DEFINITION`, None when the model diverges) plus ``normalised_by``.
    per_recording : list of dict
        The same per held-out recording (``recording``, ``nominal``, ``fitted``).
    regions : dict
        ``regions[part][model]`` = :func:`aeropend_ident.greybox.baseline.residual_regions`.
    divergence : dict
        ``divergence[part][model]``: why the model diverges there
        (:func:`aeropend_ident.io.overlay_axes.diverges`), absent if not.
    implausible : dict
        Parameter name -> reasons it is implausible (:func:`aeropend_ident.greybox.baseline.implausible`).
    timing : TimingRange or None
        The search range of a fitted dead time or lag (None when none is fitted).
    warnings : list of str
        What the report must not let pass unnoticed (terminal, JSON, overlay).
    """

    fit: GreyBoxResult
    nominal_rig: Rig
    nominal_theta_offset: float
    rig_ref: str
    recordings: tuple[Recording, ...]
    held_out_recordings: tuple[Recording, ...]
    train_fraction: float | None
    train: UniformData
    heldout: UniformData
    t_split: float | None
    theta: dict[str, dict[str, np.ndarray]]
    metrics: dict[str, dict[str, dict[str, Any]]]
    regions: dict[str, dict[str, dict[str, Any]]]
    per_recording: list[dict[str, Any]] = field(default_factory=list)
    divergence: dict[str, dict[str, str]] = field(default_factory=dict)
    implausible: dict[str, list[str]] = field(default_factory=dict)
    timing: TimingRange | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def recording(self) -> Recording:
        """The first fit recording (the only one in the common case)."""
        return self.recordings[0]

    def split_rule(self) -> str:
        """The held-out design in words."""
        if self.held_out_recordings:
            return (f"fit on {', '.join(_name(r) for r in self.recordings)} (whole); held out: "
                    f"{', '.join(_name(r) for r in self.held_out_recordings)} (never used for fitting)")
        return (f"time-ordered: the first {self.train_fraction:.0%} of each recording fitted, the rest held "
                "out (never used for fitting)")

    def summary(self) -> str:
        """A few lines for a terminal: parameters, NRMSE nominal vs fitted, warnings."""
        lines = [f"baseline: rig {self.nominal_rig.name} on {', '.join(_name(r) for r in self.recordings)}"]
        if self.held_out_recordings:
            lines.append(f"  split: {self.split_rule()} ({len(self.train)} fit, {len(self.heldout)} held-out "
                         "samples)")
        elif len(self.recordings) == 1:
            lines.append(f"  split: {self.train_fraction:.0%} train ({len(self.train)} samples), "
                         f"held out from t = {self.t_split:.2f} s ({len(self.heldout)} samples)")
        else:
            lines.append(f"  split: {self.split_rule()} ({len(self.train)} fit, {len(self.heldout)} held-out "
                         "samples)")
        lines.append(f"  fit: {self.fit.nfev} simulations, {self.fit.elapsed:.1f} s, {self.fit.message}")
        for p in self.fit.parameters:
            rel = f" ({p.relative_std_error:.1%})" if math.isfinite(p.relative_std_error) else ""
            flag = "  AT BOUND" if p.at_bound else ""
            why = [w for w in self.implausible.get(p.name, []) if not w.startswith("at its")]
            if why:
                flag += f"  implausible: {'; '.join(why)}"
            elif not flag and p.relative_std_error > 0.5:
                flag = "  poorly determined (std error > 50 %)"
            lines.append(
                f"  {p.name:28s} {p.value:12.5g} ± {p.std_error:<10.3g}{rel:9s} {p.unit:10s}"
                f" (nominal {p.initial:.5g}){flag}"
            )
        for part in ("train", "heldout"):
            m, d = self.metrics[part], self.divergence.get(part, {})
            figs = ["DIVERGES" if k in d else f"{m[k]['nrmse']:.4f}" for k in ("nominal", "fitted")]
            rms = (f"   (RMS {m['nominal']['rms_error']:.4f} -> {m['fitted']['rms_error']:.4f} rad)"
                   if not d else "")
            lines.append(f"  NRMSE {part:8s} nominal {figs[0]}   fitted {figs[1]}{rms}")
        lines += [f"  WARNING: {w}" for w in self.warnings]
        return "\n".join(lines)

    def report(self) -> dict[str, Any]:
        """JSON-ready report (what ``report.json`` holds)."""
        m = self.metrics
        return jsonable({
            "summary": {
                "rig": self.nominal_rig.name,
                "recording": self.recording.source,
                "recordings": [r.source for r in self.recordings],
                "held_out_recordings": [r.source for r in self.held_out_recordings],
                "nrmse_heldout_nominal": m["heldout"]["nominal"]["nrmse"],
                "nrmse_heldout_fitted": m["heldout"]["fitted"]["nrmse"],
                "nrmse_train_nominal": m["train"]["nominal"]["nrmse"],
                "nrmse_train_fitted": m["train"]["fitted"]["nrmse"],
                "parameters": {p.name: {"value": p.value, "unit": p.unit, "std_error": p.std_error}
                               for p in self.fit.parameters},
                "warnings": self.warnings,
            },
            "warnings": self.warnings,
            "divergence": self.divergence,
            "parameters": [
                {"name": p.name, "value": p.value, "unit": p.unit, "std_error": p.std_error,
                 "relative_std_error": p.relative_std_error, "nominal": p.initial,
                 "lower": p.lower, "upper": p.upper, "log_parametrised": p.log, "at_bound": p.at_bound,
                 "implausible": self.implausible.get(p.name, []),
                 "bounds_from": ("the data (timing_search)"
                                 if self.timing is not None and p.name in TIMING_PARAMS
                                 else "the parameter's declaration")}
                for p in self.fit.parameters
            ],
            "theta_offset": {"nominal": self.nominal_theta_offset, "fitted": self.fit.theta_offset,
                             "unit": "rad", "meaning": "theta_model = theta_recorded + theta_offset"},
            "fit": {k: v for k, v in self.fit.as_dict().items() if k != "parameters"},
            "timing_search": self.timing.as_dict() if self.timing is not None else None,
            "metrics": {"definition": NRMSE_DEFINITION, "units": {"rms_error": "rad", "max_abs_error": "rad",
                                                                  "range": "rad", "nrmse": "1"},
                        **m},
            "per_recording": self.per_recording,
            "regions": {
                "definition": "residual = theta_sim - theta_meas [rad]; theta and duty bins are equal-width "
                              "over the part's measured range; 'steady' = |d theta_meas/dt| < rate_threshold",
                **self.regions,
            },
            "split": {
                "rule": self.split_rule(),
                "train_fraction": self.train_fraction, "t_split_s": self.t_split,
                "n_train": len(self.train), "n_heldout": len(self.heldout),
                "order": ("time-ordered: train = first part, held out = the rest (never used for fitting)"
                          if not self.held_out_recordings else "by recordings"),
                "heldout_initial_state": f"the one free run of every command: {START_RULE} of each "
                                         "held-out part (values per part in per_recording)",
            },
            "provenance": self._provenance(),
        })

    def _provenance(self) -> dict[str, Any]:
        meta_keys = ("preset", "provenance", "licence", "rig", "files", "csv_file", "csv_sha256",
                     "angle_reference", "input_note", "sample_period_note")
        rec = self.recording
        every = (*self.recordings, *self.held_out_recordings)
        return {
            "recording": {
                "source": rec.source, "n_samples": len(rec), "duration_s": float(rec.t[-1] - rec.t[0]),
                "dt_median_s": rec.dt,
                "resampled_to_uniform": self.train.resampled or self.heldout.resampled,
                "fit_grid_dt_s": self.train.dt, "decimate": self.train.decimate,
                "channels": sorted(rec.channels),
                "meta": {k: rec.meta[k] for k in meta_keys if k in rec.meta},
            },
            "recordings": [{"source": r.source, "n_samples": len(r), "duration_s": float(r.t[-1] - r.t[0]),
                            "dt_median_s": r.dt, "channels": sorted(r.channels),
                            "resampling": r.meta.get("resampling")} for r in every],
            "resampling": resampling_notes(every),
            "rig": {"ref": self.rig_ref, "name": self.nominal_rig.name,
                    "description": self.nominal_rig.description,
                    "effects": dict(vars(self.nominal_rig.effects))},
            "tool": "aeropend_ident.greybox.baseline",
            "created_utc": _dt.datetime.now(_dt.UTC).isoformat(),
            "versions": {"python": platform.python_version(), "numpy": np.__version__,
                         "scipy": scipy.__version__},
        }


def _name(rec: Recording) -> str:
    """A recording's short name for the summaries (file name, or the source)."""
    return Path(str(rec.source)).name or str(rec.source) or "<recording>"
