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

**Timing.** Every recording is put on a uniform time grid by :func:`uniform_recording` of
:mod:`aeropend_ident.io.resampling`, the one resampling of every command and fit (a lab's logger
jitters, drops rows and pauses, and none of that is refused).
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
from aeropend_ident.io.resampling import uniform_recording
from aeropend_ident.io.split import interleaved_blocks, leave_one_out
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
