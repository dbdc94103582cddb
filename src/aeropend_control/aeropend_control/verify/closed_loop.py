"""A designed controller driven in closed loop on the simulator of the whole rig file (no rclpy).

A design model (the pendulum alone, or the linearised drive chain of
:mod:`aeropend_control.drive_design`) leaves out what makes a step hard on a real rig: the
actuator's saturation, its dead time and lag, the rotor's response, dry friction, the sensor's
quantum, noise and sample rate. Every figure ``design_gains`` prints is therefore measured here, on
:class:`aeropend_sim.simulation.PlantStepper` of the rig file with every switched-on effect,
driven by the controller node's own per-sample loop
(:class:`~aeropend_control.controller_core.ControllerLoop`: the same strategy object, observer,
allocation and reference clamping the node runs), at the rig's sample period, from rest hanging
down (θ = 0) to a step of the reference at t = 0.

A run is judged on the true angle (the plant's state, not the quantised measurement) with the
step metrics of :func:`aeropend_control.metrics.step_metrics`, and it is flagged

* ``limit cycle`` when the angle still swings over the last second by more than the 2 % band
  (peak to peak, at least 4·quantum) and crosses its mean there at least twice — a loop the
  actuator's limits keep oscillating (a slow creep is ``not settled``);
* ``diverged`` when the plant left a finite state or the angle went past π (over the top).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from aeropend_control.controller_core import SIGNALS, ControllerLoop, ControllerSettings
from aeropend_control.design import PoleSpec
from aeropend_control.metrics import MetricsError, Requirements, StepMetrics, step_metrics
from aeropend_control.strategies.loop import DEFAULT_TF
from aeropend_sim.model import THETA
from aeropend_sim.params import Rig
from aeropend_sim.simulation import PlantStepper, SimulationError

#: What a lab's step is checked against (issue 59): settling time ≤ 1 s (2 % band), overshoot M_p ≤ 5 %.
LAB_GOAL = Requirements(settling_time=1.0, overshoot=5.0)
#: A step that settles (no limit cycle, no divergence, inside the 2 % band) within the goal's overshoot.
SETTLES = Requirements(overshoot=LAB_GOAL.overshoot)
#: Default step references [rad] of a check (cut to the rig's reach).
STEPS = (0.2, 0.4, 0.6)
#: Shortest length of a checked step [s]: the goal's 1 s settling, plus time to see a limit cycle.
DURATION = 4.0
#: A pole pattern of natural frequency ω_n shows that it settled after about this many radians of
#: ω_n·t (four time constants 1/(ζ·ω_n) and the band's hold): a step of a slow pattern runs
#: SETTLE_RAD/ω_n seconds (:func:`duration_for`), so its settling time is measured, not cut off.
SETTLE_RAD = 16.0


@dataclass(frozen=True)
class StepRun:
    """One closed-loop step on the simulated rig.

    Attributes
    ----------
    strategy : str
    requested, reference : float
        The step's reference as asked and as the loop used it (clamped to the rig's reach) [rad].
    t, theta, duty : ndarray, shape (N,)
        Sample instants [s], true angle [rad], commanded duty cycle τ.
    metrics : StepMetrics or None
        None when the run diverged.
    status : str
        ``"ok"`` (settles), ``"limit cycle"``, ``"diverged"`` or ``"not settled"``.
    detail : str
        Why, in words (empty for ``ok``).
    """

    strategy: str
    requested: float
    reference: float
    t: np.ndarray = field(repr=False)
    theta: np.ndarray = field(repr=False)
    duty: np.ndarray = field(repr=False)
    metrics: StepMetrics | None
    status: str
    detail: str = ""

    def failures(self, goal: Requirements = LAB_GOAL) -> list[str]:
        """The goal's requirements this run misses (its status first when it is not ``ok``)."""
        if self.metrics is None:
            return [self.status + (f": {self.detail}" if self.detail else "")]
        out = [] if self.status == "ok" else [self.status + (f": {self.detail}" if self.detail else "")]
        return out + self.metrics.failures(goal)

    def meets(self, goal: Requirements = LAB_GOAL) -> bool:
        """True when the run settles and meets every requirement of ``goal``."""
        return not self.failures(goal)


