"""Sparse identification on real third-party recordings, validated on held-out data (issue 4, item 10).

Three rigs from ``shared/data/real`` (provenance, units and licences in its README; the data are
read from there, never copied into the repository):

* **AeroShield** (gergelytakacs/AutomationShield, ``Identification_Data``): APRBS "voltage" u,
  angle only, 66.7 Hz. Pendulum equation with estimated θ̇ and a first-order thrust map
  (:func:`aeropend_ident.sindy.partial.select_thrust_map`), v_a = 3.7 V·τ (``aeroshield_rig``'s map).
* **BA-Etchepareborda** open-loop runs: PWM and MPU6050 angle, 50 Hz. The same pendulum equation
  per unit duty (no voltage map is stated); every run is also replayed by every other run's model.
* **YangZhu** Quanser AERO pitch step (16.51 V, 1 kHz): angle, gyro rate, motor current and tach.
  Pendulum equation on the gyro rate with the rotor speed as thrust variable (weak form),
  rotor equation dω₁/dt, quasi-static armature equation v_a = R_a·i_a + K_ω·ω₁ (thesis Eq. 3.6).

Every case splits its record in time order (first part fits and selects, the rest is held
out), simulates the identified model freely over the held-out part from its first measured
state with the measured inputs, and reports the held-out NRMSE of θ normalised by the range of
the measured angle (as the grey-box baseline, :func:`aeropend_ident.greybox.fit.error_metrics`) and
by its standard deviation (as :func:`aeropend_ident.sindy.model.free_run`), next to the parameters the
rigs' repositories state.
"""

from __future__ import annotations

import gzip
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.errors import IdentificationError
from aeropend_ident.io.csv_import import import_csv
from aeropend_ident.sindy.core import fit
from aeropend_ident.sindy.libraries import Candidate, CandidateLibrary
from aeropend_ident.sindy.model import FreeRun, IdentData, SindyModel, free_run, model_to_dict
from aeropend_ident.sindy.partial import (
    ThrustMapFit,
    angle_only_data,
    select_thrust_map,
    theta_scores,
    thrust_map_library,
    with_thrust_map,
)
from aeropend_ident.sindy.preprocess import differentiate
from aeropend_sim.model import PlantModel
from aeropend_sim.params import load_rig
from aeropend_sim.recording import Recording

Progress = Callable[[str], None] | None

AEROSHIELD = Path("gergelytakacs__AutomationShield") / "AeroShield" / "Identification_Data.csv"
AEROSHIELD2 = Path("gergelytakacs__AutomationShield") / "AeroShield" / "Identification_Data2.csv"
ETCHEPAREBORDA = Path("BA-Etchepareborda__adaptive-control-aeropendulum")
ETCHEPAREBORDA_RUNS = (
    "openloop_random_binary_80_120.csv",
    "openloop_steps_0_100_180.csv",
    "openloop_steps_0_100_130.csv",
    "openloop_gaussian_pwm.csv",
)
YANGZHU = (Path("YangZhu-uestc__Quanser-AERO-2-DOF-helicopter-Model-Identification")
           / "aero_pitch_step_16p5V_1kHz.csv.gz")

#: AeroShield repository grey-box initial guesses (data README §4): m, l, c, K.
AEROSHIELD_STATED = {"m": 0.005, "l": 0.1, "c": 0.001, "K": 0.01, "g": 9.80665}
#: YangZhu repository (data README §1): J_p, half-quadrotor identified and manual values.
YANGZHU_STATED = {
    "J_p": 0.02189,
    "identified": {"K_sp": 0.09, "K_pp": 1.09e-3, "D_p": 0.0056},
    "manual": {"K_sp": 0.037463, "K_pp": 0.0011, "D_p": 0.0071116},
    "V_p": 16.51,
}
#: BA-Etchepareborda README steady angles [rad] per PWM count (ranges over repeats).
ETCHEPAREBORDA_STEADY = {100: (0.39, 0.41), 130: (0.43, 0.44), 180: (0.68, 0.79)}


