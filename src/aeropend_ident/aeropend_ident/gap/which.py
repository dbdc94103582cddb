"""Which unmodelled effect causes a sim-to-real gap, and how far the gap shrinks once it is added.

Pipeline of :func:`diagnose_effects`. Two data sets: the **fit** recordings (effects are
fitted there) and the **validation** recordings (effects are ranked and chosen there; carved from
the fit data by :func:`aeropend_ident.io.split.validation_split`). The **held-out** recordings of
:func:`aeropend_ident.gap.run.run_gap` are never seen here.

1. **Validation of the inputs** (:func:`aeropend_ident.gap.effects.check_recordings`): θ and the
   duty cycle present and finite, enough samples; the channels recorded in every recording decide
   which catalog effects are identifiable (:func:`aeropend_ident.gap.effects.identifiable`).
   Noise part of every channel (:func:`_noise_var`: white-noise estimate, at least the
   quantisation floor). When the validation part shows no gap above noise but the fit part does
   after each recording's first second (the stretch never reaches, say, an end stop), the
   effects are ranked on the fit part and the report says so.
2. **Screening by discrepancy SINDy under group sparsity** (:func:`screen`): for each state
   equation that the recorded channels support (θ̈ always; di_a/dt, dω₁/dt and the algebraic
   v_a map when i_a, ω₁, v_a are recorded) the residual of the nominal model,
   r = ẋ_recorded − f_nominal(x), is regressed on the catalog's term groups. The column of an
   effect parameter is the change of the model's right-hand side when it goes from its nominal
   (``off``) value to a typical physical magnitude (``probe``), evaluated on the recorded states.
   Strong form (estimated derivatives) and weak form (test-function integrals of
   :func:`aeropend_ident.sindy.core.weak_matrices`). Whole groups are selected by group orthogonal
   matching pursuit with a BIC stop (:func:`group_select`); a bootstrap over time segments gives
   each group's inclusion frequency. Each effect's own regression coefficient is its
   **equation-error estimate** of the physical parameter.
3. **Confirmation by grey-box output error** (:func:`fit_effects`): each shortlisted effect's
   physical parameters are fitted by free-run output error on every recorded channel (θ, i_a,
   v_a, ω₁, each normalised by its range), over the physical range the rig and the data imply
   (:class:`aeropend_ident.gap.effects.EffectContext`), from several starts (the equation-error
   estimate, a scan of the range, the probe), each refined by
   :func:`scipy.optimize.least_squares` with an absolute-step Jacobian.
4. **Ranking and decision**: candidates are ranked by the share of the nominal validation error
   they remove (an effect that nests a simpler one must beat it by :data:`MIN_EXPLAINED_SECOND`
   of what the simpler one leaves). "No significant gap" when no channel's nominal validation
   error exceeds :data:`ABOVE_NOISE` times its noise part plus the chance margin of its held
   rounding errors (:func:`_rounding_chance`), or when no effect removes
   :data:`MIN_EXPLAINED` of the validation gap above noise with a BIC gain of :data:`MIN_BIC_GAIN`
   on the fit data (and, when the effects are ranked on the fit part because the validation part
   shows no gap, with an in-sample split-test p-value of at most :data:`IN_SAMPLE_MAX_P`).
   Further effects are added by forward selection (:func:`_add_effect`) while
   the chosen set leaves a gap above the noise, up to ``max_effects``.
5. **Two numbers: presence and completeness** (:func:`_evidence`). An effect's **presence**
   (0..1) is the evidence that it is in the plant: a sample-split test of its fit (made on the
   fit part) on the validation part (:func:`split_test`: one-sided t test that it shrinks each
   second's validation error, weighted by the share of that second's error above noise, by more
   than the share the decision asks for, the sample size corrected for the correlation of
   neighbouring seconds),
   against the nominal rig for a single effect and against the set before it for an effect added
   by forward selection; the p-values of every candidate tried are adjusted for
   the false-discovery rate (Benjamini-Hochberg), and presence = (1 − q) × the bootstrap
   frequency (over validation segments) with which the effect wins against the candidates that
   explain the same error (first among the single effects; the added gain passing), times
   0.5 + 0.5·completeness (:func:`misspecification_factor`: a residual left far above the noise
   shows something outside the catalog, for which a passing effect may stand in). So presence
   ≥ 0.9 reads "at a false-discovery rate of 10 %, not a rival's stand-in, and the model leaves
   (nearly) the noise level". **Completeness**
   (:func:`_completeness`: channel by channel, the validation error left over the noise part)
   says how fully the chosen set explains the gap. The words follow from the two by stated
   thresholds (:func:`status_of`): a chosen effect is ``named`` with presence ≥
   :data:`NAMED_PRESENCE` and a set completeness ≥ :data:`NAMED_COMPLETENESS`, otherwise a
   ``candidate`` (a cause outside the catalog leaves a residual far above the noise, whichever
   effect approximates it best); runner-ups that win a share of the resamples, and physics-confusable
   runner-ups neither of which removes :data:`SWAP_GAIN` of what the other leaves
   (:func:`_not_separated`), are ``not separated`` from the first (``ambiguous_with``); others
   are a ``candidate`` with presence ≥ :data:`CANDIDATE_PRESENCE`, else ``not significant``.
6. **Validation table** (:func:`gap_metrics`): NRMSE per channel, max error, steady-state map
   error and step metrics before and after, per cumulative effect set.

Quantisation is detected directly from the recorded angle (values on a lattice of step q,
:func:`aeropend_ident.gap.effects.detect_quantum`): a property of the data, not an effect to fit.
It is reported in ``detected`` (and ranked, marked ``detected``), sets the corrected rig's angle
LSB and the noise floor (q²/12), and never enters ``chosen``, whose effects later steps refit.

A timing effect fitted shorter than half the sample period (:func:`unresolved_times`) is not
resolved at that rate: never chosen (first, added or as a replacement), presence 0, entry field
``unresolved`` with the reason; what such a fit matches is when the logger stamps a channel.

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import savgol_filter
from scipy.stats import false_discovery_control
from scipy.stats import t as student_t

from aeropend_ident.errors import GapError, IdentificationError
from aeropend_ident.gap.effects import (
    Effect,
    EffectContext,
    EffectParameter,
    MeasurementMap,
    ParamRange,
    apply_effects,
    catalog,
    check_recordings,
    detect_quantum,
    get_effect,
    identifiable,
    measurement_noise,
    nominal_model_check,
)
from aeropend_ident.greybox.batch import RigReplays, one_replay_thread, replay_threads
from aeropend_ident.greybox.fit import motor_equilibrium
from aeropend_ident.greybox.replay import FreeRun, free_run
from aeropend_ident.io.jsonutil import jsonable
from aeropend_ident.sindy.core import weak_matrices
from aeropend_ident.sindy.model import IdentData
from aeropend_sim.compiled.plant import derivatives
from aeropend_sim.components import registry
from aeropend_sim.model import ModelError, PlantModel
from aeropend_sim.params import Rig, rig_to_dict
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import SimulationError, simulate

#: Channels compared in the output-error fits (when recorded).
FIT_CHANNELS = ("theta", "i_a", "v_a", "omega_rotor")
#: Least share of the validation gap above noise an effect must remove to be significant.
MIN_EXPLAINED = 0.25
#: Least further share of the remaining validation gap above noise a second effect must remove.
MIN_EXPLAINED_SECOND = 0.3
#: Further screened effects confirmed when the best shortlisted effect leaves more than
#: EXTEND_BELOW_GAP of the validation gap above noise.
EXTEND_SHORTLIST = 3
EXTEND_BELOW_GAP = 0.2
#: Screened groups and ranked single effects tried (each) as the next effect of forward selection.
FORWARD_CANDIDATES = 3
#: Least share of the validation gap above noise left by the chosen set that a confusable
#: alternative must remove to replace a chosen effect (:func:`_swap_confusables`).
SWAP_GAIN = 0.1
#: BIC gain (negative change) an effect must reach on the fit data.
MIN_BIC_GAIN = 10.0
#: Largest split-test p-value (:func:`split_test`) with which an effect is chosen when the effects are
#: ranked on the fit part itself (the in-sample fallback of :func:`_setup`): there the test is
#: in-sample and optimistic, and p ≤ 0.5 asks only that the effect remove the required share of the
#: gap second by second on a weighted average, not through a few seconds that carry the total (an
#: inertia scale fitted to a closed-loop log's first seconds on an effect-free lab plant: 26 % of the
#: total, p 0.98; docs/findings/gap.md).
IN_SAMPLE_MAX_P = 0.5
#: Nominal θ error below this many noise standard deviations counts as noise floor (the floors
#: reported per channel).
NOISE_FLOOR_FACTOR = 3.0
#: A gap is above the noise floor when some channel's nominal validation error exceeds its noise
#: part by this factor (squared errors: RMS 1.12× the noise; the noise estimates of
#: :func:`_noise_var` are good to about 5 % on white noise), plus the chance margin of a held
#: rounding error (:data:`ROUNDING_CHANCE_Z`).
ABOVE_NOISE = 1.25
#: Standard deviations of the rounding part of the noise added to the above-noise threshold
#: (:func:`_rounding_chance`). With white noise far below a lattice step (a 10-bit encoder holding
#: a set point), the rounding error e = Q(θ) − θ is one draw of U(−q/2, q/2) per hold, not one per
#: sample: its mean square q²/12 is then an average over a few holds, with a relative standard
#: deviation 0.894/√(holds). An effect-free closed loop at 50 Hz read 1.43× its noise part
#: (effective holds 17, one standard deviation 0.22 of it) and had a voltage drop of −0.0016 V
#: fitted to its holds' rounding errors (docs/findings/gap.md).
ROUNDING_CHANCE_Z = 2.0
#: sqrt(Var(u²))/E(u²) for u uniform on (−q/2, q/2): E(u²) = q²/12, Var(u²) = q⁴(1/80 − 1/144).
_ROUNDING_SQUARE_REL_SD = 12.0 * math.sqrt(1.0 / 80.0 - 1.0 / 144.0)
#: Residual samples per independent sample in the BIC (free-run residuals are autocorrelated), at
#: the thesis rig's 490 Hz; see :data:`BIC_RESIDUAL_TIME` for other rates.
BIC_DECIMATION = 20
#: Recording time [s] per independent residual sample in the confirmation BIC: the
#: :data:`BIC_DECIMATION` samples at 490 Hz. A free-run error stays correlated over a time set by
#: the rod's dynamics, not by the logger, so a 40 s log carries the same evidence at 50 Hz as at
#: 490 Hz (counting 1 in 20 samples at 50 Hz asked a slow logger for 10× the evidence per second).
#: Tried once before the resampling of jittered logs put each command on its own sample, it named
#: a motor time constant on an effect-free jittered 100 Hz log; with that fixed, it no longer does
#: (docs/findings/gap.md, "The BIC's effective sample count").
BIC_RESIDUAL_TIME = BIC_DECIMATION / 490.0


def bic_samples(preps: Sequence[Prepared]) -> int:
    """Independent residual samples the confirmation BIC counts in ``preps`` (all channels).

    Each recording contributes its residual samples (channels × samples) divided by the number of
    its samples in :data:`BIC_RESIDUAL_TIME` (at least 1: a log slower than that counts every
    sample); at least 10 in all.

    Parameters
    ----------
    preps : sequence of Prepared
        The recordings the BIC is computed on.

    Returns
    -------
    int
        The effective sample count n_eff of ``n_eff·ln(SSE/n_eff) + k·ln(n_eff)``.
    """
    return max(sum(len(p.y) * p.n // max(round(BIC_RESIDUAL_TIME / p.dt), 1) for p in preps), 10)


#: Number of shortlisted effects confirmed by grey-box fits.
SHORTLIST = 5
#: Time block [s] of the block-sandwich parameter covariance (:func:`parameter_covariance`): longer
#: than the few tenths of a second a rod's free-run error stays correlated by its own dynamics, short
#: enough that a 40 s recording holds 20 blocks.
COVARIANCE_BLOCK_S = 2.0
#: Bootstrap resamples for screening inclusion and the ranking's bootstrap frequencies.
N_BOOTSTRAP = 30
#: Savitzky-Golay window [s] of the derivative estimates (strong form) and initial rates.
SAVGOL_WINDOW = 0.06
#: Sample period [s] of the screening regressions (the recordings are decimated to it).
SCREEN_DT = 0.016
#: Segment length [s] of the bootstraps.
SEGMENT = 1.0
#: Window [s] of the fit that takes a recorded motor channel's value at a replay's first sample.
INITIAL_WINDOW = 0.02
#: Window [s] at the start of a recording over which each replay's initial θ and θ̇ are estimated by
#: least squares (one bootstrap segment). A rate from a few noisy or quantised samples (10 at 100 Hz)
#: is off by a few 0.01 rad/s, which starts a free oscillation that the rod's light damping carries
#: for seconds: a validation "gap" several times the noise on an effect-free plant.
INITIAL_STATE_WINDOW = 1.0
#: Fewest samples of that window for the estimate; a shorter recording keeps the smoothed start.
INITIAL_STATE_MIN_SAMPLES = 20
#: Largest correction of the smoothed start, in its standard deviations under the θ noise.
INITIAL_STATE_BOUND = 3.0
#: Perturbations of θ [rad] and θ̇ [rad/s] of the finite-difference sensitivities of that estimate.
INITIAL_STATE_STEPS = (1e-4, 1e-3)
#: Absolute finite-difference step of the fits' Jacobian, in optimiser units (log parameters:
#: 0.1 % of the value; linear ones: 0.1 % of the search range).
FD_STEP = 1e-3
#: Values scanned over the range of a one-parameter effect before the local refinement.
N_SCAN = 7
#: Most starts refined per fit, and the largest cost ratio (to the best start) of a second start.
MAX_STARTS = 2
MULTISTART_COST_RATIO = 3.0
#: Most residual evaluations of one local refinement.
MAX_NFEV = 15
#: Exponents the thrust-law fit starts from (the level kept at the reference speed).
THRUST_LAW_EXPONENTS = (1.5, 1.8, 2.2, 2.6)
#: Bootstrap share of the validation resamples in which a runner-up is first for it to be
#: reported as not separated from the first-ranked effect (``ambiguous_with``).
AMBIGUOUS_FIRST = 0.2
#: Validation error over its noise part (per channel, squared) up to which an effect (set) counts
#: as a complete explanation, and from which it counts as none; the completeness is scaled
#: log-linearly between. Ratio − 1 is the unexplained variance over the noise variance: complete
#: while the systematic error is below 30 % of the noise variance, no explanation once it is as
#: large as the noise itself. A model with the right structure and fitted parameters leaves
#: 1 + O(k/N) plus the few-% error of the noise estimate: measured 1.00–1.2 on the independent
#: benchmark's correctly named cases, 1.8 to thousands where the cause lies outside the catalog
#: (bench/results/gap_independent.md).
RESIDUAL_NOISE_OK = 1.3
RESIDUAL_NOISE_MAX = 2.0
#: A chosen effect is "named" with presence at least this (its false-discovery-rate adjusted
#: p-value ≤ 0.1, and winning its rivals' resamples) and a chosen set that explains at least
#: NAMED_COMPLETENESS of the gap ("mostly explained"); a chosen effect short of either is a
#: "candidate", as is an unchosen effect with presence ≥ CANDIDATE_PRESENCE (as likely present as not).
NAMED_PRESENCE = 0.9
NAMED_COMPLETENESS = 0.5
CANDIDATE_PRESENCE = 0.5


# ------------------------------------------------------------------------------ data
@dataclass
class Prepared:
    """One validated recording: uniform time base, channels used, normalisation scales, and the
    compiled plants its batched replays run on (:class:`aeropend_ident.greybox.batch.RigReplays`,
    built on first use)."""

    rec: Recording
    dt: float
    duty: np.ndarray
    y: dict[str, np.ndarray]
    scale: dict[str, float]
    _replays: RigReplays | None = field(default=None, repr=False, compare=False)
    _head: RigReplays | None = field(default=None, repr=False, compare=False)
    #: How the log began, decided once by its first replay (:func:`_initial_states`): True when
    #: the motor and the rod were at rest, False when the motor ran at the first duty cycle.
    _at_rest: bool | None = field(default=None, repr=False, compare=False)

    @property
    def n(self) -> int:
        return int(self.duty.size)

    @property
    def replays(self) -> RigReplays:
        """Batched replays of rig variants on this recording (:func:`replay_many`)."""
        if self._replays is None:
            self._replays = RigReplays(self.duty, self.dt, tau_before=float(self.duty[0]))
        return self._replays

    @functools.cached_property
    def start(self) -> dict[str, float]:
        """The recording's smoothed start, the same for every rig replaying it
        (:func:`_initial_state`): the recorded θ's rate [rad/s] at the first sample as
        ``"theta_dot"`` (:func:`initial_rate`) and each recorded motor channel's value at it
        (:func:`initial_value`: ``"i_a"`` [A], ``"omega_rotor"`` [rad/s], ``"v_a"`` [V])."""
        out = {"theta_dot": initial_rate(self.y["theta"], self.dt)}
        for c in ("i_a", "omega_rotor", "v_a"):
            if c in self.y:
                out[c] = initial_value(self.y[c], self.dt)
        return out

    @functools.cached_property
    def initial_sd(self) -> np.ndarray:
        """Standard deviations (2,) of the smoothed start's θ [rad] (one sample) and θ̇ [rad/s]
        (:func:`initial_rate`'s polynomial slope) under the θ channel's noise (:func:`_noise_var`)."""
        sigma = math.sqrt(_noise_var(self.y["theta"]))
        return sigma * np.array([1.0, math.sqrt(rate_variance_factor(self.dt, self.n))])

    @property
    def head(self) -> RigReplays | None:
        """Batched replays of the first :data:`INITIAL_STATE_WINDOW` seconds, on which a replay's
        initial θ, θ̇ are estimated (:func:`_refine_initial_states`); None for a recording too short
        for it."""
        k = min(self.n, round(INITIAL_STATE_WINDOW / self.dt))
        if k < INITIAL_STATE_MIN_SAMPLES:
            return None
        if self._head is None:
            self._head = RigReplays(self.duty[:k], self.dt, tau_before=float(self.duty[0]))
        return self._head


def prepare(recordings: Sequence[Recording], channels: frozenset[str]) -> list[Prepared]:
    """Validated recordings restricted to the channels compared (those all recordings have)."""
    out = []
    for r in recordings:
        y = {c: np.asarray(r.channels[c], dtype=float) for c in FIT_CHANNELS if c in channels}
        scale = {c: max(float(np.ptp(v)), 1e-6) for c, v in y.items()}
        out.append(Prepared(rec=r, dt=r.dt, duty=np.clip(r.duty, 0.0, 1.0), y=y, scale=scale))
    return out


def _sim_rig(rig: Rig) -> Rig:
    """Rig for the replay: no noise, no quantisation (the recording supplies those)."""
    if rig.effects.sensor_noise or rig.effects.quantisation:
        return rig.with_effects(sensor_noise=False, quantisation=False)
    return rig


def _rate_design(dt: float, n: int, window: float) -> np.ndarray:
    """Design matrix (k, order + 1) of :func:`initial_rate`'s polynomial (highest power first)."""
    k = int(min(max(round(window / dt), 8), n))
    return np.vander(np.arange(k) * dt, 4 if k >= 8 else 2)


def initial_rate(theta: np.ndarray, dt: float, window: float = 0.1) -> float:
    """θ̇ at the first sample [rad/s] from a cubic least-squares fit over ``window`` seconds."""
    x = _rate_design(dt, theta.size, window)
    coef, *_ = np.linalg.lstsq(x, theta[: x.shape[0]], rcond=None)
    return float(coef[-2])


def rate_variance_factor(dt: float, n: int, window: float = 0.1) -> float:
    """Variance [1/s²] of :func:`initial_rate` per unit variance of white noise on θ."""
    x = _rate_design(dt, n, window)
    return float(np.linalg.inv(x.T @ x)[-2, -2])


def initial_value(y: np.ndarray, dt: float, window: float = INITIAL_WINDOW) -> float:
    """Value at the first sample of a noisy channel: a quadratic least-squares fit over ``window``
    seconds evaluated at t = 0 (the noise of one sample would otherwise set the free run's start)."""
    k = int(min(max(round(window / dt), 4), y.size))
    coef = np.polyfit(np.arange(k) * dt, y[:k], 2 if k >= 6 else 0)
    return float(coef[-1])


def _initial_state(sim_rig: Rig, meas: MeasurementMap, prep: Prepared, at_rest: bool = False) -> np.ndarray:
    """Initial model state (5,) of a free-run replay of ``prep`` (see :func:`replay`).

    The angle from the recording; the rate from its smoothed start and the motor states (armature
    current, rotor speed, actuator lag) steady at the first duty cycle (a stretch cut from a running
    session), or, ``at_rest``, the rod still and the motor states steady at duty 0 (a log that
    begins as the motor is switched on); each recorded motor state at its recorded start.
    """
    th = prep.y["theta"]
    th0 = float(meas.to_model(th[:1])[0])
    start = prep.start
    thd0 = 0.0 if at_rest else start["theta_dot"] / meas.theta_scale
    i0, w0, tf0 = motor_equilibrium(sim_rig, 0.0 if at_rest else float(prep.duty[0]))
    if "i_a" in start and sim_rig.effects.armature_inductance == "dynamic":
        i0 = start["i_a"]
    if "omega_rotor" in start:
        w0 = start["omega_rotor"]
    if "v_a" in start and sim_rig.effects.actuator_lag:
        # the lag state from the recorded drive output (the stretch may start mid-transient)
        model = PlantModel(sim_rig)
        v0 = min(max(start["v_a"], 0.0), model.armature_voltage(1.0))
        tf0 = model.duty_for_voltage(v0)
    return np.array([th0, thd0, i0, w0, tf0])


def replay(rig: Rig, meas: MeasurementMap, prep: Prepared) -> dict[str, np.ndarray]:
    """Free-run replay of a recording: simulated channels in the recording's frame.

    The model starts at the angle and rate that best replay the recording's first
    :data:`INITIAL_STATE_WINDOW` (:func:`_refine_initial_states`, from the recorded angle through the
    inverse measurement map and a smoothed rate); the armature current and rotor speed start at
    their recorded values when those channels are recorded (a stretch cut from a longer run may
    begin mid-transient), otherwise at
    the steady state of the first duty cycle; the actuator lag state at the first duty cycle. The
    model is then driven by the recorded duty cycle only. One row of :func:`replay_many` (the
    diagnosis' sub-steps, so that every figure of a diagnosis comes from the same replays);
    :func:`replay_reference` replays with :func:`aeropend_sim.simulation.simulate` and gives the
    state too.

    Raises
    ------
    GapError
        If the simulation fails for this rig.
    """
    out = replay_many([(rig, meas)], prep)[0]
    if out is None:
        raise GapError(f"replay of {prep.rec.source or 'a recording'} with rig {rig.name!r} failed: the "
                       "rig's initial state or its replay is not finite")
    return out


def replay_reference(rig: Rig, meas: MeasurementMap, prep: Prepared) -> dict[str, np.ndarray]:
    """:func:`replay` by :func:`aeropend_sim.simulation.simulate` (the reference sub-steps), with the
    model state (N, 5) as ``"_x"``.

    Raises
    ------
    GapError
        If the simulation fails for this rig.
    """
    try:
        (sim_rig,), x0 = _initial_states([(rig, meas)], prep)
        traj = simulate(sim_rig, prep.duty, x0=x0[0], dt=prep.dt, tau_before=float(prep.duty[0]))
    except (SimulationError, ModelError, IdentificationError, ValueError) as exc:
        raise GapError(
            f"replay of {prep.rec.source or 'a recording'} with rig {rig.name!r} failed: {exc}") from exc
    out = {"theta": meas.to_recorded(traj.true["theta"])}
    for c in ("i_a", "v_a", "omega_rotor"):
        if c in prep.y:
            out[c] = traj.true[c]
    out["_x"] = traj.x
    return out


def _initial_states(rows: Sequence[tuple[Rig, MeasurementMap]], prep: Prepared
                    ) -> tuple[list[Rig], np.ndarray]:
    """The replay rigs (noise-free) and initial states (B, 5) of ``rows`` on ``prep``: the start of
    :func:`_initial_state`, its θ and θ̇ then estimated by :func:`_refine_initial_states`; a row whose
    start fails is NaN.

    The motor states a recording does not hold are not observed at its first sample. Two starts
    are possible when the first duty cycle is not 0: the motor steady at it and the rod's rate
    smoothed from the recording (a stretch cut from a running session), and everything at rest,
    the motor steady at duty 0 and the rod still (a log that begins as the controller or the test
    switches the motor on: a closed-loop run from the hanging rod). How a log began is a fact of the
    log, not of the rig replaying it: it is decided once, by the recording's first replay (the
    first row of the first call: the nominal rig in a diagnosis), as the start whose refined θ(0),
    θ̇(0) replay the first :data:`INITIAL_STATE_WINDOW` better (the output-error comparison with
    estimated initial conditions, Ljung, *System Identification*, 2nd ed., §7.3), and every later
    replay of that recording starts the same way. Decided per rig, the start could absorb a
    candidate's model error and switch where two starts' errors cross (on jahoyosr's held-out
    staircase pieces, five of them on the lower stop, the held-out shrink fell to 0.36). A
    spinning rotor assumed at the start of a log that begins at rest put 60-99 % of a closed-loop
    replay's squared error into its first second and biased the fits that weigh it (an inertia
    1.23× fitted as 1.43×).
    """
    rigs = [_sim_rig(rig) for rig, _ in rows]
    metas = [m for _, m in rows]
    two = float(prep.duty[0]) > 0.0

    def starts(at_rest: bool) -> np.ndarray:
        x0 = np.zeros((len(rows), 5))
        for b, sim_rig in enumerate(rigs):
            try:
                x0[b] = _initial_state(sim_rig, metas[b], prep, at_rest=at_rest)
            except (ModelError, IdentificationError, ValueError):
                x0[b] = np.nan
        return x0

    if not two or not rows or prep._at_rest is False:
        return rigs, _refine_initial_states(rigs, metas, starts(False), prep)[0]
    if prep._at_rest:
        return rigs, _refine_initial_states(rigs, metas, starts(True), prep)[0]
    run, run_err = _refine_initial_states(rigs, metas, starts(False), prep)
    rest, rest_err = _refine_initial_states(rigs, metas, starts(True), prep)
    prep._at_rest = bool(rest_err[0] < run_err[0])
    return rigs, rest if prep._at_rest else run


def _refine_initial_states(rigs: Sequence[Rig], metas: Sequence[MeasurementMap], x0: np.ndarray,
                           prep: Prepared) -> tuple[np.ndarray, np.ndarray]:
    """Initial θ, θ̇ of each row estimated on the recording's first :data:`INITIAL_STATE_WINDOW`.

    One Gauss-Newton step of the recorded angle's least squares over that window from the smoothed
    start (finite-difference sensitivities, :data:`INITIAL_STATE_STEPS`), all rows in one batched
    replay of the window: the output-error comparison with estimated initial conditions (Ljung,
    *System Identification*, 2nd ed., §7.3). The correction stays within
    :data:`INITIAL_STATE_BOUND` standard deviations of the smoothed start (:attr:`Prepared.initial_sd`):
    it removes what the noise put into the start, never a model error the window would otherwise
    show (a far-off model would take any start that shortens its first second's error). The motor
    states keep the values they are given (:func:`_initial_states` compares two such starts). A row
    whose window replay fails keeps its start.

    Parameters
    ----------
    rigs : sequence of Rig
        Noise-free replay rigs, B of them.
    metas : sequence of MeasurementMap
        Their measurement maps (recorded θ = map of model θ).
    x0 : ndarray, shape (B, 5)
        Starting states (NaN rows are left alone).
    prep : Prepared
        The recording.

    Returns
    -------
    (ndarray, ndarray)
        The states, shape (B, 5), and each row's squared θ error over the window after its
        correction (linearised; ∞ where the window replay failed or the recording has no window).
    """
    head = prep.head
    err = np.full(len(rigs), np.inf)
    if head is None or not len(rigs):
        return x0, err
    y = prep.y["theta"][: head.duty.size]
    bound = INITIAL_STATE_BOUND * prep.initial_sd
    trial = np.repeat(x0, 3, axis=0)
    trial[1::3, 0] += INITIAL_STATE_STEPS[0]
    trial[2::3, 1] += INITIAL_STATE_STEPS[1]
    sim, ok = head.run([r for r in rigs for _ in range(3)], trial, ("theta",))
    out = x0.copy()
    for b, meas in enumerate(metas):
        if not ok[3 * b: 3 * b + 3].all():
            continue
        th = meas.to_recorded(sim["theta"][3 * b: 3 * b + 3])
        jac = np.stack([(th[1] - th[0]) / INITIAL_STATE_STEPS[0], (th[2] - th[0]) / INITIAL_STATE_STEPS[1]],
                       axis=1)
        delta, *_ = np.linalg.lstsq(jac, y - th[0], rcond=None)
        if np.all(np.isfinite(delta)):
            delta = np.clip(delta, -bound, bound)
            out[b, :2] += delta
            err[b] = float(np.sum((y - th[0] - jac @ delta) ** 2))
    return out, err


def replay_many(rows: Sequence[tuple[Rig, MeasurementMap]], prep: Prepared,
                channels: Sequence[str] | None = None) -> list[dict[str, np.ndarray] | None]:
    """Free-run replays of many (rig, measurement map) rows on one recording, in one batch.

    What :func:`replay` gives for each row (without ``"_x"``), computed by
    :attr:`Prepared.replays` (:mod:`aeropend_ident.greybox.batch`: one compiled plant per model
    structure, the fit sub-steps); ``channels`` default to the recording's compared channels.
    A row whose initial state or replay fails is None.
    """
    names = tuple(prep.y) if channels is None else tuple(channels)
    rigs, x0 = _initial_states(rows, prep)
    sim, ok = prep.replays.run(rigs, x0, names)
    out: list[dict[str, np.ndarray] | None] = []
    for b, (_rig, meas) in enumerate(rows):
        if not ok[b]:
            out.append(None)
            continue
        row = {c: sim[c][b] for c in names}
        if "theta" in row:
            row["theta"] = meas.to_recorded(row["theta"])
        out.append(row)
    return out


def residuals(rig: Rig, meas: MeasurementMap, preps: Sequence[Prepared]) -> np.ndarray:
    """Normalised output errors of all recordings and channels, concatenated.

    Each channel's error is divided by the channel's range and by sqrt(N) of its recording, so
    every recording/channel pair weighs equally (the sum of squares is a sum of squared NRMSEs).

    Raises
    ------
    GapError
        If the replay fails on a recording.
    """
    r = residuals_many([(rig, meas)], preps)[0]
    if not np.all(np.isfinite(r)):
        raise GapError(f"replay with rig {rig.name!r} failed on "
                       f"{', '.join(p.rec.source or 'a recording' for p in preps)}")
    return r


def residuals_many(rows: Sequence[tuple[Rig, MeasurementMap]], preps: Sequence[Prepared]) -> np.ndarray:
    """:func:`residuals` of many (rig, measurement map) rows, shape (B, M): one batched replay per
    recording (:func:`replay_many`); a row whose replay fails on some recording is NaN there."""
    blocks = []
    for p in preps:
        sims = replay_many(rows, p)
        m = len(p.y) * p.n
        block = np.full((len(rows), m), np.nan)
        for b, sim in enumerate(sims):
            if sim is not None:
                block[b] = np.concatenate([(sim[c] - y) / (p.scale[c] * math.sqrt(p.n))
                                           for c, y in p.y.items()])
        blocks.append(block)
    return np.concatenate(blocks, axis=1)


# ------------------------------------------------------------------------------ fitting
@dataclass
class EffectFit:
    """Fitted effect set: values, standard errors, fitted rig and measurement map, fit SSE."""

    effects: tuple[str, ...]
    values: dict[str, dict[str, float]]
    std: dict[str, dict[str, float]]
    rig: Rig
    meas: MeasurementMap
    sse: float
    n: int
    nfev: int
    #: Covariance of the optimiser coordinates (log value for a log parameter, share of the range
    #: otherwise), shape (k, k), in the order of ``labels`` ((effect, parameter) pairs); None when
    #: not computed.
    cov: np.ndarray | None = None
    labels: tuple[tuple[str, str], ...] = ()
    log: tuple[bool, ...] = ()
    #: Per coordinate, the change of its parameter (log value for a log one, the value otherwise) per
    #: unit of the coordinate: 1 for a log parameter, the search range's span for a linear one.
    spans: tuple[float, ...] = ()
    #: Reference rotor speed ω_ref [rad/s] of the search ranges (:attr:`EffectContext.omega_ref`).
    omega_ref: float | None = None


class _Coord(NamedTuple):
    """One optimiser coordinate: effect, parameter and its search range."""

    effect: Effect
    param: EffectParameter
    range: ParamRange


def _coords(effects: Sequence[Effect], ctx: EffectContext) -> list[_Coord]:
    """The optimiser's coordinates: every parameter, but a held one (the onset width v_ε) only where
    ``ctx`` frees it (:attr:`aeropend_ident.gap.effects.EffectContext.free_settings`)."""
    return [_Coord(e, p, p.bind(ctx)) for e in effects for p in e.parameters
            if not p.held or e.name in ctx.free_settings]


def _n_fitted(name: str, ctx: EffectContext) -> int:
    """Parameters of effect ``name`` its fits search (BIC's k): a held parameter counts only
    where ``ctx`` frees it (:func:`_coords`)."""
    return sum(1 for p in get_effect(name).parameters if not p.held or name in ctx.free_settings)


def _to_z(r: ParamRange, v: float) -> float:
    """Optimiser coordinate of a physical value: log(v), or (v − lower)/(upper − lower)."""
    v = r.clip(v)
    return math.log(v) if r.log else (v - r.lower) / (r.upper - r.lower)


def _from_z(r: ParamRange, z: float) -> float:
    v = math.exp(z) if r.log else r.lower + z * (r.upper - r.lower)
    return r.clip(v)


def _assemble(rig: Rig, coords: Sequence[_Coord], z: np.ndarray) -> tuple[Rig, MeasurementMap, dict]:
    vals: dict[str, dict[str, float]] = {}
    for c, zi in zip(coords, z, strict=True):
        vals.setdefault(c.effect.name, {})[c.param.name] = _from_z(c.range, float(zi))
    new, meas = apply_effects(rig, vals)
    return new, meas, vals


def _thrust_law_starts(ctx: EffectContext, start: Mapping[str, float]) -> list[dict[str, float]]:
    """Starts of a thrust-law fit: exponents across the physical range, each with the coefficient
    that keeps the start's thrust at the reference propeller speed ω_ref (level kept, shape varied)."""
    w = max(ctx.omega_ref, 1e-9)
    k0, a0 = start["K_q"], start["exponent"]
    return [{"K_q": k0 * w ** (a0 - a), "exponent": a} for a in THRUST_LAW_EXPONENTS]


def fit_effects(rig: Rig, effects: Sequence[str], preps: Sequence[Prepared], ctx: EffectContext, *,
                start: Mapping[str, Mapping[str, float]] | None = None, scan: bool = True,
                starts: Sequence[Mapping[str, Mapping[str, float]]] = (),
                max_nfev: int = MAX_NFEV) -> EffectFit:
    """Fit the physical parameters of one or more catalog effects by free-run output error.

    Each parameter is searched over its physical range (:meth:`Effect.ranges` of ``ctx``), log(value)
    for strictly positive ones; a held parameter (the dry friction's onset width v_ε) only where
    ``ctx.free_settings`` frees it, else it keeps ``rig``'s value. The objective is the normalised
    output error of every compared channel (:func:`residuals`). Output error in a delay, dead
    zone, stop angle or friction level has local minima, so the fit is **multi-start**: the given
    start (default: the probe values), the extra ``starts`` (e.g. the equation-error estimates of
    the screening), and, for a one-parameter effect with ``scan``, :data:`N_SCAN` values spread
    over the whole range (:func:`_scan_starts`; for the thrust law: exponents over [1.4, 3] at a
    kept thrust level); the best :data:`MAX_STARTS`
    distinct starts are refined by :func:`scipy.optimize.least_squares` (trust-region reflective)
    and the best result is kept.

    The Jacobian is a forward difference with an **absolute** step of :data:`FD_STEP` optimiser
    units (0.1 % of the value for log parameters, 0.1 % of the range otherwise): scipy's relative
    ``diff_step`` collapses to 1e-8 at a coordinate of 0 (a log parameter at its nominal value),
    below the integrator's tolerance, where the gradient then reads zero.

    Parameters
    ----------
    rig : Rig
        Nominal rig (the effects are added to it with :func:`apply_effects`).
    effects : sequence of str
        Catalog names (model or measurement effects).
    preps : sequence of Prepared
        Fit recordings.
    ctx : EffectContext
        Search ranges (rig and data scales).
    start : mapping, optional
        Main start ``{effect: {parameter: value}}`` (missing values: probe values).
    scan : bool
        Scan the range of a one-parameter effect (and the thrust law's exponent).
    starts : sequence of mappings
        Further starts (partial mappings are completed from ``start``).
    max_nfev : int
        Most residual evaluations of each local refinement.

    Returns
    -------
    EffectFit

    Raises
    ------
    GapError
        On an unknown or directly detected effect.
    """
    effs = [get_effect(n) for n in effects]
    bad = [e.name for e in effs if e.kind == "direct"]
    if bad:
        raise GapError(f"effect(s) {bad} are detected from the data, not fitted")
    coords = _coords(effs, ctx)
    base = {e.name: {**e.probe_values(ctx), **dict((start or {}).get(e.name, {}))} for e in effs}

    def z_of(vals: Mapping[str, Mapping[str, float]]) -> np.ndarray:
        merged = {e: {**base[e], **dict(vals.get(e, {}))} for e in base}
        return np.array([_to_z(c.range, merged[c.effect.name][c.param.name]) for c in coords])

    lo = np.array([_to_z(c.range, c.range.lower) for c in coords])
    hi = np.array([_to_z(c.range, c.range.upper) for c in coords])
    obj = _Objective(rig, coords, preps, hi)
    funs, fun, jac = obj.rows, obj, obj.jacobian

    candidates = [z_of({})] + [z_of(s) for s in starts]
    candidates += _scan_starts(coords, z_of, lo, hi) if scan else []
    if scan and "thrust_law" in effects:
        for s in _thrust_law_starts(ctx, base["thrust_law"]):
            candidates.append(z_of({"thrust_law": s}))
    candidates = [np.clip(c, lo, hi) for c in candidates]
    costs = [float(np.sum(r**2)) for r in funs(candidates)]
    order = np.argsort(costs)
    picked: list[np.ndarray] = []
    width = np.maximum(hi - lo, 1e-12)
    for i in order:
        c = candidates[i]
        if costs[i] > MULTISTART_COST_RATIO * costs[order[0]] and picked:
            break
        if all(np.max(np.abs(c - q) / width) > 0.05 for q in picked):
            picked.append(c)
        if len(picked) >= MAX_STARTS:
            break
    best = None
    for z0 in picked:
        z0 = np.clip(z0, lo + 1e-12, hi - 1e-12)
        sol = least_squares(fun, z0, jac=jac, bounds=(lo, hi), method="trf", x_scale=1.0, max_nfev=max_nfev,
                            ftol=1e-7, xtol=1e-7, gtol=1e-9)
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    new, meas, vals = _assemble(rig, coords, best.x)
    for e in effs:  # a held setting keeps the rig's value (no standard error: not fitted)
        for k, v in e.held_values(rig).items():
            vals.setdefault(e.name, {}).setdefault(k, v)
    std: dict[str, dict[str, float]] = {}
    cov_z: np.ndarray | None = None
    try:
        cov_z = parameter_covariance(jac(best.x), best.fun, block_ids(preps))
        sz = np.sqrt(np.clip(np.diag(cov_z), 0.0, None))
    except (np.linalg.LinAlgError, ValueError):
        sz = np.full(len(coords), math.nan)
    for c, zi, sd in zip(coords, best.x, sz, strict=True):
        v = _from_z(c.range, float(zi))
        span = c.range.upper - c.range.lower
        std.setdefault(c.effect.name, {})[c.param.name] = float(abs(v) * sd if c.range.log else sd * span)
    return EffectFit(effects=tuple(effects), values=vals, std=std, rig=new, meas=meas,
                     sse=float(np.sum(best.fun**2)), n=int(best.fun.size), nfev=obj.nfev, cov=cov_z,
                     labels=tuple((c.effect.name, c.param.name) for c in coords),
                     log=tuple(bool(c.range.log) for c in coords),
                     spans=tuple(1.0 if c.range.log else c.range.upper - c.range.lower for c in coords),
                     omega_ref=float(ctx.omega_ref))


def _scan_starts(coords: Sequence[_Coord], z_of: Callable[[Mapping[str, Mapping[str, float]]], np.ndarray],
                 lo: np.ndarray, hi: np.ndarray) -> list[np.ndarray]:
    """Starts of :func:`fit_effects` from a scan: where one coordinate is a physical size and the
    others held parameters (a dry friction's level and its onset width v_ε), :data:`N_SCAN`
    values over the size's range, with the settings at the main start and at the rig's own
    values (the fit as it was with the setting held)."""
    sizes = [i for i, c in enumerate(coords) if not c.param.held]
    if len(sizes) != 1:
        return []
    k = sizes[0]
    held = {}
    for c in coords:
        if c.param.held:
            held.setdefault(c.effect.name, {})[c.param.name] = c.range.off
    out = []
    for fixed in ([{}, held] if held else [{}]):
        z0 = z_of(fixed)
        for g in np.linspace(lo[k], hi[k], N_SCAN):
            z = z0.copy()
            z[k] = g
            out.append(z)
    return out


def block_ids(preps: Sequence[Prepared], block_s: float = COVARIANCE_BLOCK_S) -> np.ndarray:
    """Time block of every element of the :func:`residuals` vector, shape (M,): the recordings'
    :data:`COVARIANCE_BLOCK_S` s stretches, every channel of a stretch in the same block."""
    out, base = [], 0
    for p in preps:
        k = np.floor(np.arange(p.n) * p.dt / block_s).astype(int)
        out.extend([base + k] * len(p.y))
        base += int(k[-1]) + 1 if p.n else 0
    return np.concatenate(out) if out else np.zeros(0, dtype=int)


def parameter_covariance(jac: np.ndarray, res: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Covariance of least-squares parameters whose residuals are correlated in time.

    The classical estimate (JᵀJ)⁻¹·s², s² the residual variance with the effective sample size
    M/:data:`BIC_DECIMATION`, assumes independent residuals; a free-run output error is correlated
    over seconds, and where the model misses something its error depends on the stretch of data.
    The block sandwich (cluster-robust) estimate
    (JᵀJ)⁻¹ (Σ_b J_bᵀ r_b r_bᵀ J_b) (JᵀJ)⁻¹ · B/(B − 1) over time blocks b (the linearised block
    bootstrap of the fit: how far the estimate moves when whole stretches are resampled) measures
    that within-session variation. Returned: the sandwich, its diagonal raised to the classical one
    where that is larger (a few blocks can underestimate), correlations kept; the classical estimate
    alone with fewer than 2k + 2 blocks.

    Parameters
    ----------
    jac : numpy.ndarray
        Shape (M, k), Jacobian of the residuals at the optimum.
    res : numpy.ndarray
        Shape (M,), residuals at the optimum.
    blocks : numpy.ndarray
        Shape (M,), block id of each residual (:func:`block_ids`).

    Returns
    -------
    numpy.ndarray
        Shape (k, k), covariance of the optimiser coordinates. A coordinate the residuals do not
        depend on at all (a zero Jacobian column: an end stop the recording never reaches) has
        infinite variance and no covariance: the data do not determine it (a pseudo-inverse alone
        would give it variance 0, an exactly known value).
    """
    norms = np.sqrt(np.sum(jac**2, axis=0))
    dead = ~(norms > 1e-12 * max(float(norms.max(initial=0.0)), 1e-300))
    if np.any(dead):
        live = np.flatnonzero(~dead)
        out = np.zeros((jac.shape[1],) * 2)
        out[dead, dead] = math.inf
        if live.size:
            out[np.ix_(live, live)] = parameter_covariance(jac[:, live], res, blocks)
        return out
    k = jac.shape[1]
    a_inv = np.linalg.pinv(jac.T @ jac)
    dof = max(res.size // BIC_DECIMATION - k, 1)
    classical = a_inv * float(np.sum(res**2)) / dof
    ids, inv = np.unique(blocks, return_inverse=True)
    if ids.size < 2 * k + 2:
        return classical
    g = np.zeros((ids.size, k))
    np.add.at(g, inv, jac * res[:, None])
    sandwich = a_inv @ (g.T @ g) @ a_inv * ids.size / (ids.size - 1)
    sd_s = np.sqrt(np.clip(np.diag(sandwich), 0.0, None))
    sd = np.maximum(sd_s, np.sqrt(np.clip(np.diag(classical), 0.0, None)))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.where(np.outer(sd_s, sd_s) > 0.0, sandwich / np.outer(sd_s, sd_s), 0.0)
    np.fill_diagonal(corr, 1.0)
    return corr * np.outer(sd, sd)


class _Objective:
    """The normalised output error of :func:`fit_effects` and its forward-difference Jacobian.

    Residuals of many coordinate vectors are one batched replay per recording
    (:func:`residuals_many`); evaluated vectors are cached (the Jacobian's base point is the
    optimiser's last evaluation). A vector whose effects cannot be applied or whose replay fails
    gets a constant penalty residual. ``nfev`` counts the vectors replayed.
    """

    def __init__(self, rig: Rig, coords: Sequence[_Coord], preps: Sequence[Prepared], hi: np.ndarray) -> None:
        self.rig, self.coords, self.preps, self.hi = rig, list(coords), list(preps), hi
        self.n_res = sum(len(p.y) * p.n for p in preps)
        self.penalty = 10.0 / math.sqrt(max(self.n_res, 1))
        self.nfev = 0
        self._cache: dict[bytes, np.ndarray] = {}

    def __call__(self, z: np.ndarray) -> np.ndarray:
        return self.rows([z])[0]

    def rows(self, zs: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Residuals of many coordinate vectors: the new ones in one batched replay."""
        keys = [np.asarray(z, dtype=float).tobytes() for z in zs]
        got = {k: self._cache[k] for k in keys if k in self._cache}
        new = [k for k in dict.fromkeys(keys) if k not in got]
        if new:
            self.nfev += len(new)
            rows, where = [], []
            for k in new:
                got[k] = np.full(self.n_res, self.penalty)
                try:
                    r_rig, r_meas, _ = _assemble(self.rig, self.coords, np.frombuffer(k))
                except (GapError, ValueError):
                    continue
                rows.append((r_rig, r_meas))
                where.append(k)
            for k, r in zip(where, residuals_many(rows, self.preps) if rows else (), strict=True):
                if np.all(np.isfinite(r)):
                    got[k] = r
            if len(self._cache) + len(new) > 256:
                self._cache.clear()
            self._cache.update({k: got[k] for k in new})
        return [got[k] for k in keys]

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        """Forward differences with the absolute step :data:`FD_STEP` (backward at the upper
        bound): 1 + n_p residuals in one batched replay."""
        steps = [FD_STEP if z[j] + FD_STEP <= self.hi[j] else -FD_STEP for j in range(z.size)]
        shifted = []
        for j, h in enumerate(steps):
            zz = np.array(z, dtype=float)
            zz[j] += h
            shifted.append(zz)
        f0, *fs = self.rows([z, *shifted])
        out = np.empty((f0.size, z.size))
        for j, (h, f) in enumerate(zip(steps, fs, strict=True)):
            out[:, j] = (f - f0) / h
        return out


# ------------------------------------------------------------------------------ metrics
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
        ``per_recording`` θ NRMSEs, ``channel_nrmse`` (mean NRMSE of every compared channel),
        ``nrmse_channels`` (RMS over the compared channels of their NRMSEs: the gauge of a gap
        that lies in i_a, v_a or ω₁ rather than in θ), ``diverges`` (per recording whose free run
        diverges, :func:`aeropend_ident.io.overlay_axes.diverges`: its source and the reason; then
        the NRMSE only measures how far the run went, and the report gives no shrink).
    """
    nrmse, maxe, ss, gone, runs = [], 0.0, [], [], []
    per_channel: dict[str, list[float]] = {}
    step: dict[str, Any] = {}
    for p in preps:
        run = one_free_run(rig, meas, p)
        runs.append({"recording": p.rec.source, **run.as_dict()})
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
    seen through ``meas`` on the recording ``p``: the figures a diagnosis reports come from it.

    Raises
    ------
    GapError
        If the replay fails for this rig (naming the recording and the rig).
    """
    try:
        return free_run(rig, np.arange(p.n) * p.dt, p.duty, p.y["theta"], theta_offset=meas.theta_offset,
                        theta_scale=meas.theta_scale, source=p.rec.source or "a recording")
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


# ------------------------------------------------------------------------------ screening
def _delayed(duty: np.ndarray, dt: float, delay: float) -> np.ndarray:
    if delay <= 0.0:
        return duty
    k = np.arange(duty.size)
    idx = np.floor((k * dt - delay) / dt + 1e-9).astype(int)
    return np.where(idx >= 0, duty[np.clip(idx, 0, None)], duty[0])


def _savgol(y: np.ndarray, dt: float, deriv: int) -> np.ndarray:
    w = max(round(SAVGOL_WINDOW / dt) | 1, 7)
    w = min(w, (y.size - 1) | 1 if y.size % 2 == 0 else y.size)
    return savgol_filter(y, w, 3, deriv=deriv, delta=dt, mode="interp")


def motor_channels(rig: Rig) -> tuple[str, ...]:
    """Channels of a replay that give the motor chain's states (i_a when the family has an
    armature, ω₁, τ_f): what :func:`hybrid_rhs` takes from a simulation."""
    armature = "armature" not in registry.family(rig.family).lacks
    return (*(("i_a",) if armature else ()), "omega_rotor", "tau_f")


def hybrid_rhs(rig: Rig, meas: MeasurementMap, prep: Prepared, theta_dot: np.ndarray,
               equations: Sequence[str], step: int = 1,
               sim: Mapping[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Model right-hand side on the recorded states, in the recording's frame.

    θ and θ̇ come from the recording (through the inverse measurement map); i_a and ω₁ from the
    recording when recorded, else from a simulation of the rig driven by the recorded duty cycle
    (the motor chain does not depend on θ); τ_f and the delayed input from that simulation.

    ``step`` evaluates every ``step``-th sample only (the simulation still runs at full rate).
    ``sim`` is that simulation when the caller has replayed it already (the :func:`motor_channels`
    of a :func:`replay_many` row, so that many rigs are simulated in one batch); by default the
    rig is replayed here the same way.

    Returns
    -------
    dict
        ``equation -> (ceil(N/step),)``: ``"theta_dot"`` θ̈_recorded [rad/s²], ``"i_a"`` [A/s],
        ``"omega_rotor"`` [rad/s²], ``"v_a"`` [V].

    Raises
    ------
    GapError
        If the replay fails.
    """
    model = PlantModel(_sim_rig(rig))
    if sim is None:
        sim = replay_many([(rig, meas)], prep, motor_channels(rig))[0]
        if sim is None:
            raise GapError(f"replay of {prep.rec.source or 'a recording'} with rig {rig.name!r} failed")
    x = np.zeros((prep.n, 5))
    s = meas.theta_scale
    x[:, 0] = meas.to_model(prep.y["theta"])
    x[:, 1] = theta_dot / s
    x[:, 2] = sim.get("i_a", 0.0)
    x[:, 3] = sim["omega_rotor"]
    x[:, 4] = sim["tau_f"]
    if "i_a" in prep.y and model.dynamic_current:
        x[:, 2] = prep.y["i_a"]
    if "omega_rotor" in prep.y:
        x[:, 3] = prep.y["omega_rotor"]
    u = _delayed(prep.duty, prep.dt, model.delay)
    x, u = x[::step], u[::step]
    need = set(equations)
    f, drive = derivatives(model, x, u)  # = model.rhs per sample, bit for bit, in one compiled loop
    out: dict[str, np.ndarray] = {}
    if "theta_dot" in need:
        out["theta_dot"] = s * f[:, 1]
    if "i_a" in need:
        out["i_a"] = f[:, 2]
    if "omega_rotor" in need:
        out["omega_rotor"] = f[:, 3]
    if "v_a" in need:
        model.armature_voltage(0.0)  # a family without an armature voltage (ESC) raises here
        out["v_a"] = drive  # v_a of τ_f (lag on) or of u: the drive quantity
    return out


def _probe_rigs(rig: Rig, meas: MeasurementMap, effs: Sequence[Effect],
                ranges: Mapping[str, Mapping[str, Any]]) -> list[tuple[Rig, MeasurementMap] | None]:
    """The screening's probe of each effect parameter, in order: the rig with that parameter at its
    probe value and the effect's others off, or None where the effect cannot be applied so."""
    out: list[tuple[Rig, MeasurementMap] | None] = []
    for e in effs:
        for prm in e.parameters:
            vals = {k: (r.probe if k == prm.name else r.off) for k, r in ranges[e.name].items()}
            try:
                out.append(apply_effects(rig, {e.name: vals}, meas))
            except GapError:
                out.append(None)
    return out


def screening_equations(channels: frozenset[str]) -> list[str]:
    """Equations the recorded channels support: θ̈ always, then i_a, ω₁, v_a when recorded."""
    eqs = ["theta_dot"]
    for c in ("i_a", "omega_rotor", "v_a"):
        if c in channels:
            eqs.append(c)
    return eqs


def _bic(rss: float, n: int, k: int) -> float:
    return n * math.log(max(rss, 1e-300) / n) + k * math.log(n)


def group_select(X: np.ndarray, y: np.ndarray, groups: Sequence[int], *, max_groups: int = 3,
                 n_eff: int | None = None, min_gain: float = MIN_BIC_GAIN) -> list[int]:
    """Group orthogonal matching pursuit with a BIC stop (group sparsity over the catalog).

    At each step the whole group (all its columns) whose addition lowers the least-squares
    residual most is selected; selection stops when the BIC (with ``n_eff`` independent samples)
    no longer falls by ``min_gain``.

    Parameters
    ----------
    X : ndarray, shape (N, M)
        Columns (already normalised).
    y : ndarray, shape (N,)
        Residual target.
    groups : sequence of int, length M
        Group index of each column.
    max_groups : int
    n_eff : int, optional
        Effective sample count of the BIC (default N).

    Returns
    -------
    list of int
        Selected group indices in order of selection.
    """
    groups = np.asarray(groups)
    n = y.size
    n_eff = n if n_eff is None else max(int(n_eff), 2)
    rss0 = float(y @ y)
    chosen: list[int] = []
    cols: list[int] = []
    best_bic = _bic(rss0 * n_eff / n, n_eff, 0)
    for _ in range(max_groups):
        best = None
        for g in np.unique(groups):
            if g in chosen:
                continue
            c = cols + list(np.flatnonzero(groups == g))
            coef, *_ = np.linalg.lstsq(X[:, c], y, rcond=None)
            r = y - X[:, c] @ coef
            rss = float(r @ r)
            if best is None or rss < best[0]:
                best = (rss, int(g), c)
        if best is None:
            break
        bic = _bic(best[0] * n_eff / n, n_eff, len(best[2]))
        if bic > best_bic - min_gain:
            break
        best_bic = bic
        chosen.append(best[1])
        cols = best[2]
    return chosen


@dataclass
class Screening:
    """Result of :func:`screen` (discrepancy SINDy with group sparsity)."""

    effects: list[str]
    explained_strong: dict[str, float]
    explained_weak: dict[str, float]
    explained_equation: dict[str, float]
    selected_strong: list[str]
    selected_weak: list[str]
    inclusion: dict[str, float]
    equations: list[str]
    columns: dict[str, list[str]]
    estimates: dict[str, dict[str, float]] = field(default_factory=dict)

    def shortlist(self, k: int = SHORTLIST) -> list[str]:
        """Selected groups first (strong, then weak), then by mean explained residual."""
        out: list[str] = []
        for name in self.selected_strong + self.selected_weak:
            if name not in out:
                out.append(name)
        score = {e: max(0.5 * (self.explained_strong[e] + self.explained_weak[e]), self.explained_equation[e])
                 for e in self.effects}
        for name in sorted(self.effects, key=lambda e: -score[e]):
            if len(out) >= k:
                break
            if name not in out:
                out.append(name)
        return out[: max(k, len(self.selected_strong))]

    def as_dict(self) -> dict[str, Any]:
        return {
            "equations": self.equations,
            "per_effect": {e: {"explained_strong": self.explained_strong[e],
                               "explained_weak": self.explained_weak[e],
                               "inclusion": self.inclusion[e], "terms": self.columns[e],
                               "equation_error_estimate": self.estimates.get(e)}
                           for e in self.effects},
            "selected_strong": self.selected_strong,
            "selected_weak": self.selected_weak,
        }


def screen(rig: Rig, preps: Sequence[Prepared], effects: Sequence[str], channels: frozenset[str],
           ctx: EffectContext, *, n_bootstrap: int = N_BOOTSTRAP, seed: int = 0, weak_K: int = 150,
           meas: MeasurementMap | None = None, estimate: bool = True) -> Screening:
    """Discrepancy SINDy (strong and weak form) over the catalog's term groups.

    ``rig``/``meas`` are the base model (the nominal rig, or a corrected one when screening for a
    second effect). See the module docstring, step 2. Each equation's rows are scaled by the RMS of its
    nominal residual so the equations weigh alike; each column is scaled to unit RMS. The column of
    parameter j is the change of the right-hand side when that parameter goes from its ``off`` value
    to its probe value (``ctx``), the others staying off.

    With ``estimate`` (base = the nominal rig), each effect's own strong-form regression coefficient
    gives its **equation-error estimate**, off + coefficient·(probe − off) per parameter (exact for
    parameters that enter the equations linearly, a start value for the others), reported in
    :attr:`Screening.estimates` and used to start the output-error fits.

    Returns
    -------
    Screening
    """
    eqs = screening_equations(channels)
    effs = [get_effect(n) for n in effects]
    rng = np.random.default_rng(seed)
    strong_rows: list[np.ndarray] = []
    strong_y: list[np.ndarray] = []
    eq_of_row: list[np.ndarray] = []
    seg_id: list[np.ndarray] = []
    weak_rows: list[np.ndarray] = []
    weak_y: list[np.ndarray] = []
    col_names: dict[str, list[str]] = {e.name: [] for e in effs}
    groups: list[int] = []
    seg_base = 0
    base_meas = meas or MeasurementMap()
    ranges = {e.name: e.ranges(ctx) for e in effs}
    for pi, p in enumerate(preps):
        dec = max(1, round(SCREEN_DT / p.dt))
        th = p.y["theta"]
        thd = _savgol(th, p.dt, 1)
        lhs = {"theta_dot": _savgol(th, p.dt, 2)[::dec]}
        for c in ("i_a", "omega_rotor"):
            if c in eqs:
                lhs[c] = _savgol(p.y[c], p.dt, 1)[::dec]
        if "v_a" in eqs:
            lhs["v_a"] = p.y["v_a"][::dec]
        n_d = lhs["theta_dot"].size
        nominal = hybrid_rhs(rig, base_meas, p, thd, eqs, dec)
        cols: dict[str, list[np.ndarray]] = {q: [] for q in eqs}
        grp: list[int] = []
        probes = _probe_rigs(rig, base_meas, effs, ranges)
        sims = iter(replay_many([r for r in probes if r is not None], p, motor_channels(rig)))
        probe_of = iter(probes)
        for gi, e in enumerate(effs):
            for prm in e.parameters:
                probe = next(probe_of)
                sim = next(sims) if probe is not None else None
                alt = {q: nominal[q] for q in eqs}
                if sim is not None:
                    alt = hybrid_rhs(*probe, p, thd, eqs, dec, sim=sim)
                for q in eqs:
                    cols[q].append(alt[q] - nominal[q])
                grp.append(gi)
                if pi == 0:
                    col_names[e.name].append(
                        f"{prm.name}: " + ", ".join(e.terms.get(q, ("Δf",))[0] for q in eqs if q in e.terms))
        if pi == 0:
            groups = grp
        # strong form: rows of every equation stacked, scaled by the RMS of its left side
        for q in eqs:
            res = lhs[q] - nominal[q]
            sc = float(np.sqrt(np.mean(res**2))) or 1.0
            strong_rows.append(np.column_stack(cols[q]) / sc)
            strong_y.append(res / sc)
            eq_of_row.append(np.full(res.size, eqs.index(q)))
            w = max(round(SEGMENT / (p.dt * dec)), 1)
            seg_id.append(seg_base + np.arange(n_d) // w)
        seg_base += n_d // max(round(SEGMENT / (p.dt * dec)), 1) + 1
        # weak form (differential equations only; the v_a map is algebraic)
        data = IdentData(t=np.arange(n_d) * p.dt * dec,
                         variables={"theta_dot": thd[::dec], **{c: p.y[c][::dec] for c in p.y}},
                         source=p.rec.source)
        for q in eqs:
            if q == "v_a":
                continue
            mat, lw = weak_matrices(data, np.column_stack([nominal[q], *cols[q]]), [q], K=weak_K,
                                    seed=seed + pi)
            res = lw[:, 0] - mat[:, 0]
            sc = float(np.sqrt(np.mean(res**2))) or 1.0
            weak_rows.append(mat[:, 1:] / sc)
            weak_y.append(res / sc)
    Xs, ys, seg = np.vstack(strong_rows), np.concatenate(strong_y), np.concatenate(seg_id)
    Xw, yw = np.vstack(weak_rows), np.concatenate(weak_y)
    cs = np.sqrt(np.mean(Xs**2, axis=0))
    cw = np.sqrt(np.mean(Xw**2, axis=0))
    Xs = Xs / np.where(cs > 0, cs, 1.0)
    Xw = Xw / np.where(cw > 0, cw, 1.0)
    groups_a = np.asarray(groups)

    multipliers: dict[str, np.ndarray] = {}

    def explained(X: np.ndarray, y: np.ndarray, g: int, scale: np.ndarray | None = None) -> float:
        c = np.flatnonzero(groups_a == g)
        if not np.any(np.abs(X[:, c]) > 0):
            return 0.0
        coef, *_ = np.linalg.lstsq(X[:, c], y, rcond=None)
        if scale is not None:
            multipliers[effs[g].name] = coef / np.where(scale[c] > 0, scale[c], 1.0)
        r = y - X[:, c] @ coef
        return float(max(0.0, 1.0 - (r @ r) / max(y @ y, 1e-300)))

    n_eff_s = max(ys.size // BIC_DECIMATION, 10)
    exp_s = {e.name: explained(Xs, ys, g, cs) for g, e in enumerate(effs)}
    estimates: dict[str, dict[str, float]] = {}
    if estimate:
        for e in effs:
            est = {}
            for prm, m in zip(e.parameters, multipliers.get(e.name, ()), strict=False):
                r = ranges[e.name][prm.name]
                v = r.off + float(m) * (r.probe - r.off)
                if math.isfinite(v):
                    est[prm.name] = r.clip(v)
            if est:
                estimates[e.name] = est
    exp_w = {e.name: explained(Xw, yw, g) for g, e in enumerate(effs)}
    # the best share an effect explains within one equation: stacking the equations with equal
    # weight lets equations whose residual is noise dilute a gap that lives in one of them
    rows_eq = np.concatenate(eq_of_row)
    exp_eq = {e.name: max(explained(Xs[rows_eq == j], ys[rows_eq == j], g) for j in range(len(eqs)))
              for g, e in enumerate(effs)}
    sel_s = [effs[g].name for g in group_select(Xs, ys, groups_a, n_eff=n_eff_s)]
    sel_w = [effs[g].name for g in group_select(Xw, yw, groups_a, n_eff=yw.size)]
    counts = dict.fromkeys(exp_s, 0)
    segs = np.unique(seg)
    for _ in range(n_bootstrap):
        pick = rng.choice(segs, size=segs.size, replace=True)
        rows = np.concatenate([np.flatnonzero(seg == s_) for s_ in pick])
        sub = rows[:: max(BIC_DECIMATION // 4, 1)]
        for g in group_select(Xs[sub], ys[sub], groups_a, n_eff=max(sub.size * 4 // BIC_DECIMATION, 10)):
            counts[effs[g].name] += 1
    return Screening(
        effects=[e.name for e in effs], explained_strong=exp_s, explained_weak=exp_w,
        explained_equation=exp_eq,
        selected_strong=sel_s, selected_weak=sel_w,
        inclusion={k: v / max(n_bootstrap, 1) for k, v in counts.items()}, equations=eqs, columns=col_names,
        estimates=estimates,
    )


# ------------------------------------------------------------------------------ diagnosis
@dataclass
class EffectDiagnosis:
    """Outcome of :func:`diagnose_effects` (see the module docstring).

    "Validation" is the part of the fit data the diagnosis chooses and ranks on; the held-out
    recordings of :func:`aeropend_ident.gap.run.run_gap` are never seen here.

    Attributes
    ----------
    significant : bool
        False => "no significant gap".
    ranking : list of dict
        Best first: ``effect``, ``subsystem``, ``score``, ``validation_explained`` (share of the
        nominal validation SSE the effect removes), ``bic_delta``, ``p_value`` (its sample-split
        test), ``q_value`` (false-discovery-rate adjusted), ``presence`` (0..1, the evidence the
        effect is present: :func:`_evidence`), ``status`` ("named", "candidate", "not separated",
        "not significant", "detected": :func:`status_of`), ``parameters``
        ``{name: {value, std, unit}}`` (physical units), ``rig_values``, ``screening`` (strong/weak
        explained, inclusion, equation-error estimate), ``confusable_with`` (physics),
        ``ambiguous_with`` (effects these data do not separate from it, with the evidence in
        ``ambiguity``).
    not_identifiable : list of dict
        ``{"effect", "reason"}`` for effects the recorded channels cannot reveal.
    chosen : list of str
        Fitted effects added to the corrected rig (0 to ``max_effects``), in the order chosen.
        Never a directly detected effect (see ``detected``).
    corrected_rig : Rig
        Nominal rig + chosen effects, fitted, + the detected effects.
    validation : list of dict
        Validation gap per cumulative effect set (:func:`gap_metrics`), first row nominal
        (``effects`` = []).
    measurement : MeasurementMap
        θ transform of chosen sensor effects (offset/scale), identity otherwise.
    screening : dict
        Discrepancy-SINDy screening details.
    reason : str
        Why the gap is (not) significant.
    channels : list of str
        Channels used.
    explained : dict
        How completely the chosen set explains the validation gap: ``share_above_noise``
        (1 − (SSE_chosen − SSE_noise)/(SSE_nominal − SSE_noise)), ``residual_over_noise``
        (SSE_chosen/SSE_noise), ``completeness`` (0..1) and a ``verdict``.
    elapsed : float
        Wall time [s].
    detected : dict
        Effects read from the recordings themselves, not fitted (catalog kind ``"direct"``):
        ``{"quantisation": {"theta_quantum": q}}`` [rad] when the recorded angle lies on a lattice
        the nominal rig does not model. They describe the measurement (the corrected rig's sensor,
        the noise floor q/√12); they are never refitted (:func:`fit_effects` refuses them). Their
        ranking entry says ``"detected": True``.
    plant_side : dict or None
        When a chosen sensor-frame effect is not separated by these data from a plant-side one
        (:func:`plant_side_alternative`): ``replaces``, ``by``, ``validation_explained``,
        ``parameters`` (the alternative's fitted values) and the jointly fitted ``rig`` and
        ``measurement`` with the alternative in its place. The corrected rig *file*
        (:func:`aeropend_ident.gap.run.corrected_rig_dict`) is written from these.
    """

    significant: bool
    ranking: list[dict]
    not_identifiable: list[dict]
    chosen: list[str]
    corrected_rig: Rig
    validation: list[dict]
    measurement: MeasurementMap = field(default_factory=MeasurementMap)
    screening: dict = field(default_factory=dict)
    reason: str = ""
    channels: list[str] = field(default_factory=list)
    explained: dict = field(default_factory=dict)
    elapsed: float = 0.0
    plant_side: dict | None = None
    detected: dict[str, dict[str, float]] = field(default_factory=dict)
    free_settings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        """JSON-able summary; the corrected rig as its YAML dict (with ``recording_frame`` if a
        sensor offset was found; a sensor scale is reported in ``measurement``)."""
        rig = rig_to_dict(self.corrected_rig)
        if self.measurement.theta_offset != 0.0:
            rig["recording_frame"] = {"theta_offset": {
                "value": self.measurement.theta_offset, "unit": "rad",
                "source": "gap diagnosis: fitted sensor offset"}}
        return jsonable({
            "significant": self.significant,
            "reason": self.reason,
            "ranking": self.ranking,
            "not_identifiable": self.not_identifiable,
            "chosen": self.chosen,
            "detected": self.detected,
            "explained": self.explained,
            "corrected_rig": rig,
            "measurement": dataclasses.asdict(self.measurement),
            "validation": self.validation,
            "screening": self.screening,
            "channels": self.channels,
            "free_settings": self.free_settings,
            "elapsed_s": self.elapsed,
            "plant_side": ({k: v for k, v in self.plant_side.items() if k not in ("rig", "measurement")}
                           if self.plant_side else None),
        })


def _param_table(fitres: EffectFit, name: str) -> dict[str, dict[str, Any]]:
    """``{parameter: {value, std, unit}}`` of one effect's fit; a held parameter the fit kept at
    the rig's value (no standard error) also says ``"held": True``."""
    e = get_effect(name)
    out = {}
    for p in e.parameters:
        std = fitres.std.get(name, {}).get(p.name)
        out[p.name] = {"value": fitres.values[name][p.name], "std": std, "unit": p.unit}
        if p.held and std is None:
            out[p.name]["held"] = True
    return out


def _noise_var(y: np.ndarray) -> float:
    """Variance of the measurement noise of a channel.

    :func:`aeropend_ident.gap.effects.measurement_noise` (white-noise estimate, at least q²/12 of
    a detected quantum q), at least the quantisation floor Δ²/12, Δ the median of the non-zero
    sample-to-sample changes: on a quantised log that rarely changes (most second differences 0)
    the white-noise estimate is 0 while the changes are one LSB; resampling onto a uniform grid
    adds off-lattice values, so that the lattice is no longer detected. On white noise the median
    change is 0.95σ, so the floor (0.27σ) stays below the white-noise estimate.
    """
    y = np.asarray(y, dtype=float)
    sigma = measurement_noise(y)
    _, q = _changes(y)
    return max(sigma**2, q * q / 12.0)


def _changes(y: np.ndarray) -> tuple[np.ndarray, float]:
    """Which sample-to-sample changes of ``y`` are non-zero (bool, shape (n - 1,)), and Δ, the
    median of those (0 when the channel never changes): :func:`_noise_var`'s quantisation step."""
    dy = np.abs(np.diff(y))
    moved = dy > 1e-12 * max(float(np.max(np.abs(y))), 1e-300)
    return moved, float(np.median(dy[moved])) if moved.any() else 0.0


@dataclass
class _Setup:
    """Validated inputs and nominal figures shared by the steps of :func:`diagnose_effects`."""

    rig: Rig
    pf: list[Prepared]
    pv: list[Prepared]
    ctx: EffectContext
    channels: frozenset[str]
    model_effects: list[str]
    refinements: list[str]
    not_ident: list[dict]
    sse_fit0: float
    n_fit: int
    n_eff: int
    seg0: np.ndarray
    base_metrics: dict[str, Any]
    floors: dict[str, float]
    noise_sse: float
    noise_c: dict[str, float]
    chance_c: dict[str, float]
    sse0_c: dict[str, float]
    note: str
    say: Callable[[str], None]

    @property
    def sse_val0(self) -> float:
        return float(self.seg0.sum())

    def above_noise_share(self, sse: float, base: float | None = None) -> float:
        """Share of the validation gap above the noise part (of ``base``, default nominal) removed
        by a model with validation SSE ``sse``."""
        b = self.sse_val0 if base is None else base
        return (b - sse) / (b - self.noise_sse) if b > self.noise_sse else 0.0

    def noise_ratio(self, sse: float) -> str:
        """``sse`` as a multiple of the validation noise part, for progress lines."""
        return f"{sse / self.noise_sse:.3g} × its noise part"


def _setup(rig: Rig, fit: Sequence[Recording], validation: Sequence[Recording],
           say: Callable[[str], None], skip: Sequence[str] = ()) -> _Setup:
    nominal_model_check(rig)
    ch_fit = check_recordings(fit, "fit recordings", need_changing_input=True)
    ch_val = check_recordings(validation, "validation recordings")
    channels = ch_fit & ch_val
    pf, pv = prepare(fit, channels), prepare(validation, channels)
    ctx = EffectContext.from_prepared(rig, pf)
    model_effects, refinements, not_ident = [], [], []
    for e in catalog(rig.family):
        if e.name in skip:
            continue
        why = identifiable(e, channels)
        if why is not None:
            not_ident.append({"effect": e.name, "subsystem": e.subsystem, "reason": why})
        elif e.refines:
            refinements.append(e.name)
        elif e.kind != "direct":
            model_effects.append(e.name)
    say(f"nominal replay on {len(pf)} fit / {len(pv)} validation recordings, channels {sorted(channels)}")
    nominal = MeasurementMap()
    sse_fit0 = float(np.sum(residuals(rig, nominal, pf) ** 2))
    n_fit = sum(len(p.y) * p.n for p in pf)
    note = ""
    seg0, sse0_c = validation_errors(rig, nominal, pv)
    noise_c, chance_c = noise_parts(pv), _rounding_chance(pv)
    if not _above_noise(sse0_c, noise_c, chance_c):
        fit_c = _errors_after_start(rig, nominal, pf)
        fit_noise, fit_chance = noise_parts(pf), _rounding_chance(pf)
        if _above_noise(fit_c, fit_noise, fit_chance):
            # the validation part does not reach the operating region of the gap (e.g. an end stop
            # touched only in the fit part), judged after each fit recording's start: rank on the
            # fit data instead, and say so
            worst = max(fit_c, key=lambda c: fit_c[c] / fit_noise[c])
            note = (f"the validation part shows no gap above noise while the fit part does ({worst} "
                    f"{math.sqrt(fit_c[worst] / fit_noise[worst]):.1f}× its noise RMS): the effects were "
                    "ranked and chosen on the fit part (in-sample); only the held-out check is independent")
            say(note)
            pv, noise_c, chance_c = pf, fit_noise, fit_chance
            seg0, sse0_c = validation_errors(rig, nominal, pf)
    # noise floor of every compared channel (relative to its range), and the noise part of the
    # validation SSE (normalised like segment_sse): what no effect can remove
    floors = {c: NOISE_FLOOR_FACTOR * float(np.mean([math.sqrt(_noise_var(p.y[c])) / p.scale[c] for p in pv]))
              for c in pv[0].y}
    noise_sse = noise_part(noise_c, seg0)
    return _Setup(rig=rig, pf=pf, pv=pv, ctx=ctx, channels=channels, model_effects=model_effects,
                  refinements=refinements, not_ident=not_ident, sse_fit0=sse_fit0, n_fit=n_fit,
                  n_eff=bic_samples(pf),
                  seg0=seg0, base_metrics=gap_metrics(rig, nominal, pv), floors=floors, noise_sse=noise_sse,
                  noise_c=noise_c, chance_c=chance_c, sse0_c=sse0_c, note=note, say=say)


def _in_catalog(names: Sequence[str], st: _Setup) -> list[str]:
    """The names that are candidates for this rig (confusable effects of another family left out)."""
    have = {*st.model_effects, *st.refinements, *(r["effect"] for r in st.not_ident)}
    return [n for n in names if n in have]


def noise_parts(preps: Sequence[Prepared]) -> dict[str, float]:
    """Noise part of each channel's normalised squared error (as :func:`validation_errors`), summed
    over the recordings ``preps``: channel name -> the part no effect can remove (:func:`noise_part`
    adds them up)."""
    return {c: float(sum(_noise_var(p.y[c]) / p.scale[c] ** 2 for p in preps)) for c in preps[0].y}


def noise_part(noise_c: Mapping[str, float], seg0: np.ndarray) -> float:
    """The noise part of the validation SSE (normalised as :func:`segment_sse`): what no effect can
    remove, the sum over channels of ``noise_c`` (:func:`noise_parts`), kept above 1e-12 of the
    nominal segments' SSE ``seg0`` (n_segments,) and above 0."""
    return max(sum(noise_c.values()), 1e-12 * float(np.sum(seg0)), 1e-300)


def _errors_after_start(rig: Rig, meas: MeasurementMap, preps: Sequence[Prepared]) -> dict[str, float]:
    """Each channel's normalised squared error (as :func:`validation_errors`) without each
    recording's first :data:`INITIAL_STATE_WINDOW`: what a replay's start leaves there (a rotor
    assumed at the first duty cycle's steady speed on a log that begins as the motor starts) is no
    gap of the plant. At most half of a recording is left out."""
    out: dict[str, float] = {}
    for p in preps:
        sim = replay(rig, meas, p)
        k0 = min(round(INITIAL_STATE_WINDOW / p.dt), p.n // 2)
        for c, y in p.y.items():
            out[c] = out.get(c, 0.0) + float(np.mean(((sim[c][k0:] - y[k0:]) / p.scale[c]) ** 2))
    return out


def _rounding_chance(preps: Sequence[Prepared]) -> dict[str, float]:
    """Chance margin of each channel's noise part (normalised as :func:`noise_parts`):
    :data:`ROUNDING_CHANCE_Z` standard deviations of its rounding part.

    The rounding part of a recording's noise variance is Δ²/12 (Δ as in :func:`_noise_var`, the
    median non-zero sample-to-sample change), at most the noise variance. Its rounding errors are
    independent between runs of one recorded value, not between samples: while the value holds,
    the error does not change. A recording's runs of durations d_i give an effective number of
    independent errors (Σd_i)²/Σd_i², and the rounding part a relative standard deviation of
    :data:`_ROUNDING_SQUARE_REL_SD` over its square root. A recording whose value changes at every
    sample (white noise, an unquantised signal: no rounding error is held, and the Δ of a moving
    rod is its motion, not a step) adds no margin; a coarse lattice holding a set point, a margin
    that counts its few holds.
    """
    out: dict[str, float] = {}
    for c in preps[0].y:
        var = 0.0
        for p in preps:
            y = np.asarray(p.y[c], dtype=float)
            moved, q = _changes(y)
            if moved.all() or not moved.any():
                continue  # no value held (white noise, an unquantised signal), or nothing to count
            part = min(q * q / 12.0, _noise_var(y)) / p.scale[c] ** 2
            runs = np.diff(np.concatenate([[0], np.flatnonzero(moved) + 1, [y.size]])).astype(float)
            holds = float(runs.sum() ** 2 / np.sum(runs**2))
            var += (part * _ROUNDING_SQUARE_REL_SD) ** 2 / holds
        out[c] = ROUNDING_CHANCE_Z * math.sqrt(var)
    return out


def _above_noise(sse_c: Mapping[str, float], noise_c: Mapping[str, float],
                 chance_c: Mapping[str, float]) -> bool:
    """Some channel's error exceeds :data:`ABOVE_NOISE` times its noise part plus the chance margin
    of its rounding errors (:func:`_rounding_chance`): a gap to explain."""
    return any(sse_c[c] > ABOVE_NOISE * noise_c[c] + chance_c[c] and sse_c[c] > 1e-8 for c in sse_c)


@dataclass
class _Candidates:
    """Single-effect fits on the nominal rig and their validation figures."""

    fits: dict[str, EffectFit] = field(default_factory=dict)
    segs: dict[str, np.ndarray] = field(default_factory=dict)
    stats: dict[str, dict[str, float]] = field(default_factory=dict)
    completeness: dict[str, dict[str, Any]] = field(default_factory=dict)

    def confirm(self, st: _Setup, names: Sequence[str], scr: Screening) -> None:
        """Fit each effect alone (multi-start, from its equation-error estimate too) and score it
        on the validation recordings.

        The fits are independent and run at once (:func:`_each`); the figures are those of
        fitting one after the other. A held setting freed by one fit
        (:func:`_free_settings_if_validated`) concerns that effect's parameters only, so it is
        merged into ``st.ctx`` after the fit: one after the other, each fit reads the context the
        ones before it left; at once, the context of the step's start (the same for its own
        parameters)."""
        todo = [n for n in dict.fromkeys(names) if n not in self.fits]
        def work(name: str, say: Callable[[str], None]) -> tuple[EffectFit, np.ndarray, dict, frozenset[str]]:
            return _confirm_one(st, st.ctx, name, scr.estimates.get(name), say)

        for name, result in _each(st, todo, work):
            self._take(st, name, result)

    def _take(self, st: _Setup, name: str,
              result: tuple[EffectFit, np.ndarray, dict, frozenset[str]]) -> None:
        """Record one single-effect fit (:func:`_confirm_one`) and its validation figures."""
        fr, sg, per_channel, freed = result
        if freed:
            st.ctx = dataclasses.replace(st.ctx, free_settings=st.ctx.free_settings | freed)
        self.fits[name] = fr
        self.segs[name] = sg
        self.completeness[name] = _completeness(st, per_channel)
        k = _n_fitted(name, st.ctx)
        self.stats[name] = {
            "validation_explained": 1.0 - float(sg.sum()) / max(st.sse_val0, 1e-300),
            "above_noise_explained": st.above_noise_share(float(sg.sum())),
            "bic_delta": (_bic(fr.sse * st.n_eff / st.n_fit, st.n_eff, k)
                          - _bic(st.sse_fit0 * st.n_eff / st.n_fit, st.n_eff, 0)),
        }

    def best_above_noise(self) -> float:
        """Largest share of the validation gap above noise that one candidate removes."""
        return max((c["above_noise_explained"] for c in self.stats.values()), default=0.0)


def fit_threads() -> int:
    """Threads the independent fits of one diagnosis step run in (:func:`_each`):
    :func:`aeropend_ident.greybox.batch.replay_threads` if set (a pool or cluster worker running
    one case per core sets 1), else one per available core."""
    n = replay_threads()
    return n if n is not None else max(1, len(os.sched_getaffinity(0)))


def _each(st: _Setup, items: Sequence[str], work: Callable[[str, Callable[[str], None]], Any]
          ) -> Iterator[tuple[str, Any]]:
    """``(item, work(item, say))`` for every item, in order, the independent fits of one step run
    in :func:`fit_threads` threads at once (the compiled replays release the GIL).

    ``work`` reports progress through the ``say`` it is given; in threads its lines are kept and
    passed on to ``st.say`` in the order of ``items``, each before its result is yielded, so the
    progress reads as when the fits run one after the other (which they do with one thread).
    ``work`` must not change ``st``; an exception in one item is raised when its turn comes.
    """
    n = min(fit_threads(), len(items))
    if n <= 1:
        for item in items:
            yield item, work(item, st.say)
        return
    for prep in (*st.pf, *st.pv):  # their compiled replays are built here, not raced for by the threads
        _ = prep.replays, prep.head
    with ThreadPoolExecutor(max_workers=n, thread_name_prefix="aeropend-fit") as pool:
        jobs = []
        for item in items:
            lines: list[str] = []
            jobs.append((item, lines, pool.submit(_on_one_replay_thread, work, item, lines.append)))
        for item, lines, job in jobs:
            result = job.result()
            for line in lines:
                st.say(line)
            yield item, result


def _on_one_replay_thread(work: Callable[[str, Callable[[str], None]], Any], item: str,
                          say: Callable[[str], None]) -> Any:
    """``work(item, say)`` with its batch replays on the calling thread (one of :func:`_each`'s)."""
    with one_replay_thread():
        return work(item, say)


def _confirm_one(st: _Setup, ctx: EffectContext, name: str, est: Mapping[str, float] | None,
                 say: Callable[[str], None]) -> tuple[EffectFit, np.ndarray, dict, frozenset[str]]:
    """The single-effect fit of ``name`` on the fit recordings (starting from its equation-error
    estimate ``est`` too), its validation SSE per segment and per channel, and the effects whose
    held settings it freed (:func:`_free_settings_if_validated`; empty when none). Reads ``st``
    and ``ctx`` only: the fits of several effects may run at once."""
    say(f"grey-box fit of {name}")
    fr = fit_effects(st.rig, [name], st.pf, ctx, starts=[{name: est}] if est else ())
    sg, per_channel = validation_errors(fr.rig, fr.meas, st.pv)
    if any(p.held for p in get_effect(name).parameters) and name not in ctx.free_settings:
        return _free_settings_if_validated(st, ctx, name, est, (fr, sg, per_channel), say)
    return fr, sg, per_channel, frozenset()


def _free_settings_if_validated(st: _Setup, ctx: EffectContext, name: str, est: Mapping[str, float] | None,
                                held: tuple[EffectFit, np.ndarray, dict], say: Callable[[str], None]
                                ) -> tuple[EffectFit, np.ndarray, dict, frozenset[str]]:
    """The single-effect fit of ``name`` with its held parameters (the dry friction's onset
    width v_ε) fitted too, kept when it predicts the validation recordings better than the fit
    with the rig's settings (``held``: fit, validation SSE per segment, per channel); the diagnosis
    then fits them wherever the effect enters (the returned names join ``st.ctx.free_settings``:
    ``name`` and its refinements, a Stribeck law of the dry friction; empty when the rig's
    settings stay). A sample-split choice
    between two nested models: on a rod that creeps slower than the rig file's regularisation
    allows, the free width wins by far; where the fit data alone favour a width the validation
    data do not bear out (a real rig with more than dry friction), the rig's width stays."""
    freed = frozenset({name} | {r for r in st.refinements if name in get_effect(r).refines})
    fr = fit_effects(st.rig, [name], st.pf, dataclasses.replace(ctx, free_settings=ctx.free_settings | freed),
                     starts=[{name: est}] if est else ())
    sg, per_channel = validation_errors(fr.rig, fr.meas, st.pv)
    what = ", ".join(p.name for p in get_effect(name).parameters if p.held)
    if float(sg.sum()) < float(held[1].sum()):
        say(f"  {name}: {what} fitted (validation SSE {st.noise_ratio(float(sg.sum()))} against "
            f"{st.noise_ratio(float(held[1].sum()))} at the rig's value)")
        return fr, sg, per_channel, freed
    say(f"  {name}: {what} kept at the rig's value (fitted, the validation SSE is "
        f"{st.noise_ratio(float(sg.sum()))}, not below {st.noise_ratio(float(held[1].sum()))})")
    return (*held, frozenset())


def _bootstrap_first(st: _Setup, cands: _Candidates, order: Sequence[str],
                     seed: int) -> tuple[dict[str, float], dict[str, float]]:
    """Bootstrap over validation segments: how often each effect is first, and significant."""
    rng = np.random.default_rng(seed)
    first = dict.fromkeys(order, 0)
    signif = dict.fromkeys(order, 0)
    nseg = st.seg0.size
    for _ in range(N_BOOTSTRAP):
        pick = rng.integers(0, nseg, nseg)
        base = float(st.seg0[pick].sum())
        sse = {n: float(cands.segs[n][pick].sum()) for n in order}
        ex = {n: st.above_noise_share(sse[n], base) for n in order}
        if order:
            win = max(ex, key=ex.get)
            for simple in get_effect(win).nests:  # parsimony, as in _ranking
                if simple in sse and st.above_noise_share(sse[win], sse[simple]) < MIN_EXPLAINED_SECOND:
                    win = simple
            first[win] += 1
        for n in order:
            signif[n] += ex[n] >= MIN_EXPLAINED
    return ({n: v / N_BOOTSTRAP for n, v in first.items()}, {n: v / N_BOOTSTRAP for n, v in signif.items()})


def _ranking(st: _Setup, cands: _Candidates, scr: Screening, seed: int) -> list[dict[str, Any]]:
    """Candidates best first by validation explained, with their bootstrap frequencies, split-test
    p-value and ambiguity."""
    order = sorted(cands.stats, key=lambda n: -cands.stats[n]["validation_explained"])
    # parsimony: an effect that nests a simpler one (the thrust law with α = 2 is a thrust-coefficient
    # error) ranks above it only when it removes at least MIN_EXPLAINED_SECOND of the validation gap
    # above noise that the simpler one leaves, the criterion any further parameter must meet
    for name in list(order):
        for simple in get_effect(name).nests:
            if simple in order and order.index(simple) > order.index(name):
                s_rich, s_simple = float(cands.segs[name].sum()), float(cands.segs[simple].sum())
                if st.above_noise_share(s_rich, s_simple) < MIN_EXPLAINED_SECOND:
                    order.remove(simple)
                    order.insert(order.index(name), simple)
    first, signif = _bootstrap_first(st, cands, order, seed)
    ranking: list[dict[str, Any]] = []
    for name in order:
        e = get_effect(name)
        c = cands.stats[name]
        ranking.append({
            "effect": name, "subsystem": e.subsystem, "score": c["validation_explained"],
            "validation_explained": c["validation_explained"],
            "above_noise_explained": c["above_noise_explained"], "bic_delta": c["bic_delta"],
            "bootstrap_first": first[name], "bootstrap_significant": signif[name],
            # the sample-split test of the single effect against the nominal (presence: _evidence)
            "p_value": split_test(st.seg0, cands.segs[name], st.noise_sse / st.seg0.size, MIN_EXPLAINED),
            "explained": {k: cands.completeness[name][k] for k in ("completeness", "worst_channel",
                                                                  "residual_over_noise", "verdict")},
            "parameters": _param_table(cands.fits[name], name),
            "rig_values": get_effect(name).rig_values(st.rig, cands.fits[name].values[name]),
            "screening": ({"explained_strong": scr.explained_strong[name],
                           "explained_weak": scr.explained_weak[name], "inclusion": scr.inclusion[name],
                           "equation_error_estimate": scr.estimates.get(name)}
                          if name in scr.explained_strong else {"not_screened": True}),
            "confusable_with": _in_catalog(e.confusable_with, st),
            "ambiguous_with": [],
        })
    if ranking:
        top = ranking[0]
        # effects these data do not separate from the first: they win a share of the bootstrap
        # resamples of the validation segments
        amb = [r for r in ranking[1:] if r["bootstrap_first"] >= AMBIGUOUS_FIRST]
        top["ambiguous_with"] = [r["effect"] for r in amb]
        if amb:
            top["ambiguity"] = {r["effect"]: {"validation_explained": r["validation_explained"],
                                              "bootstrap_first": r["bootstrap_first"]} for r in amb}
    return ranking


class _Added(NamedTuple):
    """The effect one forward-selection step adds (:func:`_add_effect`)."""

    gain: float  # share of the validation SSE left by the chosen set that it removes
    effect: str
    fit: EffectFit  # chosen + effect, fitted jointly
    bic_delta: float
    screening: Screening  # of the residual the chosen set left
    sse: float  # validation SSE of chosen + effect (segment_sse summed)
    segs: np.ndarray  # validation SSE per segment of chosen + effect
    share: float  # bootstrap frequency of the gain passing the threshold
    p_value: float  # sample-split test of chosen + effect against chosen (split_test)


def excluded_with(chosen: Sequence[str]) -> set[str]:
    """The chosen effects and every effect that sets the same rig parameter as one of them
    (``exclusive_with``): what may not join them in a fit."""
    out = set(chosen)
    for n in chosen:
        out |= set(get_effect(n).exclusive_with)
    return out


def _joint(st: _Setup, cur: EffectFit, chosen: Sequence[str], o: str,
           alone: EffectFit | None = None,
           o_start: Mapping[str, float] | None = None,
           say: Callable[[str], None] | None = None) -> tuple[EffectFit, np.ndarray] | None:
    """``chosen`` + ``o`` fitted jointly from the chosen values and ``o``'s fit on the corrected
    model (fitted here unless given, from ``o_start`` where given); its validation SSE per segment.
    None when a fit fails. Progress goes to ``say`` (default ``st.say``)."""
    (say or st.say)(f"joint fit of {' + '.join(chosen)} + {o}")
    try:
        alone = alone or fit_effects(cur.rig, [o], st.pf, st.ctx, start={o: dict(o_start or {})})
        start = {**{n: cur.values[n] for n in chosen}, o: alone.values[o]}
        fr2 = fit_effects(st.rig, [*chosen, o], st.pf, st.ctx, start=start, scan=False, max_nfev=MAX_NFEV)
    except GapError:
        return None
    return fr2, segment_sse(fr2.rig, fr2.meas, st.pv)


def _add_effect(st: _Setup, cur: EffectFit, cur_segs: np.ndarray, chosen: Sequence[str],
                ranking: Sequence[Mapping[str, Any]], screened: Sequence[str], forced: Sequence[str],
                seed: int) -> _Added | None:
    """One forward-selection step of :func:`diagnose_effects`: the next effect, or None.

    The residual left by the ``chosen`` effects (fitted in ``cur``) is screened (discrepancy SINDy
    on the corrected model); its :data:`FORWARD_CANDIDATES` best groups, the next
    :data:`FORWARD_CANDIDATES` ranked single effects that remove more than 10 % of the validation
    residual alone, and the ``forced`` (timing) effects are each fitted jointly with the chosen
    ones, starting from the chosen values and the candidate's fit on the corrected model. When none
    of them passes, every other identifiable effect is fitted alone on the corrected model and the
    :data:`FORWARD_CANDIDATES` best are fitted jointly too (a sign-function friction, say, is
    blurred in the derivative-based screening). A candidate counts when it removes at least
    :data:`MIN_EXPLAINED_SECOND` of the validation gap above noise the chosen set leaves, with a BIC
    gain of :data:`MIN_BIC_GAIN` on the fit data; the largest removal wins. Effects that set the
    same rig parameter as a chosen one (``exclusive_with``) are not tried.
    """
    cur_sse = float(cur_segs.sum())
    skip = excluded_with(chosen)
    rest = [n for n in screened if n not in skip]
    st.say(f"screening the residual left by {' + '.join(chosen)}")
    scr2 = screen(cur.rig, st.pf, rest, st.channels, st.ctx, seed=seed, meas=cur.meas, estimate=False)
    ranked = [r for r in ranking if r["effect"] not in skip and r["validation_explained"] is not None]
    ranked = ranked[:FORWARD_CANDIDATES]
    others: list[str] = []
    for o in (*scr2.shortlist(FORWARD_CANDIDATES),
              *(r["effect"] for r in ranked if r["validation_explained"] > 0.1)):
        if o not in others and o not in skip:
            others.append(o)
    # timing effects requested by the caller are also tried: a lead or lag often shows only once
    # the dominant (e.g. damping) error is removed
    cands = others + [f for f in forced if f not in others and f not in skip]
    k1 = sum(_n_fitted(n, st.ctx) for n in chosen)
    rng = np.random.default_rng(seed)
    best2 = None

    def consider(o: str, res: tuple[EffectFit, np.ndarray] | None) -> None:
        nonlocal best2
        if res is None:
            return
        fr2, segs2 = res
        sse2 = float(segs2.sum())
        gain = st.above_noise_share(sse2, cur_sse)
        k2 = k1 + _n_fitted(o, st.ctx)
        bic_gain = (_bic(fr2.sse * st.n_eff / st.n_fit, st.n_eff, k2)
                    - _bic(cur.sse * st.n_eff / st.n_fit, st.n_eff, k1))
        st.say(f"  {o}: removes {100 * gain:.1f} % of the remaining validation gap above noise, "
               f"BIC change {bic_gain:.1f}")
        passes = gain >= MIN_EXPLAINED_SECOND and bic_gain <= -MIN_BIC_GAIN
        why = unresolved_times(o, fr2.values[o], max(p.dt for p in st.pf))
        if passes and why:
            st.say(f"  {why}")
            passes = False
        p_value = (split_test(cur_segs, segs2, st.noise_sse / cur_segs.size, MIN_EXPLAINED_SECOND)
                   if passes else 1.0)
        if passes and not _holds_in_sample(st, p_value):
            st.say(f"  {o}: in-sample, its gain does not hold second by second (split-test p {p_value:.2f})")
            passes = False
        if passes and (best2 is None or gain > best2.gain):
            hits = 0
            for _ in range(N_BOOTSTRAP):
                pick = rng.integers(0, segs2.size, segs2.size)
                hits += st.above_noise_share(float(segs2[pick].sum()),
                                             float(cur_segs[pick].sum())) >= MIN_EXPLAINED_SECOND
            best2 = _Added(gain, o, fr2, bic_gain, scr2, sse2, segs2, hits / N_BOOTSTRAP, p_value)

    # the joint fits are independent (run at once, _each); their figures are taken in order
    for o, res in _each(st, cands, lambda o, say: _joint(st, cur, chosen, o, say=say)):
        consider(o, res)
    if best2 is None:
        more = [n for n in st.model_effects if n not in skip and n not in cands]
        st.say(f"no proposed effect passes; fitting the rest of the catalog on the corrected model: {more}")

        def alone_fit(o: str, _say: Callable[[str], None]) -> tuple[float, EffectFit] | None:
            try:
                fr = fit_effects(cur.rig, [o], st.pf, st.ctx)
            except GapError:
                return None
            return float(segment_sse(fr.rig, fr.meas, st.pv).sum()), fr

        alone = {o: r for o, r in _each(st, more, alone_fit) if r is not None}
        best = sorted(alone, key=lambda n: alone[n][0])[:FORWARD_CANDIDATES]
        for o, res in _each(st, best, lambda o, say: _joint(st, cur, chosen, o, alone[o][1], say=say)):
            consider(o, res)
    return best2


_Swapped = tuple[EffectFit, np.ndarray, list[str], dict[str, dict[str, float]],
                 dict[tuple[str, str], EffectFit]]


def _swap_confusables(st: _Setup, cur: EffectFit, cur_segs: np.ndarray, chosen: list[str]) -> _Swapped:
    """Replacement pass after forward selection: each chosen effect is replaced, in turn, by each
    of its physics-confusable or nested alternatives, fitted jointly with the other chosen ones.

    With two causes at once, the best single effect is often a stand-in (a back-EMF error for an
    armature-resistance error) that the joint fit with the true partner then keeps. An
    alternative replaces it when it removes at least :data:`SWAP_GAIN` of the validation gap above
    noise that the current set leaves; a simpler nested effect (K_q for the thrust law) replaces
    its richer one unless the richer one removes :data:`MIN_EXPLAINED_SECOND` of what it leaves.
    An alternative that neither set beats by :data:`SWAP_GAIN` is returned as not separated from
    the chosen effect (``{chosen effect: {alternative: its validation explained, jointly fitted}}``),
    and its joint fit as ``{(chosen effect, alternative): fit}``.
    """
    amb: dict[str, dict[str, float]] = {}
    alt_fits: dict[tuple[str, str], EffectFit] = {}
    for i in range(len(chosen)):
        name = chosen[i]
        others = [n for n in chosen if n != name]
        blocked = excluded_with(others) | set(chosen)
        alts = [a for a in dict.fromkeys((*get_effect(name).nests, *get_effect(name).confusable_with))
                if a in st.model_effects and a not in blocked]
        for alt in alts:
            st.say(f"replacement: {name} -> {alt}")
            base = EffectFit(effects=tuple(others), values={n: cur.values[n] for n in others}, std={},
                             rig=cur.rig, meas=cur.meas, sse=cur.sse, n=cur.n, nfev=0)
            res = _joint(st, base, others, alt)
            if res is None:
                continue
            fr2, segs2 = res
            if unresolved_times(alt, fr2.values[alt], max(p.dt for p in st.pf)):
                continue  # not resolved at this rate: neither a replacement nor an alternative
            s_cur, s_alt = float(cur_segs.sum()), float(segs2.sum())
            if alt in get_effect(name).nests:  # simpler alternative: the richer one must earn it
                better = st.above_noise_share(s_cur, s_alt) < MIN_EXPLAINED_SECOND
            elif name in get_effect(alt).nests:  # richer alternative: the same criterion
                better = st.above_noise_share(s_alt, s_cur) >= MIN_EXPLAINED_SECOND
            else:
                better = st.above_noise_share(s_alt, s_cur) >= SWAP_GAIN
            if not better and st.above_noise_share(s_cur, s_alt) < SWAP_GAIN:
                # neither is better: these data do not separate the two (for a confusable one, the
                # rule of :func:`_not_separated`)
                amb.setdefault(name, {})[alt] = 1.0 - s_alt / max(st.sse_val0, 1e-300)
                alt_fits[(name, alt)] = fr2
            if better:
                st.say(f"  {alt} replaces {name}")
                amb.pop(name, None)
                alt_fits = {k: v for k, v in alt_fits.items() if k[0] != name}
                chosen = [alt if n == name else n for n in chosen]
                order = list(chosen)
                cur = EffectFit(effects=tuple(order), values={n: fr2.values[n] for n in order}, std=fr2.std,
                                rig=fr2.rig, meas=fr2.meas, sse=fr2.sse, n=fr2.n, nfev=fr2.nfev)
                cur_segs = segs2
                break
    return cur, cur_segs, chosen, amb, alt_fits


def _not_separated(st: _Setup, sse_a: float, sse_b: float) -> bool:
    """Whether two models with validation SSE ``sse_a`` and ``sse_b`` are not separated by these
    data: neither removes :data:`SWAP_GAIN` of the validation gap above noise that the other
    leaves (the replacement pass' rule for a confusable alternative, :func:`_swap_confusables`)."""
    return st.above_noise_share(sse_a, sse_b) < SWAP_GAIN and st.above_noise_share(sse_b, sse_a) < SWAP_GAIN


def plant_side_alternative(chosen: Sequence[str], ambiguous: Mapping[str, Mapping[str, float]]
                           ) -> tuple[str, str] | None:
    """The plant-side effect to write instead of a chosen sensor-frame effect the data do not
    separate from it, as ``(sensor effect, plant-side effect)``; ``None`` when there is none.

    A sensor gain and a thrust-coefficient (or gravity, inertia) error shape the recorded angle
    alike at small angles (only sin θ tells them apart), so one recording often cannot separate
    them. For the rig file a controller is designed on they are not alike: a wrong sensor frame
    makes the loop hold every set point at the wrong physical angle (by the fitted gain), while a
    plant-side stand-in for a true sensor error holds the angle the nominal rig file would. The
    plant-side alternative is therefore the one written (:attr:`EffectDiagnosis.plant_side`); the
    diagnosis still names what fitted best.

    Parameters
    ----------
    chosen : sequence of str
        Effects chosen, in order.
    ambiguous : mapping
        ``{chosen effect: {alternative: validation explained}}`` (the replacement pass' record of
        alternatives the data do not separate).

    Returns
    -------
    tuple of str or None
        The first chosen ``kind == "measurement"`` effect with a ``kind == "model"`` alternative,
        and of those alternatives the one explaining most of the validation error.
    """
    for name in chosen:
        if get_effect(name).kind != "measurement":
            continue
        alts = {a: v for a, v in ambiguous.get(name, {}).items() if get_effect(a).kind == "model"}
        if alts:
            return name, max(alts, key=lambda a: alts[a])
    return None


#: A refinement's own parameter this close to a bound of its search range (a factor for log
#: parameters, a share of the range otherwise) does not describe the refinement.
AT_BOUND_FACTOR = 1.25
AT_BOUND_SHARE = 0.02


def _added_at_bound(st: _Setup, name: str, ref: str, values: Mapping[str, float]) -> list[str]:
    """The parameters ``ref`` adds to ``name`` whose fitted values sit at a bound of their search
    range: a Stribeck velocity at its floor (3× the sign's regularisation width) only sharpens the
    model's smooth sign, an excess static friction at 0 is no stiction; the refinement is then not
    what the data show."""
    out = []
    shared = set(get_effect(name).parameter_names)
    for p in get_effect(ref).parameters:
        if p.name in shared:
            continue
        r, v = p.bind(st.ctx), values[p.name]
        if r.log:
            near = v <= r.lower * AT_BOUND_FACTOR or v >= r.upper / AT_BOUND_FACTOR
        else:
            span = r.upper - r.lower
            near = v <= r.lower + AT_BOUND_SHARE * span or v >= r.upper - AT_BOUND_SHARE * span
        if near:
            out.append(p.name)
    return out


def _refine(st: _Setup, cur: EffectFit, cur_segs: np.ndarray, chosen: list[str]
            ) -> tuple[EffectFit, np.ndarray, list[str], dict[str, dict[str, float]]]:
    """Refinement pass: each chosen effect that an operating-point refinement refines (Coulomb →
    Stribeck friction, ``Effect.refines``) is replaced by it, fitted jointly with the other chosen
    effects from the values they share, when the refinement earns its extra parameters twice:
    it removes :data:`MIN_EXPLAINED_SECOND` of the validation gap above noise that the chosen set
    leaves, and lowers the fit data's BIC by :data:`MIN_BIC_GAIN`; and its own parameters are not
    at a bound of their range (:func:`_added_at_bound`). Returns the (new) fit, its
    validation SSE per segment, the chosen names and, per tried refinement, its figures."""
    tried: dict[str, dict[str, float]] = {}
    for name in list(chosen):
        for ref in st.refinements:
            if name not in get_effect(ref).refines:
                continue
            others = [n for n in chosen if n != name]
            if ref in excluded_with(others):
                continue
            st.say(f"refinement: {name} -> {ref}")
            shared = {k: v for k, v in cur.values[name].items() if k in get_effect(ref).parameter_names}
            base = EffectFit(effects=tuple(others), values={n: cur.values[n] for n in others}, std={},
                             rig=cur.rig, meas=cur.meas, sse=cur.sse, n=cur.n, nfev=0)
            res = _joint(st, base, others, ref, o_start=shared)
            if res is None:
                continue
            fr2, segs2 = res
            k1 = sum(_n_fitted(n, st.ctx) for n in chosen)
            k2 = k1 - _n_fitted(name, st.ctx) + _n_fitted(ref, st.ctx)
            bic = (_bic(fr2.sse * st.n_eff / st.n_fit, st.n_eff, k2)
                   - _bic(cur.sse * st.n_eff / st.n_fit, st.n_eff, k1))
            gain = st.above_noise_share(float(segs2.sum()), float(cur_segs.sum()))
            at_bound = _added_at_bound(st, name, ref, fr2.values[ref])
            kept = gain >= MIN_EXPLAINED_SECOND and bic <= -MIN_BIC_GAIN and not at_bound
            tried[ref] = {"replaces": name, "above_noise_explained_of_rest": gain, "bic_delta": bic,
                          "at_bound": at_bound, "kept": kept}
            st.say(f"  {ref} removes {100 * gain:.1f} % of what {name} leaves above noise, BIC change "
                   f"{bic:.1f}{', ' + ', '.join(at_bound) + ' at a bound' if at_bound else ''}: "
                   f"{'kept' if kept else 'not kept'}")
            if kept:
                chosen = [ref if n == name else n for n in chosen]
                cur = EffectFit(effects=tuple(chosen), values={n: fr2.values[n] for n in chosen}, std=fr2.std,
                                rig=fr2.rig, meas=fr2.meas, sse=fr2.sse, n=fr2.n, nfev=fr2.nfev)
                cur_segs = segs2
                break
    return cur, cur_segs, chosen, tried


def split_test(base: np.ndarray, new: np.ndarray, noise: float, min_share: float) -> float:
    """One-sided p-value that a model removes a relevant share of the validation gap: the
    sample-split test of presence.

    ``base`` and ``new`` are the validation SSE per segment (:func:`segment_sse`, 1 s segments) of
    the model without and with the effect, whose parameters were fitted on the fit part only. Per
    segment, l_j = log(base_j / new_j) is the factor by which the effect shrinks that second's
    error (scale-free: a second with a large gap and one with a small gap weigh as evidence by how
    much of their own error goes, not by their size); the segments are weighted by the share of
    their error above the noise, w_j = max(base_j − noise, 0)/base_j (a second at the noise floor
    holds no evidence either way, one whose error is all gap counts fully). H0: the weighted mean
    of l is at most −log(1 − ``min_share``), i.e. the effect removes less than the share of the
    gap the decision asks for (:data:`MIN_EXPLAINED`; under "absent", a
    model fitted on other data removes nothing on average: l ≤ 0). A t test whose sample size is
    the weights' effective number (Σw)²/Σw² reduced for the correlation of neighbouring seconds
    (a free-run error persists): n_eff·(1 − ρ₁)/(1 + ρ₁), ρ₁ the lag-1 autocorrelation of l
    clipped to [0, 0.9] (Wilks, *Statistical methods in the atmospheric sciences*, §5.2.4).

    Parameters
    ----------
    base, new : numpy.ndarray
        Shape (n,), validation SSE per segment without / with the effect (same segments).
    noise : float
        Noise part of one segment's SSE (same normalisation).
    min_share : float
        Share of the gap the effect must remove, in [0, 1).

    Returns
    -------
    float
        p in [0, 1]; 1.0 when no segment carries a gap above noise.
    """
    base = np.asarray(base, dtype=float)
    tiny = 1e-300
    lr = np.log(np.maximum(base, tiny) / np.maximum(np.asarray(new, dtype=float), tiny))
    w = np.maximum(base - noise, 0.0) / np.maximum(base, tiny)
    if w.sum() <= 0.0:
        return 1.0
    w = w / w.sum()
    mean = float(np.sum(w * lr))
    h0 = -math.log(1.0 - min_share)
    var = float(np.sum(w * (lr - mean) ** 2))
    n_w = 1.0 / float(np.sum(w**2))
    keep = w > 0.0
    rho = float(np.corrcoef(lr[:-1], lr[1:])[0, 1]) if keep.sum() > 3 and np.ptp(lr) > 0 else 0.0
    rho = float(np.clip(rho if np.isfinite(rho) else 0.0, 0.0, 0.9))
    n_eff = max(n_w * (1.0 - rho) / (1.0 + rho), 2.0)
    if var <= 1e-24:
        return 0.0 if mean > h0 else 1.0
    se = math.sqrt(var * n_w / max(n_w - 1.0, 1.0) / n_eff)
    return float(student_t.sf((mean - h0) / se, df=n_eff - 1.0))


#: A fitted time (a dead time, a lag or a response time constant: a parameter in s) shorter than this
#: share of the recordings' sample period is not resolved by them (:func:`unresolved_times`).
RESOLVED_SHARE = 0.5


def unresolved_times(effect: str, values: Mapping[str, float], dt: float) -> str:
    """Why a fitted timing effect is not resolved by recordings sampled every ``dt``, '' when it is.

    A dead time or a first-order lag shorter than half the sample period settles between two
    samples: the angle cannot show it, and what such a fit improves is *when the logger stamps* a
    channel. A drive output (the armature voltage v_a) logged as the previous period's value, after
    the command of that period, is matched by the smallest lag or an input delay → 0 that moves the
    model's drive output by one sample. That is a logging convention, not the plant's physics
    (found on closed-loop logs whose v_a is stamped one period late: an actuator lag at its range's
    lower bound, 1 ms at 4.1 ms per sample, and an input delay of 2e-9 s at 20.5 ms, each named at
    presence ≥ 0.9 on plants without them; docs/findings/gap.md).

    Parameters
    ----------
    effect : str
        Catalog name.
    values : mapping
        Its fitted parameter values (physical units).
    dt : float
        The recordings' (longest) sample period [s].

    Returns
    -------
    str
        The reason (every time parameter of the effect below :data:`RESOLVED_SHARE` × dt), or ''
        (the effect has no time parameter, or one at least that long).
    """
    times = [p for p in get_effect(effect).parameters if p.unit == "s"]
    if not times or any(float(values.get(p.name, math.inf)) >= RESOLVED_SHARE * dt for p in times):
        return ""
    fitted = ", ".join(f"{p.name} {1e3 * float(values[p.name]):.2g} ms" for p in times)
    return (f"{effect} fitted shorter than half the {1e3 * dt:.3g} ms sample period ({fitted}): not resolved "
            "at this rate; what it fits is when the logger stamps a channel (e.g. v_a read as the previous "
            "period's drive output), not the plant")


def _mark_unresolved(ranking: list[dict[str, Any]], cands: Any, dt: float) -> None:
    """Mark, in place, the ranked single-effect fits not resolved at the sample period ``dt``
    (:func:`unresolved_times`, entry field ``unresolved``)."""
    for r in ranking:
        fr = cands.fits.get(r["effect"])
        why = unresolved_times(r["effect"], fr.values[r["effect"]], dt) if fr is not None else ""
        if why:
            r["unresolved"] = why


def _unresolved_reason(ranking: Sequence[Mapping[str, Any]], chosen: Sequence[str]) -> str:
    """'; why' for each unchosen timing fit that passed the bar but is not resolved at this rate."""
    out = ""
    for r in ranking:
        passed = (r.get("bic_delta") is not None and r["bic_delta"] <= -MIN_BIC_GAIN
                  and (r.get("above_noise_explained") or 0.0) >= MIN_EXPLAINED)
        if r.get("unresolved") and r["effect"] not in chosen and passed:
            out += f"; {r['unresolved']}"
    return out


def status_of(presence: float | None, chosen: bool, completeness: float | None,
              not_separated: bool = False) -> str:
    """The word the report uses for an effect, from its presence and the chosen set's completeness.

    Parameters
    ----------
    presence : float or None
        Evidence the effect is present (0..1, :func:`_evidence`).
    chosen : bool
        In the corrected rig.
    completeness : float or None
        How completely the chosen set explains the validation gap (0..1, :func:`_completeness`).
    not_separated : bool
        The data do not separate it from a chosen effect (``ambiguous_with`` of one).

    Returns
    -------
    str
        ``"named"`` (chosen, presence ≥ :data:`NAMED_PRESENCE`, completeness ≥
        :data:`NAMED_COMPLETENESS`), ``"candidate"`` (chosen but short of either, or presence ≥
        :data:`CANDIDATE_PRESENCE`), ``"not separated"`` or ``"not significant"``.
    """
    p = presence or 0.0
    if chosen:
        return "named" if p >= NAMED_PRESENCE and (completeness or 0.0) >= NAMED_COMPLETENESS else "candidate"
    if not_separated:
        return "not separated"
    return "candidate" if p >= CANDIDATE_PRESENCE else "not significant"


def misspecification_factor(completeness: float | None) -> float:
    """The bound a residual far above the noise puts on any catalog effect's presence.

    The sample-split test compares two models of one family; it tells "this effect" from "no
    effect" only when the family holds the plant. When the best model (the chosen set for a chosen
    effect, the effect alone otherwise) still leaves a residual far above the noise (completeness
    0, :func:`_completeness`), the data show something the catalog does not hold, and an effect that
    passes the test is as likely a stand-in for it as present itself: its presence is at most ½.
    Linear between: 0.5 + 0.5·completeness (1 for a model that leaves the noise level).

    Parameters
    ----------
    completeness : float or None
        0..1; None (not computed) counts as 1.
    """
    c = 1.0 if completeness is None else float(np.clip(completeness, 0.0, 1.0))
    return 0.5 + 0.5 * c


def _evidence(ranking: list[dict[str, Any]], chosen: Sequence[str], shares: Mapping[str, float],
              pvals: Mapping[str, float], explained: Mapping[str, Any], *, in_sample: bool) -> None:
    """Presence, q-value and status of every ranked effect (module doc, step 5), in place; the
    chosen effects first (in the order chosen), the others by presence.

    The p-values of every test made (each single candidate against the nominal, each added effect
    against the set before it: ``pvals`` overrides an entry's own) are adjusted together by
    Benjamini-Hochberg (:func:`scipy.stats.false_discovery_control`); presence = (1 − q) × the
    effect's bootstrap share (``shares`` for a chosen effect, else its ``bootstrap_first``) ×
    :func:`misspecification_factor` of the completeness (the chosen set's for a chosen effect,
    its own otherwise). A chosen effect with k alternatives the validation figures do not separate
    from it (``ambiguity`` entries without a bootstrap share: :func:`_not_separated`, alone or in the
    joint fit) shares its bootstrap share equally with them, each 1/(k + 1) of it: the bootstrap
    gives every resample to the one a hair ahead, and the data give no reason to prefer it.
    ``in_sample``: the validation part was the fit part (see :func:`_setup`), said on each entry.
    """
    shares = dict(shares)
    first = {r["effect"]: r.get("bootstrap_first") or 0.0 for r in ranking}
    for r in ranking:
        tied = [a for a, v in (r.get("ambiguity") or {}).items() if v.get("bootstrap_first") is None]
        own = shares.get(r["effect"], r.get("bootstrap_first"))
        if r["effect"] in chosen and tied and own is not None:
            shares[r["effect"]] = own / (len(tied) + 1)
            for a in tied:
                if a not in chosen:
                    shares[a] = max(shares.get(a, first.get(a, 0.0)), own / (len(tied) + 1))
    tested = [r for r in ranking if not r.get("detected")]
    ps = [pvals.get(r["effect"], r.get("p_value")) for r in tested]
    have = [i for i, p in enumerate(ps) if p is not None]
    qs = false_discovery_control([ps[i] for i in have], method="bh") if have else []
    q_of = {tested[i]["effect"]: float(q) for i, q in zip(have, qs, strict=True)}
    ambiguous = {a for r in ranking if r["effect"] in chosen for a in r.get("ambiguous_with", [])}
    for r in tested:
        name = r["effect"]
        if name in pvals:
            r["p_value"] = pvals[name]
        q = q_of.get(name)
        share = shares.get(name, r.get("bootstrap_first"))
        comp = (explained.get("completeness") if name in chosen
                else (r.get("explained") or {}).get("completeness"))
        r["q_value"] = q
        r["presence"] = (None if q is None or share is None
                         else float((1.0 - q) * share * misspecification_factor(comp)))
        if r.get("unresolved") and name not in chosen:  # not the plant's: no evidence of a present effect
            r["presence"] = 0.0 if r["presence"] is not None else None
        r["status"] = status_of(r["presence"], name in chosen, explained.get("completeness"),
                                name in ambiguous)
        if in_sample:
            r["presence_in_sample"] = True
    rank = {n: i for i, n in enumerate(chosen)}
    ranking.sort(key=lambda r: (rank.get(r["effect"], len(rank)), not r.get("detected"),
                                -(r.get("presence") or 0.0)))


def _completeness(st: _Setup, sse: Mapping[str, float]) -> dict[str, Any]:
    """How completely a corrected model explains the validation gap, judged channel by channel.

    ``sse`` is the corrected model's validation error per channel (:func:`validation_errors`).
    Each channel's error is compared with its noise part (:func:`_noise_var`): a model that
    captures the plant leaves only noise (ratio near 1). ``completeness`` is 1 while every channel's
    ratio is at most :data:`RESIDUAL_NOISE_OK` (RMS within 2× the noise), 0 from
    :data:`RESIDUAL_NOISE_MAX` on (RMS 5×), log-linear between; the worst channel counts. Pooling the
    channels would let the noise of well-modelled channels hide a residual left in another.
    """
    per: dict[str, dict[str, float]] = {}
    comp = 1.0
    for c, s_c in sse.items():
        n_c = max(st.noise_c[c], 1e-300)
        s0 = st.sse0_c[c]
        ratio = s_c / n_c
        share = (s0 - s_c) / (s0 - n_c) if s0 > n_c else math.nan
        c_c = float(np.clip(math.log(RESIDUAL_NOISE_MAX / max(ratio, 1e-300))
                            / math.log(RESIDUAL_NOISE_MAX / RESIDUAL_NOISE_OK), 0.0, 1.0))
        per[c] = {"residual_over_noise": ratio, "nominal_over_noise": s0 / n_c, "share_above_noise": share,
                  "completeness": c_c}
        comp = min(comp, c_c)
    worst = max(per, key=lambda k: per[k]["residual_over_noise"])
    w = per[worst]
    times = f"{math.sqrt(w['residual_over_noise']):.1f}× its noise RMS"
    if comp >= 1.0:
        verdict = "explained: the corrected model leaves the noise level"
    elif comp >= 0.5:
        verdict = f"mostly explained ({worst} residual {times})"
    else:
        verdict = (f"partly explained: the {worst} residual stays {times}, which no chosen effect accounts "
                   "for (an effect outside the catalog, several at once, or a time-varying rig)")
    return {"completeness": comp, "worst_channel": worst, "residual_over_noise": w["residual_over_noise"],
            "share_above_noise": w["share_above_noise"], "per_channel": per, "verdict": verdict}


def _quantisation_entry(st: _Setup, q_hat: float) -> dict[str, Any]:
    """Ranking entry of a detected angle quantum q (not fitted): its score is the share of the nominal
    validation mean square error that the rounding noise q²/12 accounts for."""
    ms0 = float(np.mean([np.mean((replay(st.rig, MeasurementMap(), p)["theta"] - p.y["theta"]) ** 2)
                         for p in st.pv]))
    share = min(1.0, (q_hat**2 / 12.0) / max(ms0, 1e-300))
    return {
        "effect": "quantisation", "subsystem": get_effect("quantisation").subsystem, "score": share,
        "validation_explained": share, "bic_delta": None, "presence": 1.0, "status": "detected",
        "detected": True,
        "parameters": {"theta_quantum": {"value": q_hat, "std": 0.0, "unit": "rad"}},
        "rig_values": {"sensors.theta_quantum": q_hat},
        "screening": {"detected": "lattice of recorded angles"},
        "confusable_with": [], "ambiguous_with": [],
    }


def _unmodelled_quantum(rig: Rig, st: _Setup) -> float:
    """The angle quantum q [rad] every fit and validation recording shows
    (:func:`aeropend_ident.gap.effects.detect_quantum`, median over them) when the nominal rig does
    not model it (no quantisation, or an LSB under 2/3 of q); else 0."""
    quanta = [detect_quantum(p.y["theta"]) for p in (*st.pf, *st.pv)]
    q_hat = float(np.median(quanta)) if all(q > 0 for q in quanta) else 0.0
    q_nominal = rig.sensors.theta_quantum if rig.effects.quantisation else 0.0
    return q_hat if q_hat > 0.0 and q_hat > 1.5 * q_nominal else 0.0


def _add_quantum(st: _Setup, q_hat: float, ranking: list[dict[str, Any]], corrected: Rig, sig_first: bool,
                 reason: str) -> tuple[Rig, str]:
    """A detected angle quantum into the diagnosis: its ranking entry (first when no dynamic effect is
    significant or it accounts for more of the validation error), the corrected rig's sensor LSB and
    the reason; returns (corrected rig, reason)."""
    entry = _quantisation_entry(st, q_hat)
    # the first entry may be a chosen effect a replacement pass brought in, never fitted alone (no
    # figure of its own): compare with the best single effect's
    first_ex = max((r["validation_explained"] for r in ranking if r.get("validation_explained") is not None),
                   default=0.0)
    ranking.insert(0 if (not sig_first or entry["validation_explained"] >= first_ex) else 1, entry)
    corrected = get_effect("quantisation").apply(corrected, {"theta_quantum": q_hat})
    note = (f"angle quantised with LSB {q_hat:.4g} rad (detected from the recorded values, not "
            "fitted), not modelled by the nominal rig")
    return corrected, (f"{reason}; {note}" if sig_first else
                       f"{note}; no dynamic effect is significant ({reason})")


def _screen_and_confirm(rig: Rig, st: _Setup, also_confirm: Sequence[str], seed: int,
                        say: Callable[[str], None]) -> tuple[Screening, _Candidates, list[str], list[str]]:
    """Screening and grey-box confirmation of :func:`diagnose_effects`: (screening, candidates,
    screened effects, effects confirmed without screening)."""
    # screening; effects marked screened=False (the motor time constant: its θ̈ column, through the
    # simulated thrust, is nearly collinear with the damping term and crowds it out of the group
    # selection) are not screened but always confirmed by a grey-box fit
    screened = [n for n in st.model_effects if get_effect(n).screened]
    unscreened = [n for n in st.model_effects if not get_effect(n).screened]
    say(f"screening {len(screened)} effects by discrepancy SINDy (strong + weak, group sparse)")
    scr = screen(rig, st.pf, screened, st.channels, st.ctx, seed=seed)
    short = scr.shortlist(SHORTLIST)
    say(f"shortlist: {short}")
    cands = _Candidates()
    forced = list(dict.fromkeys(n for n in (*unscreened, *also_confirm) if n in st.model_effects))
    if forced:
        say(f"also confirming {[f for f in forced if f not in short]} (not screened, or requested: "
            "timing lead/lag seen by the where-analysis)")
    cands.confirm(st, [*short, *forced], scr)  # one step: the fits run at once (_each)
    if 1.0 - cands.best_above_noise() > EXTEND_BELOW_GAP:
        # the best candidate leaves much of the gap above noise: confirm the next screened effects
        extra = [n for n in scr.shortlist(SHORTLIST + EXTEND_SHORTLIST) if n not in cands.fits]
        say(f"best candidate leaves {100 * (1 - cands.best_above_noise()):.0f} % of the gap above noise; "
            f"also confirming {extra}")
        cands.confirm(st, extra, scr)
    if cands.best_above_noise() < MIN_EXPLAINED and _above_noise(st.sse0_c, st.noise_c, st.chance_c):
        # a gap, but nothing the screening proposed explains it (small gaps at low SNR blur the
        # derivative-based screening): confirm every remaining identifiable effect
        rest = [n for n in st.model_effects if n not in cands.fits]
        say(f"no shortlisted effect explains the gap; confirming the rest of the catalog {rest}")
        cands.confirm(st, rest, scr)
    return scr, cands, screened, forced


def _holds_in_sample(st: _Setup, p_value: float | None) -> bool:
    """Whether an effect's split-test p-value allows its choice: always on a validation part of its
    own; when the effects are ranked on the fit part (the in-sample fallback of :func:`_setup`),
    only up to :data:`IN_SAMPLE_MAX_P`."""
    return st.pv is not st.pf or (p_value is not None and p_value <= IN_SAMPLE_MAX_P)


def _no_effect_reason(st: _Setup, best: dict[str, Any] | None, above_floor: bool) -> str:
    """Why :func:`diagnose_effects` names no dynamic effect."""
    if best is None:
        reason = "no identifiable candidate effect"
    elif not above_floor:
        noise = {c: max(st.noise_c[c], 1e-300) for c in st.noise_c}
        worst = max(st.sse0_c, key=lambda c: st.sse0_c[c] / (ABOVE_NOISE * noise[c] + st.chance_c[c]))
        bound = math.sqrt(ABOVE_NOISE + st.chance_c[worst] / noise[worst])
        reason = (f"nominal validation error is at the noise floor: every channel's error is within "
                  f"{math.sqrt(ABOVE_NOISE):.2f}× its noise RMS, more by the chance of a few held rounding "
                  f"errors (closest: {worst}, {math.sqrt(st.sse0_c[worst] / noise[worst]):.2f}× "
                  f"against {bound:.2f}×)")
    elif (best["above_noise_explained"] >= MIN_EXPLAINED and best["bic_delta"] <= -MIN_BIC_GAIN
          and not _holds_in_sample(st, best["p_value"])):
        reason = (f"best candidate {best['effect']} removes {100 * best['above_noise_explained']:.1f} % of "
                  "the fit part's gap above noise in all but not second by second: in-sample split-test p "
                  f"{best['p_value']:.2f}, needs {IN_SAMPLE_MAX_P:g} or less, and the validation part, which "
                  "shows no gap, cannot support it")
    elif best["above_noise_explained"] >= MIN_EXPLAINED:
        reason = (f"best candidate {best['effect']} removes {100 * best['above_noise_explained']:.1f} % of "
                  "the validation gap above noise, but its BIC on the fit data changes by "
                  f"{best['bic_delta']:+.1f} (needs -{MIN_BIC_GAIN:g} or less)")
    else:
        reason = (f"best candidate {best['effect']} removes only {100 * best['above_noise_explained']:.1f} % "
                  f"of the validation gap above noise (needs {100 * MIN_EXPLAINED:.0f} % and a BIC gain of "
                  f"{MIN_BIC_GAIN:g}; BIC change {best['bic_delta']:.1f})")
    return reason


def diagnose_effects(rig: Rig, fit: Sequence[Recording], validation: Sequence[Recording], *,
                     max_effects: int = 2, seed: int = 0,
                     progress: Callable[[str], None] | None = None,
                     also_confirm: Sequence[str] = (), skip: Sequence[str] = ()) -> EffectDiagnosis:
    """Find which catalog effect(s) explain the gap between a rig file and recordings.

    Parameters
    ----------
    rig : Rig
        Nominal rig (the simulator as the lab has it).
    fit : sequence of Recording
        Recordings used for screening and fitting (θ and duty needed; i_a, v_a, ω₁ used when
        every recording has them).
    validation : sequence of Recording
        Recordings on which the effects are ranked and chosen (another stretch or experiment;
        never the held-out recordings of the final before/after).
    max_effects : int
        Most effects added to the corrected rig (1, 2 or 3; each one after the first by the same
        forward-selection step, :func:`_add_effect`).
    seed : int
        Seed of the bootstraps and weak-form test functions.
    progress : callable, optional
        Called with short status messages.
    also_confirm : sequence of str
        Catalog effects confirmed by a grey-box fit in addition to the screening shortlist, e.g.
        the timing effects (:func:`aeropend_ident.gap.effects.timing_effects`) when the
        where-analysis finds the simulated response leading or lagging the recorded one. Effects the
        channels cannot reveal, or that are not candidates for the rig's family, are skipped.
    skip : sequence of str
        Catalog effects left out of the diagnosis (hypotheses the lab rules out, or a benchmark
        measuring what one candidate changes).

    Returns
    -------
    EffectDiagnosis

    Raises
    ------
    GapError
        Recordings lacking θ or the duty cycle, with NaNs, too short, non-uniform or unexcited;
        an unusable nominal rig; ``max_effects`` outside 1..3; an unknown effect in
        ``also_confirm`` or ``skip``.
    """
    t0 = time.perf_counter()
    for name in (*also_confirm, *skip):
        get_effect(name)
    say = progress or (lambda _m: None)
    if max_effects not in (1, 2, 3):
        raise GapError(f"max_effects = {max_effects!r}; expected 1, 2 or 3")
    if not isinstance(rig, Rig):
        raise GapError(f"rig is a {type(rig).__name__}; expected aeropend_sim.params.Rig (load_rig)")
    st = _setup(rig, fit, validation, say, skip)
    q_hat = _unmodelled_quantum(rig, st)
    scr, cands, screened, forced = _screen_and_confirm(rig, st, also_confirm, seed, say)
    ranking = _ranking(st, cands, scr, seed + 1)
    _mark_unresolved(ranking, cands, max(p.dt for p in st.pf))
    best = next((r for r in ranking if not r.get("unresolved")), None)
    # a gap above the noise floor: some channel's nominal validation error exceeds its noise part
    above_floor = _above_noise(st.sse0_c, st.noise_c, st.chance_c)
    sig_first = bool(best and above_floor and best["above_noise_explained"] >= MIN_EXPLAINED
                     and best["bic_delta"] <= -MIN_BIC_GAIN and _holds_in_sample(st, best["p_value"]))
    chosen: list[str] = []
    plant_side: dict[str, Any] | None = None
    corrected, meas = rig, MeasurementMap()
    table = [{"effects": [], **st.base_metrics}]
    reason, explained = "", {}
    shares: dict[str, float] = {}  # chosen effect -> bootstrap share of its presence
    pvals: dict[str, float] = {}  # chosen effect -> its split-test p-value
    if sig_first:
        name = best["effect"]
        chosen.append(name)
        cur, cur_segs = cands.fits[name], cands.segs[name]
        corrected, meas = cur.rig, cur.meas
        table.append({"effects": list(chosen), **gap_metrics(corrected, meas, st.pv)})
        say(f"{name} leaves a validation SSE of {st.noise_ratio(float(cur_segs.sum()))}")
        shares[name], pvals[name] = best["bootstrap_first"], best["p_value"]
        # forward selection: while the chosen set leaves some channel's residual above its noise
        # (completeness < 1), screen its residual and confirm the best candidates by a joint fit with
        # the effects already chosen
        while (len(chosen) < max_effects
               and _completeness(st, channel_sse(corrected, meas, st.pv))["completeness"] < 1.0):
            added = _add_effect(st, cur, cur_segs, chosen, ranking, screened, forced, seed + 2 * len(chosen))
            if added is None:
                break
            o = added.effect
            chosen.append(o)
            cur, cur_segs = added.fit, added.segs
            corrected, meas = cur.rig, cur.meas
            shares[o], pvals[o] = added.share, added.p_value
            _record_added(ranking, st, added, chosen)
            table.append({"effects": list(chosen), **gap_metrics(corrected, meas, st.pv)})
        amb, alt_fits = _unseparated_single(st, best, cands, ranking) if len(chosen) == 1 else ({}, {})
        if len(chosen) >= 2:
            before = list(chosen)
            cur, cur_segs, chosen, amb, alt_fits = _swap_confusables(st, cur, cur_segs, chosen)
            for r in ranking:
                alts = amb.get(r["effect"], {})
                if alts:
                    r["ambiguous_with"] = list(dict.fromkeys([*r.get("ambiguous_with", []), *alts]))
                    r.setdefault("ambiguity", {}).update(
                        {a: {"validation_explained": v, "bootstrap_first": None, "joint_fit": True}
                         for a, v in alts.items()})
            if chosen != before:
                corrected, meas = _take_over(st, cur, before, chosen, (shares, pvals), ranking, scr, table,
                                             "replacement")
        if st.refinements:
            before = list(chosen)
            cur, cur_segs, chosen, tried = _refine(st, cur, cur_segs, chosen)
            if chosen != before:
                corrected, meas = _take_over(st, cur, before, chosen, (shares, pvals), ranking, scr, table,
                                             "refinement")
            for r in ranking:  # the figures of each tried refinement, on the refined and the refining entry
                refs = {k: v for k, v in tried.items() if r["effect"] in (k, v["replaces"])}
                if refs:
                    r["refinements"] = refs
        plant_side = _plant_side_entry(chosen, amb, alt_fits)
        explained = _completeness(st, channel_sse(corrected, meas, st.pv))
        reason = (f"{name} removes {100 * best['above_noise_explained']:.1f} % of the validation gap above "
                  f"noise (BIC change {best['bic_delta']:.1f}); {explained['verdict']}")
    else:
        reason = _no_effect_reason(st, best, above_floor)
    detected: dict[str, dict[str, float]] = {}
    if q_hat > 0.0:
        # a property of the recordings, not an effect to fit: it describes the corrected rig's
        # sensor (and, through _noise_var, the noise floor), and never enters ``chosen``, whose
        # effects later steps refit (attainable shrink, drift tables)
        detected["quantisation"] = {"theta_quantum": q_hat}
        corrected, reason = _add_quantum(st, q_hat, ranking, corrected, sig_first, reason)
        sig_first = True
    _evidence(ranking, chosen, shares, pvals, explained, in_sample=st.pv is st.pf)
    if st.note:
        reason += f"; {st.note}"
    reason += _unresolved_reason(ranking, chosen)
    if st.not_ident and sig_first:
        reason += ("; not identifiable from the recorded channels (their θ signature may be what the "
                   f"ranked effect stands in for): {', '.join(x['effect'] for x in st.not_ident)}")
    return EffectDiagnosis(
        significant=sig_first, ranking=ranking, not_identifiable=st.not_ident, chosen=chosen,
        corrected_rig=corrected, validation=table, measurement=meas, screening=scr.as_dict(),
        reason=reason if sig_first or reason else "no significant gap", channels=sorted(st.channels),
        explained=explained, elapsed=time.perf_counter() - t0, plant_side=plant_side, detected=detected,
        free_settings=sorted(st.ctx.free_settings),
    )


def _unseparated_single(st: _Setup, best: dict[str, Any], cands: _Candidates,
                        ranking: Sequence[Mapping[str, Any]]
                        ) -> tuple[dict[str, dict[str, float]], dict[tuple[str, str], EffectFit]]:
    """Alternatives the single-effect fits do not separate from the first-ranked effect, and their
    fits, in the form :func:`_swap_confusables` returns them; ``best``'s ``ambiguous_with`` and
    ``ambiguity`` are completed in place.

    Two kinds: a runner-up first in a share of the bootstrap resamples (:data:`AMBIGUOUS_FIRST`,
    :func:`_ranking`), and a physics-confusable alternative (``confusable_with``, fitted alone,
    resolved at this rate: not marked ``unresolved`` in ``ranking``, :func:`_mark_unresolved`)
    that the figures do not separate by the rule of the replacement pass (:func:`_not_separated`).
    The second catches a rival that loses every resample by a margin too small to matter (an
    armature-resistance error and a back-EMF error each explain 97.4 % of a motor's gap, one
    consistently 0.04 % more). A nested alternative (the thrust law for K_q) is left to the
    parsimony rule of :func:`_ranking`: at its nesting value it is the same model.
    """
    name = best["effect"]
    amb = {name: {a: v["validation_explained"] for a, v in (best.get("ambiguity") or {}).items()}}
    e = get_effect(name)
    s_best = float(cands.segs[name].sum())
    unresolved = {r["effect"] for r in ranking if r.get("unresolved")}
    for alt in _in_catalog(e.confusable_with, st):
        if (alt in amb[name] or alt not in cands.segs or alt in e.nests or name in get_effect(alt).nests
                or alt in unresolved):
            continue
        if _not_separated(st, s_best, float(cands.segs[alt].sum())):
            amb[name][alt] = cands.stats[alt]["validation_explained"]
            best["ambiguous_with"] = [*best.get("ambiguous_with", []), alt]
            best.setdefault("ambiguity", {})[alt] = {"validation_explained": amb[name][alt],
                                                     "bootstrap_first": None, "within_swap_gain": True}
    return amb, {(name, a): cands.fits[a] for a in amb[name] if a in cands.fits}


def _plant_side_entry(chosen: Sequence[str], amb: Mapping[str, Mapping[str, float]],
                      alt_fits: Mapping[tuple[str, str], EffectFit]) -> dict[str, Any] | None:
    """:attr:`EffectDiagnosis.plant_side` from the record of unseparated alternatives, if its fit
    belongs to the final chosen set (a later replacement or refinement makes it stale)."""
    pair = plant_side_alternative(chosen, amb)
    fit = alt_fits.get(pair) if pair else None
    if pair is None or fit is None or set(fit.effects) != (set(chosen) - {pair[0]}) | {pair[1]}:
        return None
    return {"replaces": pair[0], "by": pair[1], "validation_explained": float(amb[pair[0]][pair[1]]),
            "parameters": dict(fit.values[pair[1]]), "rig": fit.rig, "measurement": fit.meas}


def _take_over(st: _Setup, cur: EffectFit, before: Sequence[str], chosen: Sequence[str],
               evidence: tuple[dict[str, float], dict[str, float]], ranking: list[dict[str, Any]],
               scr: Screening, table: list[dict[str, Any]], step: str) -> tuple[Rig, MeasurementMap]:
    """A chosen set changed by a replacement or refinement pass (``step``): each new effect takes
    over its predecessor's evidence (bootstrap share and split-test p-value; the replacement beat
    it on the validation part), the ranking gets the joint values, the validation table a row
    ``{step: True}``; returns the corrected rig and measurement map."""
    for old_name, new_name in zip(before, chosen, strict=True):
        if old_name != new_name:
            for d in evidence:
                d[new_name] = d.pop(old_name)
    _record_chosen(ranking, st, cur, chosen, scr)
    table.append({"effects": list(chosen), step: True, **gap_metrics(cur.rig, cur.meas, st.pv)})
    return cur.rig, cur.meas


def _record_chosen(ranking: list[dict[str, Any]], st: _Setup, fit: EffectFit, chosen: Sequence[str],
                   scr: Screening) -> None:
    """Update the ranking for a (new) chosen set fitted jointly in ``fit``: an entry for a chosen
    effect that was not ranked yet (screening figures from ``scr``), the joint values of the chosen
    effects, and the chosen set first, in its order."""
    for name in chosen:
        if name not in [r["effect"] for r in ranking]:
            e = get_effect(name)
            ranking.append({
                "effect": name, "subsystem": e.subsystem, "score": None, "validation_explained": None,
                "bic_delta": None, "p_value": None, "parameters": {}, "rig_values": {},
                "screening": ({"explained_strong": scr.explained_strong[name],
                               "explained_weak": scr.explained_weak[name], "inclusion": scr.inclusion[name]}
                              if name in scr.explained_strong else {"not_screened": True}),
                "confusable_with": _in_catalog(e.confusable_with, st), "ambiguous_with": [],
            })
    for r in ranking:
        if r["effect"] in chosen:
            r["parameters"] = _param_table(fit, r["effect"])
            r["rig_values"] = get_effect(r["effect"]).rig_values(st.rig, fit.values[r["effect"]])
    ranking.sort(key=lambda r: list(chosen).index(r["effect"]) if r["effect"] in chosen else len(chosen))


def _record_added(ranking: list[dict[str, Any]], st: _Setup, added: _Added, chosen: Sequence[str]) -> None:
    """Update the ranking after a forward-selection step (:func:`_record_chosen`) and note the added
    effect's gain."""
    _record_chosen(ranking, st, added.fit, chosen, added.screening)
    for r in ranking:
        if r["effect"] == added.effect:
            r["added_explained"] = added.gain
            r["added_bic_delta"] = added.bic_delta
