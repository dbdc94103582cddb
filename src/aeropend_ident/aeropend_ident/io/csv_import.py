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
row detection, decimal comma, UTF-8 BOM, ``.csv.gz``. A malformed file raises
:class:`CsvImportError` naming the file, the line (1-based, as an editor shows it) and the
column, e.g. ``data.csv line 57 column 'angle [deg]': 'abc' is not a number``.

:data:`PRESETS` holds specs for the real recordings in ``shared/data/real`` (provenance and
licence notes in each preset's ``meta``); a lab's own preset is a YAML file of the same schema
(docs/csv_import.md). The command line (console script ``csv_import``,
:mod:`aeropend_ident.cli.csv_import`) converts one file to a bag.
"""

from __future__ import annotations

import hashlib
import math
import warnings
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from aeropend_ident.errors import ConstantInputWarning, CsvImportError, CsvRowWarning
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
    "CsvImportError",
    "CsvSpec",
    "csv_to_bag",
    "find_preset",
    "import_csv",
    "import_csv_runs",
    "load_presets",
    "resolve_preset",
    "summary",
]

TimeUnit = Literal["s", "ms", "us", "sample"]
_TIME_SCALE = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
_DELIMITERS = ("\t", ";", ",")
#: What :func:`import_csv` does with a bad row: raise (default) or drop it and report it.
BadRows = Literal["error", "drop"]
#: The option that drops bad rows, named in the messages (``bad_rows="drop"`` in Python).
_DROP_HINT = "csv_import --drop-bad-rows"
#: Bad rows listed by line in a drop report.
_SHOWN_ROWS = 5


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


@dataclass
class _Table:
    path: Path
    header: list[str] | None
    rows: list[list[str]]
    line_no: np.ndarray  # 1-based line number of each row
    delimiter: str
    decimal: str
    comment_lines: int
    blank_lines: int
    header_line: int | None
    terminated: bool  # the text ends with a line break (False: its last line may be cut)


def _gunzip(path: Path, raw: bytes, partial: bool) -> bytes:
    """Decompress a gzip file (every member, CRCs checked by zlib); the readable part of a cut one
    when ``partial``, else an error saying it is cut."""
    out: list[bytes] = []
    rest = raw
    try:
        while rest:
            d = zlib.decompressobj(wbits=16 + zlib.MAX_WBITS)
            out.append(d.decompress(rest))
            if not d.eof:
                text = b"".join(out)
                if not partial:
                    raise CsvImportError(
                        f"{path}: the gzip stream is cut: it ends after {len(raw)} compressed bytes without "
                        f"its end marker ({len(text)} bytes of text readable); {_DROP_HINT} imports the "
                        "readable part")
                return text
            rest = d.unused_data.lstrip(b"\x00")  # members follow one another; zero padding is allowed
    except zlib.error as exc:
        raise CsvImportError(f"{path}: corrupt gzip data ({exc})") from exc
    return b"".join(out)


def _read_text(path: Path, encoding: str, partial_gzip: bool = False) -> tuple[str, bytes]:
    """Text of a CSV file (a gzip one decompressed, a UTF-8 BOM removed) and its raw bytes."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise CsvImportError(f"{path}: cannot read file ({exc.strerror or exc})") from exc
    if not raw:
        raise CsvImportError(f"{path}: empty file (0 bytes)")
    data = _gunzip(path, raw, partial_gzip) if raw[:2] == b"\x1f\x8b" else raw
    try:
        text = data.decode(encoding)
    except UnicodeDecodeError as exc:
        if partial_gzip and raw[:2] == b"\x1f\x8b" and exc.start >= len(data) - 3:
            text = data[:exc.start].decode(encoding)  # a character cut with the gzip stream
        else:
            line = data[:exc.start].count(b"\n") + 1
            raise CsvImportError(f"{path}:{line}: bytes are not valid {encoding} text ({exc.reason})") \
                from exc
    return text.lstrip("\ufeff"), raw


def _is_number(s: str, decimal: str) -> bool:
    s = s.strip()
    if decimal == ",":
        s = s.replace(",", ".")
    try:
        float(s)
    except ValueError:
        return False
    return True


def _detect_delimiter(lines: list[str]) -> str:
    sample = lines[:50]
    for d in _DELIMITERS:
        counts = {ln.count(d) for ln in sample}
        if len(counts) == 1 and counts.pop() > 0:
            return d
    # inconsistent counts (e.g. a header with more commas): take the most frequent candidate
    best = max(_DELIMITERS, key=lambda d: sum(ln.count(d) for ln in sample))
    return best if any(best in ln for ln in sample) else ","


def _tabulate(path: Path, text: str, spec: CsvSpec) -> _Table:
    lines = text.splitlines()
    keep: list[int] = []
    comment = blank = 0
    for i, ln in enumerate(lines):
        s = ln.strip()
        if not s:
            blank += 1
        elif spec.comment and s.startswith(spec.comment):
            comment += 1
        else:
            keep.append(i)
    if not keep:
        raise CsvImportError(f"{path}: no data lines (only {comment} comment and {blank} blank line(s))")
    content = [lines[i] for i in keep]
    delimiter = spec.delimiter or _detect_delimiter(content)
    first = content[0].split(delimiter)
    decimal = spec.decimal
    if decimal is None:
        decimal = "."
        if delimiter != ",":
            probe = [f for ln in content[1:51] for f in ln.split(delimiter)]
            if any("," in f for f in probe) and not any("." in f for f in probe):
                decimal = ","
    has_header = spec.header
    if has_header is None:
        numeric = all(_is_number(f, decimal) for f in first if f.strip())
        has_header = not numeric or not any(f.strip() for f in first)
    header = [f.strip().strip('"').strip() for f in first] if has_header else None
    data_idx = keep[1:] if has_header else keep
    rows = [lines[i].split(delimiter) for i in data_idx]
    if not rows:
        raise CsvImportError(f"{path}:{keep[0] + 1}: header line but no data rows")
    return _Table(path, header, rows, np.asarray(data_idx, dtype=np.int64) + 1, delimiter, decimal, comment,
                  blank, keep[0] + 1 if has_header else None, terminated=text.endswith(("\n", "\r")))


def _norm(s: str) -> str:
    return " ".join(s.lower().split())


def _base(s: str) -> str:
    for mark in ("[", "("):
        s = s.split(mark, 1)[0]
    return _norm(s)


def _resolve(tab: _Table, col: Column, role: str) -> tuple[int, str]:
    """Column index and display name; raises naming the file, header line and columns."""
    ncols = len(tab.header) if tab.header is not None else len(tab.rows[0])
    if isinstance(col, int) and not isinstance(col, bool):
        if not 0 <= col < ncols:
            raise CsvImportError(f"{tab.path}: {role} column index {col} out of range; the file has {ncols} "
                                 f"column(s) (0-based indices 0..{ncols - 1})")
        label = tab.header[col] if tab.header is not None else f"#{col}"
        return col, label
    if tab.header is None:
        raise CsvImportError(f"{tab.path}: {role} column {col!r} given by name but the file has no "
                             "header row; "
                             "give a 0-based column index")
    for match in (lambda h: h == col, lambda h: _norm(h) == _norm(col), lambda h: _base(h) == _base(col)):
        hits = [i for i, h in enumerate(tab.header) if match(h)]
        if len(hits) == 1:
            return hits[0], tab.header[hits[0]]
        if len(hits) > 1:
            raise CsvImportError(f"{tab.path}:{tab.header_line}: {role} column {col!r} is ambiguous: "
                                 f"matches {[tab.header[i] for i in hits]}")
    raise CsvImportError(f"{tab.path}:{tab.header_line}: no {role} column {col!r}; "
                         f"header has {tab.header}")


def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def _cell_problem(cell: str, decimal: str, required: bool) -> str | None:
    """What is wrong with one cell of a used column (None if nothing): not a number, empty or NaN in
    a required column (time, input, angle, run label), ±inf in any."""
    shown = cell.strip()
    s = shown.strip('"').strip()
    if not s:
        return "'' is empty" if required else None
    try:
        v = float(s.replace(",", ".") if decimal == "," else s)
    except ValueError:
        return f"'{shown}' is not a number"
    if math.isinf(v) or (required and math.isnan(v)):
        return f"'{shown}' is not a finite number"
    return None


def _row_problems(tab: _Table, used: Sequence[tuple[int, str, bool]]) -> dict[int, str]:
    """Row index -> what is wrong with it (its first problem) for every bad row.

    A row is bad when its field count differs from the header's (the first row's in a file without
    header: short, cut or with an extra field) or when a cell of a used column is bad
    (:func:`_cell_problem`). ``used`` holds (column index, label, required) per used column.
    """
    ncols = len(tab.header) if tab.header is not None else len(tab.rows[0])
    last = len(tab.rows) - 1
    bad: dict[int, str] = {}
    for k, r in enumerate(tab.rows):
        if len(r) != ncols:
            why = f"row has {_plural(len(r), 'field')}, expected {ncols}"
            if k == last and len(r) < ncols:
                why += " (last line cut?)" if tab.terminated else \
                    " (last line cut: the file does not end with a line break)"
            bad[k] = why
    for idx, label, required in used:
        cells = [r[idx] if idx < len(r) else "" for r in tab.rows]
        try:  # fast path: a clean numeric column
            text = [c.replace(",", ".") for c in cells] if tab.decimal == "," else cells
            values = np.array(text, dtype=float)
        except ValueError:
            values = None
        if values is not None and not np.isinf(values).any() and not (required and np.isnan(values).any()):
            continue
        for k, cell in enumerate(cells):
            if k not in bad and (why := _cell_problem(cell, tab.decimal, required)):
                bad[k] = f"column '{label}': {why}"
    return bad


def _check_rows(tab: _Table, used: Sequence[tuple[int, str, bool]],
                mode: BadRows) -> tuple[_Table, dict[str, Any]]:
    """Refuse (``"error"``) or drop (``"drop"``) the bad rows of a table; flag a last line without
    line break.

    A last row that parses but lacks its line break may still be cut inside its last number (the
    typical trace of a logger stopped mid-write): it raises a :class:`CsvRowWarning` (and is
    dropped in ``"drop"`` mode); files that merely lack the final line break exist (3 of the 47
    logs in ``shared/data/real``), so it is not an error.

    Returns
    -------
    (table, report)
        The table without dropped rows and what to add to the recording's ``meta``.

    Raises
    ------
    CsvImportError
        ``"error"`` mode and a bad row: ``FILE:LINE: what is wrong`` of the first, with the count.
    """
    bad = _row_problems(tab, used)
    report: dict[str, Any] = {}
    last = len(tab.rows) - 1
    if not tab.terminated and last not in bad:
        text = tab.delimiter.join(tab.rows[last])
        if mode == "drop":
            bad[last] = "no line break at the end of the file: the last row may be cut"
        else:
            report["last_line_unterminated"] = int(tab.line_no[last])
            warnings.warn(f"{tab.path}:{tab.line_no[last]}: the file does not end with a line break, so "
                          f"its last row ({text!r}) may be cut; check it against the source ({_DROP_HINT} "
                          "drops it)",
                          CsvRowWarning, stacklevel=5)
    if not bad:
        return tab, report
    order = sorted(bad)
    shown = [{"line": int(tab.line_no[k]), "problem": bad[k]} for k in order[:_SHOWN_ROWS]]
    if mode != "drop":
        k = order[0]
        more = f"; {len(order)} bad rows in all, lines {', '.join(str(r['line']) for r in shown)}" \
            + (", ..." if len(order) > _SHOWN_ROWS else "") if len(order) > 1 else ""
        raise CsvImportError(f"{tab.path}:{tab.line_no[k]}: {bad[k]}{more}; {_DROP_HINT} drops "
                             f"{'it' if len(order) == 1 else 'them'}")
    keep = np.ones(len(tab.rows), dtype=bool)
    keep[order] = False
    warnings.warn(f"{tab.path}: dropped {_plural(len(order), 'bad row')} of {len(tab.rows)}: "
                  + "; ".join(f"line {r['line']} ({r['problem']})" for r in shown)
                  + ("; ..." if len(order) > _SHOWN_ROWS else ""), CsvRowWarning, stacklevel=5)
    report["dropped_rows"] = {"count": len(order), "first": shown}
    tab = replace(tab, rows=[r for r, k in zip(tab.rows, keep, strict=True) if k], line_no=tab.line_no[keep])
    return tab, report


def _column(tab: _Table, idx: int, label: str, allow_nan: bool) -> np.ndarray:
    """Column ``idx`` as floats (rows checked by :func:`_check_rows`; empty cells are NaN)."""
    cells = [r[idx].strip().strip('"').strip() for r in tab.rows]
    if tab.decimal == ",":
        cells = [c.replace(",", ".") for c in cells]
    try:
        values = np.array(cells, dtype=float)
    except ValueError:  # empty cells of an optional channel
        values = np.array([float(c) if c else math.nan for c in cells])
    if not allow_nan and not np.isfinite(values).all():  # pragma: no cover - _check_rows refused them
        raise CsvImportError(f"{tab.path}: column '{label}' has non-finite values")
    return values


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


def _load(path: Path, spec: CsvSpec, bad_rows: BadRows,
          run_col: Column | None = None) -> tuple[_Table, dict[str, tuple[int, str]], dict[str, Any], bytes]:
    """Read, tabulate, resolve the used columns and check the rows of a CSV log.

    Returns the table (bad rows dropped in ``"drop"`` mode), the used columns by role
    (``time``, ``input``, ``theta``, extra channel names, ``run``) as (index, label), the row
    report for ``meta`` and the file's raw bytes.
    """
    if bad_rows not in ("error", "drop"):
        raise CsvImportError(f"bad_rows {bad_rows!r}; expected 'error' or 'drop'")
    text, raw = _read_text(path, spec.encoding, partial_gzip=bad_rows == "drop")
    tab = _tabulate(path, text, spec)
    roles: list[tuple[str, Column | None, bool]] = [
        ("time", spec.time_col, True), ("input", spec.input_col, True), ("theta", spec.angle_col, True),
        ("reference", spec.reference_col, False),
        *((ch, col, False) for ch, (col, _) in spec.channels.items()),
        *((f"extra:{ch}", col, False) for ch, (col, _, _) in spec.extra_channels.items()),
        ("run", run_col, True)]
    cols: dict[str, tuple[int, str]] = {}
    used: list[tuple[int, str, bool]] = []
    for role, col, required in roles:
        if col is not None:
            shown = {"theta": "angle", "run": "run label"}.get(role, role.replace("extra:", "extra channel "))
            cols[role] = _resolve(tab, col, shown)
            used.append((*cols[role], required))
    tab, report = _check_rows(tab, used, bad_rows)
    if len(tab.rows) < 2:
        where = f" (line {tab.line_no[0]})" if len(tab.rows) else ""
        raise CsvImportError(f"{path}: {_plural(len(tab.rows), 'data row')}{where}; need at least 2 samples")
    return tab, cols, report, raw


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


def _time(path: Path, spec: CsvSpec, tab: _Table, cols: dict[str, tuple[int, str]],
          columns: dict[str, str]) -> tuple[np.ndarray, float]:
    """Sample times [s] from 0 and the file's first time [s]; time must increase strictly."""
    n = len(tab.rows)
    if spec.time_col is None:
        t = np.arange(n) / float(spec.rate_hz)  # type: ignore[arg-type]
    else:
        idx, label = cols["time"]
        columns["time"] = label
        raw_t = _column(tab, idx, label, allow_nan=False)
        t = raw_t / float(spec.rate_hz) if spec.time_unit == "sample" else raw_t * _TIME_SCALE[spec.time_unit]
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            k = int(bad[0]) + 1
            raise CsvImportError(
                f"{path}:{tab.line_no[k]}: column '{label}': time {raw_t[k]:g} {spec.time_unit} "
                f"is not after the previous row's {raw_t[k - 1]:g} {spec.time_unit} "
                f"(line {tab.line_no[k - 1]}); "
                f"time must increase strictly ({bad.size} such row(s))")
    t0 = float(t[0])
    return t - t0, t0


def _duty(path: Path, spec: CsvSpec, tab: _Table, cols: dict[str, tuple[int, str]],
          columns: dict[str, str]) -> tuple[np.ndarray, int, int]:
    """Duty cycle by the spec's input map (clipped values counted and warned), quantised if asked."""
    imap = spec.input_map()
    n = len(tab.rows)
    if spec.input_col is None:
        u = np.full(n, float(spec.input_constant))  # type: ignore[arg-type]
        columns["input"] = f"constant {spec.input_constant:g} ({spec.input_kind})"
    else:
        idx, label = cols["input"]
        columns["input"] = label
        u = _column(tab, idx, label, allow_nan=False)
    duty, below, above = imap.duty(u)
    if below or above:
        unit = "" if imap.kind.unit == "1" else f" {imap.kind.unit}"
        lo, hi = imap.offset, imap.offset + imap.span
        warnings.warn(f"{path}: {below + above} actuator value(s) outside the input range "
                      f"{lo:g}-{hi:g}{unit} clipped ({below} below {lo:g}{unit}: duty 0, {above} above full "
                      f"scale {hi:g}{unit}: duty 1)", stacklevel=4)
    if spec.quantize_counts:
        q = int(spec.quantize_counts)
        duty = np.floor(duty * q + 1e-9) / q
    return duty, below, above


def _angles(spec: CsvSpec, tab: _Table, cols: dict[str, tuple[int, str]], columns: dict[str, str]
            ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, str]]:
    """θ and the contract channels; the extra channels (reference in θ's frame) and their units."""
    factor = math.pi / 180.0 if spec.angle_unit == "deg" else 1.0

    def angle(raw: np.ndarray) -> np.ndarray:
        return spec.angle_sign * (raw - spec.angle_zero) * factor

    idx, label = cols["theta"]
    columns["theta"] = label
    channels: dict[str, np.ndarray] = {"theta": angle(_column(tab, idx, label, allow_nan=False))}
    for ch, (_, scale) in spec.channels.items():
        idx, label = cols[ch]
        columns[ch] = label
        y = _column(tab, idx, label, allow_nan=True) * float(scale)
        if np.isfinite(y).any():
            channels[ch] = y
    extra: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    if spec.reference_col is not None:
        idx, label = cols["reference"]
        columns[REFERENCE_CHANNEL] = label
        extra[REFERENCE_CHANNEL] = angle(_column(tab, idx, label, allow_nan=True))
    for ch, (_, scale, unit) in spec.extra_channels.items():
        idx, label = cols[f"extra:{ch}"]
        columns[ch] = label
        extra[ch] = _column(tab, idx, label, allow_nan=True) * float(scale)
        units[ch] = unit
    extra = {k: v for k, v in extra.items() if np.isfinite(v).any()}
    return channels, extra, {k: u for k, u in units.items() if k in extra}


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