def default_real_dir() -> Path:
    """``$AEROPEND_REAL_DATA`` or ``../shared/data/real`` next to the repository / working copy."""
    env = os.environ.get("AEROPEND_REAL_DATA")
    if env:
        return Path(env)
    here = Path(__file__).resolve()
    for parent in here.parents:
        cand = parent.parent / "shared" / "data" / "real"
        if (parent / "src" / "aeropend_ident").is_dir() and cand.is_dir():
            return cand
    return Path.cwd().parent / "shared" / "data" / "real"


def _require(path: Path) -> Path:
    if not path.is_file():
        raise IdentificationError(f"real recording {path} not found (see shared/data/real/README.md)")
    return path


# ------------------------------------------------------------------------------------ results
@dataclass
class CaseResult:
    """One real recording identified and validated.

    Attributes
    ----------
    name : str
        Case key (``aeroshield``, ``etchepareborda_<run>``, ``yangzhu``).
    summary : dict
        JSON-able: split, selection, equations, model file content, derived vs stated
        parameters, held-out figures, notes on what the data does not support.
    model : SindyModel
    train, heldout : IdentData
    train_run, heldout_run : FreeRun
        Free runs over the two parts.
    """

    name: str
    summary: dict[str, Any]
    model: SindyModel
    train: IdentData
    heldout: IdentData
    train_run: FreeRun
    heldout_run: FreeRun
    extra: dict[str, Any] = field(default_factory=dict)


def _static_angle(coef: dict[str, float], v: float) -> float | None:
    """Steady angle of θ̈ = ξ₀ − (c/J)θ̇ − (mgd/J) sin θ + ξ₁ v + ξ₂ v² (+ sgn θ̇ term ignored)."""
    k = -coef.get("sin(θ)", 0.0)
    if k <= 0:
        return None
    s = (coef.get("1", 0.0) + coef.get("F(v_a)", 0.0) * v + coef.get("F(v_a²)", 0.0) * v * v) / k
    return float(math.asin(s)) if -1.0 <= s <= 1.0 else None


def _thrust_map_summary(fitres: ThrustMapFit, final: SindyModel, held: FreeRun, train_run: FreeRun,
                        unit_note: str) -> dict[str, Any]:
    d = model_to_dict(final)
    return {
        "split": {"train_samples": len(fitres.train), "heldout_samples": len(fitres.heldout),
                  "t_split_s": float(fitres.heldout.t[0])},
        "selection": {"criterion": "training free-run NRMSE (range) over the (T, delay) grid",
                      "time_constant_s": fitres.time_constant, "delay_samples": fitres.delay,
                      "quadratic_offered": fitres.quadratic, "grid": fitres.grid},
        "input_unit": unit_note,
        "equations": final.equations(),
        "model": d,
        "train": theta_scores(fitres.train.variables["theta"], train_run.states["theta"]),
        "heldout": theta_scores(fitres.heldout.variables["theta"], held.states["theta"]),
        "notes": list(fitres.notes),
    }


def fit_thrust_map_case(
    data: IdentData, train_fraction: float, time_constants: Sequence[float], delays: Sequence[int],
    threshold: float = 0.02, coulomb: bool = False, quadratic: bool | None = None, ensemble: bool = True,
    progress: Progress = None,
) -> tuple[ThrustMapFit, SindyModel, FreeRun, FreeRun]:
    """Select (T, d) on the training part, refit with the bagging ensemble (coefficient spread),
    and free-run the final model over both parts.

    Returns
    -------
    (selection, final model, training free run, held-out free run)
    """
    sel = select_thrust_map(data, train_fraction, time_constants=time_constants, delays=delays,
                            threshold=threshold, coulomb=coulomb, quadratic=quadratic, progress=progress)
    final = sel.model
    if ensemble:
        lib = thrust_map_library(quadratic=sel.quadratic, coulomb=coulomb)
        final = fit(sel.train, lib, ["theta_dot"], threshold=threshold, method="ensemble", n_models=40)
    if progress:
        progress("free run over the training and held-out parts")
    return sel, final, free_run(final, sel.train, substeps=1), free_run(final, sel.heldout, substeps=1)


