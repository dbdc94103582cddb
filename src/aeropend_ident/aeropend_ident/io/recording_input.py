"""Recording arguments of the command-line tools: a bag or a CSV log, each with its own preset.

Every recording argument of ``compare``, ``gap``, ``baseline`` and ``identify`` is one of

* a rosbag2 directory, ``.mcap`` or ``.db3`` file (read with :func:`aeropend_ident.io.bags.read_bag`);
* a CSV log (``.csv``, ``.csv.gz``, ``.txt``) read with :func:`aeropend_ident.io.csv_import.import_csv`
  and a preset: ``FILE.csv:PRESET`` names the preset of this file, a shipped preset's name (e.g.
  ``Identification_Data2.csv:aeroshield_ident2``) or a lab's preset file (``log.csv:my_rig.yaml``,
  docs/csv_import.md); ``FILE.csv`` alone uses the tool's ``--preset`` (a name or a file) or,
  without one (or with ``auto``), the shipped preset whose file patterns match the name.

So recordings of different formats can be mixed in one call. Channels a tool does not use (the
extra channels: a second axis, a closed loop's reference, ...) are kept in the recording and
ignored; :func:`ignored_channels` says which, for the tools' summaries. :func:`load_and_split` reads the
``gap`` tool's recordings and makes its held-out design (:mod:`aeropend_ident.io.split`).

**Timing.** :func:`uniform_recording` is the one resampling of every command (``baseline``,
``identify``, ``gap``, ``compare``, ``csv_import --resample``) and of the fits (the grey-box
:func:`aeropend_ident.greybox.uniform.uniform_data`, the gap diagnosis' channels): a lab's logger
jitters, drops rows and pauses, and none of that is refused. The rule (:data:`RESAMPLING_RULE`):
grid step = the median (regular) interval; the command and the reference held (zero-order hold), measured
channels interpolated linearly, a quantised channel (:func:`detect_quantum`) taken at its nearest
sample (not smoothed); jitter, dropped rows (intervals up to :data:`GAP_STEPS` steps) and gaps
(longer intervals) are reported in one line (:class:`Resampling`, :func:`resampling_notes`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.errors import GapCliError, RecordingInputError
from aeropend_ident.io.split import interleaved_blocks, leave_one_out
from aeropend_sim.contract import REFERENCE_CHANNEL
from aeropend_sim.recording import Recording

#: File suffixes read as CSV logs.
CSV_SUFFIXES = (".csv", ".gz", ".txt")
#: Preset value that picks the preset by file name.
AUTO = "auto"


def split_preset(arg: str | Path) -> tuple[Path, str | None]:
    """Split ``FILE:PRESET`` into (path, preset); a plain path gives (path, None).

    The text after the last ``:`` is taken as a preset only if the whole argument is not an
    existing path (a file name may contain ``:``).

    Raises
    ------
    RecordingInputError
        If the suffix after ``:`` is not a known preset, a preset file (``.yaml`` / ``.yml``) nor
        ``auto``.
    """
    from aeropend_ident.io.csvspec.spec import PRESETS, is_preset_file

    text = str(arg)
    if Path(text).exists() or ":" not in text:
        return Path(text), None
    head, _, preset = text.rpartition(":")
    if preset != AUTO and preset not in PRESETS and not is_preset_file(preset):
        raise RecordingInputError(
            f"{text}: unknown preset {preset!r} after ':'; expected FILE:PRESET with a preset of "
            f"{sorted(PRESETS)}, a preset file (my_rig.yaml) or 'auto'"
        )
    return Path(head), preset


def load_recording(arg: str | Path, preset: str | None = None, namespace: str = "") -> Recording:
    """Read one recording argument (see the module docstring).

    Parameters
    ----------
    arg : str or Path
        ``PATH`` or ``PATH:PRESET``.
    preset : str, optional
        The tool's default preset for CSV logs without their own: a shipped preset's name, a
        preset file (``.yaml``), or ``auto`` / None (by file name).
    namespace : str
        Topic namespace of a bag (default: auto-detected by the reader).

    Returns
    -------
    Recording

    Raises
    ------
    RecordingInputError
        The path does not exist, its kind is unknown, a preset is given for a bag, or no preset
        is given and none matches a CSV file's name.
    BagError, CsvImportError, RecordingError
        From the readers (unreadable file, missing topics or columns, bad values); all are
        ValueErrors.
    """
    path, own = split_preset(arg)
    if not path.exists():
        raise RecordingInputError(f"input {path} does not exist; expected a bag directory, .mcap, .db3 "
                                  "or a CSV log")
    if path.is_dir() or path.suffix in (".mcap", ".db3"):
        if own is not None:
            raise RecordingInputError(f"{arg}: a preset applies to CSV logs only, {path} is a bag")
        from aeropend_ident.io.bags import read_bag

        return read_bag(path, namespace=namespace)
    if path.suffix.lower() not in CSV_SUFFIXES:
        raise RecordingInputError(f"input {path}: unknown kind (suffix {path.suffix!r}); expected a bag "
                                  "directory, .mcap, .db3, .csv, .csv.gz or .txt")
    from aeropend_ident.io.csv_import import import_csv
    from aeropend_ident.io.csvspec.spec import PRESETS, find_preset, is_preset_file

    name = own if own is not None else preset
    if name is None or name == AUTO:
        name = find_preset(path)
        if name is None:
            raise RecordingInputError(
                f"{path.name}: no preset matches this file name; write {path.name}:PRESET or pass "
                f"--preset (one of {sorted(PRESETS)}, or a preset file my_rig.yaml)"
            )
    if name not in PRESETS and not is_preset_file(name):
        raise RecordingInputError(f"unknown preset {name!r}; expected one of {sorted(PRESETS)} or a preset "
                                  "file (my_rig.yaml)")
    return import_csv(path, name)


def ignored_channels(recs: Sequence[Recording], used: str = "") -> str:
    """The line a tool's summary prints for the channels it does not use, "" when there are none.

    Parameters
    ----------
    recs : sequence of Recording
        The recordings the tool read.
    used : str
        What the tool uses, for the text (e.g. "θ and the duty cycle").

    Returns
    -------
    str
        E.g. ``ignored channels (not used by this tool): phi [rad], theta_ref [rad] (in
        closedloop_IMC_reference_steps.csv)``.
    """
    seen: dict[str, str] = {}
    where: list[str] = []
    for r in recs:
        if r.extra:
            seen.update({k: r.extra_units.get(k, "") for k in r.extra})
            where.append(Path(str(r.meta.get("csv_file") or r.meta.get("bag") or r.source)).name)
    if not seen:
        return ""
    names = ", ".join(f"{k} [{u}]" for k, u in sorted(seen.items()))
    uses = f"; it uses {used}" if used else ""
    return f"ignored channels (not used by this tool{uses}): {names} (in {', '.join(dict.fromkeys(where))})"


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
        Grid step [s]: the median sample interval (or the one asked for).
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
        return (f"resampled {name} onto a uniform {_ms(self.dt)} grid (the median regular "
                f"interval): {'; '.join(parts)}; command of the nearest row (held over {over}), "
                f"measurements interpolated{held}")

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (``meta["resampling"]`` of the resampled recording)."""
        return {"rule": RESAMPLING_RULE, "dt_s": self.dt, "rows_in": self.rows_in, "rows_out": self.rows_out,
                "jitter_rms_s": self.jitter_rms, "jitter_max_s": self.jitter_max,
                "dropped_rows": self.dropped_rows, "long_interval_share": self.long_share,
                "uneven_timing": self.uneven,
                "gaps": [{"t_s": a, "length_s": b} for a, b in self.gaps],
                "held_channels": list(self.held_channels), "note": self.note()}