def duration_for(spec: PoleSpec) -> float:
    """Length [s] of a checked step of pattern ``spec``: max(:data:`DURATION`, :data:`SETTLE_RAD`/ω_n)."""
    return max(DURATION, SETTLE_RAD / spec.omega_n)


def _judge(t: np.ndarray, theta: np.ndarray, r: float, quantum: float) -> tuple[str, str]:
    tail = theta[t >= t[-1] - 1.0]
    swing = float(np.ptp(tail))
    band = max(0.04 * abs(r), 4.0 * quantum)
    crossings = int(np.count_nonzero(np.diff(np.sign(tail - tail.mean())) != 0))
    if swing > band and crossings >= 2:  # a swing, not a slow creep (that one is "not settled")
        return "limit cycle", (f"θ swings {swing:.3g} rad peak to peak over the last second "
                               f"(≈ {crossings / 2.0:.0f} Hz), more than the 2 % band")
    return "ok", ""


def controller(rig: Rig, strategy: str, spec: PoleSpec, duration: float = DURATION) -> ControllerLoop:
    """The controller node's loop (lock-step) of ``strategy`` with pole pattern ``spec`` on ``rig``,
    reference 0 until a step is set (:func:`run_step` copies it, so one design serves every step).

    Raises
    ------
    ControllerConfigError
        If the strategy cannot be built on ``rig`` (the message says why).
    """
    return ControllerLoop(ControllerSettings(
        rig=rig, strategy=strategy, mode="lockstep", steps=[], reference=0.0, allocator="model", spec=spec,
        tf=DEFAULT_TF, theta_op=None, duration=duration, trace="", estimator="observer", rig_file=rig.name,
        default_spec=spec))


def run_step(rig: Rig, strategy: str, reference: float, spec: PoleSpec, *, plant: Rig | None = None,
             duration: float | None = None, seed: int = 0, loop: ControllerLoop | None = None) -> StepRun:
    """Drive ``strategy`` designed for ``rig`` with pole pattern ``spec`` through one step.

    Parameters
    ----------
    rig : Rig
        The rig file the controller is designed on.
    strategy : str
        A registered strategy name.
    reference : float
        Step reference [rad] at t = 0, from rest at θ = 0 (clamped to the rig's reach as the node does).
    spec : PoleSpec
        The position loop's pole pattern.
    plant : Rig, optional
        The rig simulated in the loop (default ``rig``: the design checked on its own rig file).
    duration : float, optional
        Length of the run [s] (default :func:`duration_for` the pattern).
    seed : int
        Seed of the simulated sensor noise.
    loop : ControllerLoop, optional
        A fresh :func:`controller` of the same strategy and pattern, copied here (its design reused).

    Returns
    -------
    StepRun

    Raises
    ------
    ControllerConfigError
        If the strategy cannot be built on ``rig`` (the message says why).
    """
    if duration is None:
        duration = duration_for(spec)
    if loop is None:
        loop = controller(rig, strategy, spec, duration)
    else:
        loop = copy.deepcopy(loop)
    loop.reference.steps = [(0.0, float(reference))]
    dt = (plant or rig).sample_period
    run = drive(loop, plant or rig, round(duration / dt) + 1, seed=seed)
    t, theta, duty, status, detail = run.t, run.theta, run.duty, run.status, run.detail
    r = loop.last_signals[SIGNALS.index("reference")]  # as the loop used it (clamped to the reach)
    if status != "ok":
        return StepRun(strategy, float(reference), r, t, theta, duty, None, status, detail)
    quantum = _quantum(rig)
    status, detail = _judge(t, theta, r, quantum)
    try:
        metrics = step_metrics(t, theta, r)
    except MetricsError as exc:
        return StepRun(strategy, float(reference), r, t, theta, duty, None, "diverged", str(exc))
    if status == "ok" and not math.isfinite(metrics.settling_time):
        status, detail = "not settled", (f"θ ends {r - metrics.steady_state_error:.4g} rad against "
                                         f"{r:.4g} rad (outside the 2 % band)")
    return StepRun(strategy, float(reference), r, t, theta, duty, metrics, status, detail)