def _import(path: str | Path, spec: CsvSpec | str, bad_rows: BadRows,
            run_col: Column | None = None) -> tuple[Recording, _Table, dict[str, tuple[int, str]]]:
    """:func:`import_csv`, also returning the checked table and its used columns."""
    if isinstance(spec, str):
        spec = resolve_preset(spec)
    spec.check()
    path = Path(path)
    tab, cols, report, raw = _load(path, spec, bad_rows, run_col)
    columns: dict[str, str] = {}
    t, t0 = _time(path, spec, tab, cols, columns)
    duty, below, above = _duty(path, spec, tab, cols, columns)
    channels, extra, units = _angles(spec, tab, cols, columns)
    if spec.input_col is None:
        report["constant_input"] = _constant_input(path, spec, t, channels["theta"], float(duty[0]),
                                                   columns.get(REFERENCE_CHANNEL))
    meta: dict[str, Any] = dict(spec.meta)
    meta.update(_time_stats(t))
    meta.update({
        "csv_file": str(path),
        "csv_sha256": hashlib.sha256(raw).hexdigest(),
        "preset": spec.name or None,
        "spec": spec_summary(spec),
        "input_map": spec.input_map().describe(),
        "columns": columns,
        "delimiter": tab.delimiter,
        "decimal": tab.decimal,
        "header": tab.header,
        "rows": len(tab.rows),
        "comment_lines": tab.comment_lines,
        "blank_lines": tab.blank_lines,
        "t0_in_file_s": t0,
        "duty_clipped": {"below_0": below, "above_1": above},
        "duration_s": float(t[-1]),
        **report,
    })
    try:
        rec = Recording(t=t, duty=duty, channels=channels, source=str(path), meta=meta, extra=extra,
                        extra_units=units)
    except RecordingError as exc:  # pragma: no cover - checked above
        raise CsvImportError(f"{path}: {exc}") from exc
    return rec, tab, cols


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

    rec, tab, cols = _import(path, spec, bad_rows, run_col)
    idx, label = cols["run"]
    return split_runs(rec, _column(tab, idx, label, allow_nan=False), min_samples=min_samples)


def csv_to_bag(path: str | Path, out: str | Path, spec: CsvSpec | str, storage: str = "mcap",
               rig_name: str | None = None, overwrite: bool = False,
               bad_rows: BadRows = "error") -> tuple[Recording, Path]:
    """:func:`import_csv` then :func:`~aeropend_ident.io.bag_writer.write_bag`; returns (recording, bag)."""
    from aeropend_ident.io.bag_writer import write_bag

    rec = import_csv(path, spec, bad_rows)
    bag = write_bag(rec, out, storage=storage, rig_name=rig_name,  # type: ignore[arg-type]
                    overwrite=overwrite)
    return rec, bag


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
