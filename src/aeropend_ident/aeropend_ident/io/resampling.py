"""The one resampling of every command: a lab's log onto a uniform time grid.

:func:`uniform_recording` is the resampling of ``baseline``, ``identify``, ``gap``, ``compare``,
``csv_import --resample`` and of the fits (the grey-box :func:`aeropend_ident.greybox.uniform.uniform_data`,
the gap diagnosis' channels): a lab's logger jitters, drops rows and pauses, and none of that is
refused. The rule (:data:`RESAMPLING_RULE`): each row belongs to the regular instant its stamp
scatters about (:func:`regular_sampling`; the grid step the rig's sampling period), so the command,
the reference and the measured channels are the row's own; over a dropped row or a gap the command
and the reference are held (zero-order hold), measured channels interpolated linearly, a quantised
channel (:func:`detect_quantum`) taken at its nearest sample (not smoothed). Stamps that do not
scatter about regular instants (a logger that restarts at another phase after a pause) are the
sample instants: the grid step is then their median (regular) interval and the measurements are
interpolated from them. Jitter, dropped rows (intervals up to :data:`GAP_STEPS` steps) and gaps
(longer intervals) are reported in one line (:class:`Resampling`, :func:`resampling_notes`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.errors import RecordingInputError
from aeropend_sim.contract import REFERENCE_CHANNEL
from aeropend_sim.recording import Recording

#: Relative deviation of a sample interval from the grid step within which a log counts as uniform
#: (no resampling).
UNIFORM_TOLERANCE = 1e-3
#: Intervals of up to this many grid steps are dropped rows (their samples are filled on the grid);
#: longer ones are gaps, reported with where they are and how long.
GAP_STEPS = 5.0
#: Intervals shorter than this many grid steps are the logger's jitter about the grid step.
JITTER_STEPS = 1.5
#: Share of the intervals from which those of :data:`JITTER_STEPS` to :data:`GAP_STEPS` grid steps
#: are the logger's own uneven timing (a 600 Hz logger that writes every 1 or 3 ms), not dropped
#: rows: a dropped row is a rare event (a full buffer, a missed interrupt), not one interval in twenty.
UNEVEN_SHARE = 0.05


@dataclass(frozen=True)
class Resampling:
    """What :func:`uniform_recording` did to a recording's time base (the report line of every command).

    Attributes
    ----------
    source : str
        The recording.
    dt : float
        Grid step [s]: the rig's sampling period when the stamps scatter about regular instants
        (:attr:`regular`), else the median sample interval (or the one asked for).
    rows_in, rows_out : int
        Samples before and after.
    jitter_rms, jitter_max : float
        RMS and largest deviation [s] of the regular intervals (shorter than :data:`JITTER_STEPS`·dt)
        from the grid step.
    dropped_rows : int
        Missing samples inside intervals of :data:`JITTER_STEPS` to :data:`GAP_STEPS` grid steps
        (round(Δ/dt) − 1 each), filled on the grid.
    gaps : tuple of (float, float)
        (start [s], length [s]) of every interval longer than :data:`GAP_STEPS`·dt: bridged like the
        rest (command held, measurements interpolated) and reported.
    held_channels : tuple of str
        Quantised measured channels (values on a lattice k·q, :func:`detect_quantum`) taken at the
        nearest sample instead of interpolated, so they stay on their lattice.
    long_share : float
        Share of the intervals that are :data:`JITTER_STEPS` to :data:`GAP_STEPS` grid steps long;
        above :data:`UNEVEN_SHARE` the log's timing is uneven (:attr:`uneven`) and the samples filled
        between such intervals are not called dropped rows.
    regular : bool
        Whether the rows were placed at the regular instants their stamps scatter about
        (:func:`regular_sampling`), each with its command and measurements, rather than
        interpolated from their stamps.
    """

    source: str
    dt: float
    rows_in: int
    rows_out: int
    jitter_rms: float
    jitter_max: float
    dropped_rows: int
    gaps: tuple[tuple[float, float], ...]
    held_channels: tuple[str, ...]
    long_share: float = 0.0
    regular: bool = False

    @property
    def uneven(self) -> bool:
        """Whether the log's own timing is uneven (:data:`UNEVEN_SHARE`): its longer intervals are
        how the logger writes, not rows it lost."""
        return self.long_share > UNEVEN_SHARE

    def note(self) -> str:
        """One line for a command's summary, e.g. ``resampled jitter100.csv onto a uniform 10 ms grid
        (the median regular interval): 5822 rows -> 6000 samples; jitter RMS 0.87 ms (max 1.5 ms); 178 dropped
        rows filled; command of the nearest row (held over dropped rows), measurements interpolated``."""
        name = Path(self.source).name or self.source or "the recording"
        parts = [f"{self.rows_in} rows -> {self.rows_out} samples",
                 f"jitter RMS {_ms(self.jitter_rms)} (max {_ms(self.jitter_max)})"]
        if self.dropped_rows and self.uneven:
            parts.append(f"uneven timing: {self.long_share:.0%} of the intervals are "
                         f"{JITTER_STEPS:g}-{GAP_STEPS:g} grid steps long (how the logger writes, not "
                         f"dropped rows); {self.dropped_rows} grid sample(s) filled between them")
        elif self.dropped_rows:
            parts.append(f"{self.dropped_rows} dropped row(s) filled")
        if self.gaps:
            start, length = max(self.gaps, key=lambda g: g[1])
            total = sum(g[1] for g in self.gaps)
            share = total / max(self.rows_out - 1, 1) / self.dt
            parts.append(f"{len(self.gaps)} gap(s) longer than {_ms(GAP_STEPS * self.dt)} bridged "
                         f"({total:.3g} s in all, {share:.0%} of the log; the longest {length:.3g} s at "
                         f"t = {start:.3f} s)")
        held = f"; {', '.join(self.held_channels)} quantised: nearest sample, not interpolated" \
            if self.held_channels else ""
        over = "the longer intervals" if self.uneven else "dropped rows"
        if self.regular:
            return (f"resampled {name} onto the {_ms(self.dt)} sampling instants its stamps scatter "
                    f"about: {'; '.join(parts)}; command and measurements of the row at each instant "
                    f"(command held, measurements interpolated over {over}){held}")
        return (f"resampled {name} onto a uniform {_ms(self.dt)} grid (the median regular "
                f"interval): {'; '.join(parts)}; command of the nearest row (held over {over}), "
                f"measurements interpolated{held}")

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (``meta["resampling"]`` of the resampled recording)."""
        return {"rule": RESAMPLING_RULE, "dt_s": self.dt, "regular_instants": self.regular,
                "rows_in": self.rows_in, "rows_out": self.rows_out,
                "jitter_rms_s": self.jitter_rms, "jitter_max_s": self.jitter_max,
                "dropped_rows": self.dropped_rows, "long_interval_share": self.long_share,
                "uneven_timing": self.uneven,
                "gaps": [{"t_s": a, "length_s": b} for a, b in self.gaps],
                "held_channels": list(self.held_channels), "note": self.note()}


