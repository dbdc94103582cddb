"""The one rule for result folders and files: never replace an earlier result without being asked.

Every aeropend command that writes a result folder (``baseline``, ``identify``, ``compare``,
``gap``, ``pipeline``, ``csv_import`` and ``record`` with their bag folders) or a result file
(``design_gains -o``) claims it here first, before any long computation:

* a folder that does not exist or is empty is used (created when needed);
* a non-empty folder is refused unless the command's ``--overwrite`` flag is given; the message
  names the folder, what it holds and the flag;
* with ``--overwrite`` the folder's earlier contents are removed (so no stale figure of an
  earlier run stays beside the new report), but only when it is safe, see below.

What ``--overwrite`` may delete (a lab's folders hold recordings that exist nowhere else):

* only the contents of the folder named by the command's output option, never a parent of it;
* never the file-system root, the home folder, the working folder or a folder above it, a
  folder that is a git repository (holds ``.git``) or a symbolic link;
* never a folder that holds one of the command's own inputs (``gap run/bag -o run``);
* only a folder that looks like the command's own earlier output: it holds at least one entry
  the command writes (``report.json`` for ``gap``, ``metadata.yaml`` for a bag, ...). A folder
  of other files (a typo naming the recordings folder) is refused with a message even with
  ``--overwrite``: empty it yourself if that is really meant.

The check (:func:`claim_output_folder`) and the replacement are two steps, so a command that
computes for minutes checks at once and replaces the earlier result only when the new one is
complete: a run that fails keeps the earlier result.

Atomic results (issue 62): the new result is written under a temporary name in the same folder
(``.NAME.partial-XXXX/NAME``: the result keeps its own name inside, so a bag's ``NAME_0.mcap``
is named right) and renamed into place only when complete (:meth:`OutputFolder.write`,
:func:`write_file_atomically`). A full disk (ENOSPC), a read-only folder (EROFS), a missing
permission (EACCES, EPERM), a quota (EDQUOT) or Ctrl-C (KeyboardInterrupt) while it is written
removes the partial result and leaves the earlier one byte for byte; the command's ``main``
(decorated with :func:`exits_cleanly_on_faults`) then prints one line naming the cause, no
traceback, and exits with status 1 (130 on Ctrl-C).
"""

from __future__ import annotations

import contextlib
import errno
import fnmatch
import functools
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


class OutputFolderError(ValueError):
    """An output folder or file that must not be written (the message says why and what to do)."""


#: Entries of a folder listed in a message before "and N more".
LISTED = 4


def _listing(entries: Sequence[Path]) -> str:
    names = sorted(p.name + ("/" if p.is_dir() else "") for p in entries)
    head = ", ".join(names[:LISTED])
    return head + (f" and {len(names) - LISTED} more" if len(names) > LISTED else "")


def _protected(path: Path) -> str | None:
    """Why ``--overwrite`` must never empty ``path`` (None: not a protected place)."""
    resolved = path.resolve()
    cwd = Path.cwd().resolve()
    if resolved == Path(resolved.anchor):
        return "it is the file-system root"
    if resolved == Path.home().resolve():
        return "it is the home folder"
    if resolved == cwd:
        return "it is the working folder"
    if resolved in cwd.parents:
        return "it holds the working folder"
    if (resolved / ".git").exists():
        return "it is a git repository"
    return None


def _inside(inner: Path, outer: Path) -> bool:
    inner, outer = inner.resolve(), outer.resolve()
    return inner == outer or outer in inner.parents