@dataclass(frozen=True)
class LoopRun:
    """A controller loop driven on a simulated plant (:func:`drive`).

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample instants [s] from the first sample.
    theta : ndarray, shape (N,)
        True angle of the plant [rad] (NaN after a divergence).
    seen : ndarray, shape (N,)
        The angle the loop was given [rad] (the plant's measurement, through ``sensor`` when given).
    duty : ndarray, shape (N,)
        The loop's command at each sample (NaN after a divergence); the plant got it clipped to [0, 1].
    status : str
        ``"ok"`` or ``"diverged"``.
    detail : str
        Why it diverged (empty for ``ok``).
    """

    t: np.ndarray = field(repr=False)
    theta: np.ndarray = field(repr=False)
    seen: np.ndarray = field(repr=False)
    duty: np.ndarray = field(repr=False)
    status: str = "ok"
    detail: str = ""


def drive(loop: ControllerLoop, plant: Rig, n: int, *, seed: int | None = 0,
          sensor: Callable[[float], float] | None = None) -> LoopRun:
    """Run ``loop`` (lock-step, its reference as set) on :class:`~aeropend_sim.simulation.PlantStepper`
    of ``plant`` for ``n`` samples at the plant's sample period, from rest hanging down.

    At each sample the loop gets the plant's measured angle (its sensor noise and quantum as the
    rig file switches them), mapped by ``sensor`` when given (a sensor gain or offset the rig file
    does not hold), and the measured rotor speed and armature current; its command is applied
    clipped to [0, 1]. The loop object is advanced: pass a copy to reuse a designed one.

    Parameters
    ----------
    loop : ControllerLoop
    plant : Rig
        The simulated rig.
    n : int
        Samples.
    seed : int or None
        Seed of the plant's measurement noise.
    sensor : callable, optional
        Recorded angle [rad] of a measured angle [rad].

    Returns
    -------
    LoopRun
        Ended early (``diverged``) when the rod went over the top or the plant left a finite state.
    """
    sim = PlantStepper(plant, seed=seed)
    dt = plant.sample_period
    t, theta, seen, duty = (np.arange(n) * dt, np.full(n, math.nan), np.full(n, math.nan),
                            np.full(n, math.nan))
    s = sim.sample()
    for k in range(n):
        theta[k] = sim.x[THETA]
        th = s["theta"] if sensor is None else sensor(s["theta"])
        seen[k] = th
        d = loop.on_sample(round(k * dt * 1e9), th, s.get("omega_rotor", math.nan), s.get("i_a", math.nan))
        duty[k] = d
        if not (abs(theta[k]) < math.pi):
            return LoopRun(t, theta, seen, duty, "diverged",
                           f"the rod went over the top (θ = {theta[k]:.3g} rad at {t[k]:.3g} s)")
        try:
            s = sim.step(min(max(float(d), 0.0), 1.0))
        except SimulationError as exc:
            return LoopRun(t, theta, seen, duty, "diverged", str(exc))
    return LoopRun(t, theta, seen, duty)


def _quantum(rig: Rig) -> float:
    """The angle sensor's quantum [rad] when the rig quantises it, else 0."""
    if not rig.effects.quantisation:
        return 0.0
    return float(rig.sensors.theta_quantum)


# ---------------------------------------------------------------------------------- tuning
#: Factors on the strategy's default ω_n tried when its default pattern misses the goal on the rig
#: (descending: the fastest pattern that meets the goal wins; the slowest ones give the attainable
#: figures of a rig whose dead time and lag no faster pattern survives).
OMEGA_FACTORS = (1.0, 0.85, 0.7, 0.6, 0.5, 0.4, 0.3, 0.22, 0.16, 0.12)
#: Damping ratios tried at each ω_n.
ZETAS = (0.8, 0.9, 0.97)


