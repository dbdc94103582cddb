"""One pass over a CSV log, block by block (:class:`CsvReader`), and the conversion of each
block's columns to SI and the contract (:class:`Converter`).

Memory: one block of text (:data:`~.source.BLOCK_BYTES`), its parsed columns and what the caller
keeps of them, whatever the file's size. The messages are the whole-file ones of
:func:`aeropend_ident.io.csv_import.import_csv`: the first bad row with the count of all of them
(the pass goes on to count them, writing nothing more), the first time that does not increase
with its count, the clipped duty values.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.errors import CsvImportError, CsvRowWarning
from aeropend_ident.io.csvread.blocks import Part, read_block
from aeropend_ident.io.csvread.source import Block, CsvSource
from aeropend_ident.io.csvread.table import Format, detect_format, plural, resolve
from aeropend_ident.io.csvspec.spec import Column, CsvSpec
from aeropend_sim.contract import REFERENCE_CHANNEL

_TIME_SCALE = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
_DROP_HINT = "csv_import --drop-bad-rows"
_SHOWN_ROWS = 5
#: Progress callback: (file bytes read, file size).
Progress = Callable[[int, int], None]


def _merge(blocks: list[Block]) -> Block:
    return Block(b"".join(b.data for b in blocks), blocks[0].first_line, sum(b.n_lines for b in blocks),
                 any(b.odd_breaks for b in blocks), blocks[-1].last)


class CsvReader:
    """The checked numbers of a CSV log's used columns, block by block (:meth:`parts`).

    Parameters
    ----------
    path : Path
        ``.csv`` or ``.csv.gz`` file.
    spec : CsvSpec
        Column mapping (checked).
    bad_rows : {"error", "drop"}
        Refuse the file at its first bad row (after counting them all) or leave bad rows out.
    run_col : str or int, optional
        A run label column (required numbers).
    progress : callable, optional
        Called after each block with (file bytes read, file size).

    Raises
    ------
    CsvImportError
        From the first lines already: unreadable, empty or binary file, no content line, a missing
        or ambiguous column.
    """

    def __init__(self, path: Path, spec: CsvSpec, bad_rows: str, run_col: Column | None = None,
                 progress: Progress | None = None) -> None:
        if bad_rows not in ("error", "drop"):
            raise CsvImportError(f"bad_rows {bad_rows!r}; expected 'error' or 'drop'")
        self.path, self.spec, self.mode, self.progress = path, spec, bad_rows, progress
        self.source = CsvSource(path, spec.encoding, partial_gzip=bad_rows == "drop")
        self._blocks = self.source.blocks()
        head: list[Block] = []
        fmt = None
        for block in self._blocks:
            head.append(block)
            fmt = detect_format(path, b"".join(b.data for b in head).decode("utf-8"), spec)
            if fmt is not None or block.last:
                break
        if fmt is None:
            lines = b"".join(b.data for b in head).decode("utf-8").splitlines()
            blank = sum(not ln.strip() for ln in lines)
            raise CsvImportError(f"{path}: no data lines (only {len(lines) - blank} comment and {blank} "
                                 "blank line(s))")
        self.fmt: Format = fmt
        self._first = _merge(head)
        roles: list[tuple[str, Column | None, bool]] = [
            ("time", spec.time_col, True), ("input", spec.input_col, True), ("theta", spec.angle_col, True),
            ("reference", spec.reference_col, False),
            *((ch, col, False) for ch, (col, _) in spec.channels.items()),
            *((f"extra:{ch}", col, False) for ch, (col, _, _) in spec.extra_channels.items()),
            ("run", run_col, True)]
        self.cols: dict[str, tuple[int, str]] = {}
        self.used: list[tuple[int, str, bool]] = []
        for role, col, required in roles:
            if col is not None:
                shown = {"theta": "angle", "run": "run label"}.get(role,
                                                                    role.replace("extra:", "extra channel "))
                self.cols[role] = resolve(fmt, col, shown)
                self.used.append((*self.cols[role], required))
        self.rows = 0  # data rows read (good and bad)
        self.good = 0
        self.first_good_line = 0
        self.bad: dict[int, str] = {}  # the first bad rows, line -> problem
        self.n_bad = 0
        self.comment_lines = self.blank_lines = 0
        self.report: dict[str, Any] = {}

    def parts(self) -> Iterator[Part]:
        """The good rows block by block; in ``"error"`` mode none after the first bad row (the
        rest is read to count the bad rows, then :meth:`finish` raises)."""
        skip = self.fmt.header_line if self.fmt.header_line is not None else self.fmt.first_line - 1
        for k, block in enumerate(_chain(self._first, self._blocks)):
            part = read_block(block, self.fmt, self.used, self.spec.comment, skip if k == 0 else 0)
            self.comment_lines += part.comment_lines
            self.blank_lines += part.blank_lines
            self.rows += len(part) + len(part.bad)
            if part.last_text is not None:
                self._unterminated(part)
            if part.bad:
                self.n_bad += len(part.bad)
                for line in sorted(part.bad)[:_SHOWN_ROWS - len(self.bad)]:
                    self.bad[line] = part.bad[line]
            if self.progress is not None:
                self.progress(self.source.consumed, self.source.size)
            if self.n_bad and self.mode == "error":
                continue
            if len(part) and self.good == 0:
                self.first_good_line = int(part.line_no[0])
            self.good += len(part)
            yield part

    def _unterminated(self, part: Part) -> None:
        """The file's last row has no line break: drop it (``"drop"``) or warn that it may be cut."""
        line = int(part.line_no[-1])
        if self.mode == "drop":
            part.bad[line] = "no line break at the end of the file: the last row may be cut"
            part.values = {i: v[:-1] for i, v in part.values.items()}
            part.line_no = part.line_no[:-1]
            return
        self.report["last_line_unterminated"] = line
        warnings.warn(f"{self.path}:{line}: the file does not end with a line break, so its last row "
                      f"({part.last_text!r}) may be cut; check it against the source ({_DROP_HINT} drops it)",
                      CsvRowWarning, stacklevel=6)

    def finish(self) -> dict[str, Any]:
        """Check the whole file once :meth:`parts` is exhausted; returns the report for ``meta``.

        Raises
        ------
        CsvImportError
            A header but no data row; a bad row (``"error"`` mode: the first, with the count and
            the first lines); fewer than 2 good rows.
        """
        if self.rows == 0:
            line = self.fmt.header_line or self.fmt.first_line
            raise CsvImportError(f"{self.path}:{line}: header line but no data rows")
        shown = [{"line": line, "problem": why} for line, why in sorted(self.bad.items())]
        if self.n_bad and self.mode == "error":
            first = shown[0]
            more = f"; {self.n_bad} bad rows in all, lines {', '.join(str(r['line']) for r in shown)}" \
                + (", ..." if self.n_bad > _SHOWN_ROWS else "") if self.n_bad > 1 else ""
            raise CsvImportError(f"{self.path}:{first['line']}: {first['problem']}{more}; {_DROP_HINT} "
                                 f"drops {'it' if self.n_bad == 1 else 'them'}")
        if self.n_bad:
            warnings.warn(f"{self.path}: dropped {plural(self.n_bad, 'bad row')} of {self.rows}: "
                          + "; ".join(f"line {r['line']} ({r['problem']})" for r in shown)
                          + ("; ..." if self.n_bad > _SHOWN_ROWS else ""), CsvRowWarning, stacklevel=4)
            self.report["dropped_rows"] = {"count": self.n_bad, "first": shown}
        if self.good < 2:
            where = f" (line {self.first_good_line})" if self.good else ""
            raise CsvImportError(f"{self.path}: {plural(self.good, 'data row')}{where}; need at least 2 "
                                 "samples")
        return self.report


