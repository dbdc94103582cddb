"""Command line of ``compare`` (console script; ``ros2 run aeropend_ident compare``).

Usage::

    compare RECORDING [RECORDING ...] --rig RIG [RIG ...] -o OUTDIR
            [--label NAME ...] [--preset NAME] [--channels theta i_a ...] [--min-hold 1.0] [--no-plots]

Replays each rig (shipped name or rig-file path: a nominal rig, ``baseline``'s
``fitted_rig.yaml``, ``gap``'s ``corrected_rig.yaml``) on each recording and scores every recorded
channel (:mod:`aeropend_ident.gap.compare`). ``RECORDING`` is a bag (directory, ``.mcap``, ``.db3``)
or a CSV log with its own preset, ``FILE.csv:PRESET`` (else ``--preset``, else by file name), so
recordings of different formats mix in one call.

The report folder gets ``compare.json`` (every score, per rig and recording) and
``overlay_<recording>.png`` (:data:`REPORT_FILES`); a table is printed (θ NRMSE, fit %, max error,
steady-state error, whiteness per rig and recording). A non-empty report folder is refused at once
unless ``--overwrite`` is given; then its earlier contents (an earlier run's overlays included) are
removed when the new report is written (:mod:`aeropend_sim.output_folder`).

Exit status: 0 on success (also when a rig's replay fails on some recording: that pair reports
its error, the others are kept), 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from aeropend_ident.errors import CompareError, print_warnings_as_lines
from aeropend_ident.gap.holds import MIN_HOLD
from aeropend_ident.io.jsonutil import jsonable
from aeropend_ident.io.recording_input import ignored_channels, load_recording, split_preset
from aeropend_ident.io.resampling import resampling_notes, uniform_recording
from aeropend_sim.output_folder import claim_output_folder, exits_cleanly_on_faults
from aeropend_sim.recording import RecordingError

if TYPE_CHECKING:
    from aeropend_ident.gap.compare import CompareResult


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``compare``."""
    p = argparse.ArgumentParser(
        prog="compare",
        description="Replay rig files (nominal, fitted, corrected) on recordings; per-channel NRMSE, fit %, "
        "max and steady-state error, step metrics, residual whiteness, overlay plots and JSON.",
    )
    p.add_argument("inputs", nargs="+", metavar="RECORDING",
                   help="bag directories (.mcap/.db3) or CSV logs, FILE.csv[:PRESET]")
    p.add_argument("--rig", nargs="+", required=True, metavar="RIG",
                   help="shipped rig names or rig-file paths (.yaml), replayed in this order")
    p.add_argument("--label", nargs="+", default=None, metavar="NAME",
                   help="one label per --rig (default: the rig name or file stem)")
    p.add_argument("-o", "--out", required=True, type=Path, help="report folder (created)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the earlier compare report in OUTDIR (only a folder that holds one)")
    p.add_argument("--preset", default=None,
                   help="CSV preset for logs without their own :PRESET ('auto' = by file name)")
    p.add_argument("--channels", nargs="+", default=None, metavar="CHANNEL",
                   help="channels compared (theta, i_a, v_a, omega_rotor); default: every recorded one")
    p.add_argument("--min-hold", type=float, default=MIN_HOLD,
                   help="shortest constant-duty hold for steady-state errors and step metrics [s]")
    p.add_argument("--no-plots", action="store_true", help="no overlay PNGs")
    return p


