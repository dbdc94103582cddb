"""Closed-loop designs: a set-point sequence for the lab's controller that tells the candidates apart.

A lab that can only run its rig under feedback (a set point it cannot hold open loop, safety) plays
a **reference sequence**: set points the controller node follows (its ``steps`` parameter). A
reference rather than a dither added to the controller's command, because the controller fights
a dither (most of it never reaches the angle, and what does is the controller's doing), while a
set-point change moves the whole loop, and the angle range becomes a property of the design (the
set points lie inside it) rather than a penalty the search pays.

The prediction of a candidate is the closed loop of the lab's own controller
(:class:`aeropend_control.controller_core.ControllerLoop`: the strategy, observer, allocation and
reference clamping the controller node runs, designed on the lab's rig file) on that candidate's
rig (:func:`aeropend_control.verify.closed_loop.drive`, the candidate's sensor map between the
plant and the loop). What a recording then shows is the logged command and the logged outputs; the
diagnosis replays every candidate on the **logged command** (open loop, as ``gap`` and
:func:`aeropend_ident.design.discriminate.evidence` replay any closed-loop log). So, with ``i`` the
truth, the divergence of a pair is that of their replays on the command the loop logged on ``i``:

    D_ij = Σ_c Σ_k (y_i,c[k] − y_j,c[k | u_i])² / σ_c²,    u_i = the loop's command on candidate i.

The search scores a sequence with the loop on one candidate, the **driver** (the best fit of the
earlier recordings, the one the lab's rig most likely is): its command ``u`` is replayed on every
candidate (the batch replay of :class:`~aeropend_ident.design.discriminate.Predictor`), and the
criterion is :func:`~aeropend_ident.design.discriminate.criterion`'s mean log divergence on those
replays. That is D_ij at u_i ≈ u: the candidates fit the same earlier recordings, and the loop
makes their commands alike (to first order the same divergence). The prediction
(:func:`rank_first_probability`) does not take that shortcut: every candidate in turn is the
truth, with the loop run on it.

Limits: the set points lie in the stated angle range, kept :func:`~aeropend_ident.design.sequence.
recorded_margin` inside it and at most the controller's reach; the loop's predicted recorded angle
(overshoot included) is held to the range, and its command to the command range and the slew limit,
by the same penalty as an open-loop design's angle (:func:`~aeropend_ident.design.sequence.
angle_penalty`): the loop's command is the controller's, and a sequence whose steps make it kick
beyond the lab's limits scores below every sequence that keeps them.

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from aeropend_ident.design.candidates import Candidate
from aeropend_ident.design.discriminate import (
    Discrimination,
    Predictor,
    mean_log_divergence,
    rank_draws,
    smallest_divergence,
)
from aeropend_ident.design.sequence import (
    ANGLE_PENALTY,
    BUDGET_S,
    AprbsShape,
    DesignError,
    Limits,
    angle_penalty,
    aprbs_vector,
    holds,
    recorded_margin,
    search,
)
from aeropend_ident.greybox.batch import one_blas_thread, one_replay_thread, single_blas
from aeropend_sim.params import Rig

#: Node name of the controller in a ROS parameters file (``config/controller.yaml``).
CONTROLLER_NODE = "aeropend_controller"
#: Samples a reference design's search simulates in closed loop by default (every scored sequence
#: costs one closed loop of its length on the driver): 60 sequences of 40 s at 100 Hz, 12 at 490 Hz.
#: The loop is the controller node's own per-sample Python loop on the plant stepper, 92 µs a
#: sample on lab case 80's candidates since ccd196a (176 µs before: docs/design.md), so a reference
#: design scores far fewer sequences than an open-loop one (whose replays are compiled) in the same
#: time. On bench_design_reference's cases at twice this, the search alone took 30-54 s (at 176 µs),
#: over the issue's 60 s per design with the candidate fits and the prediction. Counted, not timed:
#: a seed gives one design on any machine.
CLOSED_LOOP_WORK = 240_000
#: Fewest sequences a reference design scores by default.
MIN_EVALUATIONS = 12


def reference_evaluations(samples: int) -> int:
    """Sequences a reference design of ``samples`` samples scores by default:
    :data:`CLOSED_LOOP_WORK` / ``samples``, at least :data:`MIN_EVALUATIONS`."""
    return max(MIN_EVALUATIONS, CLOSED_LOOP_WORK // max(1, int(samples)))


def reference_popsize(shape: AprbsShape) -> int:
    """CMA-ES population of a reference design of ``shape`` (sequences scored per generation)."""
    return 8 + shape.size // 6


def reference_shape(duration: float) -> AprbsShape:
    """The default shape of a reference design of ``duration`` seconds: a set point every 1.5 s on
    average, held 0.5 to 3 s (the loop's own settling, about 1 s for a lab's goal, fits in a hold,
    and a shorter one catches it in its transient)."""
    return AprbsShape(duration=duration, segments=max(4, round(duration / 1.5)), min_hold=0.5, max_hold=3.0)


def read_controller_params(path: str | Path) -> dict[str, Any]:
    """The controller node's parameters in a ROS 2 parameters file (``/**/aeropend_controller:
    ros__parameters: ...``, as ``config/controller.yaml``), or in a plain mapping of them.

    Raises
    ------
    DesignError
        If the file cannot be read, is not YAML, or holds no mapping of parameters.
    """
    try:
        doc = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise DesignError(f"--controller {path}: {exc}") from exc
    if not isinstance(doc, dict):
        raise DesignError(f"--controller {path}: expected a mapping of the controller node's parameters")
    for key, val in doc.items():
        if isinstance(val, dict) and isinstance(val.get("ros__parameters"), dict) and (
                str(key).rstrip("/").endswith(CONTROLLER_NODE) or len(doc) == 1):
            return dict(val["ros__parameters"])
    if any(isinstance(v, dict) and "ros__parameters" in v for v in doc.values()):
        raise DesignError(f"--controller {path}: no {CONTROLLER_NODE} node among {list(doc)}")
    return dict(doc)


def lab_controller(rig_ref: str, params: Mapping[str, Any], dt: float) -> Any:
    """The lab's controller loop (lock-step) at sample period ``dt`` [s], as the controller node builds it.

    Parameters
    ----------
    rig_ref : str
        Rig name or file the controller is designed on when ``params`` names none (the nominal rig of
        the gap report).
    params : mapping
        The controller node's parameters (``rig``, ``strategy``, ``omega_n``, ``zeta``, ``rho``,
        ``allocator``, ``estimator``, ``tf``, ``theta_op``; read by the node's own
        :func:`aeropend_control.controller_core.make_settings`); ``mode``, ``steps``,
        ``reference`` and ``duration`` are the design's.

    Raises
    ------
    DesignError
        When the controller cannot be built (the node's own message: an unknown strategy, a rig it
        cannot design on).
    """
    from aeropend_control.controller_core import ControllerConfigError, ControllerLoop, make_settings

    raw = {k: v for k, v in params.items() if k not in ("mode", "steps", "reference", "duration", "trace",
                                                        "rt_priority")}
    raw.setdefault("rig", rig_ref)
    try:
        settings = make_settings(**raw, mode="lockstep")
        fixed = dataclasses.replace(settings.rig, sample_period=float(dt))
        return ControllerLoop(dataclasses.replace(settings, rig=fixed))
    except ControllerConfigError as exc:
        raise DesignError(f"the lab's controller on {raw['rig']}: {exc}") from exc


def set_point_range(limits: Limits, reach: float, sigma_theta: float) -> tuple[float, float]:
    """Set points [rad] a design may use: the angle range kept
    :func:`~aeropend_ident.design.sequence.recorded_margin` inside, at least 0 (the loop's own
    clamp) and at most the controller's ``reach``.

    Raises
    ------
    DesignError
        If that range is empty.
    """
    m = recorded_margin(limits, sigma_theta)
    lo, hi = max(limits.theta_min + m, 0.0), min(limits.theta_max - m, float(reach))
    if not hi > lo:
        raise DesignError(f"no set point lies in the angle range [{limits.theta_min:.3g}, "
                          f"{limits.theta_max:.3g}] rad with a margin of {m:.3g} rad within the controller's "
                          f"reach [0, {reach:.3g}] rad")
    return lo, hi


def reference_steps(z: np.ndarray, shape: AprbsShape, limits: Limits, span: tuple[float, float]
                    ) -> list[tuple[float, float]]:
    """The set-point breakpoints [(t [s], θ_ref [rad])] of design vector ``z`` ∈ [0, 1]^(2M).

    0 rad over the first :data:`~aeropend_ident.design.sequence.LEAD_IN_S` (the rig at rest), then
    ``M`` holds at ``lo + z[i]·(hi − lo)`` laid on the logging grid as an open-loop design's
    (:func:`~aeropend_ident.design.sequence.holds`).

    Raises
    ------
    DesignError
        If ``z`` has the wrong size.
    """
    share, ends, n_lead = holds(z, shape, limits.dt)
    lo, hi = span
    starts = np.concatenate([[n_lead], ends[:-1]])
    return [(0.0, 0.0)] + [(float(k * limits.dt), float(lo + u * (hi - lo))) for k, u in zip(starts, share,
                                                                                              strict=True)]


def on_grid(steps: Sequence[tuple[float, float]], n: int, dt: float) -> np.ndarray:
    """The set point (N,) [rad] at each sample k·dt of ``steps`` (the latest breakpoint at or before)."""
    t = np.arange(n) * dt
    times = np.array([s[0] for s in steps])
    idx = np.searchsorted(times, t + 1e-9 * dt, side="right") - 1
    return np.array([s[1] for s in steps])[np.maximum(idx, 0)]


def closed_loop(loop: Any, plant: Rig, steps: Sequence[tuple[float, float]], n: int, meas: Any = None) -> Any:
    """A copy of ``loop`` following ``steps`` for ``n`` samples on ``plant`` (noise-free: switch its
    noise off; its sample period is the loop's), the sensor map ``meas``
    (:class:`~aeropend_ident.gap.effects.MeasurementMap`) between plant and loop: a
    :class:`aeropend_control.verify.closed_loop.LoopRun`, its ``seen`` the recorded angle."""
    from aeropend_control.verify.closed_loop import drive

    loop = copy.deepcopy(loop)
    loop.reference.steps = list(steps)
    sensor = None if meas is None or meas.identity else (lambda th: float(meas.to_recorded(th)))
    return drive(loop, plant, n, seed=None, sensor=sensor)


def loop_command(run: Any) -> np.ndarray:
    """The command (N,) a loop's run logged, as applied: clipped to [0, 1] (0 after a divergence)."""
    return np.clip(np.nan_to_num(run.duty, nan=0.0), 0.0, 1.0)


class ClosedLoopPredictor:
    """The lab's controller in closed loop on the candidates, and every candidate replayed on its command.

    Parameters
    ----------
    candidates : sequence of Candidate
    loop : ControllerLoop
        :func:`lab_controller` (copied for each run).
    channels : sequence of str
        Logged channels compared.
    dt : float
        Logging and control period [s].
    n : int
        Samples per sequence.
    workers : int
        Processes :meth:`many` runs its loops in (1: this one). Each worker holds a copy of this
        predictor, made once (the loop pickled, the candidates' replays compiled there); the
        results are the same bit for bit (each loop is deterministic). Use the predictor as a context
        manager, or call :meth:`close`, to end them.
    """

    def __init__(self, candidates: Sequence[Candidate], loop: Any, channels: Sequence[str], dt: float,
                 n: int, workers: int = 1) -> None:
        self.candidates = list(candidates)
        self.loop, self.dt, self.n = loop, float(dt), int(n)
        self.open = Predictor(candidates, channels, dt, n)
        self.plants = [dataclasses.replace(r, sample_period=self.dt) for r in self.open.rigs]
        self.calls = 0
        self.workers = max(1, int(workers))
        self._made = (self.candidates, loop, tuple(channels), self.dt, self.n)
        self._pool: Any = None
        #: Predictions already made, by (set points, candidate): :meth:`keep`.
        self._kept: dict[tuple[tuple[tuple[float, float], ...], int], tuple[dict[str, np.ndarray], Any]] = {}

    def keep(self, steps: Sequence[tuple[float, float]], b: int,
             prediction: tuple[dict[str, np.ndarray], Any]) -> None:
        """Hold ``self(steps, b)`` (made already: a design's best sequence on its driver), which
        :meth:`many` then returns instead of running that loop again (each loop is deterministic: the
        same result bit for bit)."""
        self._kept[_job_key(steps, b)] = prediction

    def run(self, steps: Sequence[tuple[float, float]], b: int) -> Any:
        """The loop on candidate ``b`` (:func:`closed_loop`)."""
        return closed_loop(self.loop, self.plants[b], steps, self.n, self.candidates[b].meas)

    def __call__(self, steps: Sequence[tuple[float, float]], b: int = 0) -> tuple[dict[str, np.ndarray], Any]:
        """(channel -> (B, N) replays of every candidate on the loop's command on candidate ``b``,
        that run)."""
        run = self.run(steps, b)
        self.calls += 1
        return self.open(loop_command(run)), run

    def many(self, jobs: Sequence[tuple[Sequence[tuple[float, float]], int]]
             ) -> list[tuple[dict[str, np.ndarray], Any]]:
        """``self(steps, b)`` of each ``(steps, b)`` job, in order; in the worker processes when there
        are several (started at the first call, or by :meth:`start`); a job :meth:`keep` holds is not
        run again."""
        todo = [(steps, b) for steps, b in jobs if _job_key(steps, b) not in self._kept]
        if self.workers == 1 or len(todo) < 2:
            made = iter([self(steps, b) for steps, b in todo])
        else:
            self.start()
            made = iter(list(self._pool.map(_held_prediction, *zip(*todo, strict=True))))
            self.calls += len(todo)
        return [self._kept.get(_job_key(steps, b)) or next(made) for steps, b in jobs]

    def start(self) -> None:
        """Start the worker processes (no wait: each builds its copy while this process goes on)."""
        if self.workers > 1 and self._pool is None:
            from aeropend_control.design_gains import design_pool

            self._pool = design_pool(self.workers, _hold_predictor, self._made)
            for _ in range(self.workers):
                self._pool.submit(int)

    def close(self) -> None:
        """End the worker processes (if any; loops not yet started are dropped: after an interrupt
        only the running ones are waited for)."""
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None

    def __enter__(self) -> ClosedLoopPredictor:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _job_key(steps: Sequence[tuple[float, float]], b: int) -> tuple[tuple[tuple[float, float], ...], int]:
    return tuple((float(t), float(r)) for t, r in steps), int(b)


def lab_predictor(candidates: Sequence[Candidate], loop: Any, sigma: Mapping[str, float], limits: Limits,
                  shape: AprbsShape) -> ClosedLoopPredictor:
    """The predictor ``excitation_design --mode reference`` designs and predicts with: ``shape``'s
    samples at ``limits.dt``, ``sigma``'s channels, its loops in
    :func:`aeropend_control.design_gains.design_workers` processes (one per core unless
    ``AEROPEND_DESIGN_WORKERS`` says otherwise). Use it as a context manager."""
    from aeropend_control.design_gains import design_workers

    return ClosedLoopPredictor(candidates, loop, tuple(sigma), limits.dt, shape.samples(limits.dt),
                               design_workers(reference_popsize(shape)))


#: A worker process's copy of the :class:`ClosedLoopPredictor` that started it.
_HELD: ClosedLoopPredictor | None = None


def _hold_predictor(*made: Any) -> None:
    global _HELD
    _HELD = ClosedLoopPredictor(*made)


def _held_prediction(steps: Sequence[tuple[float, float]], b: int) -> tuple[dict[str, np.ndarray], Any]:
    """The worker's prediction, on one BLAS and one replay thread (the workers share the cores)."""
    assert _HELD is not None, "a ClosedLoopPredictor worker without its predictor"
    with one_blas_thread(), one_replay_thread():
        return _HELD(steps, b)


def loop_penalty(run: Any, limits: Limits, sigma_theta: float, margin: np.ndarray | float | None = None
                 ) -> float:
    """0 when the loop's run keeps its recorded angle, widened by ``margin`` [rad] (default
    :func:`~aeropend_ident.design.sequence.recorded_margin`), in the angle range and its logged
    command within the command limits (:func:`command_penalty`); else the more severe of
    :func:`~aeropend_ident.design.sequence.angle_penalty`'s penalties; a diverged run scores below
    every finite excess."""
    if run.status != "ok" or not np.all(np.isfinite(run.duty)):
        return -ANGLE_PENALTY * 1002.0
    m = recorded_margin(limits, sigma_theta) if margin is None else margin
    return min(angle_penalty(run.seen, limits, m), command_penalty(run, limits))


def command_penalty(run: Any, limits: Limits) -> float:
    """0 when the loop's logged command (:func:`loop_command`) stays in the command range and its
    change per sample within the slew limit; else :func:`~aeropend_ident.design.sequence.angle_penalty`'s
    scale on the excess (the range's plus a hundredth of the slew's [1/s])."""
    u = loop_command(run)
    cmd = max(0.0, float(u.max()) - limits.duty_max, limits.duty_min - float(u.min()))
    slew = max(0.0, float(np.max(np.abs(np.diff(u)))) - limits.max_slew * limits.dt) / limits.dt \
        if u.size > 1 else 0.0
    return 0.0 if cmd == 0.0 and slew == 0.0 else -ANGLE_PENALTY * (1.0 + min(cmd + slew / 100.0, 1000.0))


def reference_criterion(outputs: Mapping[str, np.ndarray], run: Any, sigma: Mapping[str, float],
                        limits: Limits) -> float:
    """:func:`loop_penalty` when the loop breaks a limit, else the mean log divergence of the
    replays (:func:`~aeropend_ident.design.discriminate.mean_log_divergence`; no angle penalty on
    them: a replay that leaves the range, or fails, on the loop's command is a candidate the
    recording refutes, its output counted as 10⁶ away)."""
    pen = loop_penalty(run, limits, float(sigma.get("theta", 0.0)))
    if pen < 0.0:
        return pen
    return mean_log_divergence({c: np.where(np.isfinite(y), y, 1e6) for c, y in outputs.items()}, sigma)


@dataclass
class ReferenceDesign(Discrimination):
    """A closed-loop discrimination design: :class:`~aeropend_ident.design.discriminate.Discrimination`
    whose ``duty`` is the loop's predicted command on the driver, with its set points.

    Attributes
    ----------
    steps, baseline_steps : list of (float, float)
        Set-point breakpoints (t [s], θ_ref [rad]) of the design and of the seeded sequence it starts from.
    reference : ndarray, shape (N,)
        The design's set point on the logging grid [rad].
    theta : ndarray, shape (N,)
        The loop's predicted recorded angle on the driver [rad].
    driver : str
        The candidate the search ran the loop on.
    """

    steps: list[tuple[float, float]] = dataclasses.field(default_factory=list)
    baseline_steps: list[tuple[float, float]] = dataclasses.field(default_factory=list)
    reference: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    theta: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    driver: str = ""


@single_blas
def design_reference(candidates: Sequence[Candidate], loop: Any, sigma: Mapping[str, float], limits: Limits,
                     shape: AprbsShape | None = None, *, seed: int = 0, budget_s: float = BUDGET_S,
                     max_evaluations: int | None = None, workers: int = 1,
                     predictor: ClosedLoopPredictor | None = None) -> ReferenceDesign:
    """Search the set-point sequence (module doc) that best separates ``candidates`` in closed loop.

    Parameters
    ----------
    candidates : sequence of Candidate
        At least two; the first (the best fit of the earlier recordings) is the driver.
    loop : ControllerLoop
        The lab's controller (:func:`lab_controller`, at the logging period ``limits.dt``).
    sigma : mapping
        Noise σ per logged channel [its unit]; its keys are the channels compared.
    limits : Limits
        Command range, slew, angle range, logging period.
    shape : AprbsShape, optional
        Default :func:`reference_shape` of 40 s.
    seed : int
        Seed of the starting sequence and of CMA-ES.
    budget_s : float
        Wall-time safety net of the search [s].
    max_evaluations : int, optional
        Most sequences scored (default :func:`reference_evaluations`: reproducible from the seed).
    workers : int
        Processes the loops of each CMA-ES generation run in (:class:`ClosedLoopPredictor`; the
        same design whatever the number). A lab's default:
        :func:`aeropend_control.design_gains.design_workers`.
    predictor : ClosedLoopPredictor, optional
        One to use (and leave open: its workers serve :func:`rank_first_probability` next), made for
        these candidates, this loop, ``sigma``'s channels, ``limits.dt`` and the shape's samples;
        ``workers`` is then its own.

    Returns
    -------
    ReferenceDesign

    Raises
    ------
    ValueError
        With fewer than two candidates, or a ``predictor`` made for another number of samples;
        :class:`~aeropend_ident.design.sequence.DesignError` when no
        set point lies in the angle range within the controller's reach.
    """
    if len(candidates) < 2:
        raise ValueError("a discrimination design needs at least two candidates")
    shape = shape or reference_shape(40.0)
    t0 = time.perf_counter()
    n = shape.samples(limits.dt)
    span = set_point_range(limits, loop.reach, float(sigma.get("theta", 0.0)))
    pred = predictor or ClosedLoopPredictor(candidates, loop, tuple(sigma), limits.dt, n, workers)
    if pred.n != n:
        raise ValueError(f"the predictor runs {pred.n} samples, the design {n}")
    calls0 = pred.calls

    def scored(prediction: tuple[dict[str, np.ndarray], Any]) -> tuple[float, Any]:
        out, run = prediction
        return reference_criterion(out, run, sigma, limits), (out, run)

    def value(z: np.ndarray) -> tuple[float, Any]:
        return scored(pred(reference_steps(z, shape, limits, span)))

    def values(zs: list[np.ndarray]) -> list[tuple[float, Any]]:
        return [scored(p) for p in pred.many([(reference_steps(z, shape, limits, span), 0) for z in zs])]

    z0 = aprbs_vector(shape, seed)
    pred.start()  # the workers get ready while the start is scored here
    try:  # the search keeps the replays and the loop's run of the best sequence and of its start
        best_z, best_v, (out, run), v0, (out0, run0), stopped = search(
            value, z0, seed=seed, budget_s=budget_s,
            max_evaluations=max_evaluations or reference_evaluations(n), popsize=reference_popsize(shape),
            started=t0, tolfun=1e-4, batch=values if pred.workers > 1 else None)
    finally:
        if predictor is None:
            pred.close()
    steps, base = reference_steps(best_z, shape, limits, span), reference_steps(z0, shape, limits, span)
    pred.keep(steps, 0, (out, run))  # the prediction's loop on the driver is this one
    return ReferenceDesign(
        duty=loop_command(run), baseline=loop_command(run0), value=best_v, baseline_value=v0,
        min_divergence=smallest_divergence(out, sigma),
        baseline_min_divergence=smallest_divergence(out0, sigma),
        evaluations=pred.calls - calls0, elapsed_s=time.perf_counter() - t0, z=best_z, stopped_by=stopped,
        steps=steps, baseline_steps=base, reference=on_grid(steps, n, limits.dt), theta=run.seen,
        driver=candidates[0].name)


@single_blas
def rank_first_probability(candidates: Sequence[Candidate], loop: Any, steps: Sequence[tuple[float, float]],
                           n: int, sigma: Mapping[str, float], limits: Limits, *, draws: int = 200,
                           seed: int = 0, workers: int = 1, predictor: ClosedLoopPredictor | None = None
                           ) -> dict[str, Any]:
    """Probability that each candidate, when it is the truth, ranks first on a closed-loop recording
    of ``steps``: the loop is run on that candidate, every candidate is replayed on the loop's
    command (``n`` samples), and the truth's replay plus noise is ranked as in
    :func:`aeropend_ident.design.discriminate.rank_first_probability` (no refit: an upper bound).

    ``workers`` and ``predictor`` as :func:`design_reference`'s: the candidates' loops run there.

    Returns
    -------
    dict
        ``per_candidate`` {name: probability}, ``mean``, ``draws``, and ``loop`` {name: the loop's
        run on that candidate: ``status`` and the recorded angle's extremes [rad]}.
    """
    pred = predictor or ClosedLoopPredictor(candidates, loop, tuple(sigma), limits.dt, n, workers)
    if pred.n != n:
        raise ValueError(f"the predictor runs {pred.n} samples, the prediction {n}")
    try:
        loops = pred.many([(steps, t) for t in range(len(candidates))])
    finally:
        if predictor is None:
            pred.close()
    runs: dict[str, Any] = {}

    def outputs_of(t: int) -> Mapping[str, np.ndarray]:
        out, run = loops[t]
        runs[candidates[t].name] = {"status": run.status, "theta_extremes": [float(np.nanmin(run.seen)),
                                                                            float(np.nanmax(run.seen))]}
        return out if run.status == "ok" else {c: np.full_like(y, np.nan) for c, y in out.items()}

    res = rank_draws([c.name for c in candidates], outputs_of, sigma, limits.quantum, draws=draws, seed=seed)
    return {**res, "loop": runs}
