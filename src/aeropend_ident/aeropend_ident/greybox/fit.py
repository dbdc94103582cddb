"""Grey-box output-error identification of a rig's pendulum and actuator parameters.

The plant model of :mod:`aeropend_sim.model` is fitted to a recording by **output error**: the
model is simulated in free run (no state resets) with the recording's duty-cycle input on the
compiled backend (the fit sub-steps of :func:`aeropend_ident.greybox.batch.fit_substeps`), and the
selected parameters minimise

    ½ Σ_k (θ_sim(t_k) − θ_rec(t_k))²          [rad²]

with :func:`scipy.optimize.least_squares` (trust-region reflective, bounds, forward-difference
Jacobian). Each residual evaluation replays the compiled plant, and each Jacobian replays its
1 + n_p parameter sets in one batch (:mod:`aeropend_ident.greybox.batch`, which keeps the compiled
plant of the recording across evaluations); numba gives no exact Jacobian. Only the angle is
compared, because most real logs (see ``shared/data/real``) carry nothing else; other channels of
the recording are ignored.

Parameters are addressed as ``"section.field"`` of :class:`aeropend_sim.params.Rig` (e.g.
``"pendulum.c_over_J"``) plus :data:`aeropend_ident.greybox.parameters.THETA_OFFSET`, the angle offset
between the recording's
frame and the model's (θ_model = θ_recorded + θ_offset; see
:func:`aeropend_ident.greybox.parameters.rig_theta_offset`).

Default parameter set for θ-only data (:func:`aeropend_ident.greybox.parameters.default_parameters`):

* ``pendulum.mgd_over_J``, ``pendulum.c_over_J``;
* ``pendulum.L_over_J``: with θ alone, the thrust scale (``thrust.K_q``, motor constants, supply
  voltage) and the lever arm over inertia appear only as their product, so L/J absorbs the
  whole actuator gain and the other factors stay at their rig-file values;
* ``actuator.dead_zone`` when ``effects.dead_zone`` is on;
* ``actuator.lag_time_constant`` when ``effects.actuator_lag`` is on;
* ``actuator.input_delay`` when ``effects.input_delay`` is on;
* ``pendulum.coulomb_over_J`` when ``effects.rod_coulomb_friction`` is on;
* :data:`aeropend_ident.greybox.parameters.THETA_OFFSET` when the rig declares a recording-frame offset
(see-saw rigs).

Strictly positive parameters are fitted as log(p) (scale-free steps, positivity for free); the
others linearly with a parameter scale (:class:`aeropend_ident.greybox.parameters.ParameterSpec`). Bounds,
parametrisation and
scale come from the parameter's declaration (:attr:`aeropend_sim.components.base.Param.fit`, with
the component or effect that owns it) or, for parameters without fit bounds, from its sign.

Time grid: the simulator needs a uniform grid. A recording that is not on one goes through the one
resampling of every tool (:func:`aeropend_ident.io.resampling.uniform_recording`: grid step
the median interval unless given, θ interpolated linearly or, when quantised, taken at its nearest
sample, the duty cycle held: the value commanded at the last recorded instant ≤ t_k, the
recording's convention). Optional decimation by an integer factor keeps every ``decimate``-th θ
sample and averages the duty cycle over each block (this preserves the mean input). It saves little
time: the integrator's cost is set by the dynamics, not by the number of output samples
(``bench/bench_greybox.py``).

Initial state: θ(0) = first recorded angle (+ offset); θ̇(0) from a local quadratic least-squares
fit over the first :data:`N_DIFF` samples (a short finite difference); motor current/speed at
the steady state of the first duty cycle (:func:`motor_equilibrium`); lag state = first duty
cycle. When θ shows measurement noise, the fit then refines θ(0) and θ̇(0) as bounded nuisance
parameters (the short-window velocity estimate is poor on noisy data); replays of other
stretches (held-out data) use the estimates only.

Stages of :func:`fit_greybox`: optional multiple-shooting initialiser (``init_horizon``), the
free-run fit, and the initial-state polish (noisy data only).

Standard errors come from the Jacobian at the optimum, cov = s²·(JᵀJ)⁻¹ with
s² = Σr²/(m − n), mapped through the parametrisation by the delta method; parameters pinned at a
bound have none (NaN). Output-error residuals are autocorrelated, so these are lower bounds of
the true uncertainty.

No rclpy import: this module runs without ROS.
"""


from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from scipy.optimize import brentq, least_squares

from aeropend_ident.errors import IdentificationError
from aeropend_ident.greybox.batch import RigReplays, single_blas, structure
from aeropend_ident.greybox.fit_result import GreyBoxResult, ParameterEstimate
from aeropend_ident.greybox.parameters import (
    ParameterSpec,
    apply_parameters,
    default_parameters,
    parameter_spec,
)
from aeropend_ident.greybox.uniform import (
    UniformData,
    _window,
    check_excited,
    check_recording,
    concat_uniform,
    uniform_data,
)
from aeropend_ident.io.resampling import detect_quantum
from aeropend_sim.components.xp import MATH
from aeropend_sim.model import OMEGA, TAU_F, ModelError, plant_model
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import SimulationError, simulate