#: Rows per running median of the stamps' offsets from their regular instants (:func:`regular_sampling`).
SLOT_WINDOW = 25
#: Largest running median offset [share of the period] of stamps that scatter about regular instants.
SLOT_OFFSET_TOL = 0.1


#: The resampling rule in words (docs/csv_import.md, "Timing"; ``meta["resampling"]["rule"]``).
RESAMPLING_RULE = (
    "stamps that scatter about regular instants (each row in a slot of its own, every running median "
    f"of {SLOT_WINDOW} offsets within {SLOT_OFFSET_TOL:g} period): grid t_k = t_0 + k*T, the least-squares "
    "line through the stamps over their slots; each row at its slot's instant with its command and "
    "measurements; empty slots (dropped rows, gaps): the command (duty) and a reference held from the "
    "row before, measured channels interpolated linearly between the slots around, a quantised channel "
    "by its nearest sample. Other stamps: grid t_k = t_0 + phi + k*dt, dt = the median regular interval, "
    "phi the median offset of the stamps from the grid through the first sample (within +-dt/2; 0 when "
    "dt is imposed from another recording); the command and a reference: the sample stamped within "
    "dt/2 of t_k (the nearest), else the last sample at or before t_k; measured channels by linear "
    "interpolation from the stamps, a quantised channel by its nearest sample. Intervals up to "
    f"{GAP_STEPS:g} dt are jitter or dropped rows, longer ones gaps (reported, bridged the same way)")


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.3g} ms"