@dataclass(frozen=True)
class Verdict:
    """A pole pattern of one strategy checked in closed loop at each step of a check.

    Attributes
    ----------
    strategy : str
    spec : PoleSpec
    runs : list of StepRun
        One per step; a candidate that failed its first step early may hold fewer runs.
    complete : bool
        True when every step of the check was run.
    """

    strategy: str
    spec: PoleSpec
    runs: list[StepRun]
    complete: bool = True

    @property
    def meets(self) -> bool:
        """Every step settles and meets :data:`LAB_GOAL`."""
        return self.complete and all(r.meets() for r in self.runs)

    @property
    def settles(self) -> bool:
        """Every step settles (no limit cycle, no divergence) with M_p ≤ 5 %."""
        return self.complete and all(r.meets(SETTLES) for r in self.runs)

    @property
    def ends_in_band(self) -> bool:
        """Every step ends inside the 2 % band (status ``ok``), whatever its overshoot."""
        return self.complete and all(r.status == "ok" for r in self.runs)

    def worst(self, name: str) -> float:
        """Largest ``settling_time`` / ``overshoot`` / ``rise_time`` over the runs (inf if a run has none)."""
        vals = [getattr(r.metrics, name) if r.metrics is not None else math.inf for r in self.runs]
        vals = [v if math.isfinite(v) else math.inf for v in vals]
        return max(vals) if vals else math.inf

    def cost(self) -> tuple[int, float]:
        """Ranking key: patterns that settle with M_p ≤ 5 % first, then those whose every step
        ends in the band (the attainable figures of a rig no pattern settles on without
        overshoot), then the worst settling time."""
        return (0 if self.settles else 1 if self.ends_in_band else 2, self.worst("settling_time"))


def verify(rig: Rig, strategy: str, spec: PoleSpec, steps: tuple[float, ...] = STEPS, *,
           plant: Rig | None = None, stop_early: bool = False) -> Verdict:
    """The pattern ``spec`` of ``strategy`` at every step of ``steps`` (:func:`run_step`; a reference
    beyond the rig's reach is replaced by the reach, once);
    ``stop_early`` stops at the first step that does not end in the 2 % band (a limit cycle, a
    divergence, not settled): such a pattern can be neither chosen nor the attainable figures."""
    template = controller(rig, strategy, spec)
    refs: list[float] = []
    for r in steps:
        r = min(float(r), template.reach)
        if all(abs(r - q) > 1e-6 for q in refs):
            refs.append(r)
    runs: list[StepRun] = []
    for r in refs:
        run = run_step(rig, strategy, r, spec, plant=plant, loop=template)
        runs.append(run)
        if stop_early and run.status != "ok":
            return Verdict(strategy, spec, runs, complete=len(runs) == len(refs))
    return Verdict(strategy, spec, runs)


def tune(rig: Rig, strategy: str, default: PoleSpec, steps: tuple[float, ...] = STEPS,
         progress: Callable[[str], None] | None = None) -> tuple[Verdict, Verdict]:
    """The default pattern's verdict and the pattern to run on this rig.

    The default pattern (:meth:`Strategy.default_spec_for`) is kept when it meets :data:`LAB_GOAL`
    at every step. Otherwise ω_n × :data:`OMEGA_FACTORS` and ζ in :data:`ZETAS` are tried, fastest
    first, each in closed loop on the whole rig file (:func:`verify`): the first pattern that meets
    the goal is returned; when none does, the one whose worst step settles soonest with M_p ≤ 5 %
    (the attainable figures), or the least bad.

    Returns
    -------
    (Verdict, Verdict)
        The default pattern's and the chosen pattern's (the same object when the default meets the goal).
    """
    import dataclasses
    first = verify(rig, strategy, default, steps)
    if first.meets:
        return first, first
    best = first
    for factor in OMEGA_FACTORS:
        found: list[Verdict] = []
        for zeta in ZETAS:
            spec = dataclasses.replace(default, omega_n=default.omega_n * factor, zeta=zeta)
            if spec == default:
                continue
            if progress is not None:
                progress(f"{strategy}: ω_n {spec.omega_n:.3g} rad/s, ζ {spec.zeta:g}")
            v = verify(rig, strategy, spec, steps, stop_early=True)
            if v.complete and v.cost() < best.cost():
                best = v
            if v.meets:
                found.append(v)
        if found:
            return first, min(found, key=lambda v: v.worst("settling_time"))
    return first, best
