"""Identify a sparse model from recordings: ``identify BAG_OR_CSV [...] --rig RIG --out DIR``.

Command line of ``identify`` (console script; ``ros2 run aeropend_ident identify``): argument
parsing and :func:`main` only; what is identified and written is described in
:mod:`aeropend_ident.sindy.identify`. A non-empty results folder is refused at once unless
``--overwrite`` is given (then its earlier contents are removed before the run writes there;
:mod:`aeropend_sim.output_folder`). Progress lines go to stderr, with a bar when stderr is a terminal
(:mod:`aeropend_ident.progress`); ``-q`` hides both.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from aeropend_ident.errors import (
    BagError,
    CsvImportError,
    IdentificationError,
    RecordingInputError,
    print_warnings_as_lines,
)
from aeropend_ident.io.recording_input import split_preset
from aeropend_ident.progress import reporter
from aeropend_ident.sindy.choices import LIBRARIES, METHODS, OUTPUT_FILES
from aeropend_sim.model import ModelError
from aeropend_sim.output_folder import OutputFolderError, claim_output_folder, exits_cleanly_on_faults
from aeropend_sim.params import RigFileError, load_rig
from aeropend_sim.recording import RecordingError


@exits_cleanly_on_faults("identify")
def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="identify", description=__doc__.splitlines()[0]
    )
    ap.add_argument("inputs", nargs="+", metavar="BAG_OR_CSV",
                    help="contract bags or CSV logs (FILE.csv[:PRESET])")
    ap.add_argument("--rig", help="rig name or YAML file (for the duty -> v_a map and K_q)")
    ap.add_argument("--method", default=None, choices=METHODS,
                    help="default: weak for one full-state recording, sindy otherwise; weak-iv: weak "
                         "form refined by instrumental variables (one full-state recording, λ 0.1 unless "
                         "--threshold)")
    ap.add_argument("--threshold", type=float, default=None,
                    help="fixed STLSQ threshold λ (default: chosen by BIC over a sweep)")
    ap.add_argument("--output-error", action="store_true",
                    help="refine di_a/dt and dω₁/dt by output-error minimisation (full state)")
    ap.add_argument("--library", default="physics-structured", choices=LIBRARIES,
                    help="full-state path only; physics-structured (default): θ̈ from θ alone (second-order "
                         "weak form) with thrust, gravity, damping and friction terms, di_a/dt from i_a, ω₁, "
                         "v_a, dω₁/dt from i_a, ω₁, ω₁²; full/thesis: the unrestricted 31-term library")
    ap.add_argument("--preset", default=None, help="csv_import preset for CSV inputs (default: by file name)")
    ap.add_argument("--thrust-map", default="first_order", choices=("first_order", "static"),
                    help="partial-state path (θ and τ only)")
    ap.add_argument("--train-fraction", type=float, default=0.75)
    ap.add_argument("--namespace", default="")
    ap.add_argument("-o", "--out", type=Path, default=Path("ident_results"), help="results folder (created)")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace the earlier identify results in --out (only a folder that holds them)")
    ap.add_argument("--no-plots", action="store_true")
    ap.add_argument("-q", "--quiet", action="store_true",
                    help="no progress messages or bar on stderr (the bar shows only on a terminal)")
    args = ap.parse_args(argv)
    print_warnings_as_lines("identify")
    t0 = time.perf_counter()
    with reporter("identify", quiet=args.quiet,
                  line=lambda msg: f"[identify {time.perf_counter() - t0:6.1f} s] {msg}") as say:
        return _run(args, say)


def _run(args: argparse.Namespace, say: Callable[[str], None]) -> int:
    """The command after parsing, with the progress callback of :func:`main`."""
    try:
        out = claim_output_folder(args.out, args.overwrite, own=OUTPUT_FILES, looks_like="identify results",
                                  option="-o", inputs=[split_preset(x)[0] for x in args.inputs])
        rig = load_rig(args.rig) if args.rig else None
        # pysindy and scikit-learn (1.5 s): only once the output folder and the rig are accepted
        from aeropend_ident.sindy.identify import identify
        summary = out.write(lambda folder: identify(
            args.inputs, folder, rig, args.method, args.library, args.namespace, preset=args.preset,
            train_fraction=args.train_fraction, thrust_map=args.thrust_map, plots=not args.no_plots,
            progress=say, threshold=args.threshold, output_error=args.output_error))
    except (BagError, RecordingError, IdentificationError, RigFileError, CsvImportError,
            RecordingInputError, OutputFolderError, ModelError) as exc:
        print(f"identify: error: {exc}", file=sys.stderr)
        return 2
    print("\n".join(summary["equations"]))
    for tg, why in summary["not_identified"].items():
        print(f"not identified ({tg}): {why}")
    for section, why in summary["not_computed"].items():
        print(f"NOT COMPUTED: {section}: {why}")
    if summary.get("ignored_channels"):
        print(summary["ignored_channels"])
    for line in summary["resampling"]:
        print(line)
    for sc in summary["heldout"]:
        if sc.get("diverges"):
            print(f"held-out {sc['diverges']} ({sc['recording']}): no NRMSE")
        else:
            print(f"held-out free-run NRMSE(range) of θ: {sc['nrmse_range']:.4g} ({sc['recording']})")
    for w in summary["warnings"]:
        print(f"WARNING: {w}")
    print(f"λ = {summary['threshold']:g}; results in {args.out} ({summary['wall_time_s']} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
