"""The one free-run replay of a rig on a recording: its start, its divergence and its NRMSE.

Every command that replays a rig file on a recording and prints a θ figure for it — ``compare``,
``rig check``, ``rig fit`` (its fitted rig on its inputs), ``baseline`` (the held-out figures),
``gap`` and ``gap-batch`` (the held-out nominal and corrected figures) — calls :func:`free_run`, so
one rig on one recording gives one figure everywhere (issue 60). The replay is a *free run*: the
rig is driven by the recorded duty cycle only, with no later correction from the measurements.

**Initial state** (:func:`initial_state`), a property of the recording, the same for every rig:

* θ₀ and θ̇₀ are the value and slope at t = 0 of a quadratic least-squares fit of the recorded θ
  over its first :data:`START_WINDOW` seconds (at least :data:`START_MIN_SAMPLES` samples). One
  sample would put its noise into the start, and the start decides whether a run of a rod that is
  marginal (near 90°) diverges; a straight line would bias θ̇₀ by θ̈·T/2 when the record begins in
  a transient (a step), which the quadratic term absorbs. 0.1 s is short against the pendulum's
  period (≥ 0.5 s on every rig seen), so the quadratic describes the stretch. Their standard
  deviations follow from the θ channel's noise floor
  (:func:`aeropend_ident.greybox.fit.measurement_noise`) through the fit's pseudo-inverse.
* The actuator states (armature current, rotor speed, actuator lag) are at the steady state of the
  first command (:func:`aeropend_ident.greybox.fit.motor_equilibrium`), and the actuator's delay
  line holds that command: their time constants (≤ 0.1 s: L_a/R_a, the rotor, an ESC's lag) are
  short against the rod's, so in a stretch cut from a running session the motor has followed the
  command it shows; the rod's states are the slow ones and are taken from the data. The
  recording's own i_a / ω₁ channels are not used for the start (most rigs log θ only, and the
  figure must not depend on which channels a log has).

**A rod held, then released** (:func:`release_index`): in a recording whose command never changes,
a rod that rests at its first angle and then moves was held there (by hand, a stop) and let go, or
waited for a motor that was still spinning up to the command the log shows from its first sample
(dondi01's 8 V step: 0.69 s) — a rod at rest under a constant thrust stays at rest. The replay
starts at the release: the start above is estimated there, the run is scored from there, and before
it the predicted θ is the held angle.
At rest means within a band about the first angle — the larger of :data:`HOLD_BAND_SIGMAS` standard
deviations of the start fit's residual, two angle quanta and :data:`HOLD_BAND_SHARE` of the
recorded range — for at least :data:`HOLD_MIN_S`; the release is the last sample before the rod
leaves that band that is within a quarter of it. A rod that starts at a swing's peak leaves the
band within 0.28/ω s (ω its swing frequency), well inside :data:`HOLD_MIN_S` for every rod seen.

**Divergence** (the rule of :func:`aeropend_ident.io.overlay_axes.diverges`): the predicted θ turns
non-finite, or leaves the recorded range by more than
:data:`~aeropend_ident.io.overlay_axes.DIVERGENCE_SPANS` recorded spans and at least
:data:`~aeropend_ident.io.overlay_axes.MIN_DIVERGENCE_RAD` (a quarter turn). The divergence time
is the first sample outside that window (or the first non-finite one). A diverged run has no NRMSE
(None): a figure computed on it would only measure how far the run went.

**NRMSE** (:func:`nrmse`): RMS(θ̂ − θ) over every sample of the replayed stretch, divided by the
recorded θ's range max θ − min θ of that stretch [1]; a stretch that barely moves (a held-out
hold, ``baseline``) may be scored against a given span instead (``span``; then the divergence
window uses that span too).

No rclpy; the replay itself is :func:`aeropend_sim.simulation.simulate` (its default backend) on the
rig without measurement noise or quantisation (the recording supplies those).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from aeropend_ident.errors import IdentificationError
from aeropend_ident.greybox.batch import RigReplays, structure
from aeropend_ident.greybox.fit import error_metrics, measurement_noise, motor_equilibrium
from aeropend_ident.io.overlay_axes import divergence_window, diverges, excursions, short_number
from aeropend_ident.io.resampling import detect_quantum
from aeropend_sim.model import ModelError, plant_model
from aeropend_sim.params import Rig
from aeropend_sim.simulation import SimulationError, simulate

#: Length [s] of the recording's first stretch that θ₀ and θ̇₀ are estimated on (quadratic fit).
START_WINDOW = 0.1
#: Fewest samples of that fit (a 50 Hz log gets 5 samples, 0.1 s).
START_MIN_SAMPLES = 5
#: Half-width of the band a held rod rests in, in standard deviations of the start fit's residual
#: (:func:`release_index`).
HOLD_BAND_SIGMAS = 5.0
#: ... and at least this share of the recorded range (a logger's gaps, filled on the grid, shrink the
#: residual below the noise).
HOLD_BAND_SHARE = 0.02
#: Shortest rest [s] that counts as a hold.
HOLD_MIN_S = 0.5
#: The initial-state rule in words, as every report states it.
START_RULE = (f"θ₀, θ̇₀ from a quadratic fit over the first {START_WINDOW:g} s of the recorded θ "
              "(from the release, when a constant-command recording begins with the rod held); "
              "motor at the steady state of the first command")
#: The NRMSE definition in words, as every report states it.
NRMSE_RULE = "RMS(θ_sim − θ_rec) over every sample / (max θ_rec − min θ_rec)"


@dataclass(frozen=True)
class InitialState:
    """The start of a free run (module docstring).

    Attributes
    ----------
    x : ndarray, shape (n,)
        Model state [θ rad, θ̇ rad/s, i_a A, ω₁ rad/s, τ_f 1] in the model frame.
    theta0, theta_dot0 : float
        θ₀ [rad] and θ̇₀ [rad/s] in the recording's frame.
    theta0_sd, theta_dot0_sd : float
        Their standard deviations under the θ channel's noise [rad], [rad/s].
    duty0 : float
        The first command τ₀ [1] the motor is steady at.
    samples : int
        Samples the estimate used.
    """

    x: np.ndarray
    theta0: float
    theta_dot0: float
    theta0_sd: float
    theta_dot0_sd: float
    duty0: float
    samples: int
    released_at: float = 0.0

    def describe(self) -> str:
        """E.g. ``"θ₀ = 0.412 ± 0.0021 rad, θ̇₀ = 0.013 ± 0.051 rad/s, motor steady at τ = 0.43"``."""
        return start_text(self.as_dict())

    def as_dict(self) -> dict[str, float | int | str]:
        """JSON-able: the values, their standard deviations, the release time [s] (0: not held) and
        the rule."""
        return {"rule": START_RULE, "theta0": self.theta0, "theta0_sd": self.theta0_sd,
                "theta_dot0": self.theta_dot0, "theta_dot0_sd": self.theta_dot0_sd, "duty0": self.duty0,
                "samples": self.samples, "released_at": self.released_at}


def start_text(start: Mapping[str, object]) -> str:
    """How every report writes a free run's start, from :meth:`InitialState.as_dict` (also as read
    back from a JSON report): ``"θ₀ = 0.412 ± 0.0021 rad, θ̇₀ = 0.013 ± 0.051 rad/s, motor steady at
    τ = 0.43"``."""
    v = {k: float(start[k]) for k in ("theta0", "theta0_sd", "theta_dot0", "theta_dot0_sd", "duty0")}  # type: ignore[arg-type]
    released = float(start.get("released_at", 0.0) or 0.0)  # type: ignore[arg-type]
    held = (f"rod at rest until t = {short_number(released)} s (held, or waiting for the motor), then "
            if released > 0.0 else "")
    return (f"{held}θ₀ = {short_number(v['theta0'])} ± {short_number(v['theta0_sd'], 2)} rad, "
            f"θ̇₀ = {short_number(v['theta_dot0'])} ± {short_number(v['theta_dot0_sd'], 2)} rad/s, "
            f"motor steady at τ = {short_number(v['duty0'])}")


