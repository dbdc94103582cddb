"""Duty-cycle excitation signals for identification experiments (no ROS dependency).

Every generator returns an :class:`ExcitationSignal`: the duty cycle τ_k ∈ [0, 1] at the sample
instants t_k = k·dt, held (zero-order hold) over [t_k, t_{k+1}), i.e. the batch convention of
:func:`aeropend_sim.simulation.simulate`. Piecewise-constant signals also carry their segments
(``levels``, ``holds``) so tests and plots need not re-detect them.

Generators
----------
:func:`step`
    One step from an initial level to a final level.
:func:`staircase`
    A sequence of levels, each held for a given time.
:func:`prbs`
    Maximum-length pseudo-random binary sequence (``scipy.signal.max_len_seq``), two levels.
:func:`aprbs`
    Amplitude-modulated PRBS: random levels in [lo, hi], random holds in [min_hold, max_hold].
:func:`density_modulated_prbs`
    Random binary signal (fast holds) whose local density of high holds follows a slow APRBS:
    excites the electrical and rotor dynamics and moves the pendulum in one record.
:func:`from_file`
    A sequence read from a ``t,duty`` CSV (what ``excitation --print`` and ``excitation_design``
    write): plays a designed or hand-made sequence.
:func:`lhs_steps`
    The thesis' Latin-hypercube step design (§5.1): the input space τ × T (step amplitude ×
    step duration) is partitioned into ``n`` intervals along each axis and ``n`` points are drawn
    so that every interval of τ and every interval of T holds exactly one point; the points,
    in the order drawn, become a staircase of steps.

All random generators take a ``seed``: the same seed gives a bit-identical signal.
Durations are converted to whole samples by rounding the *cumulative* segment boundaries to
the sample grid, so the total duration is exact to half a sample and rounding never drifts.
:func:`make_signal` dispatches on a kind name for command-line tools.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeropend_sim.contract import SAMPLE_PERIOD_S


class ExcitationError(ValueError):
    """Invalid excitation-signal parameters (level outside [0, 1], non-positive duration, ...)."""


@dataclass(frozen=True)
class ExcitationSignal:
    """A sampled duty-cycle signal.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample instants [s], ``t[k] = k·dt``.
    duty : ndarray, shape (N,)
        Duty cycle τ_k ∈ [0, 1] held over [t_k, t_{k+1}).
    dt : float
        Sample period [s].
    kind : str
        Generator name (``"step"``, ``"staircase"``, ``"prbs"``, ``"aprbs"``, ``"density_prbs"``,
        ``"lhs"``).
    params : dict
        The generator arguments (for provenance, e.g. in a bag's metadata).
    levels : ndarray, shape (M,)
        Level of each constant segment, in order.
    holds : ndarray, shape (M,)
        Duration [s] of each constant segment after rounding to whole samples
        (``holds.sum() == N·dt``).
    design : ndarray, shape (n, 2) or None
        LHS only: the drawn design points (τ, T) before rounding T to the sample grid.
    """

    t: np.ndarray
    duty: np.ndarray
    dt: float
    kind: str
    params: dict[str, Any] = field(default_factory=dict)
    levels: np.ndarray = field(default_factory=lambda: np.empty(0))
    holds: np.ndarray = field(default_factory=lambda: np.empty(0))
    design: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.duty.size)

    @property
    def duration(self) -> float:
        """Total duration N·dt [s] (the last sample is held for one period)."""
        return len(self) * self.dt

    def to_csv(self, header: bool = True) -> str:
        """The signal as CSV text with columns ``t`` [s] and ``duty`` [1]."""
        lines = ["t,duty"] if header else []
        lines += [f"{t:.9g},{d:.9g}" for t, d in zip(self.t, self.duty, strict=True)]
        return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------- checks
def _fmt(value: Any) -> str:
    """Readable form of a user value for error messages (``0.5``, ``nan``, ``'abc'``)."""
    try:
        return f"{float(value):g}"
    except (TypeError, ValueError):
        return repr(value)


def _float(name: str, value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError) as exc:
        raise ExcitationError(f"{name} = {value!r} is not a number") from exc


def _check_dt(dt: float) -> float:
    dt = _float("dt", dt)
    if not (math.isfinite(dt) and dt > 0.0):
        raise ExcitationError(f"sample period dt = {_fmt(dt)} s must be a finite number > 0")
    return dt


def _check_level(name: str, value: float) -> float:
    v = _float(name, value)
    if not math.isfinite(v) or v < 0.0 or v > 1.0:
        raise ExcitationError(f"{name} = {_fmt(value)} is not a duty cycle; expected a fraction in [0, 1]")
    return v


def _check_duration(name: str, value: float, dt: float) -> float:
    v = _float(name, value)
    if not (math.isfinite(v) and v > 0.0):
        raise ExcitationError(f"{name} = {_fmt(value)} s must be a finite duration > 0")
    if v < 0.5 * dt:
        raise ExcitationError(
            f"{name} = {v:g} s is shorter than half a sample period ({dt:g} s) and would vanish"
        )
    return v


def _check_range(lo_name: str, lo: float, hi_name: str, hi: float) -> None:
    if not lo <= hi:
        raise ExcitationError(f"{lo_name} = {lo:g} must be <= {hi_name} = {hi:g}")


def _segments_to_signal(
    levels: Sequence[float], holds_s: Sequence[float], dt: float, kind: str, params: dict[str, Any],
    design: np.ndarray | None = None,
) -> ExcitationSignal:
    """Sample a piecewise-constant signal; boundaries = round(cumulative hold / dt)."""
    levels = np.asarray(levels, dtype=float)
    bounds = np.rint(np.cumsum(np.asarray(holds_s, dtype=float)) / dt).astype(np.int64)
    bounds = np.concatenate(([0], bounds))
    counts = np.diff(bounds)
    if (counts <= 0).any():
        j = int(np.flatnonzero(counts <= 0)[0])
        raise ExcitationError(
            f"segment {j} (hold {holds_s[j]:g} s) rounds to {counts[j]} samples at dt = {dt:g} s; "
            "expected at least one sample per segment"
        )
    duty = np.repeat(levels, counts)
    n = duty.size
    return ExcitationSignal(
        t=np.arange(n) * dt, duty=duty, dt=dt, kind=kind, params=params,
        levels=levels, holds=counts * dt, design=design,
    )


def _merge_equal(levels: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge consecutive segments with equal levels (PRBS runs)."""
    change = np.concatenate(([True], levels[1:] != levels[:-1]))
    starts = np.flatnonzero(change)
    merged_counts = np.add.reduceat(counts, starts)
    return levels[starts], merged_counts


# ---------------------------------------------------------------------------------- generators
def step(
    level: float, duration: float, *, initial: float = 0.0, step_time: float = 0.0,
    dt: float = SAMPLE_PERIOD_S,
) -> ExcitationSignal:
    """A single step: ``initial`` until ``step_time``, then ``level`` until ``duration``.

    Parameters
    ----------
    level : float
        Duty cycle after the step, in [0, 1].
    duration : float
        Total signal length [s], > 0.
    initial : float
        Duty cycle before the step, in [0, 1].
    step_time : float
        Instant of the step [s], in [0, duration); 0 gives a constant signal at ``level``.
    dt : float
        Sample period [s].

    Returns
    -------
    ExcitationSignal
        N = round(duration/dt) samples.

    Raises
    ------
    ExcitationError
        On a level outside [0, 1], a non-positive duration or ``step_time`` outside [0, duration).
    """
    dt = _check_dt(dt)
    params = {"level": level, "duration": duration, "initial": initial, "step_time": step_time, "dt": dt}
    level = _check_level("level", level)
    initial = _check_level("initial", initial)
    duration = _check_duration("duration", duration, dt)
    step_time = _float("step_time", step_time)
    if not (math.isfinite(step_time) and 0.0 <= step_time < duration):
        raise ExcitationError(f"step_time = {_fmt(step_time)} s must be in [0, duration = {duration:g} s)")
    if round(step_time / dt) == 0:
        return _segments_to_signal([level], [duration], dt, "step", params)
    return _segments_to_signal([initial, level], [step_time, duration - step_time], dt, "step", params)


def staircase(
    levels: Sequence[float], hold: float | Sequence[float], *, dt: float = SAMPLE_PERIOD_S,
) -> ExcitationSignal:
    """A staircase: ``levels[i]`` held for ``hold`` (or ``hold[i]``) seconds, in order.

    Parameters
    ----------
    levels : sequence of float, length M >= 1
        Duty cycles in [0, 1].
    hold : float or sequence of float (length M)
        Hold time of every level [s], or one per level; each > 0.
    dt : float
        Sample period [s].

    Returns
    -------
    ExcitationSignal
        N = round(sum(hold)/dt) samples.

    Raises
    ------
    ExcitationError
        On an empty ``levels``, a level outside [0, 1], a non-positive hold, or a ``hold``
        sequence whose length differs from ``levels``.
    """
    dt = _check_dt(dt)
    raw = np.atleast_1d(np.asarray(levels, dtype=float)).tolist()
    lv = [_check_level(f"levels[{i}]", v) for i, v in enumerate(raw)]
    if not lv:
        raise ExcitationError("levels is empty; expected at least one duty cycle in [0, 1]")
    holds = np.atleast_1d(np.asarray(hold, dtype=float))
    if holds.size == 1:
        holds = np.full(len(lv), holds[0])
    if holds.size != len(lv):
        raise ExcitationError(f"hold has {holds.size} entries; expected 1 or one per level ({len(lv)})")
    hs = [_check_duration(f"hold[{i}]", h, dt) for i, h in enumerate(holds)]
    params = {"levels": list(lv), "hold": hs, "dt": dt}
    return _segments_to_signal(lv, hs, dt, "staircase", params)


def prbs(
    order: int = 9, *, lo: float = 0.3, hi: float = 0.6, clock: int = 10, periods: int = 1,
    seed: int = 0, dt: float = SAMPLE_PERIOD_S,
) -> ExcitationSignal:
    """Maximum-length pseudo-random binary sequence between two duty-cycle levels.

    The bit sequence comes from a maximum-length linear-feedback shift register of ``order``
    bits (``scipy.signal.max_len_seq``): period 2^order − 1 bits, 2^(order−1) ones and
    2^(order−1) − 1 zeros per period (balanced to one bit). Each bit is held for ``clock``
    samples; bit 1 → ``hi``, bit 0 → ``lo``. The seed picks the (non-zero) initial register
    state, i.e. the phase of the sequence.

    Parameters
    ----------
    order : int
        Register length m (2 ... 32); the period is 2^m − 1 bits.
    lo, hi : float
        Duty cycles of bit 0 and bit 1, in [0, 1], lo < hi.
    clock : int
        Samples per bit (>= 1); bit duration = clock·dt.
    periods : int
        Number of full periods (>= 1).
    seed : int
        Seed of the initial register state.
    dt : float
        Sample period [s].

    Returns
    -------
    ExcitationSignal
        N = periods·(2^order − 1)·clock samples.

    Raises
    ------
    ExcitationError
        On bad levels, ``lo >= hi``, ``order`` outside [2, 32], ``clock`` or ``periods`` < 1.
    """
    dt = _check_dt(dt)
    lo = _check_level("lo", lo)
    hi = _check_level("hi", hi)
    if not lo < hi:
        raise ExcitationError(f"lo = {lo:g} must be < hi = {hi:g} for a binary signal")
    order, clock, periods = _int("order", order, 2, 32), _int("clock", clock, 1), _int("periods", periods, 1)
    params = {"order": order, "lo": lo, "hi": hi, "clock": clock, "periods": periods, "seed": seed, "dt": dt}
    rng = np.random.default_rng(seed)
    state = rng.integers(0, 2, size=order)
    if not state.any():
        state[rng.integers(0, order)] = 1
    period = 2**order - 1
    from scipy.signal import max_len_seq  # here: scipy.signal and .stats cost ~1 s to import

    bits, _ = max_len_seq(order, state=state, length=period * periods)
    levels = np.where(bits.astype(bool), hi, lo)
    lv, counts = _merge_equal(levels, np.full(levels.size, clock, dtype=np.int64))
    duty = np.repeat(levels, clock)
    return ExcitationSignal(
        t=np.arange(duty.size) * dt, duty=duty, dt=dt, kind="prbs", params=params,
        levels=lv, holds=counts * dt,
    )


def aprbs(
    duration: float, *, lo: float = 0.3, hi: float = 0.7, min_hold: float = 0.2, max_hold: float = 2.0,
    seed: int = 0, dt: float = SAMPLE_PERIOD_S,
) -> ExcitationSignal:
    """Amplitude-modulated PRBS: uniform random levels held for uniform random times.

    Each hold is a whole number of samples drawn uniformly in [ceil(min_hold/dt),
    floor(max_hold/dt)]; each level is drawn uniformly in [lo, hi]. The last hold is cut so the
    signal lasts exactly ``duration`` (round(duration/dt) samples); it may therefore be shorter
    than ``min_hold``.

    Parameters
    ----------
    duration : float
        Total length [s], > 0.
    lo, hi : float
        Level range, 0 <= lo <= hi <= 1.
    min_hold, max_hold : float
        Hold-time range [s], 0 < min_hold <= max_hold, with at least one whole sample between.
    seed : int
        Seed of the level and hold draws.
    dt : float
        Sample period [s].

    Returns
    -------
    ExcitationSignal

    Raises
    ------
    ExcitationError
        On bad levels/durations or a hold range that contains no whole number of samples.
    """
    dt = _check_dt(dt)
    lo = _check_level("lo", lo)
    hi = _check_level("hi", hi)
    _check_range("lo", lo, "hi", hi)
    duration = _check_duration("duration", duration, dt)
    min_hold = _check_duration("min_hold", min_hold, dt)
    max_hold = _check_duration("max_hold", max_hold, dt)
    _check_range("min_hold", min_hold, "max_hold", max_hold)
    n_min = max(1, math.ceil(min_hold / dt - 1e-9))
    n_max = math.floor(max_hold / dt + 1e-9)
    if n_max < n_min:
        raise ExcitationError(
            f"hold range [{min_hold:g}, {max_hold:g}] s contains no whole number of samples of {dt:g} s"
        )
    params = {"duration": duration, "lo": lo, "hi": hi, "min_hold": min_hold, "max_hold": max_hold,
              "seed": seed, "dt": dt}
    n_total = round(duration / dt)
    rng = np.random.default_rng(seed)
    counts: list[int] = []
    levels: list[float] = []
    used = 0
    while used < n_total:
        c = min(int(rng.integers(n_min, n_max + 1)), n_total - used)
        levels.append(float(rng.uniform(lo, hi)))
        counts.append(c)
        used += c
    cnt = np.asarray(counts, dtype=np.int64)
    duty = np.repeat(np.asarray(levels), cnt)
    return ExcitationSignal(
        t=np.arange(duty.size) * dt, duty=duty, dt=dt, kind="aprbs", params=params,
        levels=np.asarray(levels), holds=cnt * dt,
    )


def density_modulated_prbs(
    duration: float, *, lo: float = 0.0, hi: float = 1.0, min_hold: float = 0.005, max_hold: float = 0.03,
    density_lo: float = 0.3, density_hi: float = 0.7, density_min_hold: float = 0.3,
    density_max_hold: float = 2.0, seed: int = 0, dt: float = SAMPLE_PERIOD_S,
) -> ExcitationSignal:
    """Random binary signal whose local density of high holds follows a slow APRBS.

    An input designed for identifiability of the whole plant at once. Fast holds (``min_hold``
    … ``max_hold``, a few ms) switch between the two levels ``lo`` and ``hi`` and excite the
    armature and rotor dynamics above the mechanical pole, where i_a, ω₁ and v_a stop being
    collinear; the probability that a hold is high follows a slow APRBS density in
    [``density_lo``, ``density_hi``] (holds ``density_min_hold`` … ``density_max_hold``), so the
    mean thrust, and with it the pendulum, moves slowly through its angle range (pulse-density
    modulation of a slow APRBS). On ``thesis_sim`` at 50 dB the Cramér-Rao bound of R_a/L_a
    on 22.5 s is 0.72 % with the defaults, against 6.3 % for an APRBS with 20-300 ms holds and
    48 % for the thesis' Latin-hypercube steps (bench/bench_design_crb.py).

    Parameters
    ----------
    duration : float
        Total length [s], > 0.
    lo, hi : float
        The two duty-cycle levels, 0 <= lo <= hi <= 1.
    min_hold, max_hold : float
        Range [s] of the fast binary holds (uniform in whole samples, as in :func:`aprbs`).
    density_lo, density_hi : float
        Range of the slow density (probability of ``hi``), 0 <= density_lo <= density_hi <= 1.
    density_min_hold, density_max_hold : float
        Hold-time range [s] of the slow density APRBS.
    seed : int
        Seed; the fast and the slow draws use independent streams spawned from it.
    dt : float
        Sample period [s].

    Returns
    -------
    ExcitationSignal
        ``levels``/``holds`` are the binary segments (consecutive equal holds merged).

    Raises
    ------
    ExcitationError
        On bad levels, densities or durations, as :func:`aprbs`.
    """
    dt = _check_dt(dt)
    lo = _check_level("lo", lo)
    hi = _check_level("hi", hi)
    _check_range("lo", lo, "hi", hi)
    density_lo = _check_level("density_lo", density_lo)
    density_hi = _check_level("density_hi", density_hi)
    _check_range("density_lo", density_lo, "density_hi", density_hi)
    fast_seed, slow_seed = (int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(2))
    density = aprbs(duration, lo=density_lo, hi=density_hi, min_hold=density_min_hold,
                    max_hold=density_max_hold, seed=slow_seed, dt=dt)
    draw = aprbs(duration, lo=0.0, hi=1.0, min_hold=min_hold, max_hold=max_hold, seed=fast_seed, dt=dt)
    fast_counts = np.rint(draw.holds / dt).astype(np.int64)
    starts = np.concatenate(([0], np.cumsum(fast_counts)[:-1]))
    high = draw.levels < density.duty[starts]  # a hold is high with the density at its start
    levels, counts = _merge_equal(np.where(high, hi, lo), fast_counts)
    params = {"duration": density.params["duration"], "lo": lo, "hi": hi, "min_hold": draw.params["min_hold"],
              "max_hold": draw.params["max_hold"], "density_lo": density_lo, "density_hi": density_hi,
              "density_min_hold": density.params["min_hold"], "density_max_hold": density.params["max_hold"],
              "seed": seed, "dt": dt}
    duty = np.repeat(levels, counts)
    return ExcitationSignal(
        t=np.arange(duty.size) * dt, duty=duty, dt=dt, kind="density_prbs", params=params,
        levels=levels, holds=counts * dt,
    )


def lhs_steps(
    n: int = 10, *, tau_min: float = 0.35, tau_max: float = 0.65, hold_min: float = 1.0,
    hold_max: float = 5.0, seed: int = 0, dt: float = SAMPLE_PERIOD_S,
) -> ExcitationSignal:
    """Latin-hypercube step design of thesis §5.1.

    The input space τ ∈ [tau_min, tau_max] × T ∈ [hold_min, hold_max] is partitioned into ``n``
    equal intervals along each axis; ``scipy.stats.qmc.LatinHypercube`` draws ``n`` points such
    that each interval of τ and each interval of T contains exactly one point. Point i is a step
    to duty τ_i held for T_i seconds; the steps are concatenated in the order drawn (the thesis
    uses n = 10).

    Parameters
    ----------
    n : int
        Number of intervals per axis = number of steps (>= 1).
    tau_min, tau_max : float
        Duty-cycle range, 0 <= tau_min < tau_max <= 1.
    hold_min, hold_max : float
        Step-duration range [s], 0 < hold_min < hold_max.
    seed : int
        Seed of the Latin-hypercube sampler (``rng=seed``).
    dt : float
        Sample period [s]; each T_i is rounded to the sample grid via the cumulative sum.

    Returns
    -------
    ExcitationSignal
        ``design`` holds the n drawn points (τ_i, T_i), shape (n, 2); ``levels``/``holds`` the
        steps after rounding to whole samples.

    Raises
    ------
    ExcitationError
        On levels outside [0, 1], empty ranges or non-positive durations.
    """
    dt = _check_dt(dt)
    n = _int("n", n, 1)
    tau_min = _check_level("tau_min", tau_min)
    tau_max = _check_level("tau_max", tau_max)
    if not tau_min < tau_max:
        raise ExcitationError(f"tau_min = {tau_min:g} must be < tau_max = {tau_max:g}")
    hold_min = _check_duration("hold_min", hold_min, dt)
    hold_max = _check_duration("hold_max", hold_max, dt)
    if not hold_min < hold_max:
        raise ExcitationError(f"hold_min = {hold_min:g} s must be < hold_max = {hold_max:g} s")
    params = {"n": n, "tau_min": tau_min, "tau_max": tau_max, "hold_min": hold_min, "hold_max": hold_max,
              "seed": seed, "dt": dt}
    from scipy.stats import qmc  # here: scipy.signal and .stats cost ~1 s to import

    unit = qmc.LatinHypercube(d=2, rng=seed).random(n)
    design = qmc.scale(unit, [tau_min, hold_min], [tau_max, hold_max])
    return _segments_to_signal(design[:, 0], design[:, 1], dt, "lhs", params, design=design)


#: Second-column headers of a CSV that holds an angle, not a duty cycle (a closed-loop design's
#: ``t,reference``): :func:`from_file` refuses to play them.
ANGLE_COLUMNS = frozenset({"reference", "theta", "theta_ref", "set_point", "setpoint"})


def from_file(file: str, dt: float | None = None) -> ExcitationSignal:
    """A duty-cycle sequence read from a CSV of time [s] and duty [1] (``kind="file"``).

    Two numeric columns ``t,duty`` (one optional header line; ``#`` comment lines skipped), ``t``
    strictly increasing on a uniform grid (within 1 % of the median step, which becomes ``dt``),
    every duty finite and in [0, 1]. The format of :meth:`ExcitationSignal.to_csv` and of
    ``excitation_design``'s ``design.csv``.

    Parameters
    ----------
    file : str
        Path of the CSV file.
    dt : float, optional
        The period the player expects [s]; the file's must agree within 1 % (unset: the file's).

    Returns
    -------
    ExcitationSignal

    Raises
    ------
    ExcitationError
        On a missing or unreadable file, fewer than two rows, a non-numeric cell, a non-uniform or
        non-increasing time column, a duty outside [0, 1], a period other than ``dt``, or a header
        naming an angle column (:data:`ANGLE_COLUMNS`: a closed-loop design's set points).
    """
    try:
        with open(file, encoding="utf-8-sig") as fh:
            text = fh.read()
    except OSError as exc:
        raise ExcitationError(f"file {file!r}: {exc.strerror or exc}") from None
    rows: list[tuple[float, float]] = []
    first = True
    for i, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        cells = [c.strip() for c in line.split(",")]
        try:
            t, d = float(cells[0]), float(cells[1])
        except (ValueError, IndexError):
            if first:
                first = False
                if len(cells) > 1 and cells[1].lower() in ANGLE_COLUMNS:
                    raise ExcitationError(
                        f"file {file!r}: its second column is {cells[1]!r}, an angle [rad], not a duty "
                        "cycle: a closed-loop design's set points are for the controller (controller "
                        "--ros-args --params-file design_controller.yaml), never to be played as commands"
                    ) from None
                continue  # the header line
            raise ExcitationError(
                f"file {file!r} line {i}: expected two numbers t,duty, got {line!r}") from None
        first = False
        rows.append((t, d))
    if len(rows) < 2:
        raise ExcitationError(f"file {file!r}: fewer than two rows of t,duty")
    arr = np.asarray(rows, dtype=float)
    t, duty = arr[:, 0], arr[:, 1]
    steps = np.diff(t)
    step = float(np.median(steps))
    if not (np.all(np.isfinite(arr)) and step > 0.0 and np.all(np.abs(steps - step) <= 0.01 * step)):
        raise ExcitationError(f"file {file!r}: the time column must increase on a uniform grid (median step "
                              f"{step:g} s, steps from {steps.min():g} to {steps.max():g} s)")
    if dt is not None and abs(_check_dt(dt) - step) > 0.01 * dt:
        raise ExcitationError(f"file {file!r}: its period {step:g} s is not dt = {dt:g} s")
    dt = step
    bad = np.flatnonzero((duty < 0.0) | (duty > 1.0))
    if bad.size:
        raise ExcitationError(
            f"file {file!r}: duty {duty[bad[0]]:g} at t = {t[bad[0]]:g} s is outside [0, 1]")
    levels, counts = _merge_equal(duty, np.ones(duty.size, dtype=np.int64))
    return ExcitationSignal(t=np.arange(duty.size) * dt, duty=duty.copy(), dt=dt, kind="file",
                            params={"file": str(file), "dt": dt}, levels=levels, holds=counts * dt)


def _int(name: str, value: Any, lo: int, hi: int | None = None) -> int:
    try:
        f = float(value)
    except (TypeError, ValueError) as exc:
        raise ExcitationError(f"{name} = {value!r} is not an integer") from exc
    if not f.is_integer():
        raise ExcitationError(f"{name} = {_fmt(value)} is not an integer")
    i = int(f)
    if i < lo or (hi is not None and i > hi):
        rng = f">= {lo}" if hi is None else f"in [{lo}, {hi}]"
        raise ExcitationError(f"{name} = {i} must be {rng}")
    return i


# ---------------------------------------------------------------------------------- dispatcher
#: Signal kinds accepted by :func:`make_signal` ("lhs" is the thesis §5.1 design).
SIGNALS: dict[str, Callable[..., ExcitationSignal]] = {
    "step": step,
    "staircase": staircase,
    "prbs": prbs,
    "aprbs": aprbs,
    "density_prbs": density_modulated_prbs,
    "lhs": lhs_steps,
    "file": from_file,
}


def signal_parameters(kind: str) -> dict[str, Any]:
    """Parameter names of a signal kind and their defaults (``inspect.Parameter.empty`` if required).

    Raises
    ------
    ExcitationError
        If ``kind`` is unknown.
    """
    fn = _lookup(kind)
    return {p.name: p.default for p in inspect.signature(fn).parameters.values()}


def _lookup(kind: str) -> Callable[..., ExcitationSignal]:
    try:
        return SIGNALS[str(kind).strip().lower()]
    except KeyError:
        raise ExcitationError(f"unknown signal kind {kind!r}; expected one of {sorted(SIGNALS)}") from None


def make_signal(kind: str, **params: Any) -> ExcitationSignal:
    """Build a signal by kind name (for command-line tools and node parameters).

    Parameters
    ----------
    kind : str
        One of :data:`SIGNALS` (``step``, ``staircase``, ``prbs``, ``aprbs``, ``density_prbs``, ``lhs``).
    **params
        Arguments of the generator; ``None`` values are dropped (use the default).

    Raises
    ------
    ExcitationError
        On an unknown kind, unknown or missing parameters, or invalid values.

    Examples
    --------
    >>> sig = make_signal("staircase", levels=[0.3, 0.5], hold=2.0)
    >>> len(sig), round(sig.duration, 6)
    (1953, 3.999744)
    """
    fn = _lookup(kind)
    sig = inspect.signature(fn)
    given = {k: v for k, v in params.items() if v is not None}
    unknown = sorted(set(given) - set(sig.parameters))
    if unknown:
        raise ExcitationError(
            f"signal {kind!r} has no parameter(s) {unknown}; expected some of {list(sig.parameters)}"
        )
    required = [p.name for p in sig.parameters.values() if p.default is inspect.Parameter.empty]
    missing = [name for name in required if name not in given]
    if missing:
        raise ExcitationError(f"signal {kind!r} needs parameter(s) {missing}")
    return fn(**given)