#: The resampling rule in words (docs/csv_import.md "Timing"; ``meta["resampling"]["rule"]``).
RESAMPLING_RULE = (
    "grid t_k = t_0 + phi + k*dt, dt = the median regular interval, phi the median offset of the stamps "
    "from the grid through the first sample (within +-dt/2; 0 when dt is imposed from another recording); "
    "the command (duty) and a reference: the sample stamped within dt/2 of t_k (the nearest), else the "
    "last sample at or before t_k (zero-order hold over dropped rows and gaps); measured channels by "
    "linear interpolation between the neighbouring samples, a quantised channel by its nearest sample; "
    f"intervals up to {GAP_STEPS:g} dt are jitter or dropped rows, longer ones gaps (reported, bridged "
    "the same way)")


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

    The rule (:data:`RESAMPLING_RULE`): grid t_k = φ + k·dt, dt the median interval unless given, φ
    where the stamps scatter about (:func:`grid_phase`; through the first sample when dt is given
    and differs from the recording's own); the duty cycle and the reference ``theta_ref`` (set
    points) of the row stamped within dt/2 of t_k, else held from the last row before it
    (:func:`uniform_grid`); measured channels (θ, the contract channels, the extra channels) by
    linear interpolation at t_k, except a quantised one (:func:`detect_quantum`), which takes its
    nearest sample so that it stays on its lattice. The result's time starts at 0. Timestamp
    jitter, dropped rows and gaps are measured and reported (:class:`Resampling` in
    ``meta["resampling"]``, :func:`resampling_notes`), never refused. A
    recording whose intervals are all within :data:`UNIFORM_TOLERANCE` of dt is returned unchanged.
    A constant input is accepted here (a step from rest or a free decay is a valid recording); the
    fits decide what the data can identify.

    Parameters
    ----------
    rec : Recording
    dt : float, optional
        Grid step [s] (default: :func:`grid_step`, the median regular interval). A step other than
        the recording's own forces resampling (e.g. several recordings onto one grid).

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
    step = grid_step(t) if dt is None else float(dt)
    if not (math.isfinite(step) and step > 0.0):
        raise RecordingInputError(f"{src}: grid step dt = {dt!r}; expected a finite value > 0 s")
    own = dt is None or abs(step - grid_step(t)) <= UNIFORM_TOLERANCE * step
    grid = uniform_grid(t, step, align=own)
    if grid is None:
        return rec
    tu, idx = grid
    nearest = np.clip(np.searchsorted(t, tu, side="left"), 1, t.size - 1)
    nearest -= (tu - t[nearest - 1]) < (t[nearest] - tu)
    held = tuple(k for k, v in rec.channels.items() if detect_quantum(v) > 0.0)

    def measured(name: str, v: np.ndarray) -> np.ndarray:
        return v[nearest] if name in held else np.interp(tu, t, v)

    ch = {k: measured(k, v) for k, v in rec.channels.items()}
    # a set point (the reference) holds between samples like the duty; measured channels are interpolated
    extra = {k: v[idx] if k == REFERENCE_CHANNEL else measured(k, v) for k, v in rec.extra.items()}
    report = _timing_report(src, t, step, tu.size, held)
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
    if np.all(np.abs(np.diff(t) - dt) <= UNIFORM_TOLERANCE * dt):
        return None
    phase = grid_phase(t, dt) if align else 0.0
    tu = phase + np.arange(math.floor((t[-1] - phase) / dt + 1e-9) + 1) * dt
    hold = np.clip(np.searchsorted(t, tu + 1e-9 * dt, side="right") - 1, 0, t.size - 1)
    after = np.clip(hold + 1, 0, t.size - 1)
    near = np.where(np.abs(t[after] - tu) < np.abs(t[hold] - tu), after, hold)
    idx = np.where(np.abs(t[near] - tu) <= 0.5 * dt * (1 + 1e-9), near, hold)
    return tu, idx


