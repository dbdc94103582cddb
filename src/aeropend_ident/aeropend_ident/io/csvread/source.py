"""A CSV log as byte blocks cut at line ends, read with bounded memory (:class:`CsvSource`).

The file is read in pieces of :data:`READ_BYTES`; a ``.gz`` one is decompressed on the fly
(every member, CRCs checked by zlib); a UTF-8 BOM is removed. Each :class:`Block` holds whole
lines (about :data:`BLOCK_BYTES` of text) and the 1-based number of its first line, so every
message can name the line an editor shows. A binary file is refused from its first
:data:`SNIFF_BYTES` (a NUL byte: a 2 GB file of zeros is refused in milliseconds), a NUL byte
further on when its block is read, a line longer than :data:`MAX_LINE_BYTES` as not a line-per-
sample log, bytes that are not text in the file's encoding with their line. Memory: one read
piece plus one block plus one line, whatever the file's size.
"""

from __future__ import annotations

import codecs
import hashlib
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from aeropend_ident.errors import CsvImportError

#: Text per block [bytes] (a block ends at the first line end after this much).
BLOCK_BYTES = 4 << 20
#: Bytes read from the file at a time.
READ_BYTES = 1 << 20
#: The head searched for NUL bytes before anything else is done.
SNIFF_BYTES = 64 << 10
#: Longest line accepted [bytes]: a CSV log has one sample per line.
MAX_LINE_BYTES = 16 << 20
#: Line ends other than \n and \r\n that :meth:`str.splitlines` honours (\v, \f, \x1c-\x1e, NEL, LS,
#: PS; and \r alone): a block holding one is read row by row (:mod:`.blocks`), as the text is split.
_ODD_BREAKS = (b"\x0b", b"\x0c", b"\x1c", b"\x1d", b"\x1e", b"\xc2\x85", b"\xe2\x80\xa8", b"\xe2\x80\xa9")
_DROP_HINT = "csv_import --drop-bad-rows"
_UTF8 = {"utf-8", "utf8", "utf_8", "utf-8-sig", "utf_8_sig", "ascii", "us-ascii"}


@dataclass
class Block:
    """Whole lines of the file's text (UTF-8).

    Attributes
    ----------
    data : bytes
        The lines, UTF-8 encoded, each with its line break (the file's last may lack one).
    first_line : int
        1-based line number of the first line.
    n_lines : int
        Lines in ``data`` (as :meth:`str.splitlines` counts them).
    odd_breaks : bool
        ``data`` holds a line end other than ``\\n`` / ``\\r\\n``.
    last : bool
        The file's last block.
    """

    data: bytes
    first_line: int
    n_lines: int
    odd_breaks: bool
    last: bool

    @property
    def terminated(self) -> bool:
        """The block ends with a line break."""
        return self.data.endswith((b"\n", b"\r"))


