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

The check (:func:`claim_output_folder`) and the removal (:meth:`OutputFolder.prepare`) are two
steps, so a command that computes for minutes checks at once and replaces the earlier result only
when the new one is ready to be written: a run that fails keeps the earlier result.
"""

from __future__ import annotations

import fnmatch
import shutil
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path


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
