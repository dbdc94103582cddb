"""Command line of the sim-to-real gap diagnosis (console script ``gap``; ``ros2 run aeropend_ident gap``).

Usage::

    gap RECORDING [RECORDING ...] --rig RIG --out DIR
        [--preset NAME] [--sessions A[,A2] B[,B2] ... (instead of RECORDING ...)] [--no-oracle]
        [--held-out RECORDING [RECORDING ...] | --split FRACTION | --blocks SECONDS]
        [--block-every 3] [--block-offset 1] [--min-range RAD]
        [--validation RECORDING ... | --validation-fraction 0.3]
        [--max-effects 2 (cap, 1-3)] [--horizon 0.2] [--theta-offset RAD] [--seed 0]
        [--workers N] [--scheduler ADDRESS] [-q]

``RECORDING`` is a rosbag2 directory (or ``.mcap`` / ``.db3``) or a CSV log with its own preset
(``FILE.csv:PRESET``; else ``--preset NAME``; else picked by file name), read by
:func:`aeropend_ident.io.recording_input.load_recording`, so formats can be mixed in one call.
``RIG`` is a shipped rig name (``thesis_rig``, ``jahoyosr_rig``, ...) or a rig-file path.
The inputs ``rig fit`` takes are accepted as they are: a static table (balance or thrust table,
:mod:`aeropend_ident.greybox.rig_inputs`) among them is checked against the nominal and the
corrected rig (steady-state RMS error); free decays and holds are fitted beside the recordings
whose command changes.

Held-out rule: ``--held-out FILES`` keeps those recordings for the check only (the positional
recordings are used to find the effects); otherwise every recording is split in time order and
its last ``1 − FRACTION`` is held out (``--split``, default 0.7; a recording too short for two
parts is fitted whole, and when no usable split remains one whole recording is held out: leave
one recording out, said in the report); ``--blocks SECONDS`` holds out
every ``--block-every``-th block of that length instead, from block ``--block-offset`` (0-based,
default 1; the offsets 0 … N−1 are the folds of a cross-validation over blocks), optionally
dropping blocks whose angle moves less than ``--min-range`` (:mod:`aeropend_ident.io.split`). Inside the
fit data the diagnosis fits on the first part and chooses the effects on the last
``--validation-fraction`` (default 0.3) of each fit recording that can be split (else on one
whole fit recording: :func:`aeropend_ident.io.split.carve_validation`), or on explicit
``--validation`` recordings, so the held-out data stay unseen until the final before/after.

Before the held-out recordings are replayed, the corrected rig's held-out θ NRMSE is predicted with
an 80 % interval from the fit data and the held-out duty (never the held-out angle after its first
second); after it, the prediction is checked, the correction and
the best catalog set are fitted on each held-out recording (attainable shrink) and the held-out gap
is split into removed / removable but not removed / not removable, with a drift table of fit vs
held-out parameters; ``--sessions`` adds the leave-one-session-out diagnosis and the drift table
across sessions, whose measured drift replaces the prior in the prediction
(:mod:`aeropend_ident.gap.drift`).

The report folder gets ``report.json``, ``report.html``, ``corrected_rig.yaml`` and
``figures/*.png`` (:mod:`aeropend_ident.gap.report`); a one-screen summary is printed. A non-empty
report folder is refused at once (before any computation) unless ``--overwrite`` is given; then
the earlier report is replaced only when the new one is written, so a failed run keeps it
(:mod:`aeropend_sim.output_folder`).

Progress: one line per step on stderr and, when stderr is a terminal, a bar over the stages
(where, which, sessions, predict, after; :mod:`aeropend_ident.progress`); ``-q`` hides both. With
``--sessions`` the per-session diagnoses run as independent cases on a local Dask cluster
(``--workers``, default one per core) or on a lab's (``--scheduler``;
:mod:`aeropend_ident.parallel`).

Exit status: 0 on success, 2 on bad input (message naming the problem: unknown rig, missing
channel, too short, NaNs, bad option).
"""

from __future__ import annotations

import argparse
import itertools
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from aeropend_ident.errors import GapCliError, print_warnings_as_lines
from aeropend_ident.io.recording_input import (
    check_length,
    ignored_channels,
    load_and_split,
    load_recording,
    split_preset,
)
from aeropend_ident.io.resampling import resampling_notes, uniform_recording
from aeropend_ident.progress import reporter
from aeropend_sim.output_folder import claim_output_folder, exits_cleanly_on_faults
from aeropend_sim.params import RigFileError
from aeropend_sim.recording import Recording, RecordingError

#: Stages of the progress bar: the prefixes of :func:`aeropend_ident.gap.run.run_gap`'s messages.
STAGES = ("where", "which", "sessions", "predict", "after")