#: Samples used for the initial angular-velocity estimate (local quadratic fit).
N_DIFF = 7


#: ftol/xtol/gtol of the multiple-shooting initialisation stage (see ``init_horizon``).
INIT_STAGE_TOL = 1e-4


#: Sections of a rig's values that cannot enter the steady motor state: the rod's equation and
#: the measurement (the motor chain's terms read none of them, which test_fit.py checks for every
#: family). :func:`motor_equilibrium` results are cached on the other values.
ROD_SECTIONS = ("pendulum.", "sensors.")


#: Entries of that cache (it is emptied when full).
EQUILIBRIUM_CACHE_SIZE = 4096


_equilibria: dict[tuple, tuple[float, float, float]] = {}


def motor_equilibrium(rig: Rig, duty: float) -> tuple[float, float, float]:
    """Steady motor state for a constant duty cycle.

    The rotor speed ω₁ at which the rig's rotor is at rest in its own equation: for the DC motor
    families, the torque balance Σ rotor-torque terms(i_a, ω₁) = 0 (K_t·i_a = B_m·ω₁ + T_c·sgn ω₁ +
    K_d·ω₁|ω₁| with whichever loads are on) with the steady armature current i_a = (v_a + Σ
    armature terms(ω₁))/R_a; for an ESC, its speed response ω̇₁ = 0 at the set-point of the
    throttle map. The drive comes through the actuator chain (dead zone, map) and every term from
    the rig's components (:meth:`aeropend_sim.components.assembly.Assembly.point`,
    :meth:`~aeropend_sim.components.assembly.Assembly.slot_values`); nothing is re-written here.

    Parameters
    ----------
    rig : Rig
    duty : float
        Duty cycle τ ∈ [0, 1].

    Returns
    -------
    (i_a [A] (0 without an armature), ω₁ [rad/s], τ_f [1])

    Raises
    ------
    IdentificationError
        If the motor has no finite steady state (no back-EMF, friction or drag).

    Notes
    -----
    A fit replays hundreds of rigs that differ in the rod's parameters only; each starts from this
    state, so results are cached on the family, the effect switches, the duty cycle and the values
    outside :data:`ROD_SECTIONS` (a value that is NaN never matches: it is recomputed).
    """
    key = (*structure(rig), float(duty),
           tuple((k, v) for k, v in rig.values().items() if not k.startswith(ROD_SECTIONS)))
    hit = _equilibria.get(key)
    if hit is None:
        hit = _motor_equilibrium(rig, float(duty))
        if len(_equilibria) >= EQUILIBRIUM_CACHE_SIZE:
            _equilibria.clear()
        _equilibria[key] = hit
    return hit


def _motor_equilibrium(rig: Rig, duty: float) -> tuple[float, float, float]:
    """:func:`motor_equilibrium` computed."""
    model = plant_model(rig.with_effects(armature_inductance="quasi_static"))
    a = model.assembly
    duty = float(duty)
    slot = "rotor_torque" if a.armature else "rotor_response"

    rest = model.states.initial()  # an effect's own state (a winding temperature) at its initial value

    def state(w: float) -> dict[str, Any]:
        x = rest.copy()
        x[OMEGA], x[TAU_F] = w, duty
        return a.point(MATH, x.tolist(), duty)

    def rate(w: float) -> float:  # net torque (or ω̇₁), decreasing in ω₁ through the steady state
        p = state(w)
        inputs = {"i_a": p["i_a"], "omega": w, a.drive_name: p[a.drive_name]}
        return sum(a.slot_values(slot, MATH, inputs).values(), 0.0)

    if state(0.0)[a.drive_name] <= 0.0:
        return 0.0, 0.0, duty
    hi = 1.0
    while rate(hi) > 0.0:
        hi *= 2.0
        if hi > 1e9:
            raise IdentificationError(
                f"rig {rig.name!r}: the motor has no steady state at duty {duty:g} "
                "(no back-EMF, friction or propeller drag switched on)"
            )
    w = brentq(rate, 0.0, hi, xtol=1e-12, rtol=1e-12)
    return float(state(w)["i_a"]), w, duty


def initial_velocity(theta: np.ndarray, dt: float, n: int = N_DIFF) -> float:
    """θ̇(t_0) [rad/s] from a local quadratic least-squares fit over the first ``n`` samples.

    Parameters
    ----------
    theta : ndarray, shape (N,)
        Angle [rad].
    dt : float
        Sample period [s].
    n : int
        Samples used (>= 3; fewer available -> all).
    """
    k = min(max(int(n), 3), theta.size)
    tt = np.arange(k) * dt
    coef = np.polyfit(tt, theta[:k], 2 if k >= 4 else 1)
    return float(coef[-2])