@dataclass(frozen=True)
class OutputFolder:
    """An output folder a command has claimed (:func:`claim_output_folder`).

    Attributes
    ----------
    path : Path
        The folder as given on the command line.
    overwrite : bool
        Whether the command's ``--overwrite`` flag was given.
    own : tuple of str
        Names (glob patterns allowed) of the entries the command writes at the folder's top level.
    looks_like : str
        What the command writes, for messages ("a gap report").
    option, flag : str
        The command's output option and overwrite flag, as the messages name them.
    kind : str
        "output folder" or "bag folder" (messages).
    inputs : tuple of Path
        The command's input files and folders (never deleted).
    """

    path: Path
    overwrite: bool
    own: tuple[str, ...]
    looks_like: str
    option: str = "-o"
    flag: str = "--overwrite"
    kind: str = "output folder"
    inputs: tuple[Path, ...] = ()

    def _owns(self, entry: Path) -> bool:
        return any(fnmatch.fnmatch(entry.name, pattern) for pattern in self.own)

    def check(self) -> list[Path]:
        """Check that the folder may be written; return the earlier entries ``prepare`` removes.

        Raises
        ------
        OutputFolderError
            If the path is a file; if the folder is not empty and ``overwrite`` is False; with
            ``overwrite``, if emptying it is not safe (module docstring).
        """
        path = self.path
        if path.is_symlink() and not path.is_dir():
            raise OutputFolderError(f"{self.kind} {path} is a link to a missing or non-folder target; "
                                    f"choose another {self.option}")
        if not path.exists():
            return []
        if not path.is_dir():
            raise OutputFolderError(f"{self.kind} {path} exists and is a file, not a folder; choose another "
                                    f"{self.option}")
        entries = list(path.iterdir())
        if not entries:
            return []
        if not self.overwrite:
            raise OutputFolderError(f"{self.kind} {path}/ exists and is not empty ({_listing(entries)}); "
                                    f"pass {self.flag} to replace it or choose another {self.option}")
        why = "it is a symbolic link" if path.is_symlink() else _protected(path)
        if why is None:
            held = [p for p in self.inputs if _inside(p, path)]
            if held:
                why = f"it holds the input {held[0]}"
        if why is not None:
            raise OutputFolderError(f"{self.kind} {path}/ is not emptied even with {self.flag}: {why}; "
                                    f"choose another {self.option}")
        if not any(self._owns(p) for p in entries):
            raise OutputFolderError(
                f"{self.kind} {path}/ does not look like {self.looks_like} (it holds {_listing(entries)}, "
                f"none of {', '.join(self.own)}); {self.flag} replaces only an earlier output of this "
                f"kind: empty the folder yourself or choose another {self.option}")
        return entries

    def prepare(self, create: bool = True) -> Path:
        """Remove the earlier contents (``overwrite``) and return the empty folder.

        Checks again first (:meth:`check`; the folder may have changed since it was claimed).

        Parameters
        ----------
        create : bool
            Create the (empty) folder; False leaves no folder at all, for a writer that must
            create it itself (rosbag2 writers refuse an existing bag folder).

        Returns
        -------
        Path
            ``path``.

        Raises
        ------
        OutputFolderError
            As :meth:`check`.
        """
        for entry in self.check():
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
        if create:
            self.path.mkdir(parents=True, exist_ok=True)
        elif self.path.is_dir():
            self.path.rmdir()
        return self.path

    def write(self, writer: Callable[[Path], T], *, create: bool = True, stage: Path | None = None,
              keep: bool = False) -> T:
        """Write the new result atomically: ``writer`` fills a temporary folder that replaces ``path``.

        Checks again first (:meth:`check`). ``writer`` gets ``.NAME.partial-XXXX/NAME`` beside the
        folder (same file system, same last name); when it returns, the earlier folder (if any) is
        replaced by the new one and removed. If ``writer`` raises (a full disk, a read-only
        folder, Ctrl-C, any error), the partial folder is removed and the earlier one is left as
        it was; the exception passes on, marked for :func:`fault_message`.

        Parameters
        ----------
        writer : callable
            ``writer(folder) -> value``: writes the whole result into ``folder``.
        create : bool
            Create the (empty) temporary folder first; False for a writer that must create it
            itself (rosbag2 writers refuse an existing bag folder).
        stage, keep : Path, bool
            As :func:`staged_path` (a resumable result: ``gap-batch``).

        Returns
        -------
        object
            ``writer``'s value, with every :class:`~pathlib.Path` inside the temporary folder (also
            inside dicts, lists and tuples) moved to the same place in ``path``.

        Raises
        ------
        OutputFolderError
            As :meth:`check`.
        OSError, KeyboardInterrupt
            From ``writer`` or the renames (earlier result untouched, partial one removed).
        """
        self.check()
        with staged_path(self.path, folder=True, create=create, stage=stage, keep=keep) as tmp:
            value = writer(tmp)
        return _rebased(value, tmp, self.path)


def claim_output_folder(path: str | Path, overwrite: bool, *, own: Iterable[str], looks_like: str,
                        inputs: Iterable[str | Path] = (), option: str = "-o", flag: str = "--overwrite",
                        kind: str = "output folder") -> OutputFolder:
    """Claim a command's output folder: check now (fail fast), empty it later with ``prepare``.

    Parameters
    ----------
    path : str or Path
        The folder named by the command's output option.
    overwrite : bool
        The command's ``--overwrite`` flag.
    own : iterable of str
        Names (glob patterns allowed, e.g. ``overlay_*.png``) of what the command writes at the
        folder's top level: ``--overwrite`` empties only a folder holding at least one of them.
    looks_like : str
        What the command writes ("a gap report"), for the refusal message.
    inputs : iterable of str or Path
        The command's inputs: a folder that holds one is never emptied.
    option, flag : str
        The output option and the overwrite flag as the user types them (``-o``, ``--overwrite``;
        a Python API says ``overwrite=True``).
    kind : str
        "output folder" or "bag folder".

    Returns
    -------
    OutputFolder
        Call :meth:`OutputFolder.prepare` right before writing.

    Raises
    ------
    OutputFolderError
        If the folder must not be written (the message names the folder, the reason and the flag
        or option to use instead).
    """
    folder = OutputFolder(Path(path), bool(overwrite), tuple(own), looks_like, option, flag, kind,
                          tuple(Path(p) for p in inputs))
    folder.check()
    return folder