def _chain(first: Block, rest: Iterator[Block]) -> Iterator[Block]:
    yield first
    yield from rest


@dataclass
class Converted:
    """One block's samples in SI and the contract's terms.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Time [s] from the file's first sample.
    duty : ndarray, shape (n,)
        Duty cycle in [0, 1] (the spec's input map, clipped, quantised if asked).
    channels : dict of str to ndarray, shape (n,)
        θ [rad] and the spec's contract channels (SI).
    extra : dict of str to ndarray, shape (n,)
        The reference (θ's frame, rad) and the extra channels (their units).
    raw : dict of str to ndarray
        The file's numbers by role (``run`` for a run label column).
    """

    t: np.ndarray
    duty: np.ndarray
    channels: dict[str, np.ndarray]
    extra: dict[str, np.ndarray]
    raw: dict[str, np.ndarray] = field(default_factory=dict)


class Converter:
    """Turns each :class:`Part` of a :class:`CsvReader` into SI samples (:meth:`__call__`),
    checking across blocks that time increases and counting clipped duty values.

    Parameters
    ----------
    reader : CsvReader
        The pass whose parts are converted (its spec and columns).
    """

    def __init__(self, reader: CsvReader) -> None:
        self.path, self.spec, self.cols = reader.path, reader.spec, reader.cols
        self.imap = self.spec.input_map()
        self.columns: dict[str, str] = {}
        for role, key in (("time", "time"), ("input", "input"), ("theta", "theta"),
                          ("reference", REFERENCE_CHANNEL)):
            if role in self.cols:
                self.columns[key] = self.cols[role][1]
        for ch in (*self.spec.channels, *self.spec.extra_channels):
            self.columns[ch] = self.cols[ch if ch in self.spec.channels else f"extra:{ch}"][1]
        if self.spec.input_col is None:
            self.columns["input"] = f"constant {self.spec.input_constant:g} ({self.spec.input_kind})"
        self.t0: float | None = None
        self.t0_raw = 0.0
        self.n = 0
        self.below = self.above = 0
        self.time_error: str | None = None
        self.time_errors = 0
        self._prev: tuple[float, float, int] | None = None  # raw t, t [s], line of the previous row

    def _time(self, part: Part) -> tuple[np.ndarray, np.ndarray]:
        n = len(part)
        if self.spec.time_col is None:
            rate = float(self.spec.rate_hz)  # type: ignore[arg-type]
            return np.arange(self.n, self.n + n) / rate, np.empty(0)
        idx, label = self.cols["time"]
        raw = part.values[idx]
        unit = self.spec.time_unit
        t = raw / float(self.spec.rate_hz) if unit == "sample" else raw * _TIME_SCALE[unit]  # type: ignore[arg-type]
        if n and self._prev is not None:
            tt = np.concatenate(([self._prev[1]], t))
            rr = np.concatenate(([self._prev[0]], raw))
            ll = np.concatenate(([self._prev[2]], part.line_no))
        else:
            tt, rr, ll = t, raw, part.line_no
        bad = np.flatnonzero(np.diff(tt) <= 0)
        if bad.size:
            if self.time_error is None:
                k = int(bad[0]) + 1
                u = self.spec.time_unit
                self.time_error = (f"{self.path}:{ll[k]}: column '{label}': time {rr[k]:g} {u} is not "
                                   f"after the previous row's {rr[k - 1]:g} {u} (line {ll[k - 1]}); "
                                   "time must increase strictly (\0 such row(s))")
            self.time_errors += bad.size
        if n:
            self._prev = (float(raw[-1]), float(t[-1]), int(part.line_no[-1]))
        return t, raw

    def __call__(self, part: Part) -> Converted:
        """The SI samples of one part (time from the file's first sample)."""
        t, raw_t = self._time(part)
        if len(t) and self.t0 is None:
            self.t0 = float(t[0])
            self.t0_raw = float(raw_t[0]) if len(raw_t) else 0.0
        t = t - (self.t0 or 0.0)
        self.n += len(t)
        spec = self.spec
        if spec.input_col is None:
            u = np.full(len(t), float(spec.input_constant))  # type: ignore[arg-type]
        else:
            u = part.values[self.cols["input"][0]]
        duty, below, above = self.imap.duty(u)
        self.below += below
        self.above += above
        if spec.quantize_counts:
            q = int(spec.quantize_counts)
            duty = np.floor(duty * q + 1e-9) / q
        factor = math.pi / 180.0 if spec.angle_unit == "deg" else 1.0

        def angle(raw: np.ndarray) -> np.ndarray:
            return spec.angle_sign * (raw - spec.angle_zero) * factor

        channels = {"theta": angle(part.values[self.cols["theta"][0]])}
        for ch, (_, scale) in spec.channels.items():
            channels[ch] = part.values[self.cols[ch][0]] * float(scale)
        extra: dict[str, np.ndarray] = {}
        if spec.reference_col is not None:
            extra[REFERENCE_CHANNEL] = angle(part.values[self.cols["reference"][0]])
        for ch, (_, scale, _) in spec.extra_channels.items():
            extra[ch] = part.values[self.cols[f"extra:{ch}"][0]] * float(scale)
        raw = {"run": part.values[self.cols["run"][0]]} if "run" in self.cols else {}
        return Converted(t, duty, channels, extra, raw)

    def finish(self) -> None:
        """Raise the first time that does not increase (with the count); warn of clipped duties.

        Raises
        ------
        CsvImportError
            Time does not increase strictly somewhere in the file.
        """
        if self.time_error is not None:
            raise CsvImportError(self.time_error.replace("\0", str(self.time_errors)))
        if self.below or self.above:
            unit = "" if self.imap.kind.unit == "1" else f" {self.imap.kind.unit}"
            lo, hi = self.imap.offset, self.imap.offset + self.imap.span
            warnings.warn(f"{self.path}: {self.below + self.above} actuator value(s) outside the input "
                          f"range {lo:g}-{hi:g}{unit} clipped ({self.below} below {lo:g}{unit}: duty 0, "
                          f"{self.above} above full scale {hi:g}{unit}: duty 1)", stacklevel=4)