class CsvSource:
    """The blocks of one CSV file (:meth:`blocks`), its SHA-256 and read progress.

    Parameters
    ----------
    path : Path
        ``.csv`` or ``.csv.gz`` file.
    encoding : str
        Text encoding (UTF-8 and ASCII are checked in place; any other is decoded and re-encoded
        as UTF-8).
    partial_gzip : bool
        Accept a cut ``.gz`` (its readable part) instead of refusing it.

    Raises
    ------
    CsvImportError
        On construction: unreadable or empty file, a NUL byte in the first :data:`SNIFF_BYTES`
        (a binary file). While reading: corrupt or cut gzip data, a NUL byte, a line longer than
        :data:`MAX_LINE_BYTES`, bytes that are not valid text, each named by line.
    """

    def __init__(self, path: Path, encoding: str, partial_gzip: bool = False) -> None:
        self.path = path
        self.encoding = encoding
        self.partial_gzip = partial_gzip
        try:
            self._file = path.open("rb")
            self.size = path.stat().st_size
        except OSError as exc:
            raise CsvImportError(f"{path}: cannot read file ({exc.strerror or exc})") from exc
        self.consumed = 0  # file bytes read so far
        self.text_bytes = 0  # text bytes given out so far
        self._sha = hashlib.sha256()
        head = self._file.read(SNIFF_BYTES)
        if not head:
            self._file.close()
            raise CsvImportError(f"{path}: empty file (0 bytes)")
        self._gzip = self.gzip = head[:2] == b"\x1f\x8b"
        self._head = head
        # UTF-16/32 text holds NUL bytes and other line-end bytes: transcoded to UTF-8 before anything
        self._wide = encoding.lower().replace("-", "").replace("_", "").startswith(("utf16", "utf32"))
        if not self._gzip and not self._wide:
            self._refuse_nul(head, 0, 1)

    def close(self) -> None:
        """Close the file (also done when :meth:`blocks` ends)."""
        self._file.close()

    @property
    def sha256(self) -> str:
        """SHA-256 of the file's bytes read so far (all of them once :meth:`blocks` is done)."""
        return self._sha.hexdigest()

    def _refuse_nul(self, data: bytes, base: int, line: int) -> None:
        i = data.find(b"\x00")
        if i >= 0:
            line += data.count(b"\n", 0, i)
            raise CsvImportError(
                f"{self.path}:{line}: a NUL byte at byte {base + i} of the text: this is a binary "
                "file, not a CSV text log (a UTF-16 export? save it as UTF-8 CSV)")

    def _pieces(self) -> Iterator[bytes]:
        """The file's text in pieces (decompressed when gzip)."""
        piece = self._head
        self._head = b""
        if not self._gzip:
            while piece:
                self._sha.update(piece)
                self.consumed += len(piece)
                yield piece
                piece = self._file.read(READ_BYTES)
            return
        d = zlib.decompressobj(wbits=16 + zlib.MAX_WBITS)
        out_total = 0
        in_member = members = 0
        try:
            while piece:
                self._sha.update(piece)
                self.consumed += len(piece)
                rest = piece
                while rest:
                    if not in_member:
                        rest = rest.lstrip(b"\x00") if members else rest  # zero padding between members
                        if not rest:
                            break
                        d = zlib.decompressobj(wbits=16 + zlib.MAX_WBITS)
                        in_member, members = 1, members + 1
                    text = d.decompress(rest, READ_BYTES * 4)
                    rest = d.unconsumed_tail
                    if d.eof:
                        rest, in_member = d.unused_data, 0
                    if text:
                        out_total += len(text)
                        yield text
                piece = self._file.read(READ_BYTES)
        except zlib.error as exc:
            raise CsvImportError(f"{self.path}: corrupt gzip data ({exc})") from exc
        if in_member and not self.partial_gzip:
            raise CsvImportError(
                f"{self.path}: the gzip stream is cut: it ends after {self.size} compressed bytes "
                f"without its end marker ({out_total} bytes of text readable); {_DROP_HINT} imports "
                "the readable part")

    def blocks(self) -> Iterator[Block]:
        """The file's lines in :class:`Block` s, in order (the last one marked, never empty unless
        the whole text is)."""
        prev: Block | None = None
        for block in self._blocks():
            if prev is not None:
                if block.last and not block.data:  # the file ended at a block's end
                    prev.last = True
                    yield prev
                    return
                yield prev
            prev = block
        if prev is not None:
            yield prev

    def _blocks(self) -> Iterator[Block]:
        decoder = None if self.encoding.lower().replace(" ", "") in _UTF8 or self._wide else \
            codecs.getincrementaldecoder(self.encoding)()
        buf = bytearray()
        line = 1
        first = True
        try:
            pieces = _transcode(self._pieces(), self.encoding, self.path) if self._wide else self._pieces()
            done = False
            while not done:
                piece = next(pieces, None)
                done = piece is None
                if piece:
                    buf += piece
                    if len(buf) < BLOCK_BYTES:
                        continue
                cut = len(buf) if done else _last_break(buf)
                if cut < 0:
                    if len(buf) > MAX_LINE_BYTES:
                        raise CsvImportError(
                            f"{self.path}:{line}: no line break in {len(buf) >> 20} MiB: not a CSV log "
                            "with one sample per line")
                    continue
                data = bytes(buf[:cut])
                del buf[:cut]
                if first:
                    data = data.removeprefix(b"\xef\xbb\xbf")
                    first = False
                if not data and not done:
                    continue
                data = self._text(data, line, decoder, final=done)
                self.text_bytes += len(data)
                odd = _odd_breaks(data)
                n = len(data.decode("utf-8").splitlines()) if odd else \
                    data.count(b"\n") + (0 if data.endswith(b"\n") or not data else 1)
                yield Block(data, line, n, odd, done)
                line += n
        finally:
            self._file.close()

    def _text(self, data: bytes, line: int, decoder: codecs.IncrementalDecoder | None, final: bool) -> bytes:
        """Check (UTF-8) or transcode a block's bytes, refusing NUL bytes and invalid text."""
        self._refuse_nul(data, self.text_bytes, line)
        try:
            if decoder is None:
                data.decode("utf-8")
                return data
            return decoder.decode(data, final=final).encode("utf-8")
        except UnicodeDecodeError as exc:
            if self.partial_gzip and self._gzip and final and exc.start >= len(data) - 3:
                return data[:exc.start]  # a character cut with the gzip stream
            at = line + data.count(b"\n", 0, exc.start)
            raise CsvImportError(
                f"{self.path}:{at}: bytes are not valid {self.encoding} text ({exc.reason})") from exc


def _transcode(pieces: Iterator[bytes], encoding: str, path: Path) -> Iterator[bytes]:
    """Pieces of UTF-16/32 text as UTF-8 (a BOM left as U+FEFF, removed with the UTF-8 one)."""
    dec = codecs.getincrementaldecoder(encoding)()
    try:
        for piece in pieces:
            yield dec.decode(piece).encode("utf-8")
        yield dec.decode(b"", final=True).encode("utf-8")
    except UnicodeDecodeError as exc:
        raise CsvImportError(f"{path}: bytes are not valid {encoding} text ({exc.reason})") from exc


def _odd_breaks(data: bytes) -> bool:
    """Whether ``data`` holds a line end other than \\n and \\r\\n (substring searches: fast)."""
    if b"\r" in data and data.count(b"\r") != data.count(b"\r\n"):
        return True
    return any(b in data for b in _ODD_BREAKS)


def _last_break(buf: bytearray) -> int:
    """Index just after the last line end of ``buf`` (-1: none); a \\r at the very end waits for a
    possible \\n."""
    i = buf.rfind(b"\n")
    if i >= 0:
        return i + 1
    j = buf.rfind(b"\r", 0, len(buf) - 1)
    return j + 1 if j >= 0 else -1
