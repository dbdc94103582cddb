"""The numbers of one block of a CSV log (:func:`read_block`).

A clean block (no comment or blank line, no odd line end, the same number of fields on every
row, a finite number in every used cell) is parsed by pyarrow's CSV reader (C++, columnar) and
converted column by column with Arrow's compute kernels; any other block is read row by row
with the rules of :mod:`.table`, which name each bad row's line and column. Both give the same
numbers; the fast path only decides that a block needs no message.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from aeropend_ident.io.csvread.source import Block
from aeropend_ident.io.csvread.table import Format, Table, column, row_problems

#: (column index, label, required) of each used column.
Used = Sequence[tuple[int, str, bool]]
_BLANK = re.compile(rb"(?:\A|\n)[ \t\r]*\n")


@dataclass
class Part:
    """The good rows of one block.

    Attributes
    ----------
    values : dict of int to ndarray, shape (n,)
        Each used column's numbers (NaN: an empty cell of an optional column).
    line_no : ndarray of int64, shape (n,)
        1-based line of each row.
    bad : dict of int to str
        Line -> what is wrong, for each row left out.
    comment_lines, blank_lines : int
        Comment and blank lines of the block.
    last_text : str or None
        The file's last row (its line) when it has no line break after it, else None.
    """

    values: dict[int, np.ndarray]
    line_no: np.ndarray
    bad: dict[int, str] = field(default_factory=dict)
    comment_lines: int = 0
    blank_lines: int = 0
    last_text: str | None = None

    def __len__(self) -> int:
        return len(self.line_no)


def _skip(data: bytes, lines: int) -> int:
    """Byte offset after the first ``lines`` lines of ``data``."""
    pos = 0
    for _ in range(lines):
        i = data.find(b"\n", pos)
        if i < 0:
            return len(data)
        pos = i + 1
    return pos


def _arrow_values(body: bytes, n_rows: int, fmt: Format, used: Used) -> dict[int, np.ndarray] | None:
    """The used columns of a clean block by pyarrow (None: the block needs the row-by-row path)."""
    names = [f"c{i}" for i in range(fmt.ncols)]
    idx = sorted({i for i, _, _ in used})
    try:
        table = pacsv.read_csv(
            pa.BufferReader(body),
            read_options=pacsv.ReadOptions(column_names=names, use_threads=False, block_size=len(body) + 64),
            parse_options=pacsv.ParseOptions(delimiter=fmt.delimiter, quote_char=False,
                                             ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(column_types={names[i]: pa.string() for i in idx},
                                                 include_columns=[names[i] for i in idx],
                                                 strings_can_be_null=False))
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        return None
    if table.num_rows != n_rows:
        return None
    required = {i: False for i in idx}
    for i, _, req in used:
        required[i] = required[i] or req
    out: dict[int, np.ndarray] = {}
    for i in idx:
        a = pc.utf8_trim(table.column(names[i]).combine_chunks(), ' \t\r"')
        if fmt.decimal == ",":
            a = pc.replace_substring(a, ",", ".")
        empty = pc.equal(pc.utf8_length(a), 0)
        if pc.any(empty).as_py():
            if required[i]:
                return None
            a = pc.if_else(empty, pa.scalar("nan"), a)
        try:
            v = pc.cast(a, pa.float64()).to_numpy(zero_copy_only=False)
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
            return None
        if (required[i] and not np.isfinite(v).all()) or np.isinf(v).any():
            return None
        out[i] = v
    return out


def read_block(block: Block, fmt: Format, used: Used, comment: str | None, skip: int = 0) -> Part:
    """The good rows of ``block`` and what is wrong with the others.

    Parameters
    ----------
    block : Block
        Whole lines of the file.
    fmt : Format
        The file's separator, decimal mark, header and field count.
    used : sequence of (int, str, bool)
        (column index, label, required) of each used column: a required one (time, input, angle,
        run label) needs a finite number in every row, an optional one may be empty or NaN.
    comment : str or None
        Start of a full-line comment.
    skip : int
        Lines at the start of the block that are not data (the header and the lines before it).

    Returns
    -------
    Part
        Numbers of the good rows, the bad ones by line (:func:`.table.row_problems`: wrong field
        count, not a number, empty or NaN in a required column, ±inf).
    """
    start = _skip(block.data, skip) if skip else 0
    body = block.data[start:]
    first = block.first_line + skip
    n_lines = block.n_lines - skip
    comments = blanks = 0
    if skip:  # the header and the comment and blank lines before it
        for ln in block.data[:start].decode("utf-8").splitlines():
            s = ln.strip()
            if not s:
                blanks += 1
            elif comment and s.startswith(comment):
                comments += 1
    last_text = None
    if block.last and not block.terminated and body:
        last_text = body.rsplit(b"\n", 1)[-1].decode("utf-8").rstrip("\r")
    if n_lines <= 0 or not body:
        return Part({i: np.empty(0) for i, _, _ in used}, np.empty(0, dtype=np.int64), {}, comments, blanks)
    # a blank line is a row of one field to pyarrow (refused) unless the log has one column
    clean = not block.odd_breaks and (fmt.ncols > 1 or _BLANK.search(body) is None) and \
        not (comment and comment.encode() in body)
    if clean:
        values = _arrow_values(body, n_lines, fmt, used)
        if values is not None:
            return Part(values, np.arange(first, first + n_lines, dtype=np.int64), {}, comments, blanks,
                        last_text)
    rows: list[list[str]] = []
    line_no: list[int] = []
    for i, ln in enumerate(body.decode("utf-8").splitlines()):
        s = ln.strip()
        if not s:
            blanks += 1
        elif comment and s.startswith(comment):
            comments += 1
        else:
            rows.append(ln.split(fmt.delimiter))
            line_no.append(first + i)
    if not rows:
        return Part({i: np.empty(0) for i, _, _ in used}, np.empty(0, dtype=np.int64), {}, comments, blanks)
    tab = Table(fmt.path, fmt.header, rows, np.asarray(line_no, dtype=np.int64), fmt.delimiter, fmt.decimal,
                comments, blanks, fmt.header_line, block.terminated, final=block.last, ncols=fmt.ncols)
    bad = row_problems(tab, used)
    if last_text is not None and len(rows) - 1 in bad:
        last_text = None
    keep = np.ones(len(rows), dtype=bool)
    keep[list(bad)] = False
    good = Table(fmt.path, fmt.header, [r for r, k in zip(rows, keep, strict=True) if k], tab.line_no[keep],
                 fmt.delimiter, fmt.decimal, comments, blanks, fmt.header_line, block.terminated,
                 ncols=fmt.ncols)
    values = {i: column(good, i, label, allow_nan=not req) if good.rows else np.empty(0)
              for i, label, req in used}
    return Part(values, good.line_no, {int(tab.line_no[k]): why for k, why in bad.items()}, comments, blanks,
                last_text)