#: Largest deviation of a printed value from the fitted lattice, in steps q, for a channel whose
#: values were written with a few decimals (:func:`detect_quantum`): a 1.534 mrad step printed to
#: 1e-6 rad deviates by 3e-4 q; a continuous channel held for several samples fills the interval
#: between its distinct values and deviates by up to q/2.
PRINTED_LATTICE_TOL = 0.02


def detect_quantum(y: np.ndarray) -> float:
    """LSB q of a recorded channel if its values lie on a lattice k·q (+ constant), else 0.

    The lattice step is the smallest gap between distinct values; the channel counts as quantised
    when every value sits within 1e-3·q of the lattice and there are fewer distinct values than a
    third of the samples. A log written with a few decimals moves each value off the lattice by its
    printing's rounding (AeroShield's 1.534 mrad step printed to 1e-6 rad: one-step gaps of 1.533 and
    1.534 mrad), so that the smallest gap is not q and the lattice drifts away from the values over
    hundreds of steps; then q is the least-squares slope of the distinct values on their step
    indices (each gap counted in median one-step gaps), and the channel counts as quantised when
    every distinct value sits within :data:`PRINTED_LATTICE_TOL`·q of that lattice. Read by the
    resampling (a quantised channel is not interpolated) and by the gap diagnosis (the
    ``quantisation`` effect: a property of the recording, never fitted; its noise floor q/√12).

    Parameters
    ----------
    y : ndarray, shape (n,)
        Recorded channel (e.g. θ [rad]).

    Returns
    -------
    float
        q in the channel's unit; 0.0 when the values are not on a lattice (or too few).
    """
    y = np.asarray(y, dtype=float)
    u = np.unique(np.round(y, 12))
    if u.size < 3 or u.size > y.size / 3:
        return 0.0
    gaps = np.diff(u)
    q = float(np.min(gaps[gaps > 1e-12])) if np.any(gaps > 1e-12) else 0.0
    if q <= 0.0:
        return 0.0
    frac = (y - u[0]) / q
    if np.max(np.abs(frac - np.round(frac))) <= 1e-3:
        return q
    return _printed_lattice(u, gaps, q)


def _printed_lattice(u: np.ndarray, gaps: np.ndarray, smallest: float) -> float:
    """The step of a lattice whose distinct values ``u`` (sorted) were printed with a few decimals,
    0.0 when they do not lie on one (:func:`detect_quantum`)."""
    one = gaps[(gaps > 1e-12) & (gaps <= 1.5 * smallest)]  # one-step gaps, scattered by the rounding
    if one.size < 2:
        return 0.0
    steps = np.round(gaps / float(np.median(one)))  # each gap in steps: its rounding error stays in it
    if np.any(steps < 1):  # two distinct values on one lattice point: no lattice
        return 0.0
    k = np.concatenate([[0.0], np.cumsum(steps)])
    slope, intercept = np.polyfit(k, u, 1)
    q = float(slope)
    if q <= 0.0 or np.max(np.abs(u - (intercept + q * k))) > PRINTED_LATTICE_TOL * q:
        return 0.0
    return q