#: A second difference below this (relative to the channel's magnitude) is a filled sample
#: (:func:`noise_level`): rounding leaves ~1e-16 on a straight line, any measured noise far more.
FILLED_D2 = 1e-11


def noise_level(theta: np.ndarray, quantum: float = 0.0, keep: np.ndarray | None = None) -> float:
    """Robust estimate of white measurement noise σ on a recorded channel [its unit, e.g. rad].

    σ̂ = 1.4826·MAD(Δ²θ)/√6: the second difference of white noise has variance 6σ², and smooth
    motion contributes little at the sample rate. Quantised signals that rarely change give 0.

    On a quantised channel (``quantum`` q > 0, :func:`aeropend_ident.io.resampling.detect_quantum`)
    Δ²θ takes lattice values k·q only, so the MAD snaps to 0, q or 2q and the estimate above reads
    one of three values whatever the noise (1.4826·q/√6 = 3.7 mrad for q = 6.1 mrad at 50 Hz for
    any white σ from 0.5 to 3.7 mrad, whose true noise RMS is 1.9-4.1 mrad). There the estimate
    is the root mean square of Δ²θ about its median over the differences within 4 robust widths
    w = max(1.4826·MAD, q) of it (motion and outliers left out), over √6, at least the rounding
    noise q/√12: within 9 % of the true noise RMS (white noise and rounding together) for white σ
    from q/12 to 2q at 50, 100 and 490 Hz, where the MAD estimate reads 0.86-2.0× it
    (test/ident/gap/test_quantised.py; docs/findings/gap.md, "The noise on a lattice, a product in
    the drift table").

    Parameters
    ----------
    theta : ndarray, shape (n,)
        Recorded channel.
    quantum : float, optional
        Its detected lattice step q (0: not quantised).
    keep : ndarray of bool, shape (n - 2,), optional
        The second differences that count (default all): e.g. only those over three samples at a
        logger's regular interval (:func:`aeropend_ident.greybox.rig_inputs.recorded_noise`).

    Returns
    -------
    float
        σ̂ ≥ 0; 0 when fewer than 3 second differences count (or q/√12 on a quantised channel).
    """
    d2 = np.diff(np.asarray(theta, dtype=float), 2)
    if keep is not None:
        d2 = d2[np.asarray(keep, dtype=bool)]
    q = float(quantum)
    floor = q / math.sqrt(12.0) if q > 0.0 else 0.0
    if d2.size < 3:
        return floor
    med = float(np.median(d2))
    dev = np.abs(d2 - med)
    mad = 1.4826 * float(np.median(dev))
    if q <= 0.0:
        return mad / math.sqrt(6.0)
    inner = dev[dev <= 4.0 * max(mad, q)]
    return max(float(np.sqrt(np.mean(inner**2))) / math.sqrt(6.0), floor)


def measurement_noise(y: np.ndarray, keep: np.ndarray | None = None) -> float:
    """Standard deviation of the measurement noise of a recorded channel [its unit, e.g. rad].

    :func:`noise_level` given the channel's detected quantum
    (:func:`aeropend_ident.io.resampling.detect_quantum`): on a lattice the root mean square
    of the second differences (the MAD snaps to lattice steps there), at least the rounding noise
    q/√12 (a quantised channel that rarely changes still has its resolution q bound what any model
    can match; the MAD alone reads such a log as noiseless). The one noise floor of a recording:
    the gap diagnosis (where-analysis, effect ranking, attainable shrink) and the grey-box fits
    (initial-state bounds, ``rig fit``'s weights) read it. Off a lattice, second differences of
    (numerically) zero are left out (:data:`FILLED_D2`): they are samples filled on a straight line
    across a logger's gap, and a log written in bursts (10 samples, then 128 ms of nothing) would
    otherwise read as noiseless.

    Parameters
    ----------
    y : ndarray, shape (n,)
        Recorded channel.
    keep : ndarray of bool, shape (n - 2,), optional
        The second differences that count (:func:`noise_level`).

    Returns
    -------
    float
        σ ≥ 0.
    """
    y = np.asarray(y, dtype=float)
    q = detect_quantum(y)
    if q <= 0.0 and y.size >= 3:
        big = float(np.nanmax(np.abs(y))) if np.any(np.isfinite(y)) else 1.0
        real = ~(np.abs(np.diff(y, 2)) <= FILLED_D2 * max(1.0, big))  # NaN stays in, as before
        keep = real if keep is None else np.asarray(keep, dtype=bool) & real
    return noise_level(y, q, keep=keep)


