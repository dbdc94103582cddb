"""Command line of ``csv_import`` (console script; ``ros2 run aeropend_ident csv_import``).

Argument parsing and :func:`main` only: one CSV log is read with a preset and/or column options by
:func:`aeropend_ident.io.csv_import.import_csv`, summarised, and written as a contract bag with
:func:`aeropend_ident.io.bag_writer.write_bag` when ``-o`` is given. A non-empty bag folder is
refused before the CSV is read unless ``--overwrite`` is given (and then only one that holds a bag,
:func:`aeropend_ident.io.bag_writer.claim_bag_folder`).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Sequence
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.errors import BagError, CsvImportError, IdentWarning, print_warnings_as_lines
from aeropend_ident.io.csv_import import (
    PRESETS,
    Column,
    CsvSpec,
    find_preset,
    import_csv,
    summary,
)
from aeropend_sim.output_folder import OutputFolderError


def _start_time(text: str) -> str:
    """Validate ``--start-time`` (kept as text; :func:`start_time_ns` resolves it)."""
    if text not in ("file", "zero"):
        try:
            datetime.fromisoformat(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"--start-time {text!r}: expected an ISO-8601 instant, 'file' or 'zero'") from None
    return text


def start_time_ns(option: str, path: Path, duration_s: float) -> int:
    """Wall-clock instant [ns since the epoch] of the first sample for ``--start-time``: an
    ISO-8601 instant (UTC unless it carries an offset), ``file`` (the file's modification time
    minus ``duration_s``: a logger closes its file after the last sample) or ``zero``."""
    if option == "zero":
        return 0
    if option == "file":
        return max(0, path.stat().st_mtime_ns - round(duration_s * 1e9))
    when = datetime.fromisoformat(option)
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    return round(when.timestamp() * 1e9)


def _col_arg(s: str) -> Column:
    return int(s) if s.lstrip("-").isdigit() else s


def _parse_channel(s: str) -> tuple[str, tuple[Column, float]]:
    """``NAME=COLUMN[:SCALE]`` -> (name, (column, scale))."""
    if "=" not in s:
        raise argparse.ArgumentTypeError(f"--channel {s!r}: expected NAME=COLUMN[:SCALE], "
                                         "e.g. i_a='I [mA]':0.001")
    name, rest = s.split("=", 1)
    scale = 1.0
    if ":" in rest:
        col, sc = rest.rsplit(":", 1)
        try:
            scale = float(sc)
            rest = col
        except ValueError:
            pass
    return name.strip(), (_col_arg(rest), scale)


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of the ``csv_import`` command."""
    p = argparse.ArgumentParser(
        prog="csv_import",
        description="Import a rig CSV log (time, actuator, angle, ...) into a contract rosbag2 bag.",
        epilog=f"Presets: {', '.join(sorted(PRESETS))} (or 'auto' to pick one by file name).",
    )
    p.add_argument("input", type=Path, help="CSV file (.csv or .csv.gz)")
    p.add_argument("-o", "--output", type=Path,
                   help="bag directory to write (omit to only print the summary)")
    p.add_argument("--preset", help="named CsvSpec (options below override its fields)")
    p.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    p.add_argument("--rig-name", help="rig name stored in the bag")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing bag at --output (only a folder that holds a bag)")
    p.add_argument("--drop-bad-rows", action="store_true",
                   help="leave out rows that are short, cut, have an extra field, a non-number or NaN/inf "
                        "in a used column (and a last line without line break, the unreadable end of a cut "
                        ".gz) instead of refusing the file; prints the count and the first lines dropped")
    p.add_argument("--start-time", type=_start_time, default="file", metavar="ISO|file|zero",
                   help="wall-clock time of the first sample in the bag: an ISO-8601 instant "
                        "(2024-03-01T14:05:00+01:00, UTC when no offset is given), 'file' (the CSV's "
                        "modification time minus the recording's length; default) or 'zero' (1970)")
    g = p.add_argument_group("column mapping (name or 0-based index)")
    g.add_argument("--time-col", type=_col_arg)
    g.add_argument("--time-unit", choices=["s", "ms", "us", "sample"])
    g.add_argument("--rate", type=float, dest="rate_hz", help="sample rate [Hz] when there is no time column")
    g.add_argument("--angle-col", type=_col_arg)
    g.add_argument("--angle-unit", choices=["rad", "deg"])
    g.add_argument("--angle-zero", type=float, help="raw angle at theta = 0 (column unit)")
    g.add_argument("--angle-sign", type=float, choices=[1.0, -1.0])
    g.add_argument("--duty-col", type=_col_arg, help="duty fraction column")
    g.add_argument("--percent-col", type=_col_arg, help="duty percent column")
    g.add_argument("--pwm-col", type=_col_arg, help="PWM counts column")
    g.add_argument("--pwm-full-scale", type=float)
    g.add_argument("--voltage-col", type=_col_arg, help="actuator voltage column [V]")
    g.add_argument("--supply-voltage", type=float, help="voltage at 100 %% duty [V]")
    g.add_argument("--voltage-law", choices=["linear", "rms"])
    g.add_argument("--input-constant", type=float, help="constant actuator value when the file has no column")
    g.add_argument("--input-kind", choices=["duty", "percent", "pwm", "voltage"],
                   help="unit of --input-constant")
    g.add_argument("--channel", action="append", type=_parse_channel, default=[],
                   help="extra channel NAME=COLUMN[:SCALE], e.g. i_a=current:0.001 (repeatable)")
    f = p.add_argument_group("file format (auto-detected by default)")
    f.add_argument("--delimiter", help="field separator (',' ';' or 'tab')")
    f.add_argument("--decimal", choices=[".", ","])
    f.add_argument("--no-header", action="store_true")
    return p