@dataclass(frozen=True)
class FreeRun:
    """A rig's free run on a recording, scored (module docstring).

    Attributes
    ----------
    theta : ndarray, shape (N,)
        Predicted θ [rad] in the recording's frame (NaN from a non-finite step on).
    channels : mapping str -> ndarray, shape (N,)
        Every noise-free channel the replay gives (``theta`` in the recording's frame; ``i_a`` [A],
        ``v_a`` [V], ``omega_rotor`` [rad/s] as the rig has them), empty when the replay blew up.
    nrmse : float or None
        θ NRMSE [1] (:func:`nrmse`); None when the run diverged.
    rms_error : float
        RMS(θ̂ − θ) [rad] (inf when diverged to non-finite values).
    range : float
        The span the NRMSE is normalised by [rad].
    diverged_at : float or None
        Time [s, from the stretch's start] of the first sample outside the divergence window.
    divergence : str or None
        The reason (:func:`aeropend_ident.io.overlay_axes.diverges`), None when it did not diverge.
    initial : InitialState
    """

    theta: np.ndarray
    nrmse: float | None
    rms_error: float
    range: float
    diverged_at: float | None
    divergence: str | None
    initial: InitialState
    channels: Mapping[str, np.ndarray] = field(default_factory=dict)

    @property
    def diverged(self) -> bool:
        """Whether the run diverged (it then has no NRMSE)."""
        return self.divergence is not None

    def figure(self, digits: int = 4) -> str:
        """The figure every command prints: ``"NRMSE 0.4047"`` or ``"DIVERGES: diverges at t = …"``."""
        return f"DIVERGES: {self.divergence}" if self.divergence is not None else \
            f"NRMSE {self.nrmse:.{digits}f}"

    def line(self, where: str) -> str:
        """The one report line of a free run, e.g. ``"free-run θ on run2.csv: NRMSE 0.4047 (start:
        θ₀ = 0.41 ± 0.002 rad, …)"`` or ``"free-run θ on run2.csv: DIVERGES: diverges at t = 3.1 s: …
        (start: …)"``."""
        return f"free-run θ on {where}: {self.figure()} (start: {self.initial.describe()})"

    def as_dict(self) -> dict[str, object]:
        """JSON-able summary (without the traces)."""
        return {"nrmse": self.nrmse, "nrmse_rule": NRMSE_RULE, "rms_error": self.rms_error,
                "range": self.range, "diverged_at": self.diverged_at, "divergence": self.divergence,
                "initial_state": self.initial.as_dict()}