def _timing_report(src: str, t: np.ndarray, dt: float, rows_out: int, held: tuple[str, ...]) -> Resampling:
    """Jitter, dropped rows and gaps of time stamps ``t`` about the grid step ``dt``."""
    d = np.diff(t)
    regular = d[d < JITTER_STEPS * dt]
    dev = np.abs(regular - dt) if regular.size else np.zeros(1)
    dropped = d[(d >= JITTER_STEPS * dt) & (d <= GAP_STEPS * dt)]
    long = np.flatnonzero(d > GAP_STEPS * dt)
    return Resampling(
        source=src, dt=dt, rows_in=int(t.size), rows_out=int(rows_out),
        jitter_rms=float(np.sqrt(np.mean(dev**2))), jitter_max=float(np.max(dev)),
        dropped_rows=int(np.sum(np.round(dropped / dt) - 1.0)),
        gaps=tuple((float(t[k]), float(d[k])) for k in long), held_channels=held,
        long_share=float(dropped.size / max(d.size, 1)),
    )


def resampling_notes(recs: Sequence[Recording]) -> list[str]:
    """The report lines of the recordings :func:`uniform_recording` resampled (empty list: none was).

    Parameters
    ----------
    recs : sequence of Recording
        Recordings as the command used them.
    """
    return [r.meta["resampling"]["note"] for r in recs if isinstance(r.meta.get("resampling"), dict)]