# ------------------------------------------------------------------------------------ AeroShield
def aeroshield_case(real_dir: Path | None = None, train_fraction: float = 0.7,
                    time_constants: Sequence[float] = (0.0, 0.05, 0.1, 0.15, 0.2),
                    delays: Sequence[int] = (0, 1, 2), progress: Progress = None) -> CaseResult:
    """AeroShield ``Identification_Data`` (APRBS, θ only): θ̈ with a first-order thrust map.

    Split 70/30 as the grey-box baseline (``test/test_baseline_real.py``); the model is also
    replayed over the independent run ``Identification_Data2`` (2023-08, 100 Hz) when present
    (``summary["cross_run"]``). v_a = 3.7 V·τ, the
    ``aeroshield_rig`` map of the firmware's duty (u/3.7 V)²; so F(v_a) ∝ u²/3.7 V.
    Stated: the repository's grey-box guesses θ̈ = (K/(l·m))·u − (g/l)·sin θ − c/(m·l²)·θ̇ with
    m = 0.005 kg, l = 0.1 m, c = 0.001, K = 0.01, i.e. c/J = 20 s⁻¹, mgd/J = 98.07 s⁻² and a
    thrust term of 20 rad/s² per volt of u.
    """
    real_dir = Path(real_dir) if real_dir is not None else default_real_dir()
    rec = import_csv(_require(real_dir / AEROSHIELD), "aeroshield_ident")
    rig = load_rig("aeroshield_rig")
    vmap = PlantModel(rig).armature_voltage
    data = angle_only_data(rec.t, rec.channels["theta"], rec.duty, vmap,
                           source="AeroShield Identification_Data")
    sel, final, tr_run, ho_run = fit_thrust_map_case(data, train_fraction, time_constants, delays,
                                                     progress=progress)
    s = _thrust_map_summary(sel, final, ho_run, tr_run, "v_a = 3.7 V·τ [V] (aeroshield_rig map)")
    coef = final.terms("theta_dot")
    st = AEROSHIELD_STATED
    m, l_, c_, k_ = st["m"], st["l"], st["c"], st["K"]

    def thrust(u: float) -> float:  # identified input term [rad/s²] at a steady u [V]
        v = 3.7 * math.floor(255 * (u / 3.7) ** 2 + 1e-9) / 255
        return coef.get("F(v_a)", 0.0) * v + coef.get("F(v_a²)", 0.0) * v * v + coef.get("1", 0.0)

    s["parameters"] = [
        {"name": "c/J", "unit": "1/s", "identified": -coef.get("θ̇", 0.0), "stated": c_ / (m * l_**2),
         "stated_source": "repo grey-box initial guess c/(m·l²)"},
        {"name": "mgd/J", "unit": "1/s^2", "identified": -coef.get("sin(θ)", 0.0), "stated": st["g"] / l_,
         "stated_source": "repo grey-box initial guess g/l"},
        {"name": "input term at u = 1 V", "unit": "rad/s^2", "identified": thrust(1.0),
         "stated": k_ / (l_ * m) * 1.0, "stated_source": "repo K/(l·m)·u (linear in u)"},
        {"name": "input term at u = 1.9 V", "unit": "rad/s^2", "identified": thrust(1.9),
         "stated": k_ / (l_ * m) * 1.9, "stated_source": "repo K/(l·m)·u (linear in u)"},
        {"name": "thrust time constant T", "unit": "s", "identified": sel.time_constant, "stated": None,
         "stated_source": "not stated (aeroshield_rig assumes 0.05 s at u = 1 V)"},
    ]
    cross: dict[str, Any] = {}
    if (real_dir / AEROSHIELD2).is_file():
        # an independent run (2023-08, 100 Hz): the lag features are recomputed at its rate with the same T
        if progress:
            progress("replaying Identification_Data2 (independent run, 100 Hz)")
        rec2 = import_csv(real_dir / AEROSHIELD2, "aeroshield_ident2")
        d2 = angle_only_data(rec2.t, rec2.channels["theta"], rec2.duty, vmap, source="AeroShield Data2")
        delay2 = round(sel.delay * rec.dt / rec2.dt)
        d2 = with_thrust_map(d2, sel.time_constant, delay2)
        fr2 = free_run(final, d2, substeps=1)
        cross["Identification_Data2.csv"] = theta_scores(d2.variables["theta"], fr2.states["theta"])
    s["cross_run"] = cross
    s["notes"].append("angle only: θ̇ and θ̈ are estimated (Savitzky-Golay, CV window); no current or rotor "
                      "speed recorded, so di_a/dt and dω₁/dt cannot be identified and K_q is not separable "
                      "from L/J (only the product, as the input term)")
    s["recording"] = {"file": str(AEROSHIELD), "samples": len(rec), "dt_s": rec.dt,
                      "preset": "aeroshield_ident"}
    return CaseResult("aeroshield", s, final, sel.train, sel.heldout, tr_run, ho_run,
                      extra={"cross_run": cross})