def resolve_rig(ref: str) -> tuple[object, float]:
    """Load a rig by shipped name or YAML path; return (rig, recording-frame θ offset [rad]).

    Raises
    ------
    GapCliError
        Unknown rig name, missing file or malformed rig file.
    """
    from aeropend_ident.errors import CompareError
    from aeropend_ident.gap.compare import load_model

    try:
        model = load_model(ref)
    except CompareError as exc:
        raise GapCliError(str(exc)) from exc
    if model.measurement.theta_scale != 1.0:
        raise GapCliError(
            f"rig {ref}: recording_frame.theta_scale = {model.measurement.theta_scale:g}; the gap diagnosis "
            "takes a nominal rig with a θ offset only (a sensor gain is one of the effects it finds): use "
            "the nominal rig file, or compare this one with `compare`"
        )
    return model.rig, model.measurement.theta_offset


# a table: the options of ``gap``, each with its help
def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``gap``."""
    p = argparse.ArgumentParser(
        prog="gap",
        description="Sim-to-real gap diagnosis: where the nominal simulator disagrees with the recordings, "
        "which unmodelled effect causes it, and how far the disagreement shrinks on held-out recordings.",
    )
    p.add_argument(
        "inputs", nargs="*",
        help="fit recordings: bag directories (.mcap/.db3) or CSV logs (FILE.csv[:PRESET]); at least one "
             "whose command changes (steps, PRBS, closed loop), holds and free decays beside it; static "
             "tables (balance / thrust, as rig fit takes them) are checked against both rigs"
    )
    p.add_argument(
        "--sessions",
        nargs="+",
        default=None,
        metavar="SESSION",
        help="the fit recordings grouped by session, one argument per session, recordings of a session "
        "joined by commas (A.csv B1.csv,B2.csv): leave-one-session-out diagnosis, effects per session, "
        "a parameter-drift table; replaces the positional recordings",
    )
    p.add_argument(
        "--no-oracle",
        action="store_true",
        help="attainable shrink without the best-catalog oracle (a diagnosis on each held-out recording)",
    )
    p.add_argument(
        "--rig", required=True, help="nominal rig: shipped name (e.g. thesis_rig) or rig-file path"
    )
    p.add_argument("-o", "--out", required=True, type=Path, help="report folder (created)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the earlier gap report in --out (only a folder that holds one; it is "
                   "replaced when the new report is written)")
    p.add_argument(
        "--preset", default=None, help="CSV preset of aeropend_ident.io.csv_import for CSV logs "
        "without their own FILE.csv:PRESET ('auto' = by file name)"
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--held-out",
        nargs="+",
        default=None,
        metavar="RECORDING",
        help="recordings kept for the check only (never used to find or fit the effects)",
    )
    g.add_argument(
        "--split",
        type=float,
        default=0.7,
        help="time-ordered split: leading fraction of each recording used to find the effects (0-1)",
    )
    g.add_argument(
        "--blocks",
        type=float,
        default=None,
        metavar="SECONDS",
        help="interleaved held-out blocks of this length: every --block-every-th block (from block "
        "--block-offset) held out, the others fit (held-out blocks inside the fitted operating range)",
    )
    p.add_argument(
        "--block-every", type=int, default=3, help="with --blocks: hold out every N-th block (default 3)"
    )
    p.add_argument(
        "--block-offset",
        type=int,
        default=1,
        metavar="K",
        help="with --blocks: first held-out block, 0-based (default 1); offsets 0..N-1 are the folds "
        "of a cross-validation over blocks",
    )
    p.add_argument(
        "--min-range",
        type=float,
        default=0.0,
        metavar="RAD",
        help="with --blocks: drop blocks whose recorded angle moves less than this (rod resting on a stop)",
    )
    p.add_argument(
        "--max-effects", type=int, default=2,
        help="cap on the effects added to the corrected rig (1, 2 or 3; default 2); the data choose how "
             "many below it: forward selection stops at the first effect that does not pass"
    )
    p.add_argument("--horizon", type=float, default=0.2, help="short-horizon prediction length [s]")
    p.add_argument(
        "--validation",
        nargs="+",
        default=None,
        metavar="RECORDING",
        help="explicit validation recordings on which the diagnosis chooses the effects (instead of "
        "--validation-fraction of the fit recordings)",
    )
    p.add_argument(
        "--validation-fraction",
        type=float,
        default=0.3,
        help="share of the fit data the diagnosis uses to choose the effects (train/validation/test); "
        "0 = let the held-out recordings choose them too (optimistic)",
    )
    p.add_argument(
        "--theta-offset",
        type=float,
        default=None,
        help="angle offset theta_model - theta_recorded [rad] (default: the rig file's)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the effect ranking's resampling")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="with --sessions: worker processes of the local Dask cluster that runs the sessions' "
                        "diagnoses (default: one per core; 1 runs them in this process)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="with --sessions: run the sessions' diagnoses on a running Dask cluster "
                        "(tcp://host:8786, docs/gap.md) instead of a local one")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress messages or bar")
    return p


@exits_cleanly_on_faults("gap")
def main(argv: Sequence[str] | None = None) -> int:
    """Run the gap diagnosis; print the summary; write the report folder."""
    args = build_parser().parse_args(argv)
    print_warnings_as_lines("gap")

    if args.workers is not None and args.workers < 1:
        print(f"gap: error: --workers {args.workers}: expected 1 or more", file=sys.stderr)
        return 2
    with reporter("gap", STAGES, quiet=args.quiet) as progress:
        return _run(args, progress)


def _session_inputs(args: argparse.Namespace) -> tuple[list[str], list[list[str]] | None]:
    """(fit inputs, their grouping by session or None): the positional inputs, or ``--sessions``
    (two or more groups of recordings joined by commas), never both.

    Raises
    ------
    GapCliError
        Both given, ``--sessions`` with ``--blocks``, or fewer than two non-empty sessions.
    """
    inputs: list[str] = list(args.inputs)
    if not args.sessions:
        return inputs, None
    if inputs:
        raise GapCliError("give the fit recordings either as positional arguments or as --sessions")
    if args.blocks is not None:
        raise GapCliError("--sessions works with --held-out or --split, not with --blocks")
    groups = [[x for x in g.split(",") if x] for g in args.sessions]
    if len(groups) < 2 or any(not g for g in groups):
        raise GapCliError(f"--sessions {args.sessions}: expected two or more sessions, each one or "
                          "more recordings joined by commas")
    return [x for g in groups for x in g], groups


def _validation_recordings(args: argparse.Namespace) -> list[Recording] | None:
    """``--validation`` recordings, on a uniform grid and long enough (None without the option)."""
    if not args.validation:
        return None
    val = [uniform_recording(load_recording(p, args.preset)) for p in args.validation]
    for r in val:
        check_length(r, "validation recording")
    return val


def _run(args: argparse.Namespace, progress: Callable[[str], None]) -> int:
    """The command after parsing, with the progress callback of :func:`main`."""
    from aeropend_ident.gap.report import REPORT_FILES, terminal_summary, write_report
    from aeropend_ident.gap.run import run_gap
    from aeropend_ident.greybox.rig_inputs import is_table, read_table

    try:
        given = [*args.inputs, *(args.held_out or ()), *(args.validation or ()),
                 *(x for g in args.sessions or () for x in g.split(",") if x)]
        out = claim_output_folder(args.out, args.overwrite, own=REPORT_FILES.values(),
                                  looks_like="a gap report", inputs=[split_preset(x)[0] for x in given])
        if not 1 <= args.max_effects <= 3:
            raise GapCliError(f"--max-effects {args.max_effects}: expected 1, 2 or 3")
        rig, offset = resolve_rig(args.rig)
        if args.theta_offset is not None:
            offset = float(args.theta_offset)
        inputs, groups = _session_inputs(args)
        # the inputs rig fit takes are accepted as they are: static tables (balance / thrust) are read
        # and checked against the nominal and corrected rigs; the diagnosis works on the recordings
        tables = [read_table(x) for x in inputs if is_table(x)]
        inputs = [x for x in inputs if not is_table(x)]
        if not inputs:
            raise GapCliError("no fit recording given (positional RECORDING ... or --sessions)"
                              + (": static tables alone cannot show a dynamic gap" if tables else ""))
        fit, held, rule = load_and_split(
            inputs,
            args.held_out,
            args.split,
            args.preset,
            args.blocks,
            args.block_every,
            args.min_range,
            args.block_offset,
        )
        val = _validation_recordings(args)
        if val is not None:
            rule += f"; validation file(s): {', '.join(split_preset(p)[0].name for p in args.validation)}"
        sessions, labels = None, None
        if groups is not None:
            bounds = np.cumsum([0] + [len(g) for g in groups])
            sessions = [fit[a:b] for a, b in itertools.pairwise(bounds)]
            labels = [",".join(split_preset(x)[0].name for x in g) for g in groups]
            rule += f"; {len(groups)} sessions"
        result = run_gap(
            rig,
            fit,
            held,
            rig_ref=args.rig,
            theta_offset=offset,
            split_rule=rule,  # type: ignore[arg-type]
            max_effects=args.max_effects,
            horizon=args.horizon,
            seed=args.seed,
            validation_fraction=args.validation_fraction,
            validation=val,
            progress=progress,
            sessions=sessions,
            session_labels=labels,
            oracle=not args.no_oracle,
            workers=args.workers,
            scheduler=args.scheduler,
            tables=tables,
        )
        paths = out.write(lambda folder: write_report(result, folder))
    except (RecordingError, RigFileError, ValueError) as exc:
        print(f"gap: error: {exc}", file=sys.stderr)
        return 2
    print(terminal_summary(result))
    for line in dict.fromkeys(resampling_notes([*fit, *held, *(val or [])])):
        print(line)
    if note := ignored_channels([*fit, *held, *(val or [])], "θ, the duty cycle and the contract channels"):
        print(note)
    print(f"report: {paths['report']}\nhtml: {paths['html']}\ncorrected rig: {paths['corrected_rig']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