# ------------------------------------------------------------------------------ timing search ranges
#: Dead times and lags up to this long [s] are searched whenever the data can show them.
MIN_TIMING_REACH_S = 1.0
#: ... and up to this share of the longest hold of the command (a response must show inside a hold)
HOLD_SHARE = 0.5
#: ... but never beyond this share of the longest recording.
RECORDING_SHARE = 0.25
#: A step of the command counts for the onset bound when it is at least this share of the command's range.
STEP_SHARE = 0.2
#: The dead-time bound is this many times the median onset of the response after such steps.
ONSET_MARGIN = 1.5


@dataclass(frozen=True)
class TimingRange:
    """How long a dead time and a first-order lag the recordings can show: the search range of
    ``identify``'s thrust map and of ``baseline``'s ``actuator.input_delay`` /
    ``actuator.lag_time_constant`` (:func:`timing_range`).

    Attributes
    ----------
    delay_max, lag_max : float
        Upper ends [s] of the dead-time and lag searches.
    longest_hold : float
        Longest stretch [s] of a constant command over the recordings.
    duration : float
        Longest recording [s].
    onset : float or None
        Median time [s] from a step of the command to the first visible response of θ (None: no
        step with the rod at rest before it); the response cannot start before the dead time ends,
        so ONSET_MARGIN·onset bounds it.
    steps : int
        Steps the onset was measured on.
    """

    delay_max: float
    lag_max: float
    longest_hold: float
    duration: float
    onset: float | None
    steps: int

    def rule(self) -> str:
        """How the range follows from the data, in words (for the reports)."""
        reach = (f"min(max({MIN_TIMING_REACH_S:g} s, {HOLD_SHARE:g} × longest hold "
                 f"{self.longest_hold:.3g} s), {RECORDING_SHARE:g} × recording {self.duration:.3g} s)")
        onset = (f"; dead time also ≤ {ONSET_MARGIN:g} × the median response onset {self.onset:.3g} s after "
                 f"{self.steps} step(s) of the command" if self.onset is not None else
                 "; no step with the rod at rest before it bounds the dead time")
        return f"lag ≤ {self.lag_max:.3g} s and dead time ≤ {self.delay_max:.3g} s: {reach}{onset}"

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"delay_max_s": self.delay_max, "lag_max_s": self.lag_max, "longest_hold_s": self.longest_hold,
                "duration_s": self.duration, "onset_s": self.onset, "onset_steps": self.steps,
                "rule": self.rule()}