def uniform_recording(rec: Recording, dt: float | None = None) -> Recording:
    """The recording on a uniform time grid: the one resampling of every command.

    The rule (:data:`RESAMPLING_RULE`): when the stamps scatter about regular instants
    (:func:`regular_sampling`), the grid is those instants and each row sits at its own with its
    duty cycle, its reference ``theta_ref`` and its measured channels (θ, the contract channels,
    the extra channels); an empty slot (a dropped row, a gap) holds the duty and the reference of
    the row before it and interpolates the measured channels linearly between the slots around it.
    Other stamps are the sample instants: grid t_k = φ + k·dt, dt the median interval unless given,
    φ where the stamps scatter about (:func:`grid_phase`; through the first sample when dt is given
    and differs from the recording's own), the duty and the reference of the row stamped within
    dt/2 of t_k, else held from the last row before it (:func:`uniform_grid`), the measured
    channels interpolated from the stamps. A quantised measured channel (:func:`detect_quantum`)
    takes its nearest sample either way, so that it stays on its lattice. The result's time starts
    at 0. Timestamp jitter, dropped rows and gaps are measured and reported (:class:`Resampling` in
    ``meta["resampling"]``, :func:`resampling_notes`), never refused. A recording whose intervals
    are all within :data:`UNIFORM_TOLERANCE` of dt is returned unchanged (:func:`on_grid`).
    A constant input is accepted here (a step from rest or a free decay is a valid recording); the
    fits decide what the data can identify.

    Parameters
    ----------
    rec : Recording
    dt : float, optional
        Grid step [s] (default: the rig's sampling period when the stamps scatter about regular
        instants, :func:`regular_sampling`, else :func:`grid_step`, the median regular interval). A
        step other than the recording's own forces resampling (e.g. several recordings onto one
        grid); one within :data:`UNIFORM_TOLERANCE` of the rig's period keeps each row at its own
        slot on the step asked for (a clock rate error of at most 0.1 %); another resamples the
        rows' sampling instants (the stamps, or the regular instants they scatter about) onto it.

    Returns
    -------
    Recording
        ``rec`` itself when it is already on the grid, else a new recording with ``t`` from 0.

    Raises
    ------
    RecordingInputError
        No θ, NaNs in θ, the duty or a contract channel, fewer than 2 samples, time stamps out of
        order, or a grid step that is not finite and > 0 (the message names the recording).
    """
    src = rec.source or "<recording>"
    if "theta" not in rec.channels:
        raise RecordingInputError(
            f"{src}: recording lacks the 'theta' channel (has {sorted(rec.channels)}); the tools "
            "need at least the angle and the duty cycle"
        )
    for name, y in [("duty", rec.duty), *rec.channels.items()]:
        bad = ~np.isfinite(y)
        if bad.any():
            raise RecordingInputError(
                f"{src}: {name} has {int(bad.sum())} NaN/inf value(s), first at sample "
                f"{int(np.flatnonzero(bad)[0])}; repair or cut the recording"
            )
    t = rec.t - rec.t[0]
    if t.size < 2 or not np.all(np.diff(t) > 0.0):
        raise RecordingInputError(f"{src}: {t.size} sample(s) or non-increasing time stamps; expected at "
                                  "least 2 samples in time order")
    median = grid_step(t)
    step = median if dt is None else float(dt)
    if not (math.isfinite(step) and step > 0.0):
        raise RecordingInputError(f"{src}: grid step dt = {dt!r}; expected a finite value > 0 s")
    if on_grid(t, step):
        return rec
    regular = regular_sampling(t, median)
    placed = regular is not None and (dt is None or abs(step - regular.period) <= UNIFORM_TOLERANCE * step)
    if placed:  # the rows at their instants, on the period asked for (within UNIFORM_TOLERANCE of theirs)
        regular = replace(regular, period=step) if dt is not None else regular
        (tu, idx), at, step = regular.grid(), regular.instants, regular.period
    elif regular is not None:  # a period imposed from another recording: the rows' instants onto its grid
        at = regular.instants
        tu, idx = _grid(at - at[0], step, align=False)
        tu = tu + at[0]
    else:
        (tu, idx), at = _grid(t, step, align=dt is None or abs(step - median) <= UNIFORM_TOLERANCE * step), t
    nearest = np.clip(np.searchsorted(at, tu, side="left"), 1, t.size - 1)
    nearest -= (tu - at[nearest - 1]) < (at[nearest] - tu)
    held = tuple(k for k, v in rec.channels.items() if detect_quantum(v) > 0.0)

    def measured(name: str, v: np.ndarray) -> np.ndarray:
        return v[nearest] if name in held else np.interp(tu, at, v)

    ch = {k: measured(k, v) for k, v in rec.channels.items()}
    # a set point (the reference) holds between samples like the duty; measured channels are interpolated
    extra = {k: v[idx] if k == REFERENCE_CHANNEL else measured(k, v) for k, v in rec.extra.items()}
    report = _timing_report(src, t, step, tu.size, held, placed)
    meta = {**rec.meta, "resampling": report.as_dict()}
    return Recording(
        t=tu - tu[0], duty=rec.duty[idx], channels=ch, source=rec.source, stamp0_ns=rec.stamp0_ns, meta=meta,
        extra=extra, extra_units=dict(rec.extra_units),
    )


def grid_step(t: np.ndarray) -> float:
    """The grid step [s] of time stamps ``t``: the median of the regular intervals (those shorter
    than :data:`JITTER_STEPS` times the median interval, so that dropped rows do not lengthen it).

    Parameters
    ----------
    t : ndarray, shape (N,), N >= 2
        Increasing time stamps [s].
    """
    d = np.diff(np.asarray(t, dtype=float))
    first = float(np.median(d))
    regular = d[d < JITTER_STEPS * first]
    return float(np.median(regular)) if regular.size else first