def spec_from_args(args: argparse.Namespace) -> CsvSpec:
    """Build the :class:`CsvSpec` of parsed CLI arguments (preset + overrides)."""
    preset = args.preset
    if preset == "auto":
        preset = find_preset(args.input)
        if preset is None:
            raise CsvImportError(f"{args.input}: no preset matches this file name; "
                                 f"available: {sorted(PRESETS)}")
    if preset is not None and preset not in PRESETS:
        raise CsvImportError(f"unknown preset {preset!r}; available: {sorted(PRESETS)}")
    over: dict[str, Any] = {}
    for key in ("time_col", "time_unit", "rate_hz", "angle_col", "angle_unit", "angle_zero", "angle_sign",
                "pwm_full_scale", "supply_voltage", "voltage_law", "input_constant", "decimal"):
        val = getattr(args, key)
        if val is not None:
            over[key] = val
    inputs = [(k, getattr(args, f"{k}_col")) for k in ("duty", "percent", "pwm", "voltage")
              if getattr(args, f"{k}_col") is not None]
    if len(inputs) > 1:
        raise CsvImportError(f"give one actuator column, got {[f'--{k}-col' for k, _ in inputs]}")
    if inputs:
        over["input_kind"], over["input_col"] = inputs[0]
    elif args.input_kind is not None:
        over["input_kind"] = args.input_kind
    if args.input_constant is not None and not inputs:
        over["input_col"] = None
    if args.channel:
        over["channels"] = dict(args.channel)
    if args.delimiter is not None:
        over["delimiter"] = "\t" if args.delimiter in ("tab", "\\t") else args.delimiter
    if args.no_header:
        over["header"] = False
    if preset is not None:
        return replace(PRESETS[preset], **over)
    if "angle_col" not in over:
        raise CsvImportError("no --preset and no --angle-col: say which column holds the angle")
    if "time_col" in over and over.get("time_unit") is None:
        over["time_unit"] = "s"
    return CsvSpec(name="cli", **over)


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``csv_import``: CSV -> contract bag, prints a one-paragraph summary."""
    args = build_parser().parse_args(argv)
    print_warnings_as_lines("csv_import")
    from aeropend_ident.io.bag_writer import claim_bag_folder, write_bag

    try:
        target = None if args.output is None else claim_bag_folder(
            args.output, args.overwrite, inputs=[args.input], option="-o", flag="--overwrite")
        spec = spec_from_args(args)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # duty clipping: counted in the summary
            warnings.simplefilter("default", IdentWarning)  # rows dropped or possibly cut: printed
            rec = import_csv(args.input, spec, "drop" if args.drop_bad_rows else "error")
        # a real start time (Foxglove and rosbag2 tools show 1970 for stamps from 0)
        rec = replace(rec, stamp0_ns=start_time_ns(args.start_time, args.input, float(rec.t[-1])))
        if target is not None:
            write_bag(rec, target.prepare(create=False), storage=args.storage, rig_name=args.rig_name)
    except (CsvImportError, BagError, OutputFolderError) as exc:
        print(f"csv_import: error: {exc}", file=sys.stderr)
        return 1
    text = summary(rec)
    if args.output is not None:
        text += f" Wrote {args.storage} bag {args.output} ({len(rec)} joint_states + {len(rec)} armature + " \
                f"{int(np.isfinite(rec.duty).sum())} duty_cycle messages)."
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