def _start_design(dt: float, n: int) -> np.ndarray:
    """Design matrix (k, 3) (or (k, 2) for 3-4 samples) of the start fit, highest power first."""
    k = int(min(max(round(START_WINDOW / dt), START_MIN_SAMPLES), n))
    return np.vander(np.arange(k) * dt, 3 if k >= 5 else 2)


def initial_state(rig: Rig, theta: np.ndarray, duty: np.ndarray, dt: float, theta_offset: float = 0.0,
                  theta_scale: float = 1.0) -> InitialState:
    """The start of a free run of ``rig`` on a recorded stretch (module docstring).

    Parameters
    ----------
    rig : Rig
        The replayed rig (its motor steady state).
    theta : ndarray, shape (N,)
        Recorded θ [rad], recording frame, N ≥ 1.
    duty : ndarray, shape (N,)
        Duty cycle τ ∈ [0, 1].
    dt : float
        Sample period [s] > 0.
    theta_offset, theta_scale : float
        The rig's recording frame: θ_rec = theta_scale·(θ_model − theta_offset).

    Returns
    -------
    InitialState

    Raises
    ------
    IdentificationError
        Empty or non-finite start, a non-positive ``dt`` or ``theta_scale``, or a rig whose motor
        steady state cannot be computed.
    """
    th = np.asarray(theta, dtype=float)
    if th.size == 0 or not (dt > 0.0) or not (theta_scale > 0.0):
        raise IdentificationError(f"free-run start: need θ samples, dt > 0 and theta_scale > 0 (got "
                                  f"{th.size} samples, dt = {dt!r} s, theta_scale = {theta_scale!r})")
    if th.size < 3:
        th0, thd0, sd = float(th[0]), 0.0, (0.0, 0.0)
        k = th.size
    else:
        design = _start_design(dt, th.size)
        k = design.shape[0]
        coef, *_ = np.linalg.lstsq(design, th[:k], rcond=None)
        th0, thd0 = float(coef[-1]), float(coef[-2])
        pinv = np.linalg.pinv(design)
        sigma = measurement_noise(th)
        sd = (sigma * float(np.linalg.norm(pinv[-1])), sigma * float(np.linalg.norm(pinv[-2])))
    if not (math.isfinite(th0) and math.isfinite(thd0)):
        raise IdentificationError(f"free-run start: the first {k} θ samples are not finite ({th[:k]!r})")
    tau0 = float(np.clip(duty[0], 0.0, 1.0))
    try:
        i_a, w, tf = motor_equilibrium(rig, tau0)
    except (ModelError, ValueError) as exc:
        raise IdentificationError(f"free-run start: the motor's steady state at τ = {tau0:g} of rig "
                                  f"{rig.name!r}: {exc}") from exc
    x = np.array([th0 / theta_scale + theta_offset, thd0 / theta_scale, i_a, w, tf])
    return InitialState(x=x, theta0=th0, theta_dot0=thd0, theta0_sd=sd[0], theta_dot0_sd=sd[1],
                        duty0=tau0, samples=int(k))