# ------------------------------------------------------------------------------ BA-Etchepareborda
def etchepareborda_data(real_dir: Path, run: str) -> tuple[Recording, IdentData]:
    """One open-loop run: θ (MPU6050), v_a := τ = PWM/255 (per-unit input; no voltage map stated)."""
    rec = import_csv(_require(real_dir / ETCHEPAREBORDA / run), "etchepareborda_openloop")
    return rec, angle_only_data(rec.t, rec.channels["theta"], rec.duty, None, source=f"Etchepareborda {run}")


def etchepareborda_case(run: str, real_dir: Path | None = None, train_fraction: float = 0.7,
                        time_constants: Sequence[float] = (0.0, 0.02, 0.05, 0.1, 0.2),
                        delays: Sequence[int] = (0, 1), cross_runs: Sequence[str] = ETCHEPAREBORDA_RUNS,
                        progress: Progress = None) -> CaseResult:
    """One BA-Etchepareborda open-loop run: θ̈ with a first-order thrust map per unit duty.

    Besides its own held-out tail, the model is replayed over every other run of
    ``cross_runs`` in full (the lag features recomputed from that run's input with the selected
    (T, d)). Stated: only m = 0.05 kg (firmware) and the README's steady angles (PWM 100 → 0.39-0.41,
    130 → 0.43-0.44, 180 → 0.68-0.79 rad), compared with the model's static angle.
    """
    real_dir = Path(real_dir) if real_dir is not None else default_real_dir()
    rec, data = etchepareborda_data(real_dir, run)
    sel, final, tr_run, ho_run = fit_thrust_map_case(data, train_fraction, time_constants, delays,
                                                     progress=progress)
    s = _thrust_map_summary(sel, final, ho_run, tr_run, "v_a := τ = PWM/255 [1] (per unit duty)")
    coef = final.terms("theta_dot")
    s["parameters"] = [
        {"name": "c/J", "unit": "1/s", "identified": -coef.get("θ̇", 0.0), "stated": None,
         "stated_source": "not stated"},
        {"name": "mgd/J", "unit": "1/s^2", "identified": -coef.get("sin(θ)", 0.0), "stated": None,
         "stated_source": "not stated (firmware: m = 0.05 kg; J, d unknown)"},
        {"name": "thrust time constant T", "unit": "s", "identified": sel.time_constant, "stated": None,
         "stated_source": "not stated"},
    ]
    for pwm, (lo, hi) in ETCHEPAREBORDA_STEADY.items():
        s["parameters"].append({
            "name": f"steady θ at PWM {pwm}", "unit": "rad", "identified": _static_angle(coef, pwm / 255),
            "stated": [lo, hi], "stated_source": "data README §6 (range over repeats)"})
    cross: dict[str, Any] = {}
    for other in cross_runs:
        if other == run:
            continue
        if progress:
            progress(f"replaying {other}")
        _, od = etchepareborda_data(real_dir, other)
        od = with_thrust_map(od, sel.time_constant, sel.delay)
        fr = free_run(final, od, substeps=1)
        cross[other] = theta_scores(od.variables["theta"], fr.states["theta"])
    s["cross_run"] = cross
    s["notes"].append("angle only (MPU6050 complementary filter): θ̇, θ̈ estimated; no voltage, current or "
                      "speed: input coefficients are per unit duty, di_a/dt and dω₁/dt cannot be identified")
    s["recording"] = {"file": str(ETCHEPAREBORDA / run), "samples": len(rec), "dt_s": rec.dt,
                      "preset": "etchepareborda_openloop"}
    name = "etchepareborda_" + run.removeprefix("openloop_").removesuffix(".csv")
    return CaseResult(name, s, final, sel.train, sel.heldout, tr_run, ho_run, extra={"cross_run": cross})