def _holds(t: np.ndarray, duty: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) indices of the stretches of a constant command."""
    edges = [0, *(np.flatnonzero(np.diff(duty) != 0.0) + 1).tolist(), duty.size]
    return [(a, b) for a, b in itertools.pairwise(edges) if b > a]


def _onsets(rec: Recording) -> list[float]:
    """Times [s] from each large step of the command (the rod at rest before it) to θ's first visible
    response inside the following hold."""
    from aeropend_ident.io.csvspec.constant_input import noise_band

    t, duty, theta = rec.t - rec.t[0], rec.duty, rec.channels["theta"]
    span = float(np.ptp(duty)) or float(duty[0])
    band = noise_band(theta)
    threshold = max(band, 0.02 * float(np.ptp(theta)))
    holds = _holds(t, duty)
    out = []
    # a log that starts with a command applied to a rod at rest is a step at t = 0 (a step test)
    first = [((0, 0), holds[0])] if duty[0] > 0.0 and np.ptp(theta[:5]) <= band else []
    for (a0, b0), (a1, b1) in [*first, *itertools.pairwise(holds)]:
        if span == 0.0 or (b0 > a0 and abs(duty[a1] - duty[b0 - 1]) < STEP_SHARE * span):
            continue
        pre = theta[max(a0, b0 - max(5, round(0.2 / max(rec.dt, 1e-9)))):b0] if b0 > a0 else theta[:5]
        if pre.size < 3 or np.ptp(pre) > band:
            continue  # the rod was moving before the step: its response cannot be told apart
        moved = np.flatnonzero(np.abs(theta[a1:b1] - np.median(pre)) > threshold)
        if moved.size:
            out.append(float(t[a1 + moved[0]] - t[a1]))
    return out


def timing_range(recs: Sequence[Recording]) -> TimingRange:
    """The dead-time and lag search range the recordings can show (the rule of every tool).

    Up to ``min(max(MIN_TIMING_REACH_S, HOLD_SHARE·longest hold), RECORDING_SHARE·longest
    recording)`` for both (at least 1 s of dead time whenever the recordings are long enough to
    show it), and the dead time also at most :data:`ONSET_MARGIN` times the median onset of θ's
    response after the command's large steps taken with the rod at rest (the response cannot start
    before the dead time has passed: a data-driven upper bound).

    Parameters
    ----------
    recs : sequence of Recording
        θ and the duty cycle (any timing).

    Returns
    -------
    TimingRange
    """
    longest_hold = duration = 0.0
    onsets: list[float] = []
    for r in recs:
        t = r.t - r.t[0]
        duration = max(duration, float(t[-1]))
        for a, b in _holds(t, r.duty):
            longest_hold = max(longest_hold, float(t[min(b, t.size - 1)] - t[a]))
        if "theta" in r.channels:
            onsets += _onsets(r)
    reach = min(max(MIN_TIMING_REACH_S, HOLD_SHARE * longest_hold), RECORDING_SHARE * duration)
    onset = float(np.median(onsets)) if onsets else None
    delay_max = reach if onset is None else min(reach, ONSET_MARGIN * onset)
    return TimingRange(delay_max=float(delay_max), lag_max=float(reach), longest_hold=longest_hold,
                       duration=duration, onset=onset, steps=len(onsets))


#: Fewest samples per recording part (fit or held out) of the gap tool.
MIN_PART_SAMPLES = 200


def check_length(rec: Recording, what: str) -> None:
    """Refuse a recording part the gap diagnosis cannot use: too short, or no actuator command.

    A constant duty cycle alone is no reason (a hold, a free decay, a step logged from its first
    sample): such parts are accepted as held-out and validation parts and beside a fit part whose
    command changes (:func:`check_excited` refuses fit data that never changes it).

    Parameters
    ----------
    rec : Recording
        The part.
    what : str
        What the part is ("fit recording", "held-out part", ...), for the message.

    Raises
    ------
    GapCliError
        Fewer than :data:`MIN_PART_SAMPLES` samples, or a set-point reference logged instead of the
        actuator command (the csv_import refusal); names ``what``.
    """
    if len(rec) < MIN_PART_SAMPLES:
        raise GapCliError(
            f"{rec.source or what}: only {len(rec)} samples in the {what}; the gap diagnosis needs "
            f"at least {MIN_PART_SAMPLES} (record longer or change --split)"
        )
    if np.ptp(rec.duty) == 0.0:
        from aeropend_ident.io.csvspec.constant_input import excitation_problem

        why = excitation_problem(rec.t, rec.duty, rec.channels["theta"],
                                 "channel theta_ref" if "theta_ref" in rec.extra else None)
        if why is not None and why[0] == "driven":  # the csv_import refusal, whichever way the log came
            raise GapCliError(f"{rec.source or what}: {why[1]}")


def check_excited(parts: Sequence[Recording], what: str) -> None:
    """Refuse fit parts none of whose duty cycles changes (each part passed :func:`check_length`).

    Holds, free decays and steps logged from their first sample are accepted beside one part whose
    command changes: the pendulum's swing constrains the rod's parameters, the changing command
    the actuator's. With none, no effect on the input side can be told from the nominal.

    Raises
    ------
    GapCliError
        Every part has a constant duty cycle; the message says which recordings would do.
    """
    if parts and all(np.ptp(r.duty) == 0.0 for r in parts):
        levels = ", ".join(sorted({f"{r.duty[0]:g}" for r in parts}))
        raise GapCliError(
            f"the duty cycle is constant in every {what} (τ = {levels}): the diagnosis needs at least "
            "one whose command changes (a step logged with samples before it, a staircase, PRBS); "
            "holds and free decays are accepted beside it and as held-out recordings"
        )


def load_and_split(
    inputs: Sequence[str | Path],
    held_out: Sequence[str | Path] | None,
    split: float,
    preset: str | None,
    blocks: float | None = None,
    block_every: int = 3,
    min_range: float = 0.0,
    block_offset: int = 1,
) -> tuple[list[Recording], list[Recording], str]:
    """Read and split the recordings into (fit, held_out, rule description).

    The held-out design (:mod:`aeropend_ident.io.split`): separate ``held_out`` files, else
    interleaved blocks of ``blocks`` seconds (every ``block_every``-th held out from block
    ``block_offset``; blocks whose angle moves less than ``min_range`` [rad] dropped), else the
    time-ordered ``split`` of each recording long enough (the others fitted whole), and when that
    leaves no usable fit or held-out part, one whole recording held out (leave one recording out).

    Raises
    ------
    GapCliError, RecordingError, ValueError
        Unreadable file, unknown preset, missing channel, NaNs, too short, bad split or blocks.
    """
    if not (isinstance(split, float) and math.isfinite(split) and 0.0 < split < 1.0):
        raise GapCliError(f"--split {split!r}: expected a fraction in (0, 1)")
    if not (math.isfinite(min_range) and min_range >= 0.0):
        raise GapCliError(f"--min-range {min_range!r}: expected an angle range >= 0 [rad]")
    if blocks is None and (min_range != 0.0 or block_every != 3 or block_offset != 1):
        raise GapCliError(
            "--min-range, --block-every and --block-offset apply to interleaved blocks only: "
            "give --blocks SECONDS"
        )
    recs = [uniform_recording(load_recording(p, preset)) for p in inputs]
    if held_out:
        held = [uniform_recording(load_recording(p, preset)) for p in held_out]
        for r in recs:
            check_length(r, "fit recording")
        check_excited(recs, "fit recording")
        for r in held:
            check_length(r, "held-out recording")
        rule = f"separate held-out file(s): {', '.join(split_preset(p)[0].name for p in held_out)}"
        return recs, held, rule
    if blocks is not None:
        if not (math.isfinite(blocks) and blocks > 0.0):
            raise GapCliError(f"--blocks {blocks!r}: expected a block length > 0 [s]")
        if block_every < 2:
            raise GapCliError(f"--block-every {block_every!r}: expected 2 or more")
        if not 0 <= block_offset < block_every:
            raise GapCliError(
                f"--block-offset {block_offset!r}: expected a block index in [0, {block_every}) "
                "(below --block-every)"
            )
        fit, held, rule = interleaved_blocks(recs, blocks, block_every, min_range, block_offset)
        if not fit or not held:
            raise GapCliError(
                f"--blocks {blocks:g}: {len(fit)} fit and {len(held)} held-out block(s) with a changing "
                "duty cycle; use shorter blocks or --split"
            )
        for r in (*fit, *held):
            check_length(r, "block")
        return fit, held, rule
    return _default_held_out(recs, split)


def _default_held_out(recs: list[Recording], split: float) -> tuple[list[Recording], list[Recording], str]:
    """The time-ordered split of each recording long enough for two parts (the others fitted whole);
    when none is, or the fit parts never change the command, one whole recording held out (leave one
    recording out, :func:`aeropend_ident.io.split.leave_one_out`), said in the rule."""
    for r in recs:
        check_length(r, "recording")
    fit, held, whole = [], [], []
    for r in recs:
        a, b = r.split(split)
        if min(len(a), len(b)) >= MIN_PART_SAMPLES:
            fit.append(a)
            held.append(b)
        else:
            whole.append(r)
    try:
        if not held:
            raise GapCliError(f"no recording is long enough for a fit part and a held-out part of "
                              f"{MIN_PART_SAMPLES} samples each at --split {split:g}")
        for part in (*fit, *held):
            check_length(part, "part")
        check_excited(fit + whole, "fit part")
    except GapCliError as exc:
        k = leave_one_out(recs)
        if k is None:
            raise
        left = recs[k]
        return ([r for j, r in enumerate(recs) if j != k], [left],
                f"leave one recording out: {left.source or 'recording ' + str(k + 1)} held out whole, the "
                f"others fit (the time-ordered split at {split:g} does not work: {exc})")
    rule = f"time-ordered split: first {split:.0%} of each recording to fit, the rest held out"
    if whole:
        rule += f"; too short to split, fitted whole: {', '.join(r.source or '?' for r in whole)}"
    return fit + whole, held, rule
