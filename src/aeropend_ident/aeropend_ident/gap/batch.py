"""The gap diagnosis over an archive of sessions (``gap-batch``): one report per session, one drift table.

**Sessions of an archive** (:func:`find_sessions`):

* with a manifest ``sessions.yaml`` at the archive's top level, the sessions it lists::

      sessions:
        - name: monday                         # optional (default: the first recording's name)
          recordings: [run1.mcap, run2/]       # paths relative to the archive
          held_out: [run3.csv]                 # optional: else the time-ordered split
        - recordings: [tuesday.csv:mypreset]

* otherwise every recording directly in the archive is one session, in name order: a rosbag2
  folder (it holds ``metadata.yaml`` or a ``.mcap`` / ``.db3`` file), a ``.mcap`` or ``.db3`` file,
  or a CSV log (its preset from ``--preset`` or by file name, as for ``gap``). Other entries are
  listed as skipped.

**Per session** the ``gap`` command itself runs (``aeropend_ident.cli.gap_batch.diagnose_session``,
same options, its report folder ``OUT/<session>/``) as one case of
:func:`aeropend_ident.parallel.run_cases` (a local Dask cluster or a lab's). A session ``gap``
refuses is recorded with its one-line error; the others go on.

**Across sessions** (:func:`drift_across`): the effects chosen in any session (less those that set
the same rig parameter as an earlier one) plus the drift-prone parameters
(:func:`aeropend_ident.gap.sessions.drift_set`) are fitted on each session's fit part, again as cases
of the cluster, and :func:`aeropend_ident.gap.sessions.drift_rows` says which parameter changes
between sessions beyond its standard errors, as ``gap --sessions`` does.

**Resuming** (``gap-batch --resume``): each session's folder holds :data:`SESSION_FILE`, written
when its ``gap`` run has ended (diagnosed or refused), with the session's row and its key
(:func:`session_key`: a SHA-256 of the contents of every input file, the preset files, the nominal
rig's numbers and the options). A session whose folder holds a finished row with the key of its
current inputs is taken as it is (:func:`finished_row`); any other one is computed again.

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from aeropend_ident.errors import GapCliError
from aeropend_sim.files.safe_yaml import YamlRefusedError, load_yaml

#: Manifest file name at an archive's top level.
MANIFEST = "sessions.yaml"
#: Files that are one recording each.
RECORDING_SUFFIXES = (".mcap", ".db3", ".csv")
#: Top-level files ``gap-batch`` writes in its output folder (beside one folder per session).
BATCH_FILES = ("batch.json", "drift.md")
#: File in each session's folder: the key of its inputs and options and its row (module doc).
SESSION_FILE = "batch_session.json"


@dataclass(frozen=True)
class Session:
    """One session of an archive: its name, recordings (paths, ``FILE.csv:PRESET`` allowed) and
    optional held-out recordings."""

    name: str
    recordings: tuple[str, ...]
    held_out: tuple[str, ...] = ()


@dataclass
class SessionCase:
    """What a worker needs to run ``gap`` on one session (``cli.gap_batch.diagnose_session``)."""

    session: Session
    rig: str
    out: str
    options: list[str] = field(default_factory=list)
    #: :func:`session_key` of the session's inputs (written with its row; "" = not written).
    key: str = ""


def _is_bag_folder(path: Path) -> bool:
    return path.is_dir() and ((path / "metadata.yaml").is_file() or any(path.glob("*.mcap"))
                              or any(path.glob("*.db3")))


def _name(path: str) -> str:
    """Session name of a recording path (``FILE.csv:PRESET`` allowed): its file name without the
    recording suffix, other characters than letters, digits, ``_.-`` replaced."""
    stem = Path(path).name.split(":", 1)[0]
    for suffix in RECORDING_SUFFIXES:
        stem = stem.removesuffix(suffix)
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", stem) or "session"


def _unique(names: list[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}_{seen[n]}")
    return out


def find_sessions(archive: str | Path) -> tuple[list[Session], list[str]]:
    """The sessions of an archive folder (module doc) and the entries skipped (with the reason).

    Raises
    ------
    GapCliError
        If ``archive`` is not a folder, its manifest is malformed or names a missing file, or it
        holds no recording.
    """
    root = Path(archive)
    if not root.is_dir():
        raise GapCliError(f"archive {root} is not a folder; expected a folder of recordings "
                          f"(or with {MANIFEST})")
    manifest = root / MANIFEST
    if manifest.is_file():
        return _from_manifest(root, manifest), []
    sessions, skipped = [], []
    for entry in sorted(root.iterdir()):
        if entry.name.startswith("."):
            continue
        if _is_bag_folder(entry) or (entry.is_file() and entry.suffix.lower() in RECORDING_SUFFIXES):
            sessions.append(Session(_name(entry.name), (str(entry),)))
        else:
            skipped.append(f"{entry.name}: not a bag folder, .mcap/.db3 file or CSV log")
    if not sessions:
        raise GapCliError(f"archive {root} holds no recording (bag folders, .mcap/.db3 files, CSV logs) "
                          f"and no {MANIFEST}")
    names = _unique([s.name for s in sessions])
    return [Session(n, s.recordings) for n, s in zip(names, sessions, strict=True)], skipped


def _from_manifest(root: Path, manifest: Path) -> list[Session]:
    try:
        doc = load_yaml(manifest, "a gap-batch manifest (sessions.yaml)")
    except YamlRefusedError as exc:
        raise GapCliError(str(exc)) from None
    except (OSError, ValueError, yaml.YAMLError) as exc:
        raise GapCliError(f"{manifest}: cannot be read as YAML: {exc}") from exc
    items = doc.get("sessions") if isinstance(doc, dict) else None
    if not isinstance(items, list) or not items:
        raise GapCliError(f"{manifest}: expected a non-empty list 'sessions:' of "
                          "{name, recordings, held_out}")
    out = []
    for k, item in enumerate(items):
        if not (isinstance(item, dict) and isinstance(item.get("recordings"), list) and item["recordings"]):
            raise GapCliError(f"{manifest}: session {k + 1} needs a non-empty list 'recordings:'")
        paths = []
        for key in ("recordings", "held_out"):
            got = []
            for rel in item.get(key) or []:
                file, _, preset = str(rel).partition(":")
                path = root / file
                if not path.exists():
                    raise GapCliError(f"{manifest}: session {k + 1}: {key} entry {rel!r} does not exist "
                                      f"in {root}")
                got.append(f"{path}:{preset}" if preset else str(path))
            paths.append(tuple(got))
        name = str(item.get("name") or _name(str(item["recordings"][0])))
        out.append(Session(name, paths[0], paths[1]))
    names = _unique([re.sub(r"[^A-Za-z0-9_.-]+", "_", s.name) for s in out])
    return [Session(n, s.recordings, s.held_out) for n, s in zip(names, out, strict=True)]


def _fit_part(case: tuple) -> Any:
    """One session's drift fit (a worker case of :func:`drift_across`)."""
    from aeropend_ident.gap.run import to_model_frame
    from aeropend_ident.gap.sessions import session_task
    from aeropend_ident.io.recording_input import load_and_split

    session, rig, offset, effects, channels, split, preset = case
    fit, _held, _rule = load_and_split(list(session.recordings), list(session.held_out) or None, split,
                                       preset)
    return session_task(("fit", rig, effects, [to_model_frame(r, offset) for r in fit], channels))