# ------------------------------------------------------------------------------------ YangZhu
def _yangzhu_author_model(path: Path) -> np.ndarray:
    """The logged ``theta_model_sim`` column (the repository author's simulated model)."""
    with gzip.open(path, "rt", encoding="utf-8") as fh:
        header = fh.readline().strip().split(",")
    col = next(i for i, h in enumerate(header) if h.startswith("theta_model_sim"))
    return np.loadtxt(path, delimiter=",", skiprows=1, usecols=[col])


def pendulum_rotor_libraries() -> dict[str, CandidateLibrary]:
    """θ̈: {θ̇, sin θ, sgn θ̇, ω₁²} (thrust ∝ ω₁², thesis Eq. 3.3); dω₁/dt: {1, i_a, ω₁}.

    No constant in θ̈: the only input is a step, after which ω₁² is constant, so a constant and
    ω₁² would be collinear outside the first 0.2 s. No ω₁² in dω₁/dt: the rotor is at one speed
    after its 50 ms transient, so ω₁ and ω₁² cannot be told apart.
    """
    return {
        "theta_dot": CandidateLibrary((
            Candidate("θ̇", ("theta_dot",), lambda d: np.asarray(d["theta_dot"], dtype=float)),
            Candidate("sin(θ)", ("theta",), lambda d: np.sin(np.asarray(d["theta"], dtype=float))),
            Candidate("sgn(θ̇)", ("theta_dot",),
                      lambda d: np.tanh(np.asarray(d["theta_dot"], dtype=float) / 0.01)),
            Candidate("ω₁²", ("omega_rotor",), lambda d: np.asarray(d["omega_rotor"], dtype=float) ** 2),
        )),
        "omega_rotor": CandidateLibrary((
            Candidate("1", (), lambda d: np.ones(len(next(iter(d.values()))))),
            Candidate("i_a", ("i_a",), lambda d: np.asarray(d["i_a"], dtype=float)),
            Candidate("ω₁", ("omega_rotor",), lambda d: np.asarray(d["omega_rotor"], dtype=float)),
        )),
    }


def quasi_static_armature(v_a: np.ndarray, i_a: np.ndarray, omega: np.ndarray) -> dict[str, float]:
    """Least squares of v_a = R_a·i_a + K_ω·ω₁ (thesis Eq. 3.6, L_a·di_a/dt neglected).

    Returns
    -------
    dict
        ``R_a`` [Ω], ``K_omega`` [V·s/rad], ``rms_residual_V``, ``condition_number``.

    Raises
    ------
    IdentificationError
        If i_a and ω₁ are collinear (no transient in the data).
    """
    a = np.column_stack([i_a, omega])
    cond = float(np.linalg.cond(a / np.sqrt(np.mean(a**2, axis=0))))
    if not math.isfinite(cond) or cond > 1e8:
        raise IdentificationError(f"i_a and ω₁ are collinear on this data (condition number {cond:.3g}); "
                                  "the armature equation needs a speed transient")
    sol, *_ = np.linalg.lstsq(a, v_a, rcond=None)
    res = v_a - a @ sol
    return {"R_a": float(sol[0]), "K_omega": float(sol[1]), "rms_residual_V": float(np.sqrt(np.mean(res**2))),
            "condition_number": cond}


