"""Held-out designs of the gap diagnosis: which parts of the recordings find the effects and which check them.

* :func:`time_ordered` — the first fraction of each recording to fit, the rest held out. The held-out
  part is an *extrapolation* when the run ends in an operating range the fit part never held.
* :func:`interleaved_blocks` — consecutive blocks of ``block_s`` seconds, every ``every``-th one
  (from the 2nd, or from block ``offset``) held out: the held-out blocks lie inside the operating
  range of the fit blocks (*interpolation* within a run). Each block is replayed from its own
  first samples. ``offset`` = 0 … ``every`` − 1 are the folds of a block cross-validation: over
  all of them every block is held out exactly once.
* :func:`informative` — whether a part carries information on any effect: a changing duty cycle
  and an angle that moves by at least ``min_range`` (a rod resting on an end stop throughout shows
  only sensor noise). The rule looks at the recording only, never at a model.
* :func:`validation_split` — the diagnosis' own validation set carved out of the fit recordings
  (train / validation / test), used by the gap run and the drift analysis.
* :func:`split_runs` — one recording per run of a log that stores several runs one after the
  other with a run label column (e.g. the jahoyosr ``datosEscalones`` sheet).

Used by the ``gap`` command (``--split``, ``--blocks``, ``--min-range``), the real-rig bench
(``bench/bench_gap_real.py``) and the real-data tests.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

from aeropend_ident.errors import GapInputError
from aeropend_ident.io.csvspec.constant_input import excitation_problem
from aeropend_sim.recording import Recording

__all__ = ["carve_validation", "informative", "interleaved_blocks", "leave_one_out", "split_runs",
           "time_ordered", "validation_split"]


def informative(part: Recording, min_range: float = 0.0) -> bool:
    """Whether a recording part can inform the diagnosis.

    Parameters
    ----------
    part : Recording
        Recording (part) with a ``theta`` channel [rad].
    min_range : float
        Smallest peak-to-peak recorded angle [rad] (0: any).

    Returns
    -------
    bool
        False when the duty cycle is constant over the part, or its angle range is below
        ``min_range``.
    """
    if np.ptp(part.duty) == 0.0:
        return False
    return not (min_range > 0.0 and np.ptp(part.channels["theta"]) < min_range)


def time_ordered(
    recs: Sequence[Recording], fraction: float
) -> tuple[list[Recording], list[Recording], str]:
    """The first ``fraction`` of each recording to fit, the rest held out.

    Returns
    -------
    fit, held_out : list of Recording
        One part of each recording in each list.
    rule : str
        The design in words (report provenance).

    Raises
    ------
    ValueError
        ``fraction`` not in (0, 1).
    """
    if not (math.isfinite(fraction) and 0.0 < fraction < 1.0):
        raise ValueError(f"split fraction {fraction!r}: expected a fraction in (0, 1)")
    parts = [r.split(fraction) for r in recs]
    rule = f"time-ordered split: first {fraction:.0%} of each recording to fit, the rest held out"
    return [a for a, _ in parts], [b for _, b in parts], rule


def interleaved_blocks(
    recs: Sequence[Recording],
    block_s: float,
    every: int = 3,
    min_range: float = 0.0,
    offset: int = 1,
) -> tuple[list[Recording], list[Recording], str]:
    """Interleaved held-out blocks of each recording.

    Each recording is cut into consecutive blocks of ``block_s`` seconds (a last block shorter
    than half of that is dropped); block ``j`` (0-based) is held out when
    ``j % every == offset``, the others are fit blocks. Blocks that are not :func:`informative`
    (constant duty, or an angle
    range below ``min_range``) are dropped from both sides before the assignment is used.

    Parameters
    ----------
    recs : sequence of Recording
        Uniformly sampled recordings with ``theta``.
    block_s : float
        Block length [s] (> 0 and at least 2 samples).
    every : int
        Every ``every``-th block (from the 2nd) is held out (≥ 2).
    min_range : float
        Smallest recorded angle range [rad] of a kept block (0: keep any moving-input block).
    offset : int
        Index of the first held-out block, in ``[0, every)`` (default 1: from the 2nd block). The
        ``every`` offsets are the folds of a cross-validation over blocks.

    Returns
    -------
    fit, held_out : list of Recording
        Blocks, each re-based to t = 0 (``source`` names the sample range).
    rule : str
        The design in words, with the number of blocks dropped by ``min_range``.

    Raises
    ------
    ValueError
        Bad ``block_s`` / ``every`` / ``min_range`` / ``offset``.
    """
    if not (math.isfinite(block_s) and block_s > 0.0):
        raise ValueError(f"block length {block_s!r} s: expected a positive number of seconds")
    if every < 2:
        raise ValueError(f"every {every!r}: expected every 2nd block or sparser (>= 2)")
    if not (math.isfinite(min_range) and min_range >= 0.0):
        raise ValueError(f"min_range {min_range!r} rad: expected >= 0")
    if not 0 <= offset < every:
        raise ValueError(f"offset {offset!r}: expected a block index in [0, {every})")
    fit: list[Recording] = []
    held: list[Recording] = []
    dropped = 0
    for rec in recs:
        n = len(rec)
        k = max(2, round(block_s / rec.dt))
        for j, a in enumerate(range(0, n, k)):
            b = min(n, a + k)
            if b - a < k // 2:
                break
            part = rec.slice(a, b)
            if not informative(part):
                continue
            if not informative(part, min_range):
                dropped += 1
                continue
            (held if j % every == offset else fit).append(part)
    rule = (
        f"interleaved blocks of {block_s:g} s: every {_ordinal(every)} block (from the "
        f"{_ordinal(offset + 1)}) held out, the others fit"
    )
    if min_range > 0.0:
        rule += (f"; {dropped} block(s) with a recorded angle range below {min_range:g} rad "
                 "(rod on a stop) dropped")
    return fit, held, rule


def _ordinal(k: int) -> str:
    """1st, 2nd, 3rd, 4th, ... 11th, 12th, 13th, 21st."""
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"{k}{suffix}"


def split_runs(rec: Recording, labels: np.ndarray, min_samples: int = 2) -> list[Recording]:
    """One recording per run of a log that holds several runs, labelled per sample.

    Parameters
    ----------
    rec : Recording
        The whole log, shape (n,) per channel.
    labels : ndarray, shape (n,)
        Run label of each sample; a new run starts wherever the label changes.
    min_samples : int
        Runs with fewer samples are dropped (≥ 2: a recording has at least two samples).

    Returns
    -------
    list of Recording
        The runs in file order, each re-based to t = 0.

    Raises
    ------
    ValueError
        ``labels`` does not have one entry per sample, or ``min_samples`` < 2.
    """
    if min_samples < 2:
        raise ValueError(f"min_samples {min_samples!r}: expected >= 2 (a recording has at least 2 samples)")
    labels = np.asarray(labels)
    if labels.shape != (len(rec),):
        raise ValueError(f"{rec.source or 'recording'}: {labels.shape} run labels for {len(rec)} samples; "
                         "expected one per sample")
    edges = [0, *(np.flatnonzero(labels[1:] != labels[:-1]) + 1).tolist(), len(rec)]
    return [rec.slice(a, b) for a, b in itertools.pairwise(edges) if b - a >= min_samples]


#: Default share of the fit data used by the diagnosis to choose the effects.
VALIDATION_FRACTION = 0.3


#: Fewest samples of a fit-core or validation part.
MIN_PART = 200


#: A validation part split before a duty step starts this long before it [s].
SPLIT_LEAD = 1.0


def _varying(r: Recording) -> bool:
    return len(r) >= MIN_PART and float(np.ptp(r.duty)) > 0.0


def _swings(r: Recording) -> bool:
    """A constant-command recording whose rod moves (a free decay, a step from rest at t = 0):
    accepted beside a recording whose command changes (the rod's dynamics, not the input's gain)."""
    return (len(r) >= MIN_PART and float(np.ptp(r.duty)) == 0.0
            and excitation_problem(r.t, r.duty, r.channels["theta"]) is None)


def _inside_share(r: Recording, others: Sequence[Recording]) -> float:
    """Share of ``r``'s samples whose duty cycle lies within the range the ``others`` cover."""
    lo = min(float(np.min(o.duty)) for o in others)
    hi = max(float(np.max(o.duty)) for o in others)
    return float(np.mean((r.duty >= lo) & (r.duty <= hi)))


