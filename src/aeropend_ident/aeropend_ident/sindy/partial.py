"""Partial-state identification: the pendulum equation from the angle and the duty cycle only.

Most real logs have only θ and τ (issue 4, item 4). What such data supports is the pendulum
equation with an *estimated* θ̇ and a *static* thrust map:

    θ̈ = −(c/J)·θ̇ − (mgd/J)·sin θ + (L/J)·f(v_a),   f(v_a) = a·v_a² + b·v_a + c  (thesis Eq. 4.4)

with v_a = v_a(τ) from a duty -> voltage map (thesis Eq. 4.3, e.g. ``PlantModel(rig).armature_voltage``).
The library is therefore {1, θ̇, sin θ, v_a, v_a²}; its v_a², v_a and 1 coefficients are
(L/J)·(a, b, c). The map is static, i.e. it assumes the motor is fast compared with the
pendulum: true for ``thesis_rig`` (τ_e 2 ms, rotor 20-40 ms against a 1.6 s pendulum period),
not for ``thesis_sim`` (rotor modes of 26 ms and 6 ms next to ω_n = 11.5 rad/s), where the
static map makes the identified c/J and mgd/J 20-50 % too small (measured; see
``docs/identification.md``). The current and rotor equations need i_a and ω₁ and are refused
by :func:`aeropend_ident.sindy.core.fit`.

**First-order thrust map** (:func:`lagged_input`, :func:`with_thrust_map`,
:func:`thrust_map_library`, :func:`select_thrust_map`): when the motor is not fast compared
with the pendulum the thrust follows the duty cycle through the rotor's own dynamics. A
Hammerstein model f = F_T[a·v_a² + b·v_a + c] with F_T a first-order lag of time constant T
(and an optional pure delay of d samples) is *linear* in the lagged features F_T[v_a] and
F_T[v_a²], so for a fixed (T, d) the pendulum equation is again a sparse regression on
{1, θ̇, sin θ, F(v_a), F(v_a²)} (plus sgn θ̇ for dry friction). (T, d) are chosen on the
training part only, by the free-run simulation error of θ; T = 0, d = 0 is the static map.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeropend_ident.errors import IdentificationError
from aeropend_ident.sindy.core import fit
from aeropend_ident.sindy.libraries import Candidate, CandidateLibrary, constant
from aeropend_ident.sindy.model import FreeRun, IdentData, SindyModel, free_run
from aeropend_ident.sindy.preprocess import differentiate


def angle_only_data(
    t: np.ndarray, theta: np.ndarray, duty: np.ndarray,
    voltage_map: Callable[[float], float] | None = None, source: str = "angle-only",
) -> IdentData:
    """Identification data from θ and τ: smoothed θ, θ̇ and θ̈ estimated, v_a from the map.

    θ̇ and θ̈ are Savitzky-Golay derivatives with the window chosen by cross-validation
    (:func:`aeropend_ident.sindy.preprocess.differentiate`), θ̈ from the estimated θ̇.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Uniform sample times [s].
    theta : ndarray, shape (N,)
        Angle [rad].
    duty : ndarray, shape (N,)
        Duty cycle τ ∈ [0, 1] held over each sample period.
    voltage_map : callable, optional
        τ -> v_a [V] (e.g. ``PlantModel(rig).armature_voltage``); default v_a = τ (then the
        coefficients are per unit duty instead of per volt).

    Returns
    -------
    IdentData
        Variables ``theta``, ``theta_dot`` (estimated), ``v_a``, ``duty``; derivative
        ``theta_dot`` (θ̈, estimated).

    Raises
    ------
    IdentificationError
        On shape mismatch, NaNs or a duty cycle outside [0, 1].
    """
    th = np.asarray(theta, dtype=float)
    u = np.asarray(duty, dtype=float)
    if th.shape != u.shape or th.shape != np.shape(t):
        raise IdentificationError(
            f"{source}: t, theta, duty shapes differ: {np.shape(t)}, {th.shape}, {u.shape}"
        )
    if not np.isfinite(u).all() or (u < 0).any() or (u > 1).any():
        raise IdentificationError(f"{source}: duty must be finite fractions in [0, 1]")
    d1 = differentiate(t, th, method="savgol")
    d2 = differentiate(t, d1.dydt, method="savgol")
    v_a = u.copy() if voltage_map is None else np.array([voltage_map(float(x)) for x in u])
    return IdentData(
        t=np.asarray(t, dtype=float),
        variables={"theta": d1.smooth, "theta_dot": d1.dydt, "v_a": v_a, "duty": u},
        derivatives={"theta_dot": d2.dydt}, source=source,
    )


def static_thrust_library() -> CandidateLibrary:
    """{1, θ̇, sin θ, v_a, v_a²}: pendulum terms plus the thesis Eq. 4.4 thrust law in v_a."""
    return CandidateLibrary((
        constant(),
        Candidate("θ̇", ("theta_dot",), lambda d: np.asarray(d["theta_dot"], dtype=float)),
        Candidate("sin(θ)", ("theta",), lambda d: np.sin(np.asarray(d["theta"], dtype=float))),
        Candidate("v_a", ("v_a",), lambda d: np.asarray(d["v_a"], dtype=float)),
        Candidate("v_a²", ("v_a",), lambda d: np.asarray(d["v_a"], dtype=float) ** 2),
    ))


# ------------------------------------------------------------------------- first-order thrust map
def lagged_input(u: np.ndarray, dt: float, time_constant: float, delay: int = 0) -> np.ndarray:
    """First-order lag (and delay) of a zero-order-hold input: F_T[u] sampled at the sample instants.

    x[k+1] = a·x[k] + (1 − a)·u[k − d], a = exp(−dt/T), the exact discretisation of
    T·ẋ = u(t − d·dt) − x for an input held over each sample period; x[0] = u[0] (at rest with
    the first input). ``time_constant = 0`` gives the delayed input itself (static map).

    Parameters
    ----------
    u : ndarray, shape (N,)
        Input samples (any unit; the output has the same unit).
    dt : float
        Sample period [s], > 0.
    time_constant : float
        T [s], >= 0.
    delay : int
        d, whole samples, >= 0 (the first samples repeat u[0]).

    Returns
    -------
    ndarray, shape (N,)

    Raises
    ------
    IdentificationError
        On a non-finite input, dt <= 0, T < 0 or d < 0.
    """
    x = np.asarray(u, dtype=float)
    if x.ndim != 1 or not np.isfinite(x).all():
        raise IdentificationError("lagged_input: u must be a finite 1-D array")
    if not (dt > 0 and math.isfinite(dt)):
        raise IdentificationError(f"lagged_input: dt = {dt!r} s must be > 0")
    if not (time_constant >= 0 and math.isfinite(time_constant)):
        raise IdentificationError(f"lagged_input: time constant T = {time_constant!r} s must be >= 0")
    if int(delay) != delay or delay < 0:
        raise IdentificationError(f"lagged_input: delay = {delay!r} must be a whole number of samples >= 0")
    d = int(delay)
    if d:
        x = np.concatenate([np.full(min(d, x.size), x[0]), x[: max(x.size - d, 0)]])
    if time_constant == 0.0:
        return x.copy()
    from scipy.signal import lfilter

    a = math.exp(-dt / time_constant)
    # y[k] = a·y[k−1] + (1 − a)·x[k−1], y[0] = x[0]
    y = np.empty_like(x)
    y[0] = x[0]
    if x.size > 1:
        y[1:] = lfilter([1.0 - a], [1.0, -a], x[:-1], zi=[a * x[0]])[0]
    return y


def with_thrust_map(data: IdentData, time_constant: float, delay: int = 0, input_name: str = "v_a"
                    ) -> IdentData:
    """Copy of ``data`` with the lagged thrust features ``v_f`` = F_T[v_a] and ``v_f2`` = F_T[v_a²].

    Compute them on the *whole* record before splitting, so the held-out part starts with the
    lag state the input history implies.

    Raises
    ------
    IdentificationError
        If ``input_name`` is not in the data.
    """
    if input_name not in data.variables:
        raise IdentificationError(
            f"{data.source}: thrust map needs the input {input_name!r}; data has {sorted(data.variables)}"
        )
    dt = float(np.mean(np.diff(data.t)))
    u = data.variables[input_name]
    v = dict(data.variables)
    v["v_f"] = lagged_input(u, dt, time_constant, delay)
    v["v_f2"] = lagged_input(u**2, dt, time_constant, delay)
    return IdentData(t=data.t, variables=v, derivatives=dict(data.derivatives), source=data.source)


def thrust_map_library(quadratic: bool = True, bias: bool = True, coulomb: bool = False,
                       thrust: bool = True, symbol: str = "v_a") -> CandidateLibrary:
    """{1, θ̇, sin θ, [sgn θ̇], F(v_a), [F(v_a²)]}: pendulum terms plus the lagged Eq. 4.4 thrust law.

    Needs the variables of :func:`with_thrust_map`. sgn θ̇ is tanh(θ̇ / 0.01 rad/s) (the
    model's regularised Coulomb friction). ``thrust=False`` leaves the thrust terms out (an input
    with one level: the constant term holds the thrust at that level). ``symbol`` names the input
    in the equations (``v_a`` [V] of the voltage families, ``ω_sp`` [rad/s] of an ESC's set-point).
    """
    c: list[Candidate] = [constant()] if bias else []
    c += [
        Candidate("θ̇", ("theta_dot",), lambda d: np.asarray(d["theta_dot"], dtype=float)),
        Candidate("sin(θ)", ("theta",), lambda d: np.sin(np.asarray(d["theta"], dtype=float))),
    ]
    if coulomb:
        c.append(Candidate("sgn(θ̇)", ("theta_dot",),
                           lambda d: np.tanh(np.asarray(d["theta_dot"], dtype=float) / 0.01)))
    if thrust:
        c.append(Candidate(f"F({symbol})", ("v_f",), lambda d: np.asarray(d["v_f"], dtype=float)))
    if thrust and quadratic:
        c.append(Candidate(f"F({symbol}²)", ("v_f2",), lambda d: np.asarray(d["v_f2"], dtype=float)))
    return CandidateLibrary(tuple(c))


def nrmse_range(measured: np.ndarray, simulated: np.ndarray) -> float:
    """RMS(simulated − measured) / (max − min of measured); inf if the simulation diverged.

    The normalisation of :func:`aeropend_ident.greybox.fit.error_metrics` (the grey-box baseline),
    so SINDy and grey-box figures compare directly.
    """
    m = np.asarray(measured, dtype=float)
    s = np.asarray(simulated, dtype=float)
    if not np.isfinite(s).all():
        return math.inf
    rng = float(np.ptp(m))
    rms = float(np.sqrt(np.mean((s - m) ** 2)))
    return rms / rng if rng > 0 else math.inf


def theta_scores(measured: np.ndarray, simulated: np.ndarray) -> dict[str, float]:
    """Free-run angle scores: NRMSE by range and by std, RMS and max error [rad].

    A diverged run (a non-finite value) scores inf throughout; a constant measured angle
    (std 0) has ``nrmse_std`` inf, as its ``nrmse_range`` is.
    """
    m = np.asarray(measured, dtype=float)
    s = np.asarray(simulated, dtype=float)
    if not np.isfinite(s).all():
        return {"nrmse_range": math.inf, "nrmse_std": math.inf, "rms_rad": math.inf, "max_abs_rad": math.inf}
    e = s - m
    rms = float(np.sqrt(np.mean(e**2)))
    return {
        "nrmse_range": nrmse_range(m, s),
        "nrmse_std": rms / float(np.std(m)) if np.std(m) > 0 else math.inf,
        "rms_rad": rms,
        "max_abs_rad": float(np.max(np.abs(e))),
    }


def concat_data(parts: Sequence[IdentData], source: str | None = None) -> IdentData:
    """Stack several records into one for a strong-form regression (rows are independent).

    The time axis is rebuilt as k·dt (all parts must share dt within 1e-6 relative); variables
    and derivatives present in every part are kept. Do not differentiate, integrate (weak form)
    or free-run across the joins.

    Raises
    ------
    IdentificationError
        On an empty list or different sample periods.
    """
    if not parts:
        raise IdentificationError("concat_data: no records")
    if len(parts) == 1:
        return parts[0]
    dts = [float(np.mean(np.diff(p.t))) for p in parts]
    if max(dts) - min(dts) > 1e-6 * min(dts):
        raise IdentificationError(f"records have different sample periods {dts} s; resample them to one rate")
    keys_v = set.intersection(*(set(p.variables) for p in parts))
    keys_d = set.intersection(*(set(p.derivatives) for p in parts))
    n = sum(len(p) for p in parts)
    return IdentData(
        t=np.arange(n) * dts[0],
        variables={k: np.concatenate([p.variables[k] for p in parts]) for k in sorted(keys_v)},
        derivatives={k: np.concatenate([p.derivatives[k] for p in parts]) for k in sorted(keys_d)},
        source=source or " + ".join(p.source for p in parts),
    )


@dataclass
class ThrustMapFit:
    """Pendulum equation with a (first-order) thrust map, selected on the training part.

    Attributes
    ----------
    model : SindyModel
        θ̈ model on :func:`thrust_map_library` (λ and method as given).
    time_constant : float
        Selected T [s] (0 = static map).
    delay : int
        Selected delay [samples].
    quadratic : bool
        Whether F(v_a²) was offered (dropped when the input has at most two levels: then v_a²
        is an affine function of v_a and the two are collinear with the constant).
    train, heldout : IdentData
        The two parts, with the lagged features of the selected (T, d) (several records: the
        stacked training parts, and the first record's held-out part).
    train_nrmse : float
        Free-run θ NRMSE (range-normalised) on the training part, the selection score.
    grid : list of dict
        Every (T, d) tried: ``time_constant``, ``delay``, ``train_nrmse``, ``equation``.
    notes : list of str
        What the data did not support (dropped terms and why).
    """

    model: SindyModel
    time_constant: float
    delay: int
    quadratic: bool
    train: IdentData
    heldout: IdentData
    train_nrmse: float
    grid: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    parts: list[tuple[IdentData, IdentData]] = field(default_factory=list)

    def heldout_run(self, substeps: int = 1) -> FreeRun:
        """Free run of the model over the held-out part (from its first measured θ, θ̇)."""
        return free_run(self.model, self.heldout, substeps=substeps)


def select_thrust_map(
    data: IdentData | Sequence[IdentData], train_fraction: float = 0.7,
    time_constants: Sequence[float] = (0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3),
    delays: Sequence[int] = (0, 1, 2, 3), threshold: float = 0.02, method: str = "sindy",
    bias: bool = True, coulomb: bool = False, quadratic: bool | None = None,
    progress: Callable[[str], None] | None = None, symbol: str = "v_a", **fit_kw: Any,
) -> ThrustMapFit:
    """Identify θ̈ with a static or first-order thrust map; (T, d) by free-run error on training data.

    For every (T, d) the lagged features are computed on the whole record, the record is split in
    time order, θ̈ is fitted on the training part (``method``, ``threshold``; strong form needs
    ``data.derivatives["theta_dot"]``) and the model is simulated over the training part from
    its first sample. The (T, d) with the smallest training free-run NRMSE wins; the held-out
    part is not looked at.

    Parameters
    ----------
    data : IdentData or sequence of IdentData
        θ, θ̇ (measured or estimated), v_a (or a per-unit duty), θ̈ estimate for the strong form.
        Several records (same sample period): each is split, the training parts are stacked for
        the regression (strong form only), and the score is the mean training free-run NRMSE
        over the records (each simulated on its own).
    train_fraction : float
        Share of the record (from its start) used for fitting and selection.
    time_constants, delays : sequences
        Grid of T [s] and d [samples]; ``(0,), (0,)`` is the static map.
    quadratic : bool, optional
        Offer F(v_a²); None = automatic (dropped when v_a has <= 2 distinct levels in training).
        With one level (a step test, a free decay) the thrust terms are left out altogether and the
        grid is the static map only: the constant term holds the thrust at that level.
    progress : callable, optional
        Called with a one-line message per grid point.
    symbol : str
        Name of the input in the equations (:func:`thrust_map_library`).

    Raises
    ------
    IdentificationError
        If no (T, d) gives a finite training free run, or the fit fails (rank-deficient library,
        missing variables, too short record: the message of :func:`aeropend_ident.sindy.core.fit`).
    """
    if not 0.0 < train_fraction < 1.0:
        raise IdentificationError(f"train_fraction = {train_fraction!r} must be in (0, 1)")
    records = [data] if isinstance(data, IdentData) else list(data)
    if not records:
        raise IdentificationError("select_thrust_map: no records")
    if len(records) > 1 and method == "weak":
        raise IdentificationError("the weak form would integrate across the joins of several records; "
                                  "use method 'sindy' or 'ensemble' for more than one record")
    notes: list[str] = []
    levels = np.unique(np.concatenate([
        r.variables["v_a"][: round(train_fraction * len(r))] for r in records if "v_a" in r.variables
    ] or [np.array([])]))
    thrust = levels.size != 1
    if not thrust:
        notes.append(f"the input has one level ({levels[0]:.4g}) in the training part (a step test or a free "
                     f"decay): its gain is not identifiable, so the thrust terms were left out (the constant "
                     "term holds the thrust at that level) and only the static map was tried")
        time_constants, delays = (0.0,), (0,)
    if quadratic is None:
        quadratic = levels.size > 2
        if not quadratic and thrust:
            notes.append(f"input has {levels.size} level(s) in the training part: {symbol}² is affine in "
                         f"{symbol}, so the quadratic thrust term F({symbol}²) is not identifiable and was "
                         "left out")
    lib = thrust_map_library(quadratic=quadratic, bias=bias, coulomb=coulomb, thrust=thrust, symbol=symbol)
    best: ThrustMapFit | None = None
    grid: list[dict[str, Any]] = []
    last_error: Exception | None = None
    for tc in time_constants:
        for d in delays:
            parts = [with_thrust_map(r, float(tc), int(d)).split(train_fraction) for r in records]
            train, held = concat_data([p[0] for p in parts]), parts[0][1]
            try:
                m = fit(train, lib, ["theta_dot"], threshold=threshold, method=method, **fit_kw)
            except IdentificationError as exc:
                last_error = exc
                grid.append({"time_constant": float(tc), "delay": int(d), "error": str(exc)})
                continue
            scores = []
            for tr_part, _ in parts:
                fr = free_run(m, tr_part, substeps=1)
                scores.append(nrmse_range(tr_part.variables["theta"], fr.states["theta"]))
            score = float(np.mean(scores))
            grid.append({"time_constant": float(tc), "delay": int(d), "train_nrmse": score,
                         "equation": m.equations()[0]})
            if progress is not None:
                progress(f"thrust map T = {tc:g} s, delay {d}: training free-run NRMSE {score:.4g}")
            if math.isfinite(score) and (best is None or score < best.train_nrmse):
                best = ThrustMapFit(model=m, time_constant=float(tc), delay=int(d), quadratic=quadratic,
                                    train=train, heldout=held, train_nrmse=score, parts=parts)
    if best is None:
        if last_error is not None and all("error" in g for g in grid):
            raise IdentificationError(str(last_error)) from last_error
        raise IdentificationError(
            f"{records[0].source}: no thrust map (T in {list(time_constants)} s, delay in {list(delays)}) "
            "gives a stable free run on the training part"
        )
    best.grid = grid
    best.notes = notes
    return best


def search_thrust_map(
    data: IdentData | Sequence[IdentData], train_fraction: float, time_constants: Sequence[float],
    delays: Sequence[int], progress: Callable[[str], None] | None = None, **kw: Any,
) -> ThrustMapFit:
    """:func:`select_thrust_map` over a long (T, d) range by a coordinate search instead of the full grid.

    Three passes, each a :func:`select_thrust_map` over one coordinate: the delay d over ``delays``
    with the static map (T = ``time_constants[0]``), the lag T over ``time_constants`` at that d,
    then d again at that T over the whole samples between the neighbours of the first pass' d (a lag
    absorbs part of a dead time). The best of the three passes by training free-run NRMSE wins; its
    ``grid`` lists every (T, d) tried. A grid of a few points is searched whole.

    Parameters
    ----------
    data, train_fraction
        As :func:`select_thrust_map`.
    time_constants : sequence of float
        Increasing T [s], the first one (0: static map) used in the first pass.
    delays : sequence of int
        Increasing delays [samples].
    progress : callable, optional
    **kw
        Passed to :func:`select_thrust_map` (method, threshold, symbol, fit options).

    Raises
    ------
    IdentificationError
        As :func:`select_thrust_map`.
    """
    if len(time_constants) * len(delays) <= 16:
        return select_thrust_map(data, train_fraction, time_constants, delays, progress=progress, **kw)
    first = select_thrust_map(data, train_fraction, tuple(time_constants[:1]), tuple(delays),
                              progress=progress, **kw)
    second = select_thrust_map(data, train_fraction, tuple(time_constants), (first.delay,), progress=progress,
                               **kw)
    k = list(delays).index(first.delay)
    lo, hi = delays[max(k - 1, 0)], delays[min(k + 1, len(delays) - 1)]
    near = sorted({int(v) for v in np.rint(np.linspace(lo, hi, 9))} - {first.delay})
    passes = [first, second]
    if near:
        passes.append(select_thrust_map(data, train_fraction, (second.time_constant,), tuple(near),
                                        progress=progress, **kw))
    best = min(passes, key=lambda f: f.train_nrmse)
    seen: dict[tuple[float, int], dict[str, Any]] = {}
    for f in passes:
        for g in f.grid:
            seen.setdefault((g["time_constant"], g["delay"]), g)
    return dataclasses.replace(best, grid=[seen[k] for k in sorted(seen)],
                               notes=list(dict.fromkeys(n for f in passes for n in f.notes)))
