"""Recording arguments of the command-line tools: a bag or a CSV log, each with its own preset.

Every recording argument of ``compare``, ``gap``, ``baseline`` and ``identify`` is one of

* a rosbag2 directory, ``.mcap`` or ``.db3`` file (read with :func:`aeropend_ident.io.bags.read_bag`);
* a CSV log (``.csv``, ``.csv.gz``, ``.txt``) read with :func:`aeropend_ident.io.csv_import.import_csv`
  and a preset: ``FILE.csv:PRESET`` names the preset of this file (e.g.
  ``Identification_Data2.csv:aeroshield_ident2``), ``FILE.csv`` alone uses the tool's
  ``--preset`` or, without one (or with ``auto``), the preset whose file patterns match the name.

So recordings of different formats can be mixed in one call.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aeropend_ident.errors import RecordingInputError
from aeropend_ident.greybox.fit import uniform_grid
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
        If the suffix after ``:`` is not a known preset (nor ``auto``).
    """
    from aeropend_ident.io.csv_import import PRESETS

    text = str(arg)
    if Path(text).exists() or ":" not in text:
        return Path(text), None
    head, _, preset = text.rpartition(":")
    if preset != AUTO and preset not in PRESETS:
        raise RecordingInputError(
            f"{text}: unknown preset {preset!r} after ':'; expected FILE:PRESET with a preset of "
            f"{sorted(PRESETS)} or 'auto'"
        )
    return Path(head), preset


def load_recording(arg: str | Path, preset: str | None = None, namespace: str = "") -> Recording:
    """Read one recording argument (see the module docstring).

    Parameters
    ----------
    arg : str or Path
        ``PATH`` or ``PATH:PRESET``.
    preset : str, optional
        The tool's default preset for CSV logs without their own (``auto`` or None: by file name).
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
    from aeropend_ident.io.csv_import import PRESETS, find_preset, import_csv

    name = own if own is not None else preset
    if name is None or name == AUTO:
        name = find_preset(path)
        if name is None:
            raise RecordingInputError(
                f"{path.name}: no preset matches this file name; write {path.name}:PRESET or pass "
                f"--preset (one of {sorted(PRESETS)})"
            )
    if name not in PRESETS:
        raise RecordingInputError(f"unknown preset {name!r}; expected one of {sorted(PRESETS)}")
    return import_csv(path, name)


def uniform_recording(rec: Recording) -> Recording:
    """The recording on a uniform grid (θ, channels linear, duty zero-order hold) if it is not already.

    What the replaying tools (``gap``, ``compare``) need: θ and the duty cycle, finite values, time
    stamps in order. The grid period is the median interval; a recording already on that grid
    (:func:`aeropend_ident.greybox.fit.uniform_grid`) is returned unchanged. A constant input is
    accepted here (a step from rest at t = 0 is a valid recording to compare on); ``gap`` refuses
    it itself.

    Raises
    ------
    RecordingInputError
        No θ, NaNs, fewer than 2 samples or time stamps out of order (message names the recording).
    """
    src = rec.source or "<recording>"
    if "theta" not in rec.channels:
        raise RecordingInputError(
            f"{src}: recording lacks the 'theta' channel (has {sorted(rec.channels)}); replaying "
            "a rig on it (gap, compare) needs at least the angle and the duty cycle"
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
    dt = float(np.median(np.diff(t)))
    grid = uniform_grid(t, dt)
    if grid is None:
        return rec
    tu, idx = grid
    ch = {k: np.interp(tu, t, v) for k, v in rec.channels.items()}
    meta = {**rec.meta, "resampled_to_uniform_dt_s": dt}
    return Recording(
        t=tu, duty=rec.duty[idx], channels=ch, source=rec.source, stamp0_ns=rec.stamp0_ns, meta=meta
    )