def release_index(theta: np.ndarray, duty: np.ndarray, dt: float) -> int:
    """Sample at which a rod held at its first angle was released (module docstring), 0 when the
    recording does not begin with the rod held.

    Parameters
    ----------
    theta : ndarray, shape (N,)
        Recorded θ [rad].
    duty : ndarray, shape (N,)
        Duty cycle τ [1]; a recording whose command changes is never cut (its rest may be the
        model's to explain).
    dt : float
        Sample period [s] > 0.

    Returns
    -------
    int
        0 ≤ index < N.
    """
    th = np.asarray(theta, dtype=float)
    u = np.asarray(duty, dtype=float)
    if th.size < 5 or not (dt > 0.0) or float(np.ptp(u)) > 0.0 or not np.all(np.isfinite(th)):
        return 0
    design = _start_design(dt, th.size)
    k = design.shape[0]
    coef, *_ = np.linalg.lstsq(design, th[:k], rcond=None)
    resid = th[:k] - design @ coef
    q = detect_quantum(th)
    band = max(HOLD_BAND_SIGMAS * float(np.std(resid)), 2.0 * q, HOLD_BAND_SHARE * float(np.ptp(th)), 1e-9)
    centre = float(np.median(th[:k]))
    out = np.flatnonzero(np.abs(th - centre) > band)
    if out.size == 0 or out[0] * dt < HOLD_MIN_S:  # never moves, or moves from the start
        return 0
    m = int(out[0])
    near = np.flatnonzero(np.abs(th[:m] - centre) <= band / 4.0)
    return int(near[-1]) if near.size else 0


def nrmse(measured: np.ndarray, simulated: np.ndarray, span: float | None = None,
          ) -> tuple[float, float, float]:
    """The one θ NRMSE (module docstring): (nrmse [1], rms error [rad], span [rad]).

    Parameters
    ----------
    measured, simulated : ndarray, shape (N,)
        Recorded and predicted θ [rad].
    span : float, optional
        Normalise by this span instead of the recorded range (a hold scored in a longer recording).

    Returns
    -------
    (float, float, float)
        NRMSE (inf for a flat record: no span), RMS error, the span used.
    """
    m = error_metrics(measured, simulated, span)  # the one formula
    return m["nrmse"], m["rms_error"], m["range"]


def _noise_free(rig: Rig) -> Rig:
    """``rig`` without sensor noise and quantisation (a replay's: the recording supplies those)."""
    if rig.effects.sensor_noise or rig.effects.quantisation:
        return rig.with_effects(sensor_noise=False, quantisation=False)
    return rig


_EFFECT_STATES: dict[tuple, tuple[str, ...]] = {}