def drift_across(rows: Sequence[dict[str, Any]], sessions: Sequence[Session], rig: Any, offset: float, *,
                 split: float, preset: str | None, run: Callable[..., Any]) -> dict[str, Any] | None:
    """The drift table across the diagnosed sessions (module doc), or None with fewer than two.

    ``rig`` and ``offset`` are the nominal rig and its recording-frame θ offset [rad]; ``run`` is
    :func:`aeropend_ident.parallel.run_cases` with the batch's cluster settings bound.
    """
    from aeropend_ident.gap.sessions import _drift_table, drift_set
    from aeropend_ident.gap.which.ranking import excluded_with

    good = [(r, s) for r, s in zip(rows, sessions, strict=True) if r.get("exit") == 0]
    if len(good) < 2:
        return None
    chosen: list[str] = []
    for r, _s in good:
        for name in r.get("chosen", []):
            if name not in excluded_with(chosen):
                chosen.append(name)
    channels = _channels(good)
    effects = drift_set(chosen, channels, rig.family)
    cases = [(s, rig, offset, effects, channels, split, preset) for _r, s in good]
    done = dict(run(_fit_part, cases, desc="drift fits"))
    table = _drift_table([s.name for _r, s in good], effects, [done[i] for i in range(len(cases))])
    table["chosen_in_sessions"] = chosen
    return table


def _channels(good: Sequence[tuple[dict[str, Any], Session]]) -> tuple[str, ...]:
    """Channels every diagnosed session compared (read from their reports)."""
    have: set[str] | None = None
    for r, _s in good:
        doc = json.loads((Path(r["report"]) / "report.json").read_text(encoding="utf-8"))
        ch = set(doc["which"].get("channels") or ["theta"])
        have = ch if have is None else have & ch
    return tuple(sorted(have or {"theta"}))


#: The statuses of a gap-batch session (:func:`session_status`).
STATUSES = ("ok", "corrected rig worse", "diverged", "failed")


def session_status(row: dict[str, Any]) -> str:
    """One session's status (one of :data:`STATUSES`): ``failed`` (gap refused or crashed), ``diverged``
    (the nominal or the corrected held-out free run left the recorded range: no NRMSE to compare),
    ``corrected rig worse`` (its held-out θ NRMSE above the nominal's) or ``ok``."""
    if row.get("exit") != 0:
        return "failed"
    before, after = row.get("nrmse_before"), row.get("nrmse_after")
    if before is None or after is None:
        return "diverged"
    return "corrected rig worse" if after > before else "ok"


