"""Import CSV logs of real rigs into a :class:`~aeropend_sim.recording.Recording` / contract bag.

Most aeropendulum rigs log little more than a time column, the actuator command (PWM counts,
percent, a duty fraction, a voltage, an ESC pulse width or a servo angle) and the angle; some add
a second axis, the reference of a closed loop or a measured thrust. A :class:`CsvSpec`
(:mod:`aeropend_ident.io.csvspec.spec`) says which column is which and how to convert it to SI /
the contract (duty fraction in [0, 1] by the input map of
:mod:`aeropend_ident.io.csvspec.input_kinds`, θ in rad, t in s, extra channels under their own
names); :func:`import_csv` reads the file *faithfully* (no filtering, no outlier removal,
irregular sampling kept as is and reported in ``meta``) and :func:`csv_to_bag` writes the
contract bag. A log without actuator column is imported with a constant input only if a constant
input can explain it (:func:`~aeropend_ident.io.csvspec.constant_input.check_constant_input`: a
free decay or a step from rest, not a closed loop whose only input-like column is its reference).

File handling: separator auto-detection (``,`` ``;`` tab), full-line comments (``#``), header
row detection, decimal comma, UTF-8 BOM, ``.csv.gz``. The file is read as a stream of blocks
(:mod:`aeropend_ident.io.csvread`: pyarrow's CSV parser, row by row where a block needs a
message), so :func:`stream_csv_to_bag` writes a bag of any length in bounded memory; a binary file
(a NUL byte) is refused from its first 64 KiB. A malformed file raises
:class:`CsvImportError` naming the file, the line (1-based, as an editor shows it) and the
column, e.g. ``data.csv line 57 column 'angle [deg]': 'abc' is not a number``.

:data:`PRESETS` holds specs for the real recordings in ``shared/data/real`` (provenance and
licence notes in each preset's ``meta``); a lab's own preset is a YAML file of the same schema
(docs/csv_import.md). The command line (console script ``csv_import``,
:mod:`aeropend_ident.cli.csv_import`) converts one file to a bag.
"""

from __future__ import annotations

import math
import shutil
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from aeropend_ident.errors import ConstantInputWarning, CsvImportError
from aeropend_ident.io.csvread.stream import Converted, Converter, CsvReader, Progress, TimeStats
from aeropend_ident.io.csvread.table import plural as _plural
from aeropend_ident.io.csvspec.constant_input import check_constant_input, driven_message
from aeropend_ident.io.csvspec.spec import (
    PRESETS,
    Column,
    CsvSpec,
    find_preset,
    load_presets,
    resolve_preset,
    spec_summary,
)
from aeropend_sim.contract import REFERENCE_CHANNEL
from aeropend_sim.recording import Recording, RecordingError

__all__ = [
    "PRESETS",
    "BadRows",
    "Column",
    "CsvBag",
    "CsvImportError",
    "CsvSpec",
    "csv_to_bag",
    "find_preset",
    "import_csv",
    "import_csv_runs",
    "load_presets",
    "resolve_preset",
    "stream_csv_to_bag",
    "streamable",
    "summary",
]

TimeUnit = Literal["s", "ms", "us", "sample"]
_TIME_SCALE = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
#: What :func:`import_csv` does with a bad row: raise (default) or drop it and report it.
BadRows = Literal["error", "drop"]
#: The option that drops bad rows, named in the messages (``bad_rows="drop"`` in Python).
_DROP_HINT = "csv_import --drop-bad-rows"


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def _time_stats(t: np.ndarray) -> dict[str, Any]:
    dt = np.diff(t)
    med = float(np.median(dt))
    gaps = np.flatnonzero(dt > 1.5 * med)
    return {
        "dt_median_s": med,
        "dt_min_s": float(dt.min()),
        "max_gap_s": float(dt.max()),
        "max_gap_at_s": float(t[int(np.argmax(dt))]),
        "rate_hz": 1.0 / med,
        "n_gaps": int(gaps.size),
        "jitter_std_s": float(np.std(dt)),
        "uniform": bool(np.allclose(dt, med, rtol=1e-6, atol=1e-9)),
    }