def yangzhu_case(real_dir: Path | None = None, train_fraction: float = 0.2, method: str = "weak",
                 threshold: float = 0.02, progress: Progress = None) -> CaseResult:
    """YangZhu Quanser AERO pitch step: θ̈ (gyro rate, ω₁² thrust), dω₁/dt and the quasi-static
    armature equation; held out: everything after the first ``train_fraction`` of the 30 s.

    The single excitation is the step at t = 0, so the default split trains on the first 6 s
    (the rotor transient, the first two swings) and holds out 6-30 s (the rest of the decay);
    with a 70/30 split the held-out part is the settled angle (range 3 mrad = 1 encoder count).
    The gyro is calibrated against the encoder on the training part, gyro = a·dθ_enc/dt + b, by
    least squares of θ_enc(t) = c₀ + ∫(gyro − b)/a dt (the encoder, 2048 counts/rev, is the
    reference), and θ̇ = (gyro − b)/a.
    """
    real_dir = Path(real_dir) if real_dir is not None else default_real_dir()
    path = _require(real_dir / YANGZHU)
    rec = import_csv(path, "yangzhu_pitch_step")
    ch = rec.channels
    n_train = round(train_fraction * len(rec))
    if progress:
        progress("YangZhu: gyro bias, derivatives")
    # θ_enc(t) = c₀ + s·∫gyro dt + β·t on the training part (no differentiation of the quantised encoder)
    tt = rec.t[:n_train]
    ig = np.concatenate([[0.0], np.cumsum(0.5 * (ch["theta_dot"][1:n_train] + ch["theta_dot"][:n_train - 1])
                                          * np.diff(tt))])
    _c0, scale, beta = np.linalg.lstsq(np.column_stack([np.ones(n_train), ig, tt]), ch["theta"][:n_train],
                                      rcond=None)[0]
    gain, bias = 1.0 / scale, -beta / scale
    thd = (ch["theta_dot"] - bias) / gain
    v = {"theta": ch["theta"], "theta_dot": thd, "omega_rotor": ch["omega_rotor"], "i_a": ch["i_a"],
         "v_a": ch["v_a"], "duty": rec.duty}
    der = {"theta_dot": differentiate(rec.t, thd, method="savgol").dydt,
           "omega_rotor": differentiate(rec.t, ch["omega_rotor"], method="savgol").dydt}
    data = IdentData(t=rec.t, variables=v, derivatives=der, source="YangZhu AERO pitch step")
    train, held = data.split(train_fraction)
    libs = pendulum_rotor_libraries()
    kw: dict[str, Any] = {"K": 400, "H_xt": 0.1} if method == "weak" else {}
    if progress:
        progress(f"YangZhu: fitting θ̈ and dω₁/dt ({method})")
    model = fit(train, libs, ["theta_dot", "omega_rotor"], threshold=threshold, method=method, **kw)
    tr_run = free_run(model, train, substeps=1)
    ho_run = free_run(model, held, substeps=1)
    author = _yangzhu_author_model(path)
    arm = quasi_static_armature(train.variables["v_a"][1:], train.variables["i_a"][1:],
                                train.variables["omega_rotor"][1:])
    # armature transient resolvable? share of the current's peak reached in the first sample after the step
    i = ch["i_a"]
    first_nonzero = int(np.flatnonzero(i > 0.05 * i.max())[0])
    jump = float(i[first_nonzero] / i.max())
    coef_th, coef_w = model.terms("theta_dot"), model.terms("omega_rotor")
    jp = YANGZHU_STATED["J_p"]
    w_ss = float(np.mean(held.variables["omega_rotor"]))
    thrust_acc = coef_th.get("ω₁²", 0.0) * w_ss**2  # rad/s² at the steady rotor speed
    ident, manual = YANGZHU_STATED["identified"], YANGZHU_STATED["manual"]
    params = [
        {"name": "K_sp/J_p (mgd/J)", "unit": "1/s^2", "identified": -coef_th.get("sin(θ)", 0.0),
         "stated": ident["K_sp"] / jp, "stated_manual": manual["K_sp"] / jp,
         "stated_source": ("repo: K_sp = 0.09 N·m/rad identified at θe = 0.2 "
                           "(manual 0.037463), J_p = 0.02189")},
        {"name": "D_p/J_p (c/J)", "unit": "1/s", "identified": -coef_th.get("θ̇", 0.0),
         "stated": ident["D_p"] / jp, "stated_manual": manual["D_p"] / jp,
         "stated_source": "repo: D_p = 0.0056 N·m·s/rad identified (manual 0.0071116)"},
        {"name": "Coulomb/J_p", "unit": "rad/s^2", "identified": -coef_th.get("sgn(θ̇)", 0.0), "stated": None,
         "stated_source": "not in the repository's model (peaks of the decay fall nearly linearly)"},
        {"name": "K_pp = thrust torque / V_p", "unit": "N*m/V",
         "identified": thrust_acc * jp / YANGZHU_STATED["V_p"], "stated": ident["K_pp"],
         "stated_manual": manual["K_pp"],
         "stated_source": "repo: K_pp = 1.09e-3 N·m/V identified (manual 0.0011)"},
        {"name": "K_t/J_m", "unit": "1/(A*s^2)", "identified": coef_w.get("i_a", 0.0), "stated": None,
         "stated_source": "not stated (tach scale presumed 2π/2048 rad per count)"},
        {"name": "B_m/J_m", "unit": "1/s", "identified": -coef_w.get("ω₁", 0.0), "stated": None,
         "stated_source": "not stated"},
        {"name": "R_a (quasi-static, incl. amplifier)", "unit": "ohm", "identified": arm["R_a"],
         "stated": None,
         "stated_source": "not stated; README: R ≲ 16.51 V / 1.69 A = 9.8 Ω from the first sample"},
        {"name": "K_omega (quasi-static)", "unit": "V*s/rad", "identified": arm["K_omega"], "stated": None,
         "stated_source": "not stated (depends on the presumed tach scale)"},
    ]
    s: dict[str, Any] = {
        "split": {"train_samples": len(train), "heldout_samples": len(held), "t_split_s": float(held.t[0]),
                  "train_fraction": train_fraction},
        "method": model.method, "threshold": threshold,
        "gyro_calibration": {"gain": float(gain), "bias_rad_s": float(bias),
                             "note": "gyro = gain·dθ_enc/dt + bias (integrated gyro fitted to the encoder "
                                     "angle on the training part)"},
        "equations": [
            *model.equations(),
            f"v_a = {arm['R_a']:.4g} i_a + {arm['K_omega']:.4g} ω₁   (quasi-static, rms residual "
            f"{arm['rms_residual_V']:.3g} V)"],
        "model": model_to_dict(model),
        "armature_quasi_static": arm,
        "parameters": params,
        "train": theta_scores(train.variables["theta"], tr_run.states["theta"]),
        "heldout": theta_scores(held.variables["theta"], ho_run.states["theta"]),
        "heldout_omega_nrmse_std": float(ho_run.nrmse.get("omega_rotor", math.inf)),
        "heldout_omega_rms_over_mean": float(
            np.sqrt(np.mean((ho_run.states["omega_rotor"] - held.variables["omega_rotor"]) ** 2))
            / np.mean(held.variables["omega_rotor"])),
        "author_model_heldout": theta_scores(held.variables["theta"], author[len(train):]),
        "notes": [
            f"di_a/dt refused: the current reaches {jump:.0%} of its peak in the first sample after the step "
            "(armature time constant below the 1 ms sample period), so only the quasi-static armature "
            "equation v_a = R_a·i_a + K_ω·ω₁ is identifiable",
            "one constant input (16.51 V step): the thrust law's dependence on voltage (K_pp per volt) is "
            "one operating point; a thrust exponent or a v_a term cannot be separated from ω₁²",
            "ω₁ in rad/s rests on the presumed tach scale 2π/2048 per count/s (unit not stated)",
        ],
        "recording": {"file": str(YANGZHU), "samples": len(rec), "dt_s": rec.dt,
                      "preset": "yangzhu_pitch_step"},
    }
    return CaseResult("yangzhu", s, model, train, held, tr_run, ho_run, extra={"author": author})