def leave_one_out(recs: Sequence[Recording]) -> int | None:
    """Index of the recording to leave out (validation or held-out) of ``recs``, or None.

    Candidates are recordings with a changing command whose removal leaves at least one other
    with a changing command; of those, the one most inside the operating range (duty cycles) of
    the rest is left out (an interpolation, not an extrapolation), the later one on a tie.
    """
    excited = [k for k, r in enumerate(recs) if _varying(r)]
    if len(excited) < 2:
        return None
    best = max(excited, key=lambda k: (round(_inside_share(recs[k], [r for j, r in enumerate(recs)
                                                                      if j != k and _varying(r)]), 6), k))
    return best


def _split_at_step(r: Recording, fraction: float) -> tuple[Recording, Recording] | None:
    """Time-ordered split of one recording whose validation tail starts before a duty step.

    Candidate split points lie :data:`SPLIT_LEAD` before each duty change, so the validation part
    starts settled on the previous level and contains the step; the one whose validation share is
    closest to ``fraction`` (within [0.1, 0.5]) wins. None when no candidate gives two parts of
    :data:`MIN_PART` samples with a varying duty cycle.
    """
    n = len(r)
    lead = max(round(SPLIT_LEAD / r.dt), 1)
    best = None
    for k in np.flatnonzero(np.diff(r.duty) != 0.0) + 1 - lead:
        share = 1.0 - k / n
        if not (0.1 <= share <= 0.5) or k < MIN_PART or n - k < MIN_PART:
            continue
        a, b = r.slice(0, int(k)), r.slice(int(k), n)
        if _varying(a) and _varying(b) and (best is None or abs(share - fraction) < best[0]):
            best = (abs(share - fraction), a, b)
    return None if best is None else (best[1], best[2])