def import_csv(path: str | Path, spec: CsvSpec | str, bad_rows: BadRows = "error") -> Recording:
    """Read a CSV log into a :class:`Recording` (faithfully: no filtering or outlier handling).

    Every data row must have the header's number of fields (the first row's in a file without
    header) and a finite number in each used column (time, input, angle; an extra channel's cell
    may be empty or NaN, meaning "not measured", but not ±inf). A bad row (short, cut, an extra
    field, not a number, NaN/inf) is an error naming ``FILE:LINE`` and what is wrong, never a
    silently wrong number, unless ``bad_rows="drop"``. A last row without line break may have
    been cut inside its last number: it gives a :class:`~aeropend_ident.errors.CsvRowWarning`
    (see :func:`_check_rows`).

    Parameters
    ----------
    path : str or Path
        ``.csv`` or ``.csv.gz`` file.
    spec : CsvSpec or str
        Column mapping and units, the name of a preset in :data:`PRESETS`, or the path of a
        preset file (``.yaml``, docs/csv_import.md).
    bad_rows : {"error", "drop"}
        ``"drop"``: leave bad rows out (and a last row without line break, and the unreadable
        end of a cut ``.gz``), count them in ``meta["dropped_rows"]`` and warn
        (:class:`~aeropend_ident.errors.CsvRowWarning`) with the count and the first lines.

    Returns
    -------
    Recording
        ``t`` [s] re-based to 0 (``meta["t0_in_file_s"]`` keeps the file's first time),
        ``duty`` in [0, 1] by the spec's input map (``meta["input_map"]``; clipped values
        counted in ``meta["duty_clipped"]``), ``channels["theta"]`` [rad] plus the spec's
        contract channels, ``extra`` the reference ``theta_ref`` and the extra channels with
        their units (all-NaN ones dropped), ``meta`` with the spec, file hash, separator,
        sampling statistics (``dt_median_s``, ``max_gap_s``, ``n_gaps``, ...), the preset's
        provenance/licence notes and, for a constant input, ``meta["constant_input"]``.

    Warns
    -----
    ConstantInputWarning
        No actuator column: the duty is taken as constant (a free decay or a step from rest).

    Raises
    ------
    CsvImportError
        Unknown preset or invalid preset file, inconsistent spec, unreadable, empty or cut (gzip)
        file, missing column, a bad row (named by ``FILE:LINE``), fewer than 2 rows, time that
        does not increase, or a constant input that cannot explain the log
        (:func:`~aeropend_ident.io.csvspec.constant_input.check_constant_input`).
    """
    return _import(path, spec, bad_rows)[0]


def _constant_input(path: Path, spec: CsvSpec, t: np.ndarray, theta: np.ndarray, duty: float,
                    reference: str | None) -> dict[str, Any]:
    """Refuse a constant input that cannot explain θ (a driven log); warn that the run is taken as one.

    Returns what goes into ``meta["constant_input"]``.

    Raises
    ------
    CsvImportError
        θ does what no constant input allows (:func:`check_constant_input`); the message states the
        physics, that a reference is not an input, and what the lab can do.
    """
    check = check_constant_input(t, theta)
    kind = spec.input_map().kind
    unit = "" if kind.unit == "1" else f" {kind.unit}"
    given = f"input_constant = {spec.input_constant:g}{unit} ({kind.name}): duty {duty:.4g}"
    if check.driven:
        raise CsvImportError(f"{path}: " + driven_message(given, check.reason,
                                                          f"column '{reference}'" if reference else None))
    what = (f"θ moves by up to {np.max(np.abs(theta - theta[0])):.3g} rad, which a constant input explains "
            "only as a free decay or a step from rest at t = 0 (it never rests and then moves again, and "
            "its swing about the final angle never grows)" if check.moves else
            f"θ stays within {check.margin:.3g} rad of where it starts: nothing excites it")
    warnings.warn(f"{path}: no actuator column: the duty cycle is taken as constant over the whole log "
                  f"({given}); {what}; if the actuator changed during the log, log its command",
                  ConstantInputWarning, stacklevel=4)
    return {"moves": check.moves, "margin_rad": check.margin, "excess": check.excess,
            "theta_final_rad": check.theta_final}


def _collect(path: Path, spec: CsvSpec, bad_rows: BadRows, run_col: Column | None
             ) -> tuple[Any, Any, dict[str, Any], list[Converted]]:
    """Read a whole log block by block (:class:`CsvReader`, :class:`Converter`), keeping every block."""
    reader = CsvReader(path, spec, bad_rows, run_col)
    conv = Converter(reader)
    parts = [conv(part) for part in reader.parts()]
    report = reader.finish()
    conv.finish()
    return reader, conv, report, parts


