"""The gap diagnosis over a folder of sessions (console script ``gap-batch``).

Usage::

    gap-batch ARCHIVE/ --rig RIG -o OUT [--scheduler ADDRESS | --workers N]
        [--preset NAME] [--split 0.7] [--max-effects 2] [--seed 0] [--no-oracle] [--overwrite] [--resume] [-q]

Runs ``gap`` on every session of ``ARCHIVE`` (a manifest ``sessions.yaml``, or one session per bag
folder / ``.mcap`` / ``.db3`` / CSV log directly in it: :mod:`aeropend_ident.gap.batch`), each as one
case of a Dask cluster: a local one of ``--workers`` processes (default one per core), or a lab's
running cluster with ``--scheduler tcp://HOST:8786`` (docs/gap.md, "Batches on a cluster"; the
workers must reach the archive and ``OUT`` under the same paths). Writes ``OUT/<session>/`` (the
``gap`` report of each session), ``OUT/batch.json`` (every session's outcome, the drift table, the
entries skipped) and ``OUT/drift.md`` (the per-session table and which parameters drift between
sessions); prints the per-session table. A session ``gap`` refuses is listed with its one-line error;
the others go on. A progress bar counts the sessions on a terminal; ``-q`` hides it.

The batch is written in ``.OUT.partial-batch/OUT/`` beside ``OUT`` and replaces ``OUT`` only when
complete: an earlier batch in ``OUT`` (``--overwrite``) stays as it was until then. Each finished
session is kept there with its key (:mod:`aeropend_ident.gap.batch`, "Resuming"); after Ctrl-C or a
full disk, ``--resume`` computes only the sessions not finished or whose inputs changed (it also
takes unchanged sessions from an earlier complete ``OUT``). A run without ``--resume`` discards an
unfinished batch and starts again.

Exit status: 0 when every session was diagnosed, 1 when some were refused or on a full disk / a
read-only folder (one line), 130 on Ctrl-C (one line; the finished sessions kept), 2 on bad input
(no archive, no recording in it, a malformed manifest, an unknown rig, a non-empty ``OUT``).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import hashlib
import io
import json
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from aeropend_ident.cli.gap import main as gap_main
from aeropend_ident.cli.gap import resolve_rig
from aeropend_ident.errors import GapCliError, print_warnings_as_lines
from aeropend_ident.gap.batch import (
    BATCH_FILES,
    SESSION_FILE,
    Session,
    SessionCase,
    drift_across,
    find_sessions,
    finished_row,
    session_key,
    write_batch,
)
from aeropend_ident.io.jsonutil import jsonable
from aeropend_sim.output_folder import (
    OutputFolderError,
    claim_output_folder,
    exits_cleanly_on_faults,
    is_fault,
    partial_folder,
    write_file_atomically,
)
from aeropend_sim.params import RigFileError, rig_to_dict


def diagnose_session(case: SessionCase) -> dict[str, Any]:
    """Run ``gap`` on one session (in a worker); its summary for the batch table.

    Returns
    -------
    dict
        ``session``, ``recordings``, ``report`` (folder), ``exit`` (the command's status), ``error``
        (its one-line message, when refused), and from ``report.json``: ``significant``, ``chosen``,
        ``nrmse_before`` / ``nrmse_after`` (held-out θ of the nominal / corrected rig, the one free
        run's figures; None when that run diverges), ``divergence`` (run -> reasons), ``headline``,
        ``elapsed_s``.
    """
    s = case.session
    argv = [*s.recordings, "--rig", case.rig, "-o", case.out, "-q", *case.options]
    if s.held_out:
        argv += ["--held-out", *s.held_out]
    err = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = gap_main.__wrapped__(argv)  # a full disk or Ctrl-C ends the batch, not the session
    row: dict[str, Any] = {"session": s.name, "recordings": list(s.recordings), "held_out": list(s.held_out),
                           "report": case.out, "exit": int(status), "elapsed_s": time.perf_counter() - t0}
    if status != 0:
        lines = [x for x in err.getvalue().splitlines() if x.strip()]
        row["error"] = lines[-1] if lines else f"gap exited with status {status}"
    else:
        doc = json.loads((Path(case.out) / "report.json").read_text(encoding="utf-8"))
        h = doc["headline"]  # the one free run's figures: None for a run that diverges (reason: divergence)
        row.update(significant=bool(doc["which"]["significant"]), chosen=list(doc["which"]["chosen"]),
                   nrmse_before=h["heldout_nrmse_nominal"], nrmse_after=h["heldout_nrmse_corrected"],
                   divergence=h["heldout_divergence"], headline=h)
    if case.key:  # the session is finished: --resume takes it as it is while its inputs are unchanged
        Path(case.out).mkdir(parents=True, exist_ok=True)
        write_file_atomically(Path(case.out) / SESSION_FILE,
                              json.dumps(jsonable({"key": case.key, "row": row}), indent=1))
    return row


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="gap-batch", description=__doc__.splitlines()[0])
    p.add_argument("archive", type=Path, help="folder of sessions (see the module doc / docs/gap.md)")
    p.add_argument("--rig", required=True, help="nominal rig: shipped name or rig-file path (as for gap)")
    p.add_argument("-o", "--out", required=True, type=Path, help="output folder (created)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an earlier gap-batch output in --out (once the new batch is complete)")
    p.add_argument("--resume", action="store_true",
                   help="take the sessions already finished (an interrupted run's, or --out's) whose inputs "
                        "and options are unchanged; compute only the others; replaces --out when complete")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the sessions on a running Dask cluster (tcp://host:8786) instead of a local one")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="worker processes of the local cluster (default: one per core; 1: in this process)")
    p.add_argument("--preset", default=None, help="csv_import preset of CSV logs (default: by file name)")
    p.add_argument("--split", type=float, default=0.7,
                   help="fit share of each recording without held-out files (time-ordered, as gap --split)")
    p.add_argument("--max-effects", type=int, default=2,
                   help="cap on the effects per session (1-3, default 2); the data choose how many below it")
    p.add_argument("--seed", type=int, default=0, help="seed of the effect ranking's resampling")
    p.add_argument("--no-oracle", action="store_true", help="skip the best-catalog-set fit on held-out data")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    return p


@exits_cleanly_on_faults("gap-batch")
def main(argv: Sequence[str] | None = None) -> int:
    """Diagnose every session of the archive; write the reports and the drift table."""
    args = build_parser().parse_args(argv)
    print_warnings_as_lines("gap-batch")
    t0 = time.perf_counter()
    try:
        if args.workers is not None and args.workers < 1:
            raise GapCliError(f"--workers {args.workers}: expected 1 or more")
        if not 1 <= args.max_effects <= 3:
            raise GapCliError(f"--max-effects {args.max_effects}: expected 1, 2 or 3")
        if not 0.0 < args.split < 1.0:
            raise GapCliError(f"--split {args.split!r}: expected a fraction in (0, 1)")
        sessions, skipped = find_sessions(args.archive)
        rig, offset = resolve_rig(args.rig)  # an unknown rig fails here, not once per session
        folder = claim_output_folder(args.out, args.overwrite or args.resume, own=BATCH_FILES,
                                     looks_like="a gap-batch output", inputs=[args.archive],
                                     flag="--overwrite (or --resume)")
    except (GapCliError, OutputFolderError, RigFileError, ValueError) as exc:
        print(f"gap-batch: error: {exc}", file=sys.stderr)
        return 2
    stage = partial_folder(args.out, "batch")
    if not args.resume and stage.exists():
        print(f"gap-batch: note: the unfinished batch in {stage} is discarded (--resume continues from it)",
              file=sys.stderr)
        shutil.rmtree(stage)
    rig_doc = json.dumps(jsonable(rig_to_dict(rig)), sort_keys=True) + f" theta_offset={offset!r}"
    options = _options(args)
    if args.preset and Path(args.preset).is_file():  # a lab's preset file: its contents count
        options.append(hashlib.sha256(Path(args.preset).read_bytes()).hexdigest())
    keys = [_key(s, rig_doc, options) for s in sessions]
    batch = _Batch(args, argv, sessions, skipped, keys, rig, offset, t0)
    paths = folder.write(batch.write, stage=stage, keep=True)
    print(paths["md"].read_text(encoding="utf-8"), end="")
    for s in skipped:
        print(f"skipped: {s}")
    if args.resume:
        print(f"resumed: {len(batch.reused)} of {len(sessions)} session(s) taken as they were (inputs "
              f"unchanged), {len(sessions) - len(batch.reused)} computed")
    print(f"batch: {paths['json']}\ndrift table: {paths['md']}")
    return 0 if all(r.get("exit") == 0 for r in batch.rows) else 1


class _Batch:
    """One run of ``gap-batch`` writing into the temporary batch folder (:meth:`write`)."""

    def __init__(self, args: argparse.Namespace, argv: Sequence[str] | None, sessions: list[Session],
                 skipped: list[str], keys: list[str], rig: Any, offset: float, t0: float) -> None:
        self.args, self.argv, self.sessions, self.skipped, self.keys = args, argv, sessions, skipped, keys
        self.rig, self.offset, self.t0 = rig, offset, t0
        self.rows: list[dict[str, Any]] = []
        self.reused: list[str] = []

    def _taken(self, tmp: Path) -> dict[int, dict[str, Any]]:
        """Rows of the sessions finished with unchanged inputs (--resume): in ``tmp`` (an interrupted
        run) or in the earlier batch (copied into ``tmp``; the earlier batch stays as it is)."""
        rows: dict[int, dict[str, Any]] = {}
        names = {s.name for s in self.sessions}
        for entry in tmp.iterdir():  # sessions no longer in the archive, stale batch files
            if entry.name not in names:
                shutil.rmtree(entry) if entry.is_dir() else entry.unlink()
        for i, (s, key) in enumerate(zip(self.sessions, self.keys, strict=True)):
            here = tmp / s.name
            row = finished_row(here, key) if self.args.resume else None
            if row is None and self.args.resume and (earlier := finished_row(self.args.out / s.name, key)):
                if here.exists():
                    shutil.rmtree(here)
                shutil.copytree(self.args.out / s.name, here)
                row = {**earlier, "report": str(here.absolute())}
            if row is not None:
                rows[i] = row
                self.reused.append(s.name)
            elif here.exists():  # an unfinished session of an interrupted run
                shutil.rmtree(here)
        return rows

    def _earlier_drift(self, batch_key: str) -> tuple[bool, Any]:
        """The drift table of the earlier batch when every session and option is unchanged."""
        if not self.args.resume or len(self.reused) != len(self.sessions):
            return False, None
        try:
            doc = json.loads((self.args.out / "batch.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return False, None
        same = doc.get("meta", {}).get("batch_key") == batch_key and "drift_not_computed" not in doc["meta"]
        return same, doc.get("drift") if same else None

    def write(self, tmp: Path) -> dict[str, Path]:
        """Diagnose the sessions not taken, the drift table; write the batch files into ``tmp``."""
        from aeropend_ident.parallel import engine_label, run_cases

        args = self.args
        rows = self._taken(tmp)
        todo = [i for i in range(len(self.sessions)) if i not in rows]
        cases = [SessionCase(self.sessions[i], args.rig, str((tmp / self.sessions[i].name).absolute()),
                             _options(args), self.keys[i]) for i in todo]
        run = functools.partial(run_cases, workers=args.workers, scheduler=args.scheduler, quiet=args.quiet)
        for j, row in run(diagnose_session, cases, desc="gap-batch"):
            rows[todo[j]] = row
        self.rows = [rows[i] for i in range(len(self.sessions))]
        batch_key = hashlib.sha256("".join(self.keys).encode()).hexdigest()
        meta = {"archive": str(args.archive), "rig": args.rig,
                "engine": engine_label(args.workers, args.scheduler), "workers": args.workers,
                "argv": list(self.argv if self.argv is not None else sys.argv[1:]), "batch_key": batch_key,
                "reused": list(self.reused)}
        same, table = self._earlier_drift(batch_key)
        if not same:
            try:
                table = drift_across(self.rows, self.sessions, self.rig, self.offset, split=args.split,
                                     preset=args.preset, run=run)
            except Exception as exc:  # the per-session reports stand without it (not so a full disk)
                if is_fault(exc):
                    raise
                table = None
                meta["drift_not_computed"] = f"{type(exc).__name__}: {exc}"
                print(f"gap-batch: drift table not computed: {meta['drift_not_computed']}", file=sys.stderr)
        meta["wall_s"] = time.perf_counter() - self.t0
        final = Path(args.out).absolute()
        self.rows = [{**r, "report": str(final / s.name)}
                     for r, s in zip(self.rows, self.sessions, strict=True)]
        return write_batch(tmp, self.rows, self.sessions, table, self.skipped, meta)


def _key(session: Session, rig_doc: str, options: list[str]) -> str:
    """The session's key, or "" when an input cannot be read: ``gap`` then says why in the session's
    row, and such a session is never taken as it was."""
    try:
        return session_key(session, rig_doc, options)
    except OSError:
        return ""


def _options(args: argparse.Namespace) -> list[str]:
    return ["--split", str(args.split), "--max-effects", str(args.max_effects), "--seed", str(args.seed),
            *(["--preset", args.preset] if args.preset else []), *(["--no-oracle"] if args.no_oracle else [])]


if __name__ == "__main__":
    sys.exit(main())