class TimeStats:
    """The sampling statistics of :func:`aeropend_ident.io.csv_import.import_csv`'s ``meta``
    gathered block by block (:meth:`add`), in memory bounded by the number of distinct sample
    intervals (rounded to 1 ns; a logger's printed stamps have few) instead of the number of rows.

    The median interval is that of the intervals rounded to 1 ns (within 0.5 ns of ``np.median``),
    the jitter the population standard deviation merged block by block (Chan et al.).
    """

    def __init__(self) -> None:
        self.values = np.empty(0, dtype=np.int64)  # distinct intervals [ns], sorted
        self.counts = np.empty(0, dtype=np.int64)
        self.n = 0
        self.mean = self.m2 = 0.0
        self.dt_min, self.dt_max, self.max_at = math.inf, -math.inf, 0.0
        self.last: float | None = None

    def add(self, t: np.ndarray) -> None:
        """The next sample times [s] (after those already added)."""
        if not len(t):
            return
        before = t[:-1] if self.last is None else np.concatenate(([self.last], t[:-1]))
        d = np.diff(t) if self.last is None else np.diff(np.concatenate(([self.last], t)))
        self.last = float(t[-1])
        if not d.size:
            return
        k = int(np.argmax(d))
        if d[k] > self.dt_max:
            self.dt_max, self.max_at = float(d[k]), float(before[k])
        self.dt_min = min(self.dt_min, float(d.min()))
        mb = float(d.mean())
        m2b = float(((d - mb) ** 2).sum())
        total = self.n + d.size
        delta = mb - self.mean
        self.mean += delta * d.size / total
        self.m2 += m2b + delta * delta * self.n * d.size / total
        self.n = total
        v, c = np.unique(np.round(d * 1e9).astype(np.int64), return_counts=True)
        u, inv = np.unique(np.concatenate((self.values, v)), return_inverse=True)
        self.counts = np.bincount(inv, weights=np.concatenate((self.counts, c))).astype(np.int64)
        self.values = u

    def result(self) -> dict[str, Any]:
        """``dt_median_s``, ``dt_min_s``, ``max_gap_s``, ``max_gap_at_s``, ``rate_hz``, ``n_gaps``,
        ``jitter_std_s``, ``uniform`` (as ``_time_stats`` of :mod:`aeropend_ident.io.csv_import`)."""
        cum = np.cumsum(self.counts)

        def at(j: int) -> float:  # the j-th smallest interval [ns], 0-based
            return float(self.values[int(np.searchsorted(cum, j + 1))])

        med_ns = at(self.n // 2) if self.n % 2 else (at(self.n // 2 - 1) + at(self.n // 2)) / 2
        med = med_ns / 1e9
        tol_ns = (1e-9 + 1e-6 * abs(med)) * 1e9
        return {
            "dt_median_s": med,
            "dt_min_s": self.dt_min,
            "max_gap_s": self.dt_max,
            "max_gap_at_s": self.max_at,
            "rate_hz": 1.0 / med,
            "n_gaps": int(self.counts[self.values > 1.5 * med_ns].sum()),
            "jitter_std_s": math.sqrt(self.m2 / self.n),
            "uniform": bool(np.all(np.abs(self.values - med_ns) <= tol_ns)),
        }