def _import(path: str | Path, spec: CsvSpec | str, bad_rows: BadRows,
            run_col: Column | None = None) -> tuple[Recording, np.ndarray | None]:
    """:func:`import_csv`, also returning the run label column when ``run_col`` is given."""
    if isinstance(spec, str):
        spec = resolve_preset(spec)
    spec.check()
    path = Path(path)
    reader, conv, report, parts = _collect(path, spec, bad_rows, run_col)
    t = np.concatenate([p.t for p in parts])
    duty = np.concatenate([p.duty for p in parts])
    channels = {k: np.concatenate([p.channels[k] for p in parts]) for k in parts[0].channels}
    channels = {k: v for k, v in channels.items() if k == "theta" or np.isfinite(v).any()}
    extra = {k: np.concatenate([p.extra[k] for p in parts]) for k in parts[0].extra}
    extra = {k: v for k, v in extra.items() if np.isfinite(v).any()}
    units = {ch: unit for ch, (_, _, unit) in spec.extra_channels.items() if ch in extra}
    runs = np.concatenate([p.raw["run"] for p in parts]) if run_col is not None else None
    del parts
    if spec.input_col is None:
        report["constant_input"] = _constant_input(path, spec, t, channels["theta"], float(duty[0]),
                                                   conv.columns.get(REFERENCE_CHANNEL))
    meta = _meta(spec, reader, conv, report, _time_stats(t), float(t[-1]))
    try:
        rec = Recording(t=t, duty=duty, channels=channels, source=str(path), meta=meta, extra=extra,
                        extra_units=units)
    except RecordingError as exc:  # pragma: no cover - checked above
        raise CsvImportError(f"{path}: {exc}") from exc
    return rec, runs


def _meta(spec: CsvSpec, reader: CsvReader, conv: Converter, report: dict[str, Any], stats: dict[str, Any],
          duration: float) -> dict[str, Any]:
    """The recording's ``meta`` of an imported log (``stats``: its sampling statistics,
    ``duration`` its last sample time [s] from 0)."""
    meta: dict[str, Any] = dict(spec.meta)
    meta.update(stats)
    meta.update({
        "csv_file": str(reader.path),
        "csv_sha256": reader.source.sha256,
        "preset": spec.name or None,
        "spec": spec_summary(spec),
        "input_map": spec.input_map().describe(),
        "columns": dict(conv.columns),
        "delimiter": reader.fmt.delimiter,
        "decimal": reader.fmt.decimal,
        "header": reader.fmt.header,
        "rows": conv.n,
        "comment_lines": reader.comment_lines,
        "blank_lines": reader.blank_lines,
        "t0_in_file_s": conv.t0,
        "duty_clipped": {"below_0": conv.below, "above_1": conv.above},
        "duration_s": duration,
        **report,
    })
    return meta


def import_csv_runs(
    path: str | Path, spec: CsvSpec | str, run_col: Column, min_samples: int = 2, bad_rows: BadRows = "error"
) -> list[Recording]:
    """Read a CSV log that stores several runs one after the other, one recording per run.

    A run label column (e.g. the ``block`` column of the jahoyosr ``datosEscalones`` sheet)
    marks the runs: a new run starts wherever its value changes
    (:func:`aeropend_ident.io.split.split_runs`).

    Parameters
    ----------
    path : str or Path
        ``.csv`` or ``.csv.gz`` file.
    spec : CsvSpec or str
        Column mapping and units, or a preset name (as :func:`import_csv`).
    run_col : str or int
        Run label column (header name or 0-based index); numeric labels.
    min_samples : int
        Runs with fewer samples are dropped (≥ 2).
    bad_rows : {"error", "drop"}
        As :func:`import_csv` (the run label is a required column).

    Returns
    -------
    list of Recording
        The runs in file order, each re-based to t = 0 (``source`` names the sample range).

    Raises
    ------
    CsvImportError
        As :func:`import_csv`, plus a missing run label column or a label cell that is empty
        or not a number (named by file, line and column).
    ValueError
        ``min_samples`` < 2.
    """
    from aeropend_ident.io.split import split_runs

    rec, runs = _import(path, spec, bad_rows, run_col)
    return split_runs(rec, runs, min_samples=min_samples)


def csv_to_bag(path: str | Path, out: str | Path, spec: CsvSpec | str, storage: str = "mcap",
               rig_name: str | None = None, overwrite: bool = False,
               bad_rows: BadRows = "error") -> tuple[Recording, Path]:
    """:func:`import_csv` then :func:`~aeropend_ident.io.bag_writer.write_bag`; returns (recording, bag)."""
    from aeropend_ident.io.bag_writer import write_bag

    rec = import_csv(path, spec, bad_rows)
    bag = write_bag(rec, out, storage=storage, rig_name=rig_name,  # type: ignore[arg-type]
                    overwrite=overwrite)
    return rec, bag