def _slope_noise_gain(dt: float, n: int = N_DIFF) -> float:
    """Standard deviation of :func:`initial_velocity` per unit σ of white noise on θ [1/s]."""
    k = max(int(n), 3)
    design = np.vander(np.arange(k) * dt, 3 if k >= 4 else 2)
    return float(np.linalg.norm(np.linalg.pinv(design)[-2]))


def initial_state(rig: Rig, theta: np.ndarray, duty: np.ndarray, dt: float, theta_offset: float = 0.0,
                  theta_dot0: float | None = None, theta0: float | None = None) -> np.ndarray:
    """Model state at the first sample of a recorded stretch: the chain's five states (shape (5,); a
    simulation starts an effect's own state, a winding temperature, at its initial value).

    θ = θ_rec[0] + offset (or ``theta0`` + offset), θ̇ from :func:`initial_velocity` (unless
    ``theta_dot0`` is given), motor at the steady state of ``duty[0]``
    (:func:`motor_equilibrium`).
    """
    thd = initial_velocity(theta, dt) if theta_dot0 is None else float(theta_dot0)
    th0 = float(theta[0]) if theta0 is None else float(theta0)
    i_a, w, tf = motor_equilibrium(rig, float(duty[0]))
    return np.array([th0 + theta_offset, thd, i_a, w, tf])


def free_run_theta(
    rig: Rig, data: UniformData, theta_offset: float = 0.0, theta_dot0: Any = None,
    theta0: Any = None,
) -> np.ndarray:
    """Free-run simulation of a recorded stretch: θ in the recording's frame, shape (N,) [rad].

    The model starts from :func:`initial_state` of the stretch's first samples (or the given
    ``theta0`` [rad, recording frame] / ``theta_dot0`` [rad/s]) and is driven by the stretch's
    duty cycle only (no later correction from the measurements). The actuator saw the first duty
    cycle before the stretch began (its delay line holds it, as the motor sits at its steady state).
    Data with several segments (:func:`aeropend_ident.greybox.uniform.concat_uniform`) run each segment from
    its own initial
    state; ``theta0`` / ``theta_dot0`` are then sequences with one value (or None) per segment.

    Raises
    ------
    IdentificationError
        If the simulation fails (wrapped :class:`~aeropend_sim.simulation.SimulationError`).
    """
    if len(data.segments) > 1:
        parts = data.parts()
        th0s = [None] * len(parts) if theta0 is None else list(theta0)
        thd0s = [None] * len(parts) if theta_dot0 is None else list(theta_dot0)
        return np.concatenate([free_run_theta(rig, p, theta_offset, v, a)
                               for p, v, a in zip(parts, thd0s, th0s, strict=True)])
    x0 = initial_state(rig, data.theta, data.duty, data.dt, theta_offset, theta_dot0, theta0)
    try:
        traj = simulate(rig, data.duty, x0=x0, dt=data.dt, tau_before=float(data.duty[0]))
    except (SimulationError, ModelError) as exc:
        raise IdentificationError(f"simulation of {data.source or 'the recording'} failed: {exc}") from exc
    return traj.theta - theta_offset


def error_metrics(measured: np.ndarray, simulated: np.ndarray, span: float | None = None) -> dict[str, float]:
    """Fit metrics of a simulated angle against the measured one.

    NRMSE = RMS(θ_sim − θ_meas) / (max θ_meas − min θ_meas), dimensionless (0 = perfect; a
    constant prediction at the mid-range scores about 0.3 on a two-level signal); inf when the
    span is 0. ``span``: normalise by this span [rad] instead of the recorded range (a hold scored
    in a longer recording).

    Returns
    -------
    dict
        ``nrmse`` [1], ``rms_error`` [rad], ``max_abs_error`` [rad], ``range`` [rad] (the span
        used), ``n``.
    """
    measured = np.asarray(measured, dtype=float)
    e = np.asarray(simulated, dtype=float) - measured
    if span is not None:
        rng = float(span or 0.0)
    else:
        rng = float(np.ptp(measured)) if measured.size else 0.0
    rms = float(np.sqrt(np.mean(e**2))) if e.size else math.nan
    return {
        "nrmse": rms / rng if rng > 0.0 else math.inf,
        "rms_error": rms,
        "max_abs_error": float(np.max(np.abs(e))) if e.size else math.nan,
        "range": rng,
        "n": int(e.size),
    }


def _parameter_specs(rig: Rig, params: Sequence[str] | None, theta_offset: float,
                     initial: Mapping[str, float] | None,
                     bounds: Mapping[str, tuple[float, float]] | None) -> list[ParameterSpec]:
    """The checked :class:`aeropend_ident.greybox.parameters.ParameterSpec` of every parameter
    :func:`fit_greybox` fits."""
    names = list(default_parameters(rig, theta_offset) if params is None else params)
    if not names:
        raise IdentificationError("no parameters to fit; expected at least one name")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise IdentificationError(f"parameter(s) {dup} requested more than once")
    initial = dict(initial or {})
    bounds = dict(bounds or {})
    unknown = sorted((set(initial) | set(bounds)) - set(names))
    if unknown:
        raise IdentificationError(f"initial/bounds given for {unknown}, which are not fitted ({names})")
    specs = [parameter_spec(n, rig, theta_offset, initial.get(n), bounds.get(n)) for n in names]
    return specs


