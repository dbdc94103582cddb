"""Command line of the grey-box baseline (console script ``baseline``).

Usage::

    baseline INPUT [INPUT ...] --rig RIG -o OUTDIR [--held-out REC [REC ...]] [--split 0.7]
             [--preset NAME] [--params NAME [NAME ...]] [--theta-offset RAD] [--init-horizon S]
             [--decimate K]

Each ``INPUT`` (and ``REC``) is a rosbag2 directory (or ``.mcap`` / ``.db3`` file) or a CSV log with
its preset (``FILE.csv:PRESET``, else ``--preset NAME``, else picked by file name), read by
:func:`aeropend_ident.io.recording_input.load_recording`, any timing (resampled by the one rule of the
tools, reported). Without ``--held-out`` each input is split in time order (``--split`` fitted);
with it the inputs are fitted whole and the held-out recordings replayed. ``RIG`` is a shipped rig
name or a rig-file path. The report folder gets
``report.json``, ``overlay.png`` and ``fitted_rig.yaml`` (see :mod:`aeropend_ident.greybox.baseline`).
A non-empty report folder is refused at once unless ``--overwrite`` is given; then the earlier
report is replaced when the new one is written (:mod:`aeropend_sim.output_folder`).

Exit status: 0 on success, 2 on bad input (the message names the problem).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from aeropend_ident.errors import IdentificationError, print_warnings_as_lines
from aeropend_ident.greybox.baseline import INIT_HORIZON, REPORT_FILES, baseline, write_report
from aeropend_ident.io.recording_input import ignored_channels, load_recording, split_preset
from aeropend_sim.output_folder import claim_output_folder, exits_cleanly_on_faults
from aeropend_sim.params import RigFileError
from aeropend_sim.recording import RecordingError


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``baseline``."""
    p = argparse.ArgumentParser(
        prog="baseline",
        description="Grey-box baseline: fit a rig's nominal model on the first part of a recording "
                    "(output error, free run), replay the held-out rest, report NRMSE nominal vs fitted.",
    )
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="bag directory (.mcap/.db3) or CSV log, optionally FILE.csv:PRESET; several are "
                        "fitted together, each from its own initial state")
    p.add_argument("--held-out", nargs="+", default=None, metavar="REC",
                   help="recording(s) held out whole: the inputs are fitted whole and these replayed "
                        "(default: each input split in time order, --split)")
    p.add_argument("--rig", required=True, help="shipped rig name (e.g. jahoyosr_rig) or rig-file path")
    p.add_argument("-o", "--out", required=True, type=Path, help="report folder (created)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the earlier baseline report in OUTDIR (only a folder that holds one)")
    p.add_argument("--preset", default=None,
                   help="CSV preset of aeropend_ident.io.csv_import when INPUT has no :PRESET "
                        "('auto' = by file name)")
    p.add_argument("--split", "--train-fraction", dest="train_fraction", type=float, default=0.7,
                   help="leading fraction of each input fitted, the rest held out (0-1; without --held-out)")
    p.add_argument("--params", nargs="+", default=None, metavar="NAME",
                   help="fitted parameters, e.g. pendulum.c_over_J actuator.dead_zone theta_offset "
                        "(default: the θ-only set of aeropend_ident.greybox.parameters.default_parameters)")
    p.add_argument("--theta-offset", type=float, default=None,
                   help="angle offset theta_model - theta_recorded [rad] (default: the rig file's)")
    p.add_argument("--init-horizon", type=float, default=INIT_HORIZON,
                   help="multiple-shooting window [s] initialising the free-run fit; 0 = off")
    p.add_argument("--decimate", type=int, default=1, help="keep every K-th sample (runtime)")
    return p


@exits_cleanly_on_faults("baseline")
def main(argv: Sequence[str] | None = None) -> int:
    """Run the baseline; print the summary; write the report folder."""
    args = build_parser().parse_args(argv)
    print_warnings_as_lines("baseline")
    try:
        given = [*args.inputs, *(args.held_out or [])]
        out = claim_output_folder(args.out, args.overwrite, own=REPORT_FILES.values(),
                                  looks_like="a baseline report", inputs=[split_preset(a)[0] for a in given])
        recs = [load_recording(a, args.preset) for a in args.inputs]
        held = [load_recording(a, args.preset) for a in args.held_out or []]
        result = baseline(
            recs, args.rig, held_out=held, train_fraction=args.train_fraction, params=args.params,
            theta_offset=args.theta_offset, init_horizon=args.init_horizon or None, decimate=args.decimate,
        )
        paths = out.write(lambda folder: write_report(result, folder))
    except (IdentificationError, RigFileError, RecordingError, ValueError) as exc:
        print(f"baseline: error: {exc}", file=sys.stderr)
        return 2
    print(result.summary())
    for line in result.report()["provenance"]["resampling"]:
        print(line)
    if note := ignored_channels([*recs, *held], "θ and the duty cycle"):
        print(note)
    for section, why in paths["not_computed"].items():
        print(f"NOT COMPUTED: {section}: {why}")
    print(f"report: {paths['report']}\noverlay: {paths.get('overlay', 'not drawn')}\n"
          f"fitted rig: {paths['fitted_rig']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