def grid_phase(t: np.ndarray, dt: float) -> float:
    """Offset [s] of a uniform grid of period ``dt`` from the grid through the first stamp: the median
    of each stamp's offset from its nearest grid point, in [−dt/2, dt/2].

    A logger whose host stamps each row when it arrives scatters the stamps about the instants the
    rig sampled at; the first stamp is as late or early as any other, so a grid through it is off by
    its own jitter (a constant shift of the measurements against the commands). The median offset of
    all stamps puts the grid where they scatter about (dropped rows keep their place: offsets are
    taken from the nearest grid point).

    Parameters
    ----------
    t : ndarray, shape (N,)
        Increasing time stamps [s] starting at 0.
    dt : float
        Grid period [s] (> 0).
    """
    t = np.asarray(t, dtype=float)
    return float(np.median(t - dt * np.round(t / dt)))


def uniform_grid(t: np.ndarray, dt: float, align: bool = True) -> tuple[np.ndarray, np.ndarray] | None:
    """The uniform grid of period ``dt`` over time stamps ``t``, or None if ``t`` is on it.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Increasing time stamps [s] starting at 0.
    dt : float
        Grid period [s] (> 0).
    align : bool
        Place the grid where the stamps scatter about (:func:`grid_phase`); False: through the first
        stamp (a grid period imposed from another recording, about which these stamps do not scatter).

    Returns
    -------
    (t_grid, idx) or None
        The grid instants ``t_grid = φ + k·dt`` (φ the phase, 0 unaligned) up to ``t[-1]`` on the
        stamps' clock and, per grid instant, the row of the command there: the row stamped within
        dt/2 of it (the nearest; with stamp jitter of a few % of dt, row k for instant k), else the
        last row at or before it (zero-order hold over a dropped row or a gap). Holding the last row
        at or before each instant instead would give about half the rows of a jittered log to the
        next instant, a command one whole sample late; None when every interval of ``t`` is within
        ±UNIFORM_TOLERANCE of ``dt`` (no resampling needed).
    """
    return None if on_grid(t, dt) else _grid(t, dt, align)


def on_grid(t: np.ndarray, dt: float) -> bool:
    """Whether every interval of time stamps ``t`` is within ±:data:`UNIFORM_TOLERANCE` of ``dt``
    (no resampling needed)."""
    return bool(np.all(np.abs(np.diff(t) - dt) <= UNIFORM_TOLERANCE * dt))


def _grid(t: np.ndarray, dt: float, align: bool) -> tuple[np.ndarray, np.ndarray]:
    """:func:`uniform_grid` without its on-grid test."""
    phase = grid_phase(t, dt) if align else 0.0
    tu = phase + np.arange(math.floor((t[-1] - phase) / dt + 1e-9) + 1) * dt
    hold = np.clip(np.searchsorted(t, tu + 1e-9 * dt, side="right") - 1, 0, t.size - 1)
    after = np.clip(hold + 1, 0, t.size - 1)
    near = np.where(np.abs(t[after] - tu) < np.abs(t[hold] - tu), after, hold)
    idx = np.where(np.abs(t[near] - tu) <= 0.5 * dt * (1 + 1e-9), near, hold)
    return tu, idx


@dataclass(frozen=True)
class RegularSampling:
    """The regular instants a jittered logger's stamps scatter about (:func:`regular_sampling`).

    Attributes
    ----------
    t0 : float
        Instant [s] of slot 0 on the stamps' clock.
    period : float
        The rig's sampling period [s].
    slot : ndarray of int, shape (N,)
        Each row's slot (increasing from 0; a dropped row leaves its slot empty).
    """

    t0: float
    period: float
    slot: np.ndarray

    @property
    def instants(self) -> np.ndarray:
        """Each row's sampling instant [s], shape (N,): ``t0 + slot·period``."""
        return self.t0 + self.slot * self.period

    def grid(self) -> tuple[np.ndarray, np.ndarray]:
        """(every slot's instant [s], shape (K,); the row of each slot, or the last row before it)."""
        k = np.arange(int(self.slot[-1]) + 1)
        return self.t0 + k * self.period, np.searchsorted(self.slot, k, side="right") - 1


