"""Grey-box baseline: fit a rig's nominal model on the first part of a recording, test on the rest.

Pipeline (:func:`baseline`, :func:`run_baseline`):

1. **Split** the recording in time order (:meth:`aeropend_sim.recording.Recording.split`,
   default 70 % train / 30 % held out). The held-out part is never seen by the fit.
2. **Fit** the selected parameters on the training part by output error
   (:func:`aeropend_ident.greybox.fit.fit_greybox`, default parameter set for θ-only data).
3. **Replay** the held-out part's recorded duty cycle through the fitted model in free run,
   starting from the held-out part's own first samples (θ, θ̇ by a short local fit, motor at the
   steady state of its first duty), and the same for the **nominal** (unfitted) rig.
4. **Metrics** on train and held-out, for the nominal and the fitted model:
   NRMSE = RMS(θ_sim − θ_meas) / (max θ_meas − min θ_meas) over that part, RMS error [rad] and
   max |error| [rad].
5. **Residual per operating region** (residual = θ_sim − θ_meas): equal-width bins of the
   measured θ and of the duty cycle (count, mean, RMS), and transient vs steady state
   (|θ̇_meas| above/below a threshold, θ̇ from a Savitzky-Golay derivative of the measured θ).
6. **Report** (:func:`write_report`): ``report.json`` (parameters with units and standard
   errors, metrics, regions, provenance) and ``overlay.png`` (recorded vs nominal vs fitted θ
   with the train/held-out boundary, duty cycle below), plus ``fitted_rig.yaml`` (the fitted
   rig in the rig-file format, loadable by :func:`aeropend_sim.params.load_rig`).

No rclpy import; matplotlib is used with the Agg backend only when writing the plot.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import platform
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy
import yaml

from aeropend_ident.errors import IdentificationError
from aeropend_ident.greybox.fit import (
    THETA_OFFSET,
    GreyBoxResult,
    UniformData,
    error_metrics,
    fit_greybox,
    free_run_theta,
    rig_theta_offset,
    uniform_data,
)
from aeropend_ident.io.jsonutil import jsonable
from aeropend_sim.params import Rig, RigFileError, load_rig, rig_to_dict
from aeropend_sim.recording import Recording, RecordingError

#: Definition of the NRMSE used throughout the report.
NRMSE_DEFINITION = "NRMSE = RMS(theta_sim - theta_meas) / (max(theta_meas) - min(theta_meas)) over the part"
#: Default |θ̇| threshold [rad/s] separating transient from steady-state samples.
STEADY_RATE = 0.05
#: Default number of equal-width bins for the θ and duty operating regions.
N_BINS = 5
#: Default multiple-shooting horizon [s] that initialises the free-run fit.
INIT_HORIZON = 2.0


@dataclass(frozen=True)
class BaselineResult:
    """Everything the baseline computed (arrays in the recording's angle frame, SI units).

    Attributes
    ----------
    fit : GreyBoxResult
        The fit on the training part (fitted rig, parameters, standard errors, cost, ...).
    nominal_rig : Rig
        The rig as loaded (the nominal model).
    nominal_theta_offset : float
        The rig's recording-frame offset [rad] (θ_model = θ_recorded + offset).
    rig_ref : str
        The rig name or path given (provenance).
    recording : Recording
        The input recording.
    train_fraction : float
    train, heldout : UniformData
        The two parts on their uniform grids (time re-based to 0 in each).
    t_split : float
        Start of the held-out part [s] from the recording's start.
    theta : dict
        ``theta[part][model]`` simulated angle [rad], part ∈ {"train", "heldout"},
        model ∈ {"nominal", "fitted"}.
    metrics : dict
        ``metrics[part][model]`` = :func:`aeropend_ident.greybox.fit.error_metrics`.
    regions : dict
        ``regions[part][model]`` = :func:`residual_regions`.
    """

    fit: GreyBoxResult
    nominal_rig: Rig
    nominal_theta_offset: float
    rig_ref: str
    recording: Recording
    train_fraction: float
    train: UniformData
    heldout: UniformData
    t_split: float
    theta: dict[str, dict[str, np.ndarray]]
    metrics: dict[str, dict[str, dict[str, float]]]
    regions: dict[str, dict[str, dict[str, Any]]]

    def summary(self) -> str:
        """A few lines for a terminal: parameters and NRMSE nominal vs fitted."""
        lines = [
            f"baseline: rig {self.nominal_rig.name} on {self.recording.source or '<recording>'}",
            f"  split: {self.train_fraction:.0%} train ({len(self.train)} samples), "
            f"held out from t = {self.t_split:.2f} s ({len(self.heldout)} samples)",
            f"  fit: {self.fit.nfev} simulations, {self.fit.elapsed:.1f} s, {self.fit.message}",
        ]
        for p in self.fit.parameters:
            rel = f" ({p.relative_std_error:.1%})" if math.isfinite(p.relative_std_error) else ""
            flag = "  AT BOUND" if p.at_bound else ""
            if not flag and p.relative_std_error > 0.5:
                flag = "  poorly determined (std error > 50 %)"
            lines.append(
                f"  {p.name:28s} {p.value:12.5g} ± {p.std_error:<10.3g}{rel:9s} {p.unit:10s}"
                f" (nominal {p.initial:.5g}){flag}"
            )
        for part in ("train", "heldout"):
            m = self.metrics[part]
            lines.append(
                f"  NRMSE {part:8s} nominal {m['nominal']['nrmse']:.4f}   fitted {m['fitted']['nrmse']:.4f}"
                f"   (RMS {m['nominal']['rms_error']:.4f} -> {m['fitted']['rms_error']:.4f} rad)"
            )
        return "\n".join(lines)

    def report(self) -> dict[str, Any]:
        """JSON-ready report (what ``report.json`` holds)."""
        rec = self.recording
        meta_keys = ("preset", "provenance", "licence", "rig", "files", "csv_file", "csv_sha256",
                     "angle_reference", "input_note", "sample_period_note")
        m = self.metrics
        return jsonable({
            "summary": {
                "rig": self.nominal_rig.name,
                "recording": rec.source,
                "nrmse_heldout_nominal": m["heldout"]["nominal"]["nrmse"],
                "nrmse_heldout_fitted": m["heldout"]["fitted"]["nrmse"],
                "nrmse_train_nominal": m["train"]["nominal"]["nrmse"],
                "nrmse_train_fitted": m["train"]["fitted"]["nrmse"],
                "parameters": {p.name: {"value": p.value, "unit": p.unit, "std_error": p.std_error}
                               for p in self.fit.parameters},
            },
            "parameters": [
                {"name": p.name, "value": p.value, "unit": p.unit, "std_error": p.std_error,
                 "relative_std_error": p.relative_std_error, "nominal": p.initial,
                 "lower": p.lower, "upper": p.upper, "log_parametrised": p.log, "at_bound": p.at_bound}
                for p in self.fit.parameters
            ],
            "theta_offset": {"nominal": self.nominal_theta_offset, "fitted": self.fit.theta_offset,
                             "unit": "rad", "meaning": "theta_model = theta_recorded + theta_offset"},
            "fit": {k: v for k, v in self.fit.as_dict().items() if k != "parameters"},
            "metrics": {"definition": NRMSE_DEFINITION, "units": {"rms_error": "rad", "max_abs_error": "rad",
                                                                  "range": "rad", "nrmse": "1"},
                        **m},
            "regions": {
                "definition": "residual = theta_sim - theta_meas [rad]; theta and duty bins are equal-width "
                              "over the part's measured range; 'steady' = |d theta_meas/dt| < rate_threshold",
                **self.regions,
            },
            "split": {
                "train_fraction": self.train_fraction, "t_split_s": self.t_split,
                "n_train": len(self.train), "n_heldout": len(self.heldout),
                "order": "time-ordered: train = first part, held out = the rest (never used for fitting)",
                "heldout_initial_state": "theta and theta_dot from the held-out part's first samples, "
                                         "motor at the steady state of its first duty",
            },
            "provenance": {
                "recording": {
                    "source": rec.source, "n_samples": len(rec), "duration_s": float(rec.t[-1] - rec.t[0]),
                    "dt_median_s": rec.dt,
                    "resampled_to_uniform": self.train.resampled or self.heldout.resampled,
                    "fit_grid_dt_s": self.train.dt, "decimate": self.train.decimate,
                    "channels": sorted(rec.channels),
                    "meta": {k: rec.meta[k] for k in meta_keys if k in rec.meta},
                },
                "rig": {"ref": self.rig_ref, "name": self.nominal_rig.name,
                        "description": self.nominal_rig.description,
                        "effects": dict(vars(self.nominal_rig.effects))},
                "tool": "aeropend_ident.greybox.baseline",
                "created_utc": _dt.datetime.now(_dt.UTC).isoformat(),
                "versions": {"python": platform.python_version(), "numpy": np.__version__,
                             "scipy": scipy.__version__},
            },
        })


# --------------------------------------------------------------------------- regions
def residual_bins(values: np.ndarray, residual: np.ndarray, n_bins: int, unit: str) -> list[dict[str, Any]]:
    """Residual statistics in ``n_bins`` equal-width bins of an operating variable.

    Parameters
    ----------
    values : ndarray, shape (N,)
        Operating variable per sample (angle, duty cycle, |θ̇|, ...).
    residual : ndarray, shape (N,)
        Residual per sample.
    n_bins : int
        Number of bins over [min(values), max(values)] (one bin when the values are constant).
    unit : str
        Unit of ``values`` (copied into each bin).

    Returns
    -------
    list of dict
        Per bin: ``lower``, ``upper``, ``unit``, ``count``, ``mean_residual`` and ``rms_residual``
        (None for an empty bin).
    """
    lo, hi = float(np.min(values)), float(np.max(values))
    if hi == lo:
        edges = np.array([lo, hi])
    else:
        edges = np.linspace(lo, hi, n_bins + 1)
    idx = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, edges.size - 2)
    out = []
    for b in range(edges.size - 1):
        r = residual[idx == b]
        out.append({
            "lower": float(edges[b]), "upper": float(edges[b + 1]), "unit": unit, "count": int(r.size),
            "mean_residual": float(np.mean(r)) if r.size else None,
            "rms_residual": float(np.sqrt(np.mean(r**2))) if r.size else None,
        })
    return out


def measured_rate(theta: np.ndarray, dt: float, window: float = 0.2) -> np.ndarray:
    """θ̇ [rad/s] of a measured angle by a Savitzky-Golay derivative (quadratic, ≈ ``window`` s).

    Parameters
    ----------
    theta : ndarray, shape (N,)
        Angle [rad] on a uniform grid.
    dt : float
        Grid period [s].
    window : float
        Window length [s] (at least 5 samples, odd, at most N).
    """
    n = theta.size
    w = max(5, round(window / dt) | 1)
    if w > n:
        w = n if n % 2 else n - 1
    if w < 3:
        return np.gradient(theta, dt) if n > 1 else np.zeros(n)
    from scipy.signal import savgol_filter  # here: importing scipy.signal costs ~1 s (`baseline --help`)

    return savgol_filter(theta, w, min(2, w - 1), deriv=1, delta=dt, mode="interp")


def residual_regions(theta: np.ndarray, duty: np.ndarray, residual: np.ndarray, dt: float,
                     n_bins: int = N_BINS, rate_threshold: float = STEADY_RATE) -> dict[str, Any]:
    """Residual statistics per operating region.

    Parameters
    ----------
    theta : ndarray, shape (N,)
        Measured angle [rad].
    duty : ndarray, shape (N,)
        Duty cycle [1].
    residual : ndarray, shape (N,)
        θ_sim − θ_meas [rad].
    dt : float
        Sample period [s].
    n_bins : int
        Equal-width bins over the measured θ range and over the duty range.
    rate_threshold : float
        |θ̇_meas| [rad/s] below which a sample counts as steady state.

    Returns
    -------
    dict
        ``theta_bins``, ``duty_bins`` (lists of {lower, upper, unit, count, mean_residual,
        rms_residual}), ``motion`` ({"transient": {...}, "steady": {...}}), ``rate_threshold``.
    """
    rate = measured_rate(theta, dt)
    steady = np.abs(rate) < rate_threshold
    motion = {}
    for label, mask in (("transient", ~steady), ("steady", steady)):
        r = residual[mask]
        motion[label] = {"count": int(r.size),
                         "mean_residual": float(np.mean(r)) if r.size else None,
                         "rms_residual": float(np.sqrt(np.mean(r**2))) if r.size else None}
    return {
        "theta_bins": residual_bins(theta, residual, n_bins, "rad"),
        "duty_bins": residual_bins(duty, residual, n_bins, "1"),
        "motion": motion,
        "rate_threshold": rate_threshold,
        "rate_threshold_unit": "rad/s",
    }


# --------------------------------------------------------------------------- pipeline
def _resolve_rig(rig: Rig | str | Path) -> tuple[Rig, str, float]:
    if isinstance(rig, Rig):
        return rig, rig.name, 0.0
    try:
        loaded = load_rig(rig)
    except RigFileError as exc:
        raise IdentificationError(str(exc)) from exc
    return loaded, str(rig), rig_theta_offset(rig)


def baseline(
    recording: Recording,
    rig: Rig | str | Path,
    *,
    train_fraction: float = 0.7,
    params: Sequence[str] | None = None,
    theta_offset: float | None = None,
    init_horizon: float | None = INIT_HORIZON,
    decimate: int = 1,
    n_bins: int = N_BINS,
    rate_threshold: float = STEADY_RATE,
    max_nfev: int = 400,
) -> BaselineResult:
    """Split, fit on the training part, replay the held-out part, compute metrics and regions.

    Parameters
    ----------
    recording : Recording
        Needs ``theta`` [rad] and the duty cycle (a bag via :func:`aeropend_ident.io.bags.read_bag`
        or a CSV via :func:`aeropend_ident.io.csv_import.import_csv`).
    rig : Rig, str or Path
        The nominal model: a :class:`~aeropend_sim.params.Rig`, a shipped rig name or a rig-file
        path (then its ``recording_frame.theta_offset`` is used, see
        :func:`aeropend_ident.greybox.fit.rig_theta_offset`).
    train_fraction : float
        Fraction of the samples (from the start) used for fitting, in (0, 1).
    params : sequence of str, optional
        Fitted parameters (default :func:`aeropend_ident.greybox.fit.default_parameters`).
    theta_offset : float, optional
        Override of the nominal angle offset [rad].
    init_horizon : float or None
        Multiple-shooting horizon [s] that initialises the free-run fit (None: free run only).
    decimate : int
        Decimation of both parts (runtime; see :func:`aeropend_ident.greybox.fit.uniform_data`).
    n_bins, rate_threshold : int, float
        Operating-region bins and the steady-state |θ̇| threshold [rad/s].
    max_nfev : int
        Most simulations per fitting stage.

    Returns
    -------
    BaselineResult

    Raises
    ------
    IdentificationError
        On an unusable recording or part (too short, unexcited, NaNs, no θ), a bad split
        fraction or rig, or a bad parameter request.
    """
    nominal, rig_ref, off = _resolve_rig(rig)
    if theta_offset is not None:
        off = float(theta_offset)
    if not (isinstance(train_fraction, (int, float)) and 0.0 < train_fraction < 1.0):
        raise IdentificationError(f"train_fraction = {train_fraction!r}; expected a number in (0, 1)")
    try:
        train_rec, held_rec = recording.split(train_fraction)
    except RecordingError as exc:
        raise IdentificationError(f"cannot split {recording.source or 'the recording'}: {exc}") from exc
    t_split = float(recording.t[len(train_rec)] - recording.t[0])
    train = uniform_data(train_rec, decimate=decimate)
    held = uniform_data(held_rec, dt=train.dt / train.decimate, decimate=decimate, min_samples=10)
    fit = fit_greybox(train, nominal, params, theta_offset=off, init_horizon=init_horizon, max_nfev=max_nfev)
    theta: dict[str, dict[str, np.ndarray]] = {"train": {}, "heldout": {}}
    metrics: dict[str, dict[str, dict[str, float]]] = {"train": {}, "heldout": {}}
    regions: dict[str, dict[str, dict[str, Any]]] = {"train": {}, "heldout": {}}
    for part, data in (("train", train), ("heldout", held)):
        for model, r, o in (("nominal", nominal, off), ("fitted", fit.rig, fit.theta_offset)):
            th = fit.theta_fit if (part == "train" and model == "fitted") else free_run_theta(r, data, o)
            theta[part][model] = th
            metrics[part][model] = error_metrics(data.theta, th)
            regions[part][model] = residual_regions(data.theta, data.duty, th - data.theta, data.dt,
                                                    n_bins, rate_threshold)
    return BaselineResult(
        fit=fit, nominal_rig=nominal, nominal_theta_offset=off, rig_ref=rig_ref, recording=recording,
        train_fraction=float(train_fraction), train=train, heldout=held, t_split=t_split, theta=theta,
        metrics=metrics, regions=regions,
    )


# --------------------------------------------------------------------------- report writer
def fitted_rig_dict(result: BaselineResult) -> dict[str, Any]:
    """The fitted rig in the rig-file format, each fitted number's source naming the fit."""
    data = rig_to_dict(result.fit.rig)
    data["name"] = f"{result.nominal_rig.name}_fitted"
    data["description"] = (f"{result.nominal_rig.description} -- grey-box fit "
                           f"(aeropend_ident.greybox.baseline) on the first {result.train_fraction:.0%} "
                           f"of {result.recording.source}")
    moved = result.fit.theta_offset != result.nominal_theta_offset
    for p in result.fit.parameters:
        if p.name == THETA_OFFSET:
            continue
        section, field = p.name.split(".", 1)
        name = Path(result.recording.source).name or "recording"
        data[section][field]["source"] = (f"grey-box fit on {name} (train part), "
                                          f"std error {p.std_error:.3g} {p.unit}")
    if moved:
        for field in ("theta_min", "theta_max"):
            data["pendulum"][field]["source"] += " (moved with the fitted theta_offset)"
    if result.fit.theta_offset != 0.0 or result.nominal_theta_offset != 0.0:
        data["recording_frame"] = {THETA_OFFSET: {
            "value": result.fit.theta_offset, "unit": "rad",
            "source": "grey-box fit" if moved else "nominal rig file"}}
    return data


def plot_overlay(result: BaselineResult, path: str | Path) -> Path:
    """Write ``overlay.png``: recorded vs nominal vs fitted θ, train/held-out boundary, duty below.

    Angles are in the recording's frame [rad]; time [s] from the recording's start. A model that
    leaves the recorded range is cut at the plotted range with a note
    (:func:`aeropend_ident.io.overlay_axes.clip_to_recorded`).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aeropend_ident.io.overlay_axes import clip_to_recorded, fit_title
    from aeropend_ident.io.overlay_axes import short_number as num

    path = Path(path)
    fig, (ax, axu) = plt.subplots(2, 1, sharex=True, figsize=(12, 6.5), height_ratios=(3, 1),
                                  constrained_layout=True)
    parts = (("train", result.train, 0.0), ("heldout", result.heldout, result.t_split))
    for part, data, t0 in parts:
        t = data.t + t0
        first = part == "train"
        ax.plot(t, data.theta, color="black", lw=1.2, label="recorded" if first else None)
        ax.plot(t, result.theta[part]["nominal"], color="tab:orange", lw=1.0, ls="--",
                label="nominal model" if first else None)
        ax.plot(t, result.theta[part]["fitted"], color="tab:blue", lw=1.0,
                label="fitted model" if first else None)
        axu.step(t, data.duty, where="post", color="tab:green", lw=1.0)
    clip_to_recorded(ax, np.concatenate([d.t + t0 for _, d, t0 in parts]),
                     np.concatenate([d.theta for _, d, _ in parts]),
                     {f"{kind} model": np.concatenate([result.theta[p][kind] for p, _, _ in parts])
                      for kind in ("nominal", "fitted")})
    for a in (ax, axu):
        a.axvline(result.t_split, color="tab:red", lw=1.2, ls=":")
        a.grid(alpha=0.3)
    m = result.metrics
    ax.text(0.01, 0.98, "train (fit)", transform=ax.transAxes, va="top", ha="left", color="tab:red")
    ax.text(result.t_split, 0.98, "  held out", transform=ax.get_xaxis_transform(), va="top", ha="left",
            color="tab:red")
    ax.set_ylabel("θ [rad]")
    fit_title(
        ax,
        f"{result.nominal_rig.name} on {Path(result.recording.source).name}: held-out NRMSE nominal "
        f"{num(m['heldout']['nominal']['nrmse'])}, fitted {num(m['heldout']['fitted']['nrmse'])} "
        f"(train {num(m['train']['nominal']['nrmse'])} / {num(m['train']['fitted']['nrmse'])})",
        fontsize=10,
    )
    ax.legend(loc="lower right")
    axu.set_ylabel("duty τ [1]")
    axu.set_xlabel("time t [s]")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


#: The files :func:`write_report` writes into a report folder, by key (the ``baseline`` command's
#: ``--overwrite`` replaces only a folder that holds one of them).
REPORT_FILES = {"report": "report.json", "overlay": "overlay.png", "fitted_rig": "fitted_rig.yaml"}


def write_report(result: BaselineResult, outdir: str | Path) -> dict[str, Any]:
    """Write ``report.json``, ``overlay.png`` and ``fitted_rig.yaml`` (:data:`REPORT_FILES`) into
    ``outdir`` (created; files of the same names are replaced, others are left alone: the
    ``baseline`` command claims an empty folder first).

    The figure is optional: if it cannot be drawn, the report and the fitted rig are still
    written and ``report.json`` says why under ``not_computed`` (the fit is the result).

    Returns
    -------
    dict
        ``{"report": Path, "overlay": Path, "fitted_rig": Path, "not_computed": dict}``
        (no ``"overlay"`` when it could not be drawn; ``not_computed`` gives the reason).
    """
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    rig_path = out / REPORT_FILES["fitted_rig"]
    text = yaml.safe_dump(jsonable(fitted_rig_dict(result)), sort_keys=False, allow_unicode=True)
    rig_path.write_text(text, encoding="utf-8")
    paths: dict[str, Any] = {"fitted_rig": rig_path, "not_computed": {}}
    try:
        paths["overlay"] = plot_overlay(result, out / REPORT_FILES["overlay"])
    except Exception as exc:  # a figure never costs the fitted parameters
        paths["not_computed"]["figure overlay"] = f"{type(exc).__name__}: {exc}"
    paths["report"] = out / REPORT_FILES["report"]
    doc = {**result.report(), "not_computed": paths["not_computed"]}
    paths["report"].write_text(json.dumps(doc, indent=2, allow_nan=False), encoding="utf-8")
    return paths


def run_baseline(recording: Recording, rig: Rig | str | Path, outdir: str | Path | None = None,
                 **kwargs: Any) -> dict[str, Any]:
    """:func:`baseline` and, if ``outdir`` is given, :func:`write_report`; returns the report dict.

    Keyword arguments are passed to :func:`baseline`. The returned dictionary is what
    ``report.json`` holds (its ``"summary"`` entry has the headline numbers).
    """
    result = baseline(recording, rig, **kwargs)
    if outdir is not None:
        write_report(result, outdir)
    return result.report()