def drift_markdown(rows: Sequence[dict[str, Any]], table: dict[str, Any] | None) -> str:
    """``drift.md``: the per-session table and the drift table across sessions."""
    lines = ["# gap-batch", "", "| session | chosen | held-out θ NRMSE before → after | status |",
             "|---|---|---|---|"]
    for r in rows:
        if r.get("exit") == 0:
            figs = " → ".join("diverges" if v is None else f"{v:.4g}"
                              for v in (r["nrmse_before"], r["nrmse_after"]))
            lines.append(f"| {r['session']} | {', '.join(r['chosen']) or 'none'} | {figs} | "
                         f"{session_status(r)} |")
        else:
            lines.append(f"| {r['session']} | — | — | {session_status(r)}: {r.get('error', '')} |")
    lines += ["", "## Drift across sessions", ""]
    if table is None:
        lines.append("Not computed: fewer than two sessions were diagnosed.")
        return "\n".join(lines) + "\n"
    lines += [f"Effects fitted on each session's fit part: {', '.join(table['effects'])}.", "",
              "| parameter | " + " | ".join(table["sessions"]) + " | change | z | drifts |",
              "|---|" + "---|" * len(table["sessions"]) + "---|---|---|"]
    for row in table["rows"]:
        vals = " | ".join(f"{v:.4g}" for v in row["values"])
        ch = "—" if row["change"] != row["change"] else f"{100 * row['change']:+.1f} %"
        lines.append(f"| {row['effect']}.{row['parameter']} [{row['unit']}] | {vals} | {ch} | "
                     f"{row['z']:.3g} | {'yes' if row['drifts'] else 'no'} |")
    return "\n".join(lines) + "\n"


def write_batch(out: Path, rows: Sequence[dict[str, Any]], sessions: Sequence[Session],
                table: dict[str, Any] | None, skipped: Sequence[str],
                meta: dict[str, Any]) -> dict[str, Path]:
    """Write ``batch.json`` (sessions, per-session rows, drift table, skipped entries, run facts)
    and ``drift.md``; return their paths."""
    from aeropend_ident.io.jsonutil import jsonable

    doc = {"tool": "aeropend_ident gap-batch", "sessions": [asdict(s) for s in sessions],
           "rows": [{**r, "status": session_status(r)} for r in rows],
           "drift": table, "skipped": list(skipped), "meta": meta}
    paths = {"json": out / "batch.json", "md": out / "drift.md"}
    paths["json"].write_text(json.dumps(jsonable(doc), indent=1), encoding="utf-8")
    paths["md"].write_text(drift_markdown(rows, table), encoding="utf-8")
    return paths


def _input_files(arg: str) -> list[tuple[str, Path]]:
    """(name in the key, file) of one recording argument: its file(s) and an existing preset file."""
    path, _, preset = str(arg).partition(":")
    root = Path(path)
    files = sorted(p for p in root.rglob("*") if p.is_file()) if root.is_dir() else [root]
    out = [(str(p.relative_to(root)) if root.is_dir() else root.name, p) for p in files]
    if preset and Path(preset).is_file():
        out.append((f"preset {Path(preset).name}", Path(preset)))
    return out


def session_key(session: Session, rig_doc: str, options: Sequence[str]) -> str:
    """SHA-256 (hex) of what one session's ``gap`` result depends on.

    Parameters
    ----------
    session : Session
        Its recordings and held-out recordings: every file's contents (every file of a bag
        folder) and name, and a ``:PRESET`` suffix with its preset file's contents.
    rig_doc : str
        The nominal rig as text (its numbers, e.g. JSON of ``rig_to_dict``).
    options : sequence of str
        The ``gap`` options of the batch (``--split`` ..., ``--preset`` ...).

    Returns
    -------
    str
        64 hex digits; a moved archive with the same contents keeps its keys.

    Raises
    ------
    OSError
        An input that cannot be read.
    """
    import hashlib

    h = hashlib.sha256()
    h.update(json.dumps({"rig": rig_doc, "options": list(options)}, sort_keys=True).encode())
    for group, args in (("recordings", session.recordings), ("held_out", session.held_out)):
        for arg in args:
            h.update(f"\n{group} {str(arg).partition(':')[2]}\n".encode())
            for name, path in _input_files(arg):
                h.update(f"{name}\n".encode())
                with open(path, "rb") as fh:
                    for block in iter(lambda fh=fh: fh.read(1 << 20), b""):
                        h.update(block)
    return h.hexdigest()


def finished_row(folder: Path, key: str) -> dict[str, Any] | None:
    """The row of a session already diagnosed in ``folder`` with inputs of ``key`` (None: none).

    A row counts when :data:`SESSION_FILE` holds ``key`` and, for a diagnosed session (exit 0
    or 1), the report's ``report.json`` is there; a refused session (its one-line error) counts
    as it is. The row's ``report`` is set to ``folder``.
    """
    try:
        doc = json.loads((folder / SESSION_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    row = doc.get("row") if isinstance(doc, dict) and doc.get("key") == key else None
    if not isinstance(row, dict) or "exit" not in row:
        return None
    if row.get("error") is None and not (folder / "report.json").is_file():
        return None
    return {**row, "report": str(folder.absolute())}