def validation_split(
    fit: Sequence[Recording], fraction: float = VALIDATION_FRACTION
) -> tuple[list[Recording], list[Recording]]:
    """The fit core and validation parts of :func:`carve_validation` (without its rule)."""
    core, val, _ = carve_validation(fit, fraction)
    return core, val


def carve_validation(
    fit: Sequence[Recording], fraction: float = VALIDATION_FRACTION
) -> tuple[list[Recording], list[Recording], str]:
    """Carve the diagnosis' validation set out of the fit recordings (train / validation / test).

    Recordings whose command changes are *excited*; a constant-command recording whose rod moves
    (a free decay, a step logged from its first sample: :func:`_swings`) is fitted whole beside them.
    In order of preference:

    1. each excited recording split in time order, its last ``fraction`` becoming validation,
       when both parts keep :data:`MIN_PART` samples and a varying duty cycle; a recording whose
       tail holds one duty level (a long last step) is split instead just before the duty step
       nearest to that share (:func:`_split_at_step`), so its validation part starts settled and
       contains a step;
    2. when some excited recording allows neither and there are two or more, every
       round(1/``fraction``)-th whole excited recording (from the second on) is the validation set
       (with two: leave one recording out);
    3. interleaved blocks of the excited recordings (:func:`interleaved_blocks`, every 3rd block
       of about ``fraction`` × 3 of the length is validation);
    4. the longest excited recording split in time order although its last ``fraction`` holds one
       command (a hold after the last step: it checks the static level and the settling).

    Parameters
    ----------
    fit : sequence of Recording
        Uniformly sampled fit recordings with ``theta``.
    fraction : float
        Share of the fit data to validate on, in (0, 1).

    Returns
    -------
    core, validation : list of Recording
        Fit core (excited parts and the whole constant-command recordings) and validation parts.
    rule : str
        The carving in words (report provenance), naming the recordings.

    Raises
    ------
    GapInputError
        ``fraction`` outside (0, 1), no recording with a changing command, or fit data too short or
        too little excited for any of these (the message names every recording and its length).
    """
    if not 0.0 < fraction < 1.0:
        raise GapInputError(f"validation fraction {fraction!r}; expected a number in (0, 1)")
    fit = list(fit)
    excited = [r for r in fit if _varying(r)]
    whole = [r for r in fit if not _varying(r) and _swings(r)]
    left = [r for r in fit if not _varying(r) and not _swings(r)]
    if not excited:
        raise GapInputError(_too_little(fit, fraction, "none has a changing duty cycle over "
                                        f"{MIN_PART} samples or more"))
    core, val, kept = [], [], []
    for r in excited:
        pair = r.split(1.0 - fraction) if len(r) * min(fraction, 1.0 - fraction) >= MIN_PART else None
        if pair is None or not (_varying(pair[0]) and _varying(pair[1])):
            pair = _split_at_step(r, fraction)
        if pair is None:
            kept.append(r)
        else:
            core.append(pair[0])
            val.append(pair[1])
    if kept and len(excited) >= 2:
        # not every one splits: every round(1/fraction)-th whole excited recording, from the 2nd on, is
        # the validation set (with two: leave one recording out)
        step = max(2, round(1.0 / fraction))
        pick = set(range(1, len(excited), step))
        core_w = [r for i, r in enumerate(excited) if i not in pick]
        val_w = [r for i, r in enumerate(excited) if i in pick]
        why = f"{_names(kept)} cannot be split with a changing command in both parts"
        return (core_w + whole, val_w, f"validation: {_names(val_w)} whole (every {_ordinal(step)} recording "
                f"whose command changes, from the 2nd; {why})" + _whole_note(whole, left))
    if val:
        return core + whole, val, (f"validation: the last ~{fraction:.0%} of {_names(val)}"
                                   + _whole_note(whole, left))
    for n_blocks in (6, 9, 12):
        block = min(len(r) * r.dt for r in excited) / n_blocks
        core, val, _ = interleaved_blocks(excited, block, 3, 0.0, 1)
        if core and val and all(_varying(r) for r in core + val):
            return (core + whole, val, f"validation: every 3rd block of {block:.3g} s of {_names(excited)}"
                    + _whole_note(whole, left))
    for r in sorted(excited, key=len, reverse=True):
        if len(r) * min(fraction, 1.0 - fraction) >= MIN_PART:
            a, b = r.split(1.0 - fraction)
            if _varying(a) and np.ptp(b.channels["theta"]) > 0.0:
                return ([a, *(x for x in excited if x is not r), *whole], [b],
                        f"validation: the last ~{fraction:.0%} of {_names([r])}, a hold after the "
                        "recording's last command change (it checks the static level and the settling, "
                        "not a step)" + _whole_note(whole, left))
    raise GapInputError(_too_little(fit, fraction, "none can be split in time order, before a duty step "
                                    "or into interleaved blocks, and there is no second recording with a "
                                    "changing command to leave out"))


def _names(recs: Sequence[Recording]) -> str:
    return ", ".join(r.source or "a recording" for r in recs)


def _whole_note(whole: Sequence[Recording], left: Sequence[Recording] = ()) -> str:
    note = f"; constant-command recording(s) fitted whole: {_names(whole)}" if whole else ""
    if left:
        note += (f"; left out of the diagnosis (under {MIN_PART} samples, or a constant command under which "
                 f"θ does not move): {_names(left)}")
    return note


def _too_little(fit: Sequence[Recording], fraction: float, why: str) -> str:
    listing = "; ".join(f"{r.source or 'recording'}: {len(r)} samples, duty "
                        f"{'changing' if np.ptp(r.duty) > 0 else 'constant'}" for r in fit)
    return (f"the fit recordings cannot give both a fit part and a validation part (about {fraction:.0%}) "
            f"of at least {MIN_PART} samples with a varying duty cycle: {why} ({listing}); record longer "
            "or with more duty steps, add a recording whose command changes, or pass validation "
            "fraction 0 (the held-out data then choose the effects)")