def check_output_file(path: str | Path, overwrite: bool, *, option: str = "-o",
                      flag: str = "--overwrite") -> Path:
    """Check a command's output file: refuse an existing one unless ``overwrite``.

    Raises
    ------
    OutputFolderError
        If ``path`` is a folder, or an existing file and ``overwrite`` is False.
    """
    p = Path(path)
    if p.is_dir():
        raise OutputFolderError(f"output file {p} is a folder; choose another {option}")
    if p.exists() and not overwrite:
        raise OutputFolderError(f"output file {p} exists; pass {flag} to replace it or choose another "
                                f"{option}")
    return p


# ------------------------------------------------------------------------- atomic results
#: errno of the faults a command reports in one line (no traceback) -> the cause as named.
FAULTS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
}
#: Infix of a temporary result's name: ``.NAME.partial-XXXX`` beside ``NAME``.
PARTIAL = ".partial-"
#: Attribute set on an exception raised while a result was written: (final path, existed before,
#: the partial folder kept or None).
_MARK = "aeropend_output"


def _mark(exc: BaseException, final: Path, existed: bool, kept: Path | None = None) -> None:
    with contextlib.suppress(AttributeError, TypeError):  # the outermost result is the one named
        setattr(exc, _MARK, (final, existed, kept))


def _rebased(value: Any, tmp: Path, final: Path) -> Any:
    if isinstance(value, Path):
        return final / value.relative_to(tmp) if value == tmp or tmp in value.parents else value
    if isinstance(value, dict):
        return {k: _rebased(v, tmp, final) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(_rebased(v, tmp, final) for v in value)
    return value


def partial_folder(final: str | Path, label: str) -> Path:
    """The fixed temporary folder of a resumable result: ``.NAME.partial-LABEL`` beside ``final``."""
    final = Path(final)
    return final.absolute().parent / f".{final.name}{PARTIAL}{label}"


@contextlib.contextmanager
def staged_path(final: str | Path, *, folder: bool, create: bool = True, stage: Path | None = None,
                keep: bool = False) -> Iterator[Path]:
    """A temporary path beside ``final`` that is renamed onto ``final`` when the block succeeds.

    The one mechanism of atomic results (module docstring): the block writes ``.NAME.partial-XXXX/
    NAME`` in ``final``'s folder; on success a file replaces ``final`` in one ``os.replace`` and a
    folder is swapped in by two renames (the earlier folder moved aside, the new one into place,
    the earlier one removed; a failure between them puts the earlier one back). On any exception
    the temporary folder is removed and ``final`` is as it was.

    Parameters
    ----------
    final : str or Path
        The result's path (a file or a folder; a symbolic link to a folder is followed). A folder
        that must never be renamed away (the working folder or one above it, the home folder, a
        git repository, a mount point; :class:`OutputFolder` writes one only when it is empty)
        gets the new entries moved into it one by one instead.
    folder : bool
        Whether the result is a folder.
    create : bool
        For a folder: create it empty before the block.
    stage : Path, optional
        A fixed temporary folder (:func:`partial_folder`) instead of a new one, reused as it is:
        what an interrupted run left in ``stage / NAME`` is there for the block to resume from.
    keep : bool
        On an exception, keep ``stage`` (the finished part of the result, clearly named as
        partial) instead of removing it; the message says where it is.

    Yields
    ------
    Path
        Where the block writes the result.

    Raises
    ------
    OSError, KeyboardInterrupt
        Whatever the block or the renames raise, marked with ``final`` for :func:`fault_message`.
    """
    final = Path(os.path.abspath(final))  # "." and ".." get their real names
    if final.is_symlink() and final.is_dir():
        final = final.resolve()
    existed = final.exists()
    # the working folder, one above it, the home folder, a mount point ...: never renamed away;
    # the new entries are moved into it instead (such a folder is written only when empty)
    in_place = folder and final.is_dir() and (_protected(final) is not None or os.path.ismount(final))
    try:
        parent = final.absolute().parent
        parent.mkdir(parents=True, exist_ok=True)
        if stage is None:  # in place: inside the folder itself (a mount point is its own file system)
            where = final if in_place else parent
            stage = Path(tempfile.mkdtemp(prefix=f".{final.name}{PARTIAL}", dir=where))
        else:
            stage.mkdir(exist_ok=True)
    except BaseException as exc:
        _mark(exc, final, existed)
        raise
    target = stage / final.name
    done = False
    try:
        if folder and create:
            target.mkdir(exist_ok=True)
        yield target
        if in_place:
            for entry in sorted(target.iterdir()):
                os.rename(entry, final / entry.name)
        elif folder and final.exists():
            earlier = stage / f"{final.name}.earlier"
            os.rename(final, earlier)
            try:
                os.rename(target, final)
            except BaseException:
                os.rename(earlier, final)
                raise
        else:
            os.replace(target, final)
        done = True
    except BaseException as exc:
        _mark(exc, final, existed, stage if keep else None)
        raise
    finally:
        if done or not keep:
            shutil.rmtree(stage, ignore_errors=True)


def write_file_atomically(path: str | Path, content: str | bytes | Callable[[Path], Any]) -> Path:
    """Write a result file under a temporary name beside it and rename it into place.

    Parameters
    ----------
    path : str or Path
        The file.
    content : str, bytes or callable
        UTF-8 text, bytes, or ``content(tmp_path)`` that writes the file itself.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OSError, KeyboardInterrupt
        As :func:`staged_path` (an earlier file is untouched, no partial file is left).
    """
    with staged_path(path, folder=False) as tmp:
        if callable(content):
            content(tmp)
        elif isinstance(content, bytes):
            tmp.write_bytes(content)
        else:
            tmp.write_text(content, encoding="utf-8")
    return Path(path)


def is_fault(exc: BaseException) -> bool:
    """Whether ``exc`` is a fault reported in one line: Ctrl-C or an OSError of :data:`FAULTS`."""
    return isinstance(exc, KeyboardInterrupt) or (isinstance(exc, OSError) and exc.errno in FAULTS)


def _final_name(name: str) -> str:
    """A path as the user knows it: ``a/.b.partial-x1/b/c`` -> ``a/b/c``, ``a/.b.partial-x1`` -> ``a/b``."""
    parts = list(Path(name).parts)
    keep = []
    for k, p in enumerate(parts):
        if p.startswith(".") and PARTIAL in p:
            own = p[1:p.index(PARTIAL)]
            if k + 1 < len(parts) and parts[k + 1] == own:
                continue
            if k + 1 == len(parts):
                p = own
        keep.append(p)
    return str(Path(*keep)) if keep else name


def fault_message(exc: BaseException) -> str | None:
    """The one line that names a fault and what became of the result (None: not a fault).

    Parameters
    ----------
    exc : BaseException
        The exception that ended a command.

    Returns
    -------
    str or None
        E.g. ``"no space left on the device (ENOSPC) writing gap_report/report.json; gap_report
        unchanged (the earlier result is kept), the partial result removed"``; None when ``exc``
        is not a fault (:func:`is_fault`).
    """
    if not is_fault(exc):
        return None
    if isinstance(exc, KeyboardInterrupt):
        cause = "interrupted (Ctrl-C)"
    else:
        assert isinstance(exc, OSError)
        cause = f"{FAULTS[exc.errno]} ({errno.errorcode[exc.errno]})"
        if exc.filename:
            cause += f" on {_final_name(str(exc.filename))}"
    mark = getattr(exc, _MARK, None)
    if mark is not None:
        final, existed, partial = mark
        kept = f"{final} unchanged (the earlier result is kept)" if existed else f"{final} not written"
        cause += f"; {kept}, " + ("the partial result removed" if partial is None else
                                  f"the finished part kept in {partial} (--resume continues from it)")
    return cause


def exits_cleanly_on_faults(command: str) -> Callable[[Callable[..., int]], Callable[..., int]]:
    """Decorate a command's ``main``: a fault ends it with one line on stderr, no traceback.

    A fault is Ctrl-C or an OSError of :data:`FAULTS` (:func:`is_fault`); the line is
    ``"<command>: error: <fault_message>"``; the exit status is 130 after Ctrl-C, 1 otherwise.
    Other exceptions pass on unchanged. Standard output is flushed inside, so a full disk under
    ``command > file`` is caught too.

    Parameters
    ----------
    command : str
        The command's name as the user types it.

    Returns
    -------
    callable
        The decorator.
    """
    def decorate(main: Callable[..., int]) -> Callable[..., int]:
        @functools.wraps(main)
        def guarded(*args: Any, **kwargs: Any) -> int:
            try:
                status = main(*args, **kwargs)
                sys.stdout.flush()
                return status
            except (KeyboardInterrupt, OSError) as exc:
                message = fault_message(exc)
                if message is None:
                    raise
                print(f"{command}: error: {message}", file=sys.stderr, flush=True)
                return 130 if isinstance(exc, KeyboardInterrupt) else 1
        return guarded
    return decorate