def effect_states(rig: Rig) -> tuple[str, ...]:
    """Names of ``rig``'s own effect states (a winding temperature ``T_m``; none on most rigs), asked
    of its plant model once per structure (:func:`aeropend_ident.greybox.batch.structure`): a fit's
    every new rig would otherwise build a model."""
    key = structure(rig)
    names = _EFFECT_STATES.get(key)
    if names is None:
        names = _EFFECT_STATES[key] = plant_model(rig).states.extra_names
    return names


def carried_states(rigs: Sequence[Rig], history: RigReplays) -> list[dict[str, float] | None]:
    """Each rig's own effect states at the end of the run before a recording that continues it.

    No channel holds such a state (a winding temperature), so a recording that is a later part of a
    run (:attr:`aeropend_sim.recording.Recording.duty_before`: a validation stretch or a held-out
    part cut from a session) cannot start it from its own samples: it starts where the rig's replay
    of the commands before ends. That replay starts with the rod at 0 and still, the motor steady at
    the run's first command and the effect states at their initial values (the run's start).

    Parameters
    ----------
    rigs : sequence of Rig
        Noise-free replay rigs.
    history : RigReplays
        Replays of the commands before the recording, then its first command (so the last output
        sample is the state at the recording's first).

    Returns
    -------
    list of (dict or None)
        Per rig, ``{state name: value}`` (SI units: K for ``T_m``); None for a rig without effect
        states, or whose history replay fails (its states then start at their initial values).
    """
    out: list[dict[str, float] | None] = [None] * len(rigs)
    groups: dict[tuple[str, ...], list[int]] = {}
    for b, rig in enumerate(rigs):
        names = effect_states(rig)
        if names:
            groups.setdefault(names, []).append(b)
    for names, idx in groups.items():
        x0 = np.full((len(idx), 5), np.nan)
        for i, b in enumerate(idx):
            try:
                x0[i, 2:] = motor_equilibrium(rigs[b], float(history.duty[0]))
                x0[i, :2] = 0.0
            except (ModelError, IdentificationError, ValueError):
                pass
        sim, ok = history.run([rigs[b] for b in idx], x0, names)
        for i, b in enumerate(idx):
            out[b] = {n: float(sim[n][i, -1]) for n in names} if ok[i] else None
    return out


def history_replays(duty_before: np.ndarray, first: float, dt: float) -> RigReplays:
    """The :class:`RigReplays` :func:`carried_states` takes: the commands before a recording
    (clipped to [0, 1]), then its first command ``first``, at its sample period ``dt`` [s]."""
    duty = np.clip(np.concatenate([np.asarray(duty_before, dtype=float), [first]]), 0.0, 1.0)
    return RigReplays(duty, dt, tau_before=float(duty[0]))


def _simulate(rig: Rig, duty: np.ndarray, x0: np.ndarray, dt: float,
              ) -> tuple[dict[str, np.ndarray], int | None]:
    """Noise-free channels of the replay and the first non-finite sample (None if none)."""
    try:
        traj = simulate(_noise_free(rig), duty, x0=x0, dt=dt, tau_before=float(duty[0]))
    except SimulationError as exc:
        failed = getattr(exc, "sample", None)
        if failed is None:
            raise
        return {}, int(failed)
    return dict(traj.true), None