def summary_table(result: CompareResult) -> str:
    """Plain-text table: one row per recording and rig, θ scores and the other channels' NRMSE."""
    from aeropend_ident.greybox.replay import NRMSE_RULE, START_RULE, start_text

    head = (f"{'recording':<28} {'rig':<24} {'θ NRMSE':>8} {'fit %':>7} {'max err':>8} {'ss err':>8} "
            f"{'white':>5} {'u-corr':>6}  other channels (NRMSE)")
    rows = [head, "-" * len(head)]
    for rec in result.recordings:
        for m in result.scores:
            sc = result.scores[m].get(rec["label"], {})
            if "error" in sc:
                rows.append(f"{rec['label'][:28]:<28} {m[:24]:<24} replay failed: {sc['error']}")
                continue
            th = sc["channels"]["theta"]
            other = ", ".join(f"{c} {v['nrmse']:.3g}" for c, v in sc["channels"].items()
                              if c != "theta" and math.isfinite(v["nrmse"]))
            if th.get("diverges"):
                rows.append(f"{rec['label'][:28]:<28} {m[:24]:<24} DIVERGES: {th['diverges']}")
                continue
            w = th["whiteness"]
            rows.append(
                f"{rec['label'][:28]:<28} {m[:24]:<24} {th['nrmse']:8.4f} {th['fit_percent']:7.1f} "
                f"{th['max_abs_error']:8.4f} {th['steady_state_error']['rms']:8.4f} "
                f"{'yes' if w['white'] else 'no':>5} {'yes' if w['input_correlated'] else 'no':>6}  {other}"
            )
    starts = []
    for rec in result.recordings:  # the one replay's start, stated for every free run
        for m in result.scores:
            run = result.scores[m].get(rec["label"], {}).get("free_run")
            if run:
                starts.append(f"  {rec['label']} ({m}): {start_text(run['initial_state'])}")
    if starts:
        rows += [f"free-run start ({START_RULE}); θ NRMSE = {NRMSE_RULE}:", *starts]
    return "\n".join(rows)


def _file_label(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label)


#: What :func:`write_report` writes: the scores and one overlay per recording (``{}``: its label).
REPORT_FILES = {"json": "compare.json", "overlay": "overlay_{}.png"}


def write_report(result: CompareResult, out: Path, plots: bool = True) -> dict[str, Path]:
    """Write ``compare.json`` and (``plots``) ``overlay_<recording>.png`` into ``out`` (created)."""
    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": out / REPORT_FILES["json"]}
    paths["json"].write_text(json.dumps(jsonable(result.as_dict()), indent=1, allow_nan=False) + "\n",
                             encoding="utf-8")
    if plots:
        from aeropend_ident.gap.compare_plot import plot_overlay

        for rec in result.recordings:
            if result.traces.get(rec["label"], {}).get("simulated"):
                name = REPORT_FILES["overlay"].format(_file_label(rec["label"]))
                paths[Path(name).stem] = plot_overlay(result, rec["label"], out / name)
    return paths


@exits_cleanly_on_faults("compare")
def main(argv: Sequence[str] | None = None) -> int:
    """Run ``compare``; print the table; write the report folder."""
    args = build_parser().parse_args(argv)
    print_warnings_as_lines("compare")
    from aeropend_ident.gap.compare import compare, load_model  # scipy: not for --help

    try:
        out = claim_output_folder(args.out, args.overwrite, looks_like="a compare report",
                                  own=[n.format("*") for n in REPORT_FILES.values()],
                                  inputs=[split_preset(x)[0] for x in args.inputs])
        if args.label is not None and len(args.label) != len(args.rig):
            raise CompareError(
                f"--label: {len(args.label)} label(s) for {len(args.rig)} rig(s); give one per rig")
        if not args.min_hold > 0.0:
            raise CompareError(f"--min-hold {args.min_hold!r}: expected a duration > 0 [s]")
        labels = args.label or [None] * len(args.rig)
        models = [load_model(r, lab) for r, lab in zip(args.rig, labels, strict=True)]
        recs = [uniform_recording(load_recording(p, args.preset)) for p in args.inputs]
        result = compare(models, recs, args.channels, args.min_hold)
        paths = out.write(lambda folder: write_report(result, folder, plots=not args.no_plots))
    except (RecordingError, ValueError) as exc:
        print(f"compare: error: {exc}", file=sys.stderr)
        return 2
    print(summary_table(result))
    for line in resampling_notes(recs):
        print(line)
    if note := ignored_channels(recs, "θ, the duty cycle and the contract channels"):
        print(note)
    print(f"report: {paths['json']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
