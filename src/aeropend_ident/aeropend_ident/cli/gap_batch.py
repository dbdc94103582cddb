"""The gap diagnosis over a folder of sessions (console script ``gap-batch``).

Usage::

    gap-batch ARCHIVE/ --rig RIG -o OUT [--scheduler ADDRESS | --workers N]
        [--preset NAME] [--split 0.7] [--max-effects 2] [--seed 0] [--no-oracle] [--overwrite] [-q]

Runs ``gap`` on every session of ``ARCHIVE`` (a manifest ``sessions.yaml``, or one session per bag
folder / ``.mcap`` / ``.db3`` / CSV log directly in it: :mod:`aeropend_ident.archive`), each as one
case of a Dask cluster: a local one of ``--workers`` processes (default one per core), or a lab's
running cluster with ``--scheduler tcp://HOST:8786`` (docs/gap.md, "Batches on a cluster"; the
workers must reach the archive and ``OUT`` under the same paths). Writes ``OUT/<session>/`` (the
``gap`` report of each session), ``OUT/batch.json`` (every session's outcome, the drift table, the
entries skipped) and ``OUT/drift.md`` (the per-session table and which parameters drift between
sessions); prints the per-session table. A session ``gap`` refuses is listed with its one-line error;
the others go on. A progress bar counts the sessions on a terminal; ``-q`` hides it.

Exit status: 0 when every session was diagnosed, 1 when some were refused, 2 on bad input (no
archive, no recording in it, a malformed manifest, an unknown rig, a non-empty ``OUT``).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from aeropend_ident.archive import (
    BATCH_FILES,
    SessionCase,
    drift_across,
    find_sessions,
    write_batch,
)
from aeropend_ident.cli.gap import main as gap_main
from aeropend_ident.cli.gap import resolve_rig
from aeropend_ident.errors import GapCliError, print_warnings_as_lines
from aeropend_sim.output_folder import OutputFolderError, claim_output_folder
from aeropend_sim.params import RigFileError


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
        status = gap_main(argv)
    row: dict[str, Any] = {"session": s.name, "recordings": list(s.recordings), "held_out": list(s.held_out),
                           "report": case.out, "exit": int(status), "elapsed_s": time.perf_counter() - t0}
    if status != 0:
        lines = [x for x in err.getvalue().splitlines() if x.strip()]
        row["error"] = lines[-1] if lines else f"gap exited with status {status}"
        return row
    doc = json.loads((Path(case.out) / "report.json").read_text(encoding="utf-8"))
    h = doc["headline"]  # the one free run's figures: None for a run that diverges (the reason: divergence)
    row.update(significant=bool(doc["which"]["significant"]), chosen=list(doc["which"]["chosen"]),
               nrmse_before=h["heldout_nrmse_nominal"], nrmse_after=h["heldout_nrmse_corrected"],
               divergence=h["heldout_divergence"], headline=h)
    return row


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="gap-batch", description=__doc__.splitlines()[0])
    p.add_argument("archive", type=Path, help="folder of sessions (see the module doc / docs/gap.md)")
    p.add_argument("--rig", required=True, help="nominal rig: shipped name or rig-file path (as for gap)")
    p.add_argument("-o", "--out", required=True, type=Path, help="output folder (created)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier gap-batch output in --out")
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


def main(argv: Sequence[str] | None = None) -> int:
    """Diagnose every session of the archive; write the reports and the drift table."""
    args = build_parser().parse_args(argv)
    print_warnings_as_lines("gap-batch")
    from aeropend_ident.parallel import engine_label, run_cases

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
        folder = claim_output_folder(args.out, args.overwrite, own=BATCH_FILES,
                                     looks_like="a gap-batch output", inputs=[args.archive])
        out = folder.prepare()
    except (GapCliError, OutputFolderError, RigFileError, ValueError) as exc:
        print(f"gap-batch: error: {exc}", file=sys.stderr)
        return 2
    options = ["--split", str(args.split), "--max-effects", str(args.max_effects), "--seed", str(args.seed),
               *(["--preset", args.preset] if args.preset else []),
               *(["--no-oracle"] if args.no_oracle else [])]
    cases = [SessionCase(s, args.rig, str((out / s.name).resolve()), options) for s in sessions]
    run = functools.partial(run_cases, workers=args.workers, scheduler=args.scheduler, quiet=args.quiet)
    rows = dict(run(diagnose_session, cases, desc="gap-batch"))
    rows_list = [rows[i] for i in range(len(cases))]
    meta = {"archive": str(args.archive), "rig": args.rig,
            "engine": engine_label(args.workers, args.scheduler), "workers": args.workers,
            "argv": list(argv if argv is not None else sys.argv[1:])}
    try:
        table = drift_across(rows_list, sessions, rig, offset, split=args.split, preset=args.preset, run=run)
    except Exception as exc:  # the per-session reports stand without it
        table = None
        meta["drift_not_computed"] = f"{type(exc).__name__}: {exc}"
        print(f"gap-batch: drift table not computed: {meta['drift_not_computed']}", file=sys.stderr)
    meta["wall_s"] = time.perf_counter() - t0
    paths = write_batch(out, rows_list, sessions, table, skipped, meta)
    print(paths["md"].read_text(encoding="utf-8"), end="")
    for s in skipped:
        print(f"skipped: {s}")
    print(f"batch: {paths['json']}\ndrift table: {paths['md']}")
    return 0 if all(r.get("exit") == 0 for r in rows_list) else 1


if __name__ == "__main__":
    sys.exit(main())
