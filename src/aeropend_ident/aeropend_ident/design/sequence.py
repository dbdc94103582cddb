"""The designed command sequence: a compact APRBS parametrisation and the lab's limits.

A design is an amplitude-modulated PRBS (the :func:`aeropend_sim.excitation.aprbs` family) of
``M`` holds: ``M`` levels in the command range and ``M`` hold times in [min_hold, max_hold],
scaled so that the holds fill the stated duration exactly. The optimiser searches the unit cube
[0, 1]^(2M) (levels first, then holds); :func:`aprbs_vector` is the seeded random point of that
cube, i.e. an ordinary APRBS, from which the search starts and against which it is compared.

After the holds are laid on the logging grid the sequence passes a slew limiter (at most
``max_slew·dt`` change per logged sample), so every sequence this module returns respects the
command range and the slew limit by construction; the angle range is the simulators' business
(:mod:`aeropend_ident.design.discriminate` penalises it, :func:`check_limits` checks it).

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

#: Lead-in of every design [s] at the lowest command (0 by default): the rig starts at rest (rod
#: hanging, motor off), the start the gap diagnosis' replays take for a log whose first command is 0.
LEAD_IN_S = 0.5
#: Default angle margin [rad] beyond the earlier recordings' angle range.
ANGLE_MARGIN = 0.15
#: The angle no design may reach, whatever the lab states [rad] (over the top is π).
ANGLE_CAP = 2.5


class DesignError(ValueError):
    """Invalid design settings (a limit outside its range, a duration over the cap, ...)."""


#: Penalty scale of a sequence that takes a predicted angle outside the angle range (or whose
#: replay fails): far below any criterion value inside it (log scale).
ANGLE_PENALTY = 1e3


def angle_penalty(theta: np.ndarray, limits: Limits, margin: np.ndarray | float = 0.0) -> float:
    """0 when every predicted angle ``theta`` (any shape) [rad], widened by ``margin`` [rad] (a
    scalar or one per angle) on either side, stays inside ``limits``' angle range; else
    −:data:`ANGLE_PENALTY` × (1 + the excess [rad] beyond it, capped at 1000), so the search, among
    sequences that leave the range, moves toward those that leave it least (a flat penalty let it
    pick the most informative of them, which sent a rod over the top); a failed replay (non-finite
    angle or margin) scores below every finite excess."""
    th, m = np.asarray(theta, dtype=float), np.asarray(margin, dtype=float)
    if not (np.all(np.isfinite(th)) and np.all(np.isfinite(m))):
        return -ANGLE_PENALTY * 1002.0
    excess = float(max(0.0, (th + m).max() - limits.theta_max, limits.theta_min - (th - m).min()))
    return 0.0 if excess == 0.0 else -ANGLE_PENALTY * (1.0 + min(excess, 1000.0))


#: Largest margin [share of the stated angle range] kept for what the earlier recordings leave
#: uncertain: beyond it the first-order spread of a parameter nothing determines (unit prior) says
#: little, and an uncapped spread left no sequence inside (bench_design_parameters' esc_0).
SPREAD_CAP = 0.1


def recorded_margin(limits: Limits, sigma_theta: float) -> float:
    """How far [rad] a recorded angle may lie from the true one: half the angle quantum and 2σ of
    the measured noise. The limits are on the recorded angle, so a design keeps this much inside
    them (a design that reached a stated limit exactly was recorded 0.002 rad beyond it)."""
    return 0.5 * float(limits.quantum) + 2.0 * float(sigma_theta)


def spread_cap(limits: Limits) -> float:
    """The largest spread [rad] :func:`angle_margin` keeps: :data:`SPREAD_CAP` of the angle range.
    A design whose spread exceeds it cannot assure its angle limits."""
    return SPREAD_CAP * (limits.theta_max - limits.theta_min)


def angle_margin(spread: np.ndarray | float, limits: Limits, sigma_theta: float) -> np.ndarray | float:
    """The margin [rad] a predicted angle keeps from the limits: its ``spread`` (1σ under what the
    earlier recordings leave uncertain, capped at :func:`spread_cap`) plus :func:`recorded_margin`."""
    return np.minimum(spread, spread_cap(limits)) + recorded_margin(limits, sigma_theta)


#: The search's default length, in replay work: each rig replayed per sequence costs its samples
#: × (1 + logged channels) / 2 plus :data:`REPLAY_OVERHEAD` (a replay's fixed cost in
#: sample-equivalents). Measured on bench_design_discrimination's cases on two cores: about 1.9 ms
#: per replay, 0.05 µs per sample and 0.05 µs per sample and logged channel. Counted, not timed, so a
#: seed gives one design on any machine under any load; about 20-40 s of search on two cores
#: (docs/design.md).
MAX_REPLAY_WORK = 250_000_000
#: The same for a discrimination design (:mod:`aeropend_ident.design.discriminate`), whose rigs are
#: the candidates, each with its effects compiled in: a thrust law's power and a Coulomb friction's
#: smooth sign cost 2.7 times the nominal rig per sample (lab case 76: 4.9 ms per replay of 9 766
#: samples, the nominal rig 1.8 ms; its search took 68 s at :data:`MAX_REPLAY_WORK`, and with the
#: candidate fits one swap away from the best, 66 s in all at 150 000 000). A parameter design
#: replays the rig itself; its search keeps :data:`MAX_REPLAY_WORK` (a shorter one left the angle
#: range on 2 more of bench_design_parameters' 8 designs).
DISCRIMINATION_WORK = 100_000_000
#: A replay's fixed cost, in samples (see :data:`MAX_REPLAY_WORK`).
REPLAY_OVERHEAD = 18_500
#: The search's default wall-time safety net [s]: a search cut by it says so (not reproducible).
BUDGET_S = 120.0


def default_evaluations(replays_per_evaluation: int, samples: int, channels: int = 1,
                        work: int = MAX_REPLAY_WORK) -> int:
    """Sequences a search scores by default: ``work`` (:data:`MAX_REPLAY_WORK`, or
    :data:`DISCRIMINATION_WORK`) over the work of one sequence (``replays_per_evaluation`` rigs ×
    (``samples`` × (1 + ``channels``) / 2 + :data:`REPLAY_OVERHEAD`)), at least 200."""
    per_replay = int(samples) * (1 + max(1, int(channels))) // 2 + REPLAY_OVERHEAD
    return max(200, int(work) // (max(1, int(replays_per_evaluation)) * per_replay))


#: What a design is: an open-loop command sequence, or a reference (set-point) sequence for the
#: lab's controller (:mod:`aeropend_ident.design.reference`; docs/design.md, "Closed loop").
MODES = ("open_loop", "reference")


def check_mode(mode: str, supported: Sequence[str] = ("open_loop",), where: str = "this design") -> None:
    """Refuse a mode ``where`` does not support.

    Raises
    ------
    DesignError
        For a known mode outside ``supported`` (naming what is supported there: a parameter design
        is open loop only; a reference design is :func:`aeropend_ident.design.reference.design_reference`)
        and for an unknown mode.
    """
    if mode in supported:
        return
    if mode in MODES:
        raise DesignError(f"mode {mode!r} is not implemented for {where}: it supports {list(supported)} "
                          "(a reference design is a discrimination design of a gap report; docs/design.md, "
                          "'Closed loop')")
    raise DesignError(f"mode {mode!r}; expected one of {list(MODES)}")


@dataclass(frozen=True)
class Limits:
    """What a designed sequence must respect.

    Attributes
    ----------
    duty_min, duty_max : float
        Command range (duty τ ∈ [0, 1], or the family's command normalised the same way).
    max_slew : float
        Largest command change per second [1/s]; the per-sample step is ``max_slew·dt``.
    theta_min, theta_max : float
        Angle range the recorded angle must stay in [rad] (recording frame).
    dt : float
        Logging (and command) period [s].
    quantum : float
        Angle quantum of the logger [rad] (0: none).
    """

    duty_min: float = 0.0
    duty_max: float = 1.0
    max_slew: float = 20.0
    theta_min: float = -ANGLE_CAP
    theta_max: float = ANGLE_CAP
    dt: float = 2.048e-3
    quantum: float = 0.0

    def __post_init__(self) -> None:
        if not (0.0 <= self.duty_min < self.duty_max <= 1.0):
            raise DesignError(f"command range [{self.duty_min}, {self.duty_max}] must lie in [0, 1] "
                              "with min < max")
        if not (self.max_slew > 0.0 and math.isfinite(self.max_slew)):
            raise DesignError(f"max_slew = {self.max_slew} /s must be > 0")
        if not (-ANGLE_CAP <= self.theta_min < self.theta_max <= ANGLE_CAP):
            raise DesignError(f"angle range [{self.theta_min}, {self.theta_max}] rad must lie in "
                              f"[-{ANGLE_CAP}, {ANGLE_CAP}] (never over the top) with min < max")
        if not (self.dt > 0.0 and math.isfinite(self.dt)):
            raise DesignError(f"dt = {self.dt} s must be > 0")

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_recordings(cls, thetas: Sequence[np.ndarray], duties: Sequence[np.ndarray], dt: float, *,
                        quantum: float = 0.0, margin: float = ANGLE_MARGIN, max_slew: float = 20.0,
                        stated: Mapping[str, float] | None = None) -> Limits:
        """Default limits from the earlier recordings: their angle range plus ``margin`` (capped at
        ±:data:`ANGLE_CAP`), commands from 0 to their largest command; ``stated`` overrides any
        field (the lab's own limits).

        Parameters
        ----------
        thetas, duties : sequence of ndarray, shape (N_i,)
            Recorded angles [rad] and commands [1] of the earlier recordings.
        dt : float
            Logging period of the design [s].
        """
        th = np.concatenate([np.asarray(t, dtype=float) for t in thetas])
        du = np.concatenate([np.asarray(d, dtype=float) for d in duties])
        vals: dict[str, float] = {
            "duty_min": 0.0, "duty_max": float(min(max(np.max(du), 0.05), 1.0)), "max_slew": max_slew,
            "theta_min": float(max(np.min(th) - margin, -ANGLE_CAP)),
            "theta_max": float(min(np.max(th) + margin, ANGLE_CAP)), "dt": float(dt), "quantum": quantum}
        vals.update({k: float(v) for k, v in (stated or {}).items()})
        return cls(**vals)


@dataclass(frozen=True)
class AprbsShape:
    """How a point of the unit cube becomes a command sequence.

    Attributes
    ----------
    duration : float
        Length of the sequence [s], lead-in included (≤ 60 s in the benchmark and the CLI default).
    segments : int
        Number of holds M (the design has 2M numbers).
    min_hold, max_hold : float
        Hold-time range before the holds are scaled to fill the duration [s].
    """

    duration: float = 40.0
    segments: int = 80
    min_hold: float = 0.05
    max_hold: float = 1.0

    def __post_init__(self) -> None:
        if not (self.duration > LEAD_IN_S + 1.0):
            raise DesignError(f"duration = {self.duration} s must exceed {LEAD_IN_S + 1.0} s")
        if self.segments < 2:
            raise DesignError(f"segments = {self.segments}: at least 2")
        if not (0.0 < self.min_hold <= self.max_hold):
            raise DesignError(f"hold range [{self.min_hold}, {self.max_hold}] s is empty")

    def samples(self, dt: float) -> int:
        """Samples of a sequence of this shape at period ``dt`` [s]: ``round(duration / dt)``."""
        return round(self.duration / dt)

    @classmethod
    def for_duration(cls, duration: float) -> AprbsShape:
        """The default shape of a design of ``duration`` seconds: two holds per second (on the lab
        benchmark's case 87, 80 holds in 40 s separated its two candidates 3× more than 16 holds)."""
        return cls(duration=duration, segments=max(8, round(2.0 * duration)))

    @property
    def size(self) -> int:
        """Dimension of the design vector (2M)."""
        return 2 * self.segments


def slew_limited(duty: np.ndarray, step: float, start: float = 0.0) -> np.ndarray:
    """Rate-limit a sequence: each sample moves at most ``step`` from the previous one.

    Parameters
    ----------
    duty : ndarray, shape (N,)
        Commands [1].
    step : float
        Largest change per sample [1].
    start : float
        Command before the first sample.

    Returns
    -------
    ndarray, shape (N,)
    """
    # a plain loop over Python floats (a search calls this once per sequence: 19 600 samples at
    # 490 Hz); the same arithmetic as prev + min(max(u − prev, −step), step), so the same values
    values = np.asarray(duty, dtype=float).tolist()
    prev, step = float(start), float(step)
    for k, u in enumerate(values):
        d = u - prev
        if d > step:
            d = step
        elif d < -step:
            d = -step
        prev = prev + d
        values[k] = prev
    return np.array(values, dtype=float)


def sequence(z: np.ndarray, shape: AprbsShape, limits: Limits) -> np.ndarray:
    """The command sequence (N,) of design vector ``z`` ∈ [0, 1]^(2M) on the logging grid.

    The first :data:`LEAD_IN_S` holds ``duty_min``; then hold i lasts a share of the remaining time
    proportional to ``min_hold + z[M+i]·(max_hold − min_hold)`` at level
    ``duty_min + z[i]·(duty_max − duty_min)``; the whole passes :func:`slew_limited`.

    Raises
    ------
    DesignError
        If ``z`` has the wrong size.
    """
    share, edges, n_lead = holds(z, shape, limits.dt)
    levels = limits.duty_min + share * (limits.duty_max - limits.duty_min)
    counts = np.diff(np.concatenate([[n_lead], edges]))
    duty = np.concatenate([np.full(n_lead, limits.duty_min), np.repeat(levels, counts)])
    return slew_limited(duty, limits.max_slew * limits.dt, start=limits.duty_min)


def holds(z: np.ndarray, shape: AprbsShape, dt: float) -> tuple[np.ndarray, np.ndarray, int]:
    """The holds of design vector ``z`` ∈ [0, 1]^(2M) (clipped to it) on the grid k·``dt``.

    Returns
    -------
    levels : ndarray, shape (M,)
        Each hold's level as a share of the range, ``z[:M]``.
    ends : ndarray of int, shape (M,)
        The sample each hold ends before: after the lead-in, hold i lasts a share of the rest
        proportional to ``min_hold + z[M+i]·(max_hold − min_hold)``; the last ends at N.
    n_lead : int
        Samples of the lead-in (:data:`LEAD_IN_S`).

    Raises
    ------
    DesignError
        If ``z`` has the wrong size.
    """
    z = np.clip(np.asarray(z, dtype=float), 0.0, 1.0)
    m = shape.segments
    if z.size != 2 * m:
        raise DesignError(f"design vector of size {z.size}; expected {2 * m}")
    n = shape.samples(dt)
    n_lead = round(LEAD_IN_S / dt)
    lengths = shape.min_hold + z[m:] * (shape.max_hold - shape.min_hold)
    ends = n_lead + np.rint(np.cumsum(lengths) / lengths.sum() * (n - n_lead)).astype(int)
    return z[:m], ends, n_lead


def aprbs_vector(shape: AprbsShape, seed: int) -> np.ndarray:
    """A seeded uniform point of the unit cube: an ordinary APRBS of ``shape`` (levels and holds
    drawn uniformly), the start of the search and its comparison."""
    return np.random.default_rng(seed).uniform(0.0, 1.0, shape.size)


def search(score: Callable[[np.ndarray], tuple[float, Any]], z0: np.ndarray, *, seed: int, budget_s: float,
           max_evaluations: int, popsize: int, started: float, tolfun: float | None = None,
           batch: Callable[[list[np.ndarray]], list[tuple[float, Any]]] | None = None
           ) -> tuple[np.ndarray, float, Any, float, Any, str]:
    """Maximise ``score(z)[0]`` over the unit box by CMA-ES (the ``cma`` package) from ``z0``.

    The one search of every design. It ends when ``max_evaluations`` sequences were scored or
    CMA-ES converged: then the same seed gives the same design on any machine under any load.
    ``budget_s`` is a safety net: when wall time runs out first (a slow or busy machine) the search
    ends inside a generation too (an unfinished generation is not told to the strategy), and the
    returned reason says so: that design depends on the machine's speed.

    Parameters
    ----------
    score : callable
        ``score(z) -> (value, extra)``; larger values are better, ``extra`` is kept with the best.
    z0 : ndarray, shape (n,)
        Start in [0, 1]^n (also scored: the baseline).
    seed : int
        CMA-ES seed is ``seed + 1``.
    budget_s : float
        Wall time [s] from ``started`` (a :func:`time.perf_counter` reading) after which the search
        stops whatever its evaluations.
    max_evaluations : int
        Most evaluations (CMA-ES ``maxfevals``).
    popsize : int
        CMA-ES population.
    tolfun : float, optional
        CMA-ES ``tolfun`` (its default when None).
    batch : callable, optional
        ``batch(zs) -> [score(z) for z in zs]`` for a whole generation at once (in worker
        processes); the same values, so the same search. The wall-time safety net is then checked
        once a generation.

    Returns
    -------
    tuple
        ``(best_z, best_value, best_extra, baseline_value, baseline_extra, stopped_by)``;
        ``stopped_by`` is ``"evaluations"``, ``"converged"`` (a CMA-ES tolerance) or ``"budget"``
        (wall time: not reproducible).
    """
    import cma

    v0, e0 = score(z0)
    best_z, best_v, best_e = z0.copy(), v0, e0
    opts: dict[str, Any] = {"bounds": [0.0, 1.0], "seed": seed + 1, "verbose": -9,
                            "maxfevals": max_evaluations, "popsize": popsize}
    if tolfun is not None:
        opts["tolfun"] = tolfun
    es = cma.CMAEvolutionStrategy(z0, 0.25, opts)
    while not es.stop():
        zs = [np.asarray(z) for z in es.ask()]
        vals = []
        for z, (v, e) in _scored(zs, score, batch, lambda: time.perf_counter() - started >= budget_s):
            vals.append(v)
            if v > best_v:
                best_z, best_v, best_e = z.copy(), v, e
        if len(vals) < len(zs):
            return best_z, best_v, best_e, v0, e0, "budget"
        es.tell(zs, [-v for v in vals])
    return best_z, best_v, best_e, v0, e0, "evaluations" if "maxfevals" in es.stop() else "converged"


def _scored(zs: list[np.ndarray], score: Callable[[np.ndarray], tuple[float, Any]],
            batch: Callable[[list[np.ndarray]], list[tuple[float, Any]]] | None,
            late: Callable[[], bool]) -> Iterator[tuple[np.ndarray, tuple[float, Any]]]:
    """(z, score(z)) of one generation, in order, until ``late()`` (checked before each z, or once
    before a ``batch``)."""
    if batch is not None:
        if not late():
            yield from zip(zs, batch(zs), strict=True)
        return
    for z in zs:
        if late():
            return
        yield z, score(z)


def check_limits(duty: np.ndarray, limits: Limits, theta: np.ndarray | None = None) -> dict[str, Any]:
    """Check a sequence (and, given, the angle it produced) against ``limits``.

    Parameters
    ----------
    duty : ndarray, shape (N,)
        Commands on the logging grid [1].
    theta : ndarray, shape (N,), optional
        Recorded (or simulated) angle under those commands [rad].

    The slew is checked between consecutive samples (the first command is the start, reached as
    the lab switches its motor on).

    Returns
    -------
    dict
        ``command_range``, ``slew``, ``angle_range`` (True / False / None when not checked),
        ``ok`` (all checked ones hold) and the measured extremes.
    """
    duty = np.asarray(duty, dtype=float)
    tol = 1e-9
    slew = float(np.max(np.abs(np.diff(duty)))) / limits.dt if duty.size > 1 else 0.0
    out: dict[str, Any] = {
        "command_range": bool(duty.min() >= limits.duty_min - tol and duty.max() <= limits.duty_max + tol),
        "slew": bool(slew <= limits.max_slew * (1 + 1e-9) + tol / limits.dt),
        "duty_extremes": [float(duty.min()), float(duty.max())], "max_slew_seen": slew,
        "angle_range": None,
    }
    if theta is not None:
        th = np.asarray(theta, dtype=float)
        out["angle_range"] = bool(np.all(np.isfinite(th)) and th.min() >= limits.theta_min
                                  and th.max() <= limits.theta_max)
        out["theta_extremes"] = [float(np.nanmin(th)), float(np.nanmax(th))]
    out["ok"] = all(out[k] for k in ("command_range", "slew", "angle_range") if out[k] is not None)
    return out