@dataclass
class CsvBag:
    """What :func:`stream_csv_to_bag` wrote, shaped for :func:`summary` (the ranges as 2-arrays).

    Attributes
    ----------
    source : str
        The CSV file.
    t : ndarray, shape (2,)
        First and last sample time [s].
    dt : float
        Median sample interval [s].
    duty : ndarray, shape (2,)
        Smallest and largest duty cycle.
    channels : dict of str to ndarray, shape (2,)
        Range of θ [rad] and of each contract channel present.
    meta : dict
        The bag's ``meta`` (as :func:`import_csv` makes it).
    samples, commands : int
        Samples and duty commands written.
    bag : Path
        The bag folder.
    """

    source: str
    t: np.ndarray
    dt: float
    duty: np.ndarray
    channels: dict[str, np.ndarray]
    meta: dict[str, Any]
    samples: int
    commands: int
    bag: Path
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    extra_units: dict[str, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return self.samples


def streamable(spec: CsvSpec) -> bool:
    """Whether :func:`stream_csv_to_bag` takes this spec (no reference and no extra channel: those are
    written by :func:`write_bag` from the whole recording)."""
    return spec.reference_col is None and not spec.extra_channels


def _last_time(reader: CsvReader) -> float | None:
    """The time cell of the file's last data line, from its last 64 KiB (None: not found, a
    ``.gz`` file, or no time column)."""
    spec, fmt = reader.spec, reader.fmt
    if spec.time_col is None or reader.source.gzip:
        return None
    with open(reader.path, "rb") as f:
        f.seek(max(0, reader.source.size - (64 << 10)))
        tail = f.read().decode("utf-8", errors="replace").splitlines()
    idx = reader.cols["time"][0]
    for ln in reversed(tail[1:] if len(tail) > 1 else tail):
        s = ln.strip()
        if not s or (spec.comment and s.startswith(spec.comment)):
            continue
        cells = ln.split(fmt.delimiter)
        if len(cells) != fmt.ncols:
            return None
        cell = cells[idx].strip().strip('"').strip()
        try:
            return float(cell.replace(",", ".") if fmt.decimal == "," else cell)
        except ValueError:
            return None
    return None


def stream_csv_to_bag(path: str | Path, out: str | Path, spec: CsvSpec | str, storage: str = "mcap",
                      rig_name: str | None = None, bad_rows: BadRows = "error",
                      stamp0_ns: int | Callable[[float], int] = 0,
                      progress: Progress | None = None) -> CsvBag:
    """Import a CSV log into a contract bag block by block, in bounded memory.

    The bag holds what :func:`csv_to_bag` writes for the same spec (same stamps, wire convention
    and ``meta``, the sampling statistics gathered block by block: :class:`TimeStats`); memory is
    one block of text (4 MiB) and its messages, whatever the log's length (a log without actuator
    column also keeps t and θ, 16 bytes a row, for the constant-input check). A failure (bad row,
    time that does not increase, Ctrl-C) removes the bag folder: nothing partial is left.

    Parameters
    ----------
    path : str or Path
        ``.csv`` or ``.csv.gz`` file.
    out : str or Path
        Bag folder to create (absent or empty).
    spec : CsvSpec or str
        Column mapping, preset name or preset file; must be :func:`streamable`.
    storage : {"mcap", "sqlite3"}
        rosbag2 storage plugin.
    rig_name : str, optional
        Rig name stored in the bag.
    bad_rows : {"error", "drop"}
        As :func:`import_csv`.
    stamp0_ns : int or callable
        Absolute stamp of the first sample [ns], or a function of the log's duration [s] giving it
        (the duration then comes from the file's last line, or from a first pass over a ``.gz``
        file or a log without time column).
    progress : callable, optional
        Called after each block with (file bytes read, file size).

    Returns
    -------
    CsvBag
        Ranges, counts, ``meta`` and the bag folder.

    Raises
    ------
    CsvImportError
        As :func:`import_csv`; also a spec that is not :func:`streamable`.
    BagError
        The bag cannot be written.
    """
    from aeropend_ident.io.bag_writer import BagStream

    if isinstance(spec, str):
        spec = resolve_preset(spec)
    spec.check()
    if not streamable(spec):
        raise CsvImportError(f"{path}: a spec with a reference or extra channels is imported whole "
                             "(csv_to_bag), not streamed")
    path, out = Path(path), Path(out)
    existed = out.exists()
    reader = CsvReader(path, spec, bad_rows, progress=progress)
    conv = Converter(reader)
    bag: BagStream | None = None
    stats = TimeStats()
    times: list[np.ndarray] = []  # kept only for the constant-input check (no actuator column)
    thetas: list[np.ndarray] = []
    ranges: dict[str, list[float]] = {}
    try:
        for part in reader.parts():
            c = conv(part)
            if not len(c.t):
                continue
            if bag is None:
                s0 = _stamp0(stamp0_ns, reader, conv, path, spec, bad_rows)
                bag = BagStream(out, storage, s0)  # type: ignore[arg-type]
            bag.write(c.t, c.duty, c.channels)
            stats.add(c.t)
            if spec.input_col is None:
                times.append(c.t)
                thetas.append(c.channels["theta"])
            for k, v in (("duty", c.duty), *c.channels.items()):
                if np.isfinite(v).any():
                    lo, hi = float(np.nanmin(v)), float(np.nanmax(v))
                    old = ranges.get(k, [lo, hi])
                    ranges[k] = [min(old[0], lo), max(old[1], hi)]
        report = reader.finish()
        conv.finish()
        if spec.input_col is None:
            report["constant_input"] = _constant_input(path, spec, np.concatenate(times),
                                                       np.concatenate(thetas), ranges["duty"][0], None)
        t_last = float(stats.last or 0.0)
        meta = _meta(spec, reader, conv, report, stats.result(), t_last)
        assert bag is not None
        bag.close(meta, str(path), rig_name)
    except BaseException:
        if bag is not None:
            bag.abort()
        elif not existed and out.exists():  # interrupted while the bag was being created
            shutil.rmtree(out, ignore_errors=True)
        raise
    channels = {k: np.asarray(v) for k, v in ranges.items() if k != "duty"}
    return CsvBag(str(path), np.array([0.0, t_last]), float(meta["dt_median_s"]),
                  np.asarray(ranges["duty"]), channels, meta, bag.samples, bag.commands, out)


def _stamp0(stamp0_ns: int | Callable[[float], int], reader: CsvReader, conv: Converter, path: Path,
            spec: CsvSpec, bad_rows: BadRows) -> int:
    """The first sample's absolute stamp [ns] (see :func:`stream_csv_to_bag`)."""
    if not callable(stamp0_ns):
        return int(stamp0_ns)
    last = _last_time(reader)
    if last is not None:
        unit = spec.time_unit
        scale = 1.0 / float(spec.rate_hz) if unit == "sample" else _TIME_SCALE[unit]  # type: ignore[arg-type,index]
        t_last = last * scale
        return stamp0_ns(max(0.0, t_last - (conv.t0 or 0.0)))
    first = CsvReader(path, spec, bad_rows)  # a first pass for the duration
    c2 = Converter(first)
    end = 0.0
    for part in first.parts():
        c = c2(part)
        if len(c.t):
            end = float(c.t[-1])
    return stamp0_ns(end)


def summary(rec: Recording) -> str:
    """One-paragraph human summary of an imported recording."""
    m = rec.meta
    th = rec.channels["theta"]
    parts = [
        f"{rec.source}: {len(rec)} samples over {rec.t[-1]:.3f} s",
        f"median dt {m.get('dt_median_s', rec.dt) * 1e3:.3f} ms ({1.0 / rec.dt:.2f} Hz)",
    ]
    if m.get("n_gaps"):
        parts.append(f"{m['n_gaps']} gap(s) > 1.5 dt, largest {m['max_gap_s'] * 1e3:.1f} ms at "
                     f"t = {m['max_gap_at_s']:.3f} s")
    elif "uniform" in m:
        parts.append("uniform sampling" if m["uniform"] else f"jitter std {m['jitter_std_s'] * 1e3:.3f} ms")
    parts.append(f"duty {rec.duty.min():.4f}..{rec.duty.max():.4f}")
    if m.get("input_map") and not m["input_map"].endswith("(duty)"):
        parts.append(f"input {m['input_map']}")
    clipped = m.get("duty_clipped", {})
    if clipped and (clipped.get("below_0") or clipped.get("above_1")):
        parts.append(f"{clipped['below_0'] + clipped['above_1']} duty value(s) clipped")
    if m.get("dropped_rows"):
        parts.append(f"{_plural(m['dropped_rows']['count'], 'bad row')} dropped")
    parts.append(f"theta {th.min():.4f}..{th.max():.4f} rad "
                 f"({math.degrees(th.min()):.2f}..{math.degrees(th.max()):.2f} deg)")
    parts.append(f"channels {sorted(rec.channels)}")
    if rec.extra:
        parts.append("extra channels " + ", ".join(f"{k} [{rec.extra_units[k]}]" for k in rec.extra))
    if m.get("licence"):
        parts.append(f"licence: {m['licence']}")
    return "; ".join(parts) + "."


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------