def regular_sampling(t: np.ndarray, dt: float) -> RegularSampling | None:
    """The regular instants time stamps ``t`` scatter about, or None if they do not (or sit on them).

    A rig samples on its timer; a logger that stamps each row when it arrives scatters the stamps
    about those instants. The row's command and measurements belong to its instant, so the
    resampling takes both from the row in each slot (:func:`uniform_recording`). Interpolating the
    measurements from the stamps instead moves each by its rate times its stamp's error while its
    command stays in the slot (the angle by about θ̇·δt: 9 times the noise RMS of a fast-switching
    recording at 50 Hz with σ 3 % of the period, bench/repro/design_stamp_jitter.py). The instants
    are a straight line through the stamps over their slots (least squares; the slots counted
    interval by interval in grid steps ``dt``, then renumbered from the line until they stay): the
    median interval is off the period by its own scatter, 1.5e-4 of it for 1 500 rows at σ 4 %,
    which puts the last rows of a long log 0.2 of a period off their slots.

    The stamps scatter about the line when each row has a slot of its own and every running median
    (:data:`SLOT_WINDOW` rows) of their offsets from it is within :data:`SLOT_OFFSET_TOL` periods.
    They do not when the logger restarts at another phase after a pause (cychitivav's free decay:
    0.4 period after each 25-period gap) or when two rows share a slot: then the stamps are the
    instants. Stamps rounded to the logger's clock (matheusbucater's millisecond stamps of a 16.13 ms
    period: 16 and 17 ms intervals) scatter about the line like any jitter.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Increasing time stamps [s] starting at 0.
    dt : float
        Grid step [s] (:func:`grid_step`).

    Returns
    -------
    RegularSampling or None
        None also when every stamp is within :data:`UNIFORM_TOLERANCE`·dt of the grid through the
        first one (no jitter: dropped rows only).
    """
    # imported here, not with the module: scipy.ndimage costs every command 0.3 s to start
    from scipy.ndimage import median_filter

    t = np.asarray(t, dtype=float)
    slot = np.round(t / dt)
    if t.size < 3 or np.all(np.abs(t - slot * dt) <= UNIFORM_TOLERANCE * dt):
        return None
    slot = np.concatenate([[0.0], np.cumsum(np.round(np.diff(t) / dt))])  # each interval's own count
    for _ in range(3):
        if not np.all(np.diff(slot) > 0):
            return None
        period, t0 = np.polyfit(slot, t, 1)
        again = np.round((t - t0) / period)
        if np.array_equal(again, slot):
            break
        slot = again
    else:
        return None
    offset = median_filter(t - (t0 + slot * period), size=min(SLOT_WINDOW, t.size), mode="nearest")
    if np.max(np.abs(offset)) > SLOT_OFFSET_TOL * period:
        return None
    return RegularSampling(t0=float(t0), period=float(period), slot=slot.astype(int))


def _timing_report(src: str, t: np.ndarray, dt: float, rows_out: int, held: tuple[str, ...],
                   regular: bool = False) -> Resampling:
    """Jitter, dropped rows and gaps of time stamps ``t`` about the grid step ``dt``."""
    d = np.diff(t)
    short = d[d < JITTER_STEPS * dt]
    dev = np.abs(short - dt) if short.size else np.zeros(1)
    dropped = d[(d >= JITTER_STEPS * dt) & (d <= GAP_STEPS * dt)]
    long = np.flatnonzero(d > GAP_STEPS * dt)
    return Resampling(
        source=src, dt=dt, rows_in=int(t.size), rows_out=int(rows_out),
        jitter_rms=float(np.sqrt(np.mean(dev**2))), jitter_max=float(np.max(dev)),
        dropped_rows=int(np.sum(np.round(dropped / dt) - 1.0)),
        gaps=tuple((float(t[k]), float(d[k])) for k in long), held_channels=held,
        long_share=float(dropped.size / max(d.size, 1)), regular=regular,
    )


def resampling_notes(recs: Sequence[Recording]) -> list[str]:
    """The report lines of the recordings :func:`uniform_recording` resampled (empty list: none was).

    Parameters
    ----------
    recs : sequence of Recording
        Recordings as the command used them.
    """
    return [r.meta["resampling"]["note"] for r in recs if isinstance(r.meta.get("resampling"), dict)]