def _initial_state_box(data: UniformData) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Noise level of θ and the bounded coordinates of the initial-state corrections (:func:`fit_greybox`)."""
    # nuisance coordinates: corrections (δθ₀ [rad], δθ̇₀ [rad/s]) to the estimated initial state of
    # every segment, bounded by 5 σ of the estimates for the measured noise level
    sigma = float(np.median([measurement_noise(p.theta) for p in data.parts()]))
    n_seg = len(data.segments)
    x_bound = np.tile(np.maximum(5.0 * sigma * np.array([1.0, _slope_noise_gain(data.dt)]), 1e-12), n_seg)
    # coordinates w = 1 + (δ + bound)/(bound/5) ∈ [1, 11], δ = 0 at w = 6 (see ParameterSpec)
    lo_x, hi_x, mid_x = np.full(2 * n_seg, 1.0), np.full(2 * n_seg, 11.0), np.full(2 * n_seg, 6.0)
    return sigma, x_bound, lo_x, hi_x, mid_x


def _solve_stages(
    data: UniformData, make_residual: Callable[[list[tuple[int, int]], bool], Any], solve: Callable[..., Any],
    x0_correction: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], z0: np.ndarray, lo: np.ndarray,
    hi: np.ndarray,
    box: tuple[np.ndarray, np.ndarray, np.ndarray], *, init_horizon: float | None, tol: float,
    fit_initial_state: bool, sigma: float, th0_est: np.ndarray, thd0_est: np.ndarray,
) -> tuple[Any, np.ndarray, int, int, np.ndarray, np.ndarray]:
    """The stages of :func:`fit_greybox`: optional multiple shooting, free run, initial-state polish.

    Returns the final ``least_squares`` solution, the start residual, the evaluation counts and
    the initial states (θ₀, θ̇₀ per segment) used.
    """
    lo_x, hi_x, mid_x = box
    full = data.bounds()  # one free run per recording, each from its own initial state
    free_residual = make_residual(full, with_x0=False)
    r0 = free_residual(z0)
    nfev = njev = 0
    z_start = z0
    if init_horizon is not None:
        windows = [(a + wa, a + wb) for a, b in full
                   for wa, wb in _split_windows(b - a, data.dt, float(init_horizon))]
        if len(windows) > len(full):
            # an initialiser only: a loose tolerance is enough (the free-run stage refines)
            stage1 = solve(make_residual(windows, with_x0=False), z0, lo, hi, max(tol, INIT_STAGE_TOL))
            nfev, njev = int(stage1.nfev), int(stage1.njev or 0)
            z_start = np.clip(stage1.x, lo, hi)
    sol = solve(free_residual, z_start, lo, hi)
    nfev += int(sol.nfev)
    njev += int(sol.njev or 0)
    th0, thd0 = th0_est, thd0_est
    if fit_initial_state and sigma > 1e-9:
        # polish with the initial state free, from the free-run optimum (cheap when the estimate
        # was already right, e.g. on noise-free data)
        sol = solve(make_residual(full, with_x0=True), np.concatenate([np.clip(sol.x, lo, hi), mid_x]),
                    np.concatenate([lo, lo_x]), np.concatenate([hi, hi_x]))
        nfev += int(sol.nfev)
        njev += int(sol.njev or 0)
        d_th, d_thd = x0_correction(sol.x)
        th0, thd0 = th0_est + d_th, thd0_est + d_thd
    return sol, r0, nfev, njev, th0, thd0


def _parameter_estimates(specs: Sequence[ParameterSpec], sol: Any, lo_z: np.ndarray,
                         hi_z: np.ndarray) -> list[ParameterEstimate]:
    """Fitted values with standard errors (and bound flags) of the parameters of :func:`fit_greybox`."""
    n_p = len(specs)
    lo_all = lo_z[: sol.x.size]
    hi_all = hi_z[: sol.x.size]
    pinned = (np.abs(sol.x - lo_all) <= 1e-6 * lo_all) | (np.abs(sol.x - hi_all) <= 1e-6 * hi_all)
    std_z = _std_errors(sol.jac, sol.fun, pinned)[:n_p]
    estimates = []
    for s, z, sz, at_bound in zip(specs, sol.x[:n_p], std_z, pinned[:n_p], strict=True):
        v = s.from_z(z)
        se = s.dp_dz(v) * sz
        estimates.append(ParameterEstimate(
            name=s.name, unit=s.unit, value=v, std_error=float(abs(se)), initial=s.initial,
            lower=s.lower, upper=s.upper, log=s.log, at_bound=bool(at_bound),
        ))
    return estimates


@single_blas
def fit_greybox(
    recording: Recording | UniformData,
    rig: Rig,
    params: Sequence[str] | None = None,
    *,
    theta_offset: float = 0.0,
    initial: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    dt: float | None = None,
    decimate: int = 1,
    max_nfev: int = 400,
    tol: float = 1e-10,
    diff_step: float = 1e-5,
    init_horizon: float | None = None,
    fit_initial_state: bool = True,
    verbose: int = 0,
) -> GreyBoxResult:
    """Fit rig parameters to a recording by output error (free-run θ vs recorded θ).

    Parameters
    ----------
    recording : Recording, UniformData, or a sequence of them
        Training data: ``theta`` [rad] and the duty cycle; a :class:`Recording` goes through
        :func:`aeropend_ident.greybox.uniform.uniform_data` (validation, resampling, decimation). Several
        recordings are fitted
        together (:func:`aeropend_ident.greybox.uniform.concat_uniform`), each from its own initial state;
        they must share the
        grid step. The data must excite the rig (:func:`aeropend_ident.greybox.uniform.check_excited`).
    rig : Rig
        Model structure (effect switches) and starting values.
    params : sequence of str, optional
        Parameters to fit (default :func:`aeropend_ident.greybox.parameters.default_parameters`).
    theta_offset : float
        Angle offset θ_model − θ_recorded [rad] the rig's end stops are written for (start
        value if :data:`aeropend_ident.greybox.parameters.THETA_OFFSET` is fitted, fixed otherwise); see
        :func:`aeropend_ident.greybox.parameters.rig_theta_offset`.
    initial : mapping, optional
        Starting values overriding the rig's.
    bounds : mapping, optional
        ``{name: (lower, upper)}`` overriding the declared fit bounds.
    dt : float, optional
        Grid period [s] (default the recording's median interval).
    decimate : int
        Decimation factor (see :func:`aeropend_ident.greybox.uniform.uniform_data`).
    max_nfev : int
        Most residual evaluations per stage (each one simulation; SciPy does not count the
        ``n_params`` simulations of each finite-difference Jacobian).
    tol : float
        ``ftol`` = ``xtol`` = ``gtol`` of the optimiser.
    diff_step : float
        Relative finite-difference step of the Jacobian in the optimiser coordinates (z >= 1,
        see :class:`aeropend_ident.greybox.parameters.ParameterSpec`), well above the ODE tolerance 1e-8.
    init_horizon : float, optional
        If given [s], the free-run fit starts from a **multiple-shooting** fit: the data are cut
        into windows of this length, each simulated from its own recorded initial state
        (:func:`initial_state` of the window's first samples), all windows' errors minimised
        together. Short horizons keep simulation errors from accumulating, so this stage is far
        less prone to local minima when the start is poor; it is solved to the loose tolerance
        :data:`INIT_STAGE_TOL` and the free-run stage then refines it.
    fit_initial_state : bool
        Also fit the initial angle and angular velocity of the free run (nuisance parameters:
        corrections to the estimates of :func:`initial_state`, bounded by five standard
        deviations of those estimates for the noise level of θ, :func:`measurement_noise`, at
        least the rounding noise of a detected angle quantum). On noisy data the short-window
        velocity estimate alone would leave a start-up transient in the residual and bias the fit;
        the bounds stop the initial state from absorbing model error. Held when θ shows neither
        noise nor a lattice (e.g. a noise-free simulation). The values used are
        reported in :attr:`GreyBoxResult.initial_state` and counted in the standard errors.
    verbose : int
        Passed to :func:`scipy.optimize.least_squares`.

    Returns
    -------
    GreyBoxResult

    Raises
    ------
    IdentificationError
        On an unusable recording (:func:`aeropend_ident.greybox.uniform.check_recording`,
        :func:`aeropend_ident.greybox.uniform.check_excited`), an unknown
        parameter, a parameter whose effect is switched off, a duplicate, or a start outside the
        bounds.
    """
    t_start = time.perf_counter()
    parts = [recording] if isinstance(recording, (Recording, UniformData)) else list(recording)
    for k, part in enumerate(parts):
        if isinstance(part, Recording):
            check_recording(part)
            parts[k] = uniform_data(part, dt=dt, decimate=decimate)
            dt = parts[0].dt / parts[0].decimate if dt is None else dt
    data = concat_uniform(parts)
    check_excited(data)
    specs = _parameter_specs(rig, params, theta_offset, initial, bounds)
    start_values = {s.name: s.initial for s in specs}
    rig0, off0 = apply_parameters(rig, start_values, theta_offset)
    # the end stops of rig0 are written for off0; offsets are applied relative to it from here on
    z0 = np.array([s.to_z(s.initial) for s in specs])
    lo = np.array([s.to_z(s.lower) for s in specs])
    hi = np.array([s.to_z(s.upper) for s in specs])
    z0 = np.clip(z0, lo, hi)
    penalty = 10.0 * max(float(np.ptp(data.theta)), 1e-3)
    n_p = len(specs)
    th0_est = np.array([float(p.theta[0]) for p in data.parts()])
    thd0_est = np.array([initial_velocity(p.theta, p.dt) for p in data.parts()])
    sigma, x_bound, lo_x, hi_x, mid_x = _initial_state_box(data)

    def x0_correction(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = (z[n_p:] - mid_x) * x_bound / 5.0
        return d[0::2], d[1::2]

    def candidate(z: np.ndarray) -> tuple[Rig, float]:
        values = {s.name: s.from_z(zi) for s, zi in zip(specs, z[:n_p], strict=True)}
        return apply_parameters(rig0, values, off0)

    def make_residual(windows: list[tuple[int, int]], with_x0: bool) -> _Residuals:
        return _Residuals(data, windows, with_x0, candidate, x0_correction, (th0_est, thd0_est), penalty,
                          diff_step, (lo, hi))

    def solve(residual: Any, z_start: np.ndarray, lo_z: np.ndarray, hi_z: np.ndarray, t: float = tol) -> Any:
        residual.bounds = (lo_z, hi_z)
        return least_squares(
            residual, z_start, bounds=(lo_z, hi_z), x_scale=1.0, method="trf", jac=residual.jacobian,
            ftol=t, xtol=t, gtol=t, max_nfev=max_nfev, verbose=verbose,
        )

    sol, r0, nfev, njev, th0, thd0 = _solve_stages(
        data, make_residual, solve, x0_correction, z0, lo, hi, (lo_x, hi_x, mid_x), init_horizon=init_horizon,
        tol=tol, fit_initial_state=fit_initial_state, sigma=sigma, th0_est=th0_est, thd0_est=thd0_est)
    fit_rig, fit_off = candidate(sol.x)
    theta_fit = free_run_theta(fit_rig, data, fit_off, _one(thd0), _one(th0))
    estimates = _parameter_estimates(specs, sol, np.concatenate([lo, lo_x]), np.concatenate([hi, hi_x]))
    return GreyBoxResult(
        rig=fit_rig, theta_offset=fit_off, initial_rig=rig0, initial_theta_offset=off0,
        parameters=tuple(estimates), cost=float(sol.cost), initial_cost=float(0.5 * np.sum(r0**2)),
        nfev=nfev, njev=njev, success=bool(sol.success), status=int(sol.status),
        message=str(sol.message), metrics=error_metrics(data.theta, theta_fit), data=data,
        theta_fit=theta_fit, elapsed=time.perf_counter() - t_start,
        initial_state=(float(th0[0]), float(thd0[0])),
        initial_states=tuple((float(a), float(b)) for a, b in zip(th0, thd0, strict=True)),
    )


class _Residuals:
    """The output-error residual of :func:`fit_greybox` on a set of windows, and its Jacobian.

    ``candidate(z)`` gives the rig and offset of a coordinate vector, ``x0_correction(z)`` the
    initial-state corrections of every segment (with ``with_x0``, whose windows are then the data's
    segments, one each, and ``estimates`` the per-segment estimates θ₀, θ̇₀); each window is replayed
    by its own :class:`~aeropend_ident.greybox.batch.RigReplays` with the actuator holding the
    window's first command before it (as :func:`free_run_theta`); residuals of many vectors are one
    batched replay per window. A vector whose rig, initial state or replay fails gets ``penalty``
    everywhere.
    """

    def __init__(self, data: UniformData, windows: list[tuple[int, int]], with_x0: bool,
                 candidate: Callable[[np.ndarray], tuple[Rig, float]],
                 x0_correction: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                 estimates: tuple[np.ndarray, np.ndarray],
                 penalty: float, diff_step: float, bounds: tuple[np.ndarray, np.ndarray]) -> None:
        self.parts = [_window(data, a, b) for a, b in windows]
        self.velocities = [initial_velocity(p.theta, p.dt) for p in self.parts]
        self.measured = np.concatenate([p.theta for p in self.parts])
        self.replays = [RigReplays(p.duty, p.dt, tau_before=float(p.duty[0])) for p in self.parts]
        self.with_x0, self.candidate, self.x0_correction = with_x0, candidate, x0_correction
        self.th0, self.thd0 = estimates
        self.penalty, self.diff_step, self.bounds = penalty, diff_step, bounds
        self._cache: dict[bytes, np.ndarray] = {}

    def __call__(self, z: np.ndarray) -> np.ndarray:
        return self.rows([z])[0]

    def rows(self, zs: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Residuals of many coordinate vectors, the new ones in one batched replay per window."""
        keys = [np.asarray(z, dtype=float).tobytes() for z in zs]
        found = {k: self._cache[k] for k in keys if k in self._cache}
        new = [k for k in dict.fromkeys(keys) if k not in found]
        if new:
            computed = dict(zip(new, self._compute([np.frombuffer(k) for k in new]), strict=True))
            found.update(computed)
            if len(self._cache) + len(computed) > 64:  # bounded memory; this call's rows are kept above
                self._cache.clear()
            self._cache.update(computed)
        return [found[k] for k in keys]

    def _compute(self, zs: list[np.ndarray]) -> list[np.ndarray]:
        cands = []
        for b, z in enumerate(zs):
            try:
                d_x0 = self.x0_correction(z) if self.with_x0 else (None, None)
                cands.append((b, *self.candidate(z), *d_x0))
            except IdentificationError:
                continue
        sims = [np.full((len(zs), p.theta.size), np.nan) for p in self.parts]
        windows = zip(sims, self.parts, self.velocities, self.replays, strict=True)
        for k, (sim, p, v, rep) in enumerate(windows):
            rows, x0 = [], []
            for b, r_rig, r_off, d_th, d_thd in cands:
                try:
                    x0.append(initial_state(r_rig, p.theta, p.duty, p.dt, r_off,
                                            self.thd0[k] + d_thd[k] if self.with_x0 else v,
                                            self.th0[k] + d_th[k] if self.with_x0 else None))
                except IdentificationError:
                    continue
                rows.append((b, r_rig, r_off))
            if rows:
                th, _ok = rep.run([r for _, r, _ in rows], np.array(x0), ("theta",))
                for j, (b, _r, r_off) in enumerate(rows):
                    sim[b] = th["theta"][j] - r_off
        out = []
        for b in range(len(zs)):
            r = np.concatenate([sim[b] for sim in sims]) - self.measured
            out.append(r if np.all(np.isfinite(r)) else np.full(self.measured.size, self.penalty))
        return out

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        """scipy's "2-point" forward differences (relative step ``diff_step``, one-sided into the
        bounds), the 1 + n_z residuals in one batched replay per window."""
        z = np.asarray(z, dtype=float)
        lo_z, hi_z = self.bounds
        h = self.diff_step * np.where(z >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(z))
        h = np.where((z + h > hi_z) & (z - h >= lo_z), -h, h)
        h = (z + h) - z
        shifted = [z + np.where(np.arange(z.size) == j, h[j], 0.0) for j in range(z.size)]
        f0, *fs = self.rows([z, *shifted])
        return np.column_stack([(f - f0) / hj for f, hj in zip(fs, h, strict=True)])


def _one(values: np.ndarray) -> Any:
    """Per-segment initial values as :func:`free_run_theta` takes them (a float for one segment)."""
    return float(values[0]) if values.size == 1 else list(values)


def _split_windows(n: int, dt: float, horizon: float) -> list[tuple[int, int]]:
    """Consecutive windows of about ``horizon`` seconds covering n samples (last one merged if short).

    Raises
    ------
    IdentificationError
        If ``horizon`` is not positive or shorter than :data:`N_DIFF` samples.
    """
    w = round(horizon / dt) if math.isfinite(horizon) else 0
    if w < max(N_DIFF, 2):
        raise IdentificationError(
            f"init_horizon = {horizon!r} s is shorter than {max(N_DIFF, 2)} samples of {dt:g} s"
        )
    edges = list(range(0, n, w))
    if n - edges[-1] < w // 2 and len(edges) > 1:
        edges.pop()
    edges.append(n)
    return list(itertools.pairwise(edges))


def _std_errors(jac: np.ndarray, res: np.ndarray, pinned: np.ndarray) -> np.ndarray:
    """1-σ standard errors of the optimiser coordinates: sqrt(diag(s²·(JᵀJ)⁻¹)).

    s² = Σr²/(m − n_free). Coordinates pinned at a bound are held fixed (their columns dropped;
    their error is NaN: the bound, not the data, set them). Free coordinates with a weight above
    1 % in a direction the data do not determine (singular value below 1e-10 of the largest)
    get inf; the others are computed in the determined subspace.
    """
    jac = np.asarray(jac, dtype=float)
    n = jac.shape[1]
    std = np.full(n, math.nan)
    free = np.flatnonzero(~np.asarray(pinned, dtype=bool))
    if free.size == 0:
        return std
    dof = max(res.size - free.size, 1)
    s2 = float(np.sum(res**2)) / dof
    _, sv, vt = np.linalg.svd(jac[:, free], full_matrices=False)
    if sv.size == 0 or sv[0] == 0.0:
        std[free] = math.inf
        return std
    keep = sv > 1e-10 * sv[0]
    cov = (vt[keep].T / sv[keep] ** 2) @ vt[keep] * s2
    sub = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    if not keep.all():
        weak = np.abs(vt[~keep]).max(axis=0) > 1e-2
        sub[weak] = math.inf
    std[free] = sub
    return std

