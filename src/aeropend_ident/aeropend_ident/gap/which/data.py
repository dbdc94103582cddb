"""Which, stage 1 — the data: recordings prepared for the fits (:class:`Prepared`), replays, residuals.

Part of the effect diagnosis of :mod:`aeropend_ident.gap.which` (see its pipeline); no rclpy.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from aeropend_ident.errors import GapError, IdentificationError
from aeropend_ident.gap.effects import (
    MeasurementMap,
    measurement_noise,
)
from aeropend_ident.greybox.batch import RigReplays, structure
from aeropend_ident.greybox.fit import motor_equilibrium
from aeropend_ident.greybox.replay import carried_states, effect_states, history_replays
from aeropend_sim.model import ModelError, plant_model
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording
from aeropend_sim.simulation import SimulationError, simulate

#: Channels compared in the output-error fits (when recorded).
FIT_CHANNELS = ("theta", "i_a", "v_a", "omega_rotor")


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
    _history: RigReplays | None = field(default=None, repr=False, compare=False)
    #: :func:`_carried_states` of each rig (its structure and values) replayed so far.
    _carried: dict[tuple, dict[str, float] | None] = field(default_factory=dict, repr=False, compare=False)

    @property
    def n(self) -> int:
        return int(self.duty.size)

    @property
    def start_decided(self) -> bool:
        """Whether how the log began is settled: one start when its first duty cycle is 0, else
        decided by its first replay (:func:`_initial_states`)."""
        return float(self.duty[0]) <= 0.0 or self._at_rest is not None

    @property
    def replays(self) -> RigReplays:
        """Batched replays of rig variants on this recording (:func:`replay_many`)."""
        if self._replays is None:
            self._replays = RigReplays(self.duty, self.dt, tau_before=float(self.duty[0]))
        return self._replays

    @functools.cached_property
    def theta_noise_sd(self) -> float:
        """Standard deviation [rad] of the recorded θ's measurement noise (:func:`_noise_var`: at
        least the lattice's rounding noise)."""
        return math.sqrt(_noise_var(self.y["theta"]))

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

    @property
    def history(self) -> RigReplays | None:
        """Batched replays of the run before this recording (:attr:`Recording.duty_before`, then the
        first duty cycle, so that the replay's last sample is the state at this recording's first:
        :func:`_carried_states`); None for a recording that starts its run."""
        before = self.rec.duty_before
        if before is None or not before.size:
            return None
        if self._history is None:
            self._history = history_replays(before, float(self.duty[0]), self.dt)
        return self._history


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
        model = plant_model(sim_rig)
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
    model state (N, n) as ``"_x"``.

    Raises
    ------
    GapError
        If the simulation fails for this rig.
    """
    try:
        (sim_rig,), x0, (carried,) = _initial_states([(rig, meas)], prep)
        x = plant_model(sim_rig).states.with_values(x0[0], carried)
        traj = simulate(sim_rig, prep.duty, x0=x, dt=prep.dt, tau_before=float(prep.duty[0]))
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
                    ) -> tuple[list[Rig], np.ndarray, list[dict[str, float] | None]]:
    """The replay rigs (noise-free), initial states (B, 5) of ``rows`` on ``prep`` and the values of
    their own effects' states (:func:`_carried_states`): the start of :func:`_initial_state`, its θ
    and θ̇ then estimated by :func:`_refine_initial_states`; a row whose start fails is NaN.

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

    carried = _carried_states(rigs, prep)
    if not two or not rows or prep._at_rest is False:
        return rigs, _refine_initial_states(rigs, metas, starts(False), prep, carried)[0], carried
    if prep._at_rest:
        return rigs, _refine_initial_states(rigs, metas, starts(True), prep, carried)[0], carried
    run, run_err = _refine_initial_states(rigs, metas, starts(False), prep, carried)
    rest, rest_err = _refine_initial_states(rigs, metas, starts(True), prep, carried)
    prep._at_rest = bool(rest_err[0] < run_err[0])
    return rigs, rest if prep._at_rest else run, carried


def _carried_states(rigs: Sequence[Rig], prep: Prepared) -> list[dict[str, float] | None]:
    """Per replay rig, the values of its own effects' states (a winding temperature) at ``prep``'s
    first sample: :func:`aeropend_ident.greybox.replay.carried_states` of the run before it
    (:attr:`Prepared.history`), each rig carrying its own; None for a rig without such states, a
    recording that starts its run or a failed replay (the states then start at their initial
    values). Computed once per rig (its structure and values) and recording.
    """
    history = prep.history
    out: list[dict[str, float] | None] = [None] * len(rigs)
    if history is None:
        return out
    todo: dict[tuple, list[int]] = {}
    for b, rig in enumerate(rigs):
        if not effect_states(rig):
            continue
        key = (structure(rig), tuple(sorted(rig.values().items())))
        if key in prep._carried:
            out[b] = prep._carried[key]
        else:
            todo.setdefault(key, []).append(b)
    keys = list(todo)
    for key, values in zip(keys, carried_states([rigs[todo[k][0]] for k in keys], history), strict=True):
        prep._carried[key] = values
        for b in todo[key]:
            out[b] = values
    return out


def _refine_initial_states(rigs: Sequence[Rig], metas: Sequence[MeasurementMap], x0: np.ndarray,
                           prep: Prepared, carried: Sequence[dict[str, float] | None] | None = None
                           ) -> tuple[np.ndarray, np.ndarray]:
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
    carried : sequence of (dict or None), optional
        The rows' own effect states at the start (:func:`_carried_states`).

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
    sim, ok = head.run([r for r in rigs for _ in range(3)], trial, ("theta",),
                       None if carried is None else [c for c in carried for _ in range(3)])
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
    rigs, x0, carried = _initial_states(rows, prep)
    sim, ok = prep.replays.run(rigs, x0, names, carried)
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

