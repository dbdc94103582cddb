"""Rows of a CSV log as text: format detection, column lookup and the row checks whose messages
name the file, the line (1-based, as an editor shows it) and the column.

These are the exact, row-by-row rules of :mod:`aeropend_ident.io.csv_import`; the fast path of
:mod:`.blocks` gives the same numbers for clean blocks and falls back to them for any other.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aeropend_ident.errors import CsvImportError
from aeropend_ident.io.csvspec.spec import Column, CsvSpec

DELIMITERS = ("\t", ";", ",")


@dataclass
class Table:
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
    final: bool = True  # its last row is the file's last
    ncols: int = 0  # fields per row (0: the header's, else the first row's)


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
    for d in DELIMITERS:
        counts = {ln.count(d) for ln in sample}
        if len(counts) == 1 and counts.pop() > 0:
            return d
    # inconsistent counts (e.g. a header with more commas): take the most frequent candidate
    best = max(DELIMITERS, key=lambda d: sum(ln.count(d) for ln in sample))
    return best if any(best in ln for ln in sample) else ","




@dataclass
class Format:
    """How a CSV log is written (from its first lines; :func:`detect_format`).

    Attributes
    ----------
    path : Path
        The file (for messages).
    delimiter, decimal : str
        Field separator and decimal mark.
    header : list of str or None
        Column names (None: no header row).
    header_line : int or None
        1-based line of the header row.
    first_line : int
        1-based line of the first content (not comment, not blank) line.
    ncols : int
        Fields per row (the header's, else the first row's).
    """

    path: Path
    delimiter: str
    decimal: str
    header: list[str] | None
    header_line: int | None
    first_line: int
    ncols: int


def detect_format(path: Path, text: str, spec: CsvSpec) -> Format | None:
    """The :class:`Format` of a log from the text of its first lines (None: no content line in it).

    Separator: the spec's or the one of ``, ; tab`` found the same number of times on each of the
    first 50 content lines (else the most frequent); decimal comma when the separator is not ``,``
    and the first 50 data lines hold commas but no dots; header when the first content line is
    not all numbers (unless the spec says).
    """
    lines = text.splitlines()
    content: list[str] = []
    first = None
    for i, ln in enumerate(lines):
        s = ln.strip()
        if s and not (spec.comment and s.startswith(spec.comment)):
            first = i if first is None else first
            content.append(ln)
            if len(content) > 51:
                break
    if first is None:
        return None
    delimiter = spec.delimiter or _detect_delimiter(content)
    head = content[0].split(delimiter)
    decimal = spec.decimal
    if decimal is None:
        decimal = "."
        if delimiter != ",":
            probe = [f for ln in content[1:51] for f in ln.split(delimiter)]
            if any("," in f for f in probe) and not any("." in f for f in probe):
                decimal = ","
    has_header = spec.header
    if has_header is None:
        numeric = all(_is_number(f, decimal) for f in head if f.strip())
        has_header = not numeric or not any(f.strip() for f in head)
    header = [f.strip().strip('"').strip() for f in head] if has_header else None
    return Format(path, delimiter, decimal, header, first + 1 if has_header else None, first + 1, len(head))


def _norm(s: str) -> str:
    return " ".join(s.lower().split())


def _base(s: str) -> str:
    for mark in ("[", "("):
        s = s.split(mark, 1)[0]
    return _norm(s)


def resolve(tab: Format, col: Column, role: str) -> tuple[int, str]:
    """Column index and display name; raises naming the file, header line and columns."""
    ncols = tab.ncols
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


def plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def cell_problem(cell: str, decimal: str, required: bool) -> str | None:
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


def row_problems(tab: Table, used: Sequence[tuple[int, str, bool]]) -> dict[int, str]:
    """Row index -> what is wrong with it (its first problem) for every bad row.

    A row is bad when its field count differs from the header's (the first row's in a file without
    header: short, cut or with an extra field) or when a cell of a used column is bad
    (:func:`cell_problem`). ``used`` holds (column index, label, required) per used column.
    """
    ncols = tab.ncols or (len(tab.header) if tab.header is not None else len(tab.rows[0]))
    last = len(tab.rows) - 1 if tab.final else -1
    bad: dict[int, str] = {}
    for k, r in enumerate(tab.rows):
        if len(r) != ncols:
            why = f"row has {plural(len(r), 'field')}, expected {ncols}"
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
            if k not in bad and (why := cell_problem(cell, tab.decimal, required)):
                bad[k] = f"column '{label}': {why}"
    return bad


def column(tab: Table, idx: int, label: str, allow_nan: bool) -> np.ndarray:
    """Column ``idx`` as floats (rows checked by the row checks; empty cells are NaN)."""
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