def free_run(rig: Rig, t: np.ndarray, duty: np.ndarray, theta: np.ndarray, *, theta_offset: float = 0.0,
             theta_scale: float = 1.0, span: float | None = None, source: str = "", lead: int = 0,
             duty_before: np.ndarray | None = None) -> FreeRun:
    """Replay ``rig`` on a recorded stretch in free run and score its θ (module docstring).

    Parameters
    ----------
    rig : Rig
    t : ndarray, shape (N,)
        Uniform sample times [s] (N ≥ 2); dt = (t[-1] − t[0])/(N − 1).
    duty : ndarray, shape (N,)
        Recorded duty cycle τ ∈ [0, 1] (clipped), held over each sample period.
    theta : ndarray, shape (N,)
        Recorded θ [rad] in the recording's frame.
    theta_offset, theta_scale : float
        The rig's recording frame: θ_rec = theta_scale·(θ_model − theta_offset).
    span : float, optional
        Span [rad] that normalises the NRMSE and widens the divergence window, for a stretch that
        barely moves (default: the recorded range).
    source : str
        Name of the recording, for error messages.
    lead : int
        Samples at the head of the arrays that the run starts at but that are not scored (≥ 0): a
        held-out part that continues its fit part starts ``lead`` samples early, so that a dead
        time sees the commands before the split. The result (trace, NRMSE, divergence time from
        the scored part's first sample) covers the samples from ``lead`` on; the start is estimated
        at sample 0.
    duty_before : ndarray, shape (M,), optional
        Commands of the same run before ``t[0]`` (:attr:`aeropend_sim.recording.Recording.duty_before`):
        the rig's own effect states (a winding temperature) then start where its replay of them
        ends (:func:`carried_states`), not at their initial values.

    Returns
    -------
    FreeRun

    Raises
    ------
    IdentificationError
        Mismatched shapes, fewer than 2 samples, a bad start, or a simulation that fails for another
        reason than a non-finite state (naming the recording and the rig).
    """
    tt = np.asarray(t, dtype=float)
    u = np.clip(np.asarray(duty, dtype=float), 0.0, 1.0)
    y = np.asarray(theta, dtype=float)
    name = source or "the recording"
    if not (tt.shape == u.shape == y.shape and tt.ndim == 1 and tt.size >= 2):
        raise IdentificationError(f"free run on {name}: t, duty and θ need one shape (N,) with N ≥ 2 "
                                  f"(got {tt.shape}, {u.shape}, {y.shape})")
    dt = float(tt[-1] - tt[0]) / (tt.size - 1)
    if not 0 <= lead < tt.size:
        raise IdentificationError(f"free run on {name}: lead = {lead} samples must be in [0, {tt.size})")
    held = release_index(y, u, dt) if lead == 0 else 0
    start = initial_state(rig, y[held:], u[held:], dt, theta_offset, theta_scale)
    if held:
        start = replace(start, released_at=held * dt)
    x0 = start.x
    if duty_before is not None and len(duty_before) and effect_states(rig):
        before = np.concatenate([np.asarray(duty_before, dtype=float), u[:held]])
        (carried,) = carried_states([_noise_free(rig)], history_replays(before, float(u[held]), dt))
        x0 = plant_model(rig).states.with_values(x0, carried)
    try:
        sim, failed = _simulate(rig, u[held:], x0, dt)
    except (SimulationError, ModelError) as exc:
        raise IdentificationError(f"free run of rig {rig.name!r} on {name} failed: {exc}") from exc
    if held:  # before the release the rod is where it was held
        sim = {c: np.concatenate([np.full(held, start.x[0] if c == "theta" else v[0]), v])
               for c, v in sim.items()}
        failed = None if failed is None else failed + held
    tt, y = tt[lead:], y[lead:]
    rel = tt - tt[0]
    if failed is not None and failed < lead:
        failed = lead
    if failed is None:
        sim = {c: v[lead:] for c, v in sim.items()}
        th = theta_scale * (sim["theta"] - theta_offset)
        channels = {**{c: v for c, v in sim.items() if c in ("i_a", "v_a", "omega_rotor")}, "theta": th}
        why = diverges(th[held:], y[held:], rel[held:], span=span)
        found = excursions(rel[held:], {"": th[held:]}, *divergence_window(y[held:], span)) \
            if why is not None else []
        at = found[0].t if found else None
    else:  # the compiled step turned a state non-finite at sample `failed`: the trace ends there
        th, channels = np.full(y.size, np.nan), {}
        at = float(rel[min(failed - lead, rel.size - 1)])
        why = f"diverges at t = {short_number(at)} s (θ is not finite from there)"
    value, rms, rng = nrmse(y[held:], th[held:], span)
    return FreeRun(theta=th, nrmse=None if why is not None else value, rms_error=rms, range=rng,
                   diverged_at=at, divergence=why, initial=start, channels=channels)
