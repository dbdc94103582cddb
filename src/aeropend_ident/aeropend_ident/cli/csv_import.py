"""Command line of ``csv_import`` (console script; ``ros2 run aeropend_ident csv_import``).

Argument parsing and :func:`main` only: one CSV log is read with a preset (a shipped name or a
lab's preset file ``my_rig.yaml``) and/or column options by
:func:`aeropend_ident.io.csv_import.import_csv`, summarised, written as a contract bag with
:func:`aeropend_ident.io.bag_writer.write_bag` when ``-o`` is given, and the mapping saved as a
preset file with ``--write-preset`` (so a lab types its column mapping once). A non-empty bag
folder is refused before the CSV is read unless ``--overwrite`` is given (and then only one that
holds a bag, :func:`aeropend_ident.io.bag_writer.claim_bag_folder`). The input kinds, their units
and the meaning of ``--input-offset`` / ``--input-span`` come from
:data:`aeropend_ident.io.csvspec.input_kinds.INPUT_KINDS` (``--help`` prints them).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import warnings
from collections.abc import Sequence
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.errors import (
    BagError,
    CsvImportError,
    IdentWarning,
    RecordingInputError,
    print_warnings_as_lines,
)
from aeropend_ident.io.csv_import import (
    PRESETS,
    Column,
    CsvBag,
    CsvSpec,
    find_preset,
    import_csv,
    stream_csv_to_bag,
    streamable,
    summary,
)
from aeropend_ident.io.csvspec.input_kinds import INPUT_KINDS, LAWS
from aeropend_ident.io.csvspec.spec import is_preset_file, resolve_preset, write_preset_file
from aeropend_ident.io.resampling import resampling_notes, uniform_recording
from aeropend_sim.contract import EXTRA_CHANNELS
from aeropend_sim.output_folder import OutputFolderError, exits_cleanly_on_faults
from aeropend_sim.recording import MEASURED_CHANNELS

#: The earlier one-kind column flags: flag stem -> input kind.
_KIND_COLUMNS = ("duty", "percent", "pwm", "voltage")


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


def _parse_channel(s: str) -> tuple[str, tuple[Any, ...]]:
    """``NAME=COLUMN[:SCALE[:UNIT]]`` -> (name, (column, scale[, unit]))."""
    if "=" not in s:
        raise argparse.ArgumentTypeError(f"--channel {s!r}: expected NAME=COLUMN[:SCALE[:UNIT]], "
                                         "e.g. i_a='I [mA]':0.001 or x_acc=ax:9.81:m/s^2")
    name, rest = (x.strip() for x in s.split("=", 1))
    parts = rest.rsplit(":", 2)
    for n in (3, 2):  # the longest split whose SCALE is a number
        if len(parts) >= n:
            head = rest.rsplit(":", n - 1)
            try:
                scale = float(head[1])
            except ValueError:
                continue
            return name, (_col_arg(head[0]), scale, *head[2:])
    return name, (_col_arg(rest), 1.0)


def _kinds_epilog() -> str:
    """The input kinds as ``--help`` lists them (from :data:`INPUT_KINDS`)."""
    lines = ["input kinds (--input-kind): duty = (x - offset) / span, clipped to [0, 1]:"]
    for k in INPUT_KINDS.values():
        off = "required" if k.offset is None else f"{k.offset:g}"
        span = "required" if k.span is None else f"{k.span:g}"
        lines.append(f"  {k.name} [{k.unit}]: {k.meaning}; offset {off}, span {span}")
    lines.append("  e.g. an ESC calibrated to 1.1-2.3 ms: --input-kind pulse_width_ms --input-offset 1.1 "
                 "--input-span 1.2")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of the ``csv_import`` command."""
    p = argparse.ArgumentParser(
        prog="csv_import",
        description="Import a rig CSV log (time, actuator, angle, ...) into a contract rosbag2 bag.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"Presets: {', '.join(sorted(PRESETS))} (or 'auto' to pick one by file name, or a preset "
               "file my_rig.yaml; schema in docs/csv_import.md).\n\n" + _kinds_epilog(),
    )
    p.add_argument("input", type=Path, help="CSV file (.csv or .csv.gz)")
    p.add_argument("-o", "--output", type=Path,
                   help="bag directory to write (omit to only print the summary)")
    p.add_argument("--preset", help="a shipped preset's name, 'auto', or a preset file (my_rig.yaml); the "
                                    "options below override its fields")
    p.add_argument("--write-preset", type=Path, metavar="FILE.yaml",
                   help="save the column mapping the preset and options describe as a preset file (after "
                        "the CSV imported), to reuse as --preset FILE.yaml or LOG.csv:FILE.yaml")
    p.add_argument("--resample", action="store_true",
                   help="put the log on a uniform grid before writing it (the one resampling of every "
                        "command: step = the median regular interval, command held, measurements "
                        "interpolated, quantised ones at their nearest sample; jitter, dropped rows and gaps "
                        "reported). Without it the bag keeps the logger's own stamps and every command "
                        "resamples when it reads it")
    p.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    p.add_argument("--rig-name", help="rig name stored in the bag")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing bag at --output (only a folder that holds a bag) and an "
                        "existing --write-preset file")
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
    g.add_argument("--reference-col", type=_col_arg,
                   help="reference theta_ref of a closed-loop log (angle column's unit, zero and sign): "
                        "stored as the channel theta_ref, never as the input")
    g.add_argument("--channel", action="append", type=_parse_channel, default=[],
                   help="extra channel NAME=COLUMN[:SCALE[:UNIT]] (repeatable): a contract channel "
                        f"({', '.join(c for c in MEASURED_CHANNELS if c != 'theta')}, SI after SCALE) or one "
                        f"stored under its own name ({', '.join(EXTRA_CHANNELS)} or yours, with its UNIT), "
                        "e.g. i_a=current:0.001, phi=yaw, x_acc=ax:1:m/s^2")
    a = p.add_argument_group("actuator command -> duty cycle (see the input kinds below)")
    a.add_argument("--input-col", type=_col_arg, help="actuator command column")
    a.add_argument("--input-kind", choices=list(INPUT_KINDS),
                   help="how the command is logged (also the unit of --input-constant)")
    a.add_argument("--input-offset", type=float, help="logged value at duty 0 (in the kind's unit)")
    a.add_argument("--input-span", type=float, help="logged value at full duty minus --input-offset")
    a.add_argument("--input-law", choices=list(LAWS), help="rms: duty = fraction^2 (voltage only)")
    a.add_argument("--quantize-counts", type=int, help="round the duty down to multiples of 1/N")
    a.add_argument("--input-constant", type=float,
                   help="actuator value of a log without actuator column (a free decay, a step from rest); "
                        "refused when the angle shows that the actuator changed")
    for kind in _KIND_COLUMNS:
        a.add_argument(f"--{kind}-col", type=_col_arg, help=f"= --input-col COL --input-kind {kind}")
    a.add_argument("--pwm-full-scale", type=float, help="= --input-span for --input-kind pwm")
    a.add_argument("--supply-voltage", type=float, help="= --input-span for --input-kind voltage")
    a.add_argument("--voltage-law", choices=list(LAWS), help="= --input-law")
    f = p.add_argument_group("file format (auto-detected by default)")
    f.add_argument("--delimiter", help="field separator (',' ';' or 'tab')")
    f.add_argument("--decimal", choices=[".", ","])
    f.add_argument("--no-header", action="store_true")
    return p


def _base_spec(args: argparse.Namespace) -> CsvSpec | None:
    """The preset the options start from (None: none given)."""
    preset = args.preset
    if preset == "auto":
        preset = find_preset(args.input)
        if preset is None:
            raise CsvImportError(f"{args.input}: no preset matches this file name; "
                                 f"available: {sorted(PRESETS)}")
    return None if preset is None else resolve_preset(preset)


def _input_overrides(args: argparse.Namespace, base: CsvSpec | None) -> dict[str, Any]:
    """The actuator fields of the options (column, kind, map, constant); earlier flags translated."""
    over: dict[str, Any] = {}
    given = [(f"--{k}-col", k, getattr(args, f"{k}_col")) for k in _KIND_COLUMNS
             if getattr(args, f"{k}_col") is not None]
    if args.input_col is not None:
        given.append(("--input-col", args.input_kind, args.input_col))
    if len(given) > 1:
        raise CsvImportError(f"give one actuator column, got {[g[0] for g in given]}")
    kind = args.input_kind
    if given:
        flag, kind, over["input_col"] = given[0]
        if flag != "--input-col" and args.input_kind not in (None, kind):
            raise CsvImportError(f"{flag} is --input-kind {kind}, not {args.input_kind}")
        if kind is None:
            kind = base.input_kind if base is not None else None
            if kind is None:
                raise CsvImportError(f"--input-col needs --input-kind (one of {', '.join(INPUT_KINDS)})")
    elif args.input_constant is not None:
        over["input_col"] = None
    if args.input_constant is not None:
        over["input_constant"] = args.input_constant
    if kind is not None:
        over["input_kind"] = kind
        if base is not None and kind != base.input_kind:  # the preset's map is another kind's
            over.update(input_offset=None, input_span=None, input_law="linear")
    effective = kind or (base.input_kind if base is not None else "duty")
    for flag, key, value, only in (("--pwm-full-scale", "input_span", args.pwm_full_scale, "pwm"),
                                   ("--supply-voltage", "input_span", args.supply_voltage, "voltage"),
                                   ("--voltage-law", "input_law", args.voltage_law, "voltage")):
        if value is None:
            continue
        if effective != only:
            raise CsvImportError(f"{flag} applies to --input-kind {only}, not {effective}")
        if getattr(args, key) is not None and getattr(args, key) != value:
            raise CsvImportError(f"{flag} {value} and --{key.replace('_', '-')} {getattr(args, key)} "
                                 "disagree")
        over[key] = value
    for key in ("input_offset", "input_span", "input_law", "quantize_counts"):
        if getattr(args, key) is not None:
            over[key] = getattr(args, key)
    return over


def spec_from_args(args: argparse.Namespace) -> CsvSpec:
    """Build the :class:`CsvSpec` of parsed CLI arguments (preset + overrides)."""
    base = _base_spec(args)
    over: dict[str, Any] = {}
    for key in ("time_col", "time_unit", "rate_hz", "angle_col", "angle_unit", "angle_zero", "angle_sign",
                "reference_col", "decimal"):
        val = getattr(args, key)
        if val is not None:
            over[key] = val
    over.update(_input_overrides(args, base))
    contract = {n: c for n, c in args.channel if n in MEASURED_CHANNELS}
    bad = [n for n, c in contract.items() if len(c) > 2]
    if bad:
        raise CsvImportError(f"--channel {bad[0]}: a contract channel is in SI units; give "
                             "NAME=COLUMN[:SCALE] without a unit")
    if contract:
        over["channels"] = contract
    extra = {n: (c[0], c[1], c[2] if len(c) > 2 else "") for n, c in args.channel
             if n not in MEASURED_CHANNELS}
    if extra:
        over["extra_channels"] = {**(base.extra_channels if base else {}), **extra}
    if args.delimiter is not None:
        over["delimiter"] = "\t" if args.delimiter in ("tab", "\\t") else args.delimiter
    if args.no_header:
        over["header"] = False
    if base is not None:
        return replace(base, **over)
    if "angle_col" not in over:
        raise CsvImportError("no --preset and no --angle-col: say which column holds the angle")
    if "time_col" in over and over.get("time_unit") is None:
        over["time_unit"] = "s"
    return CsvSpec(name="cli", **over)


def _bag_note(rec: Any, args: argparse.Namespace) -> str:
    """What the bag holds, per topic (as ``topics`` and ``play`` will show it)."""
    commands = rec.commands if isinstance(rec, CsvBag) else int(np.isfinite(rec.duty).sum())
    parts = [f"{len(rec)} joint_states", f"{len(rec)} armature", f"{commands} duty_cycle"]
    if "theta_ref" in rec.extra:
        parts.append(f"{int(np.isfinite(rec.extra['theta_ref']).sum())} reference")
    if set(rec.extra) - {"theta_ref", "phi", "phi_dot"}:
        parts.append(f"{len(rec)} extra_channels")
    return f" Wrote {args.storage} bag {args.output} ({' + '.join(parts)} messages)."


def _import(args: argparse.Namespace, spec: CsvSpec, target: Any) -> Any:
    """Import the CSV: streamed into the bag when it goes straight to one (no ``--resample``, no
    extra channels), else read whole, resampled if asked and written. Either bag is written beside
    its final place and renamed into it once complete (:meth:`OutputFolder.write`): an error, a full
    disk or Ctrl-C late in the file leaves no partial bag and an earlier bag (--overwrite) untouched."""
    bad_rows = "drop" if args.drop_bad_rows else "error"
    if target is not None and not args.resample and streamable(spec):
        from aeropend_ident.progress import bar

        with bar(max(1, args.input.stat().st_size), "csv_import", unit="B", unit_scale=True,
                 delay=2.0) as b:
            def progress(done: int, total: int) -> None:
                b.update(done - b.n)

            res = target.write(lambda folder: stream_csv_to_bag(
                args.input, folder, spec, args.storage, args.rig_name, bad_rows,
                lambda d: start_time_ns(args.start_time, args.input, d), progress), create=False)
        res.bag = Path(target.path)
        return res
    rec = import_csv(args.input, spec, bad_rows)
    if args.resample:
        rec = uniform_recording(rec)
    # a real start time (Foxglove and rosbag2 tools show 1970 for stamps from 0)
    rec = replace(rec, stamp0_ns=start_time_ns(args.start_time, args.input, float(rec.t[-1])))
    if target is not None:
        from aeropend_ident.io.bag_writer import write_bag

        target.write(lambda folder: write_bag(rec, folder, storage=args.storage, rig_name=args.rig_name),
                     create=False)
    return rec


@exits_cleanly_on_faults("csv_import")
def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``csv_import``: CSV -> contract bag (and preset file); prints a summary."""
    args = build_parser().parse_args(argv if argv is not None else sys.argv[1:])
    print_warnings_as_lines("csv_import")
    from aeropend_ident.io.bag_writer import claim_bag_folder

    try:
        target = None if args.output is None else claim_bag_folder(
            args.output, args.overwrite, inputs=[args.input], option="-o", flag="--overwrite")
        if args.write_preset is not None:
            if not is_preset_file(args.write_preset):
                raise CsvImportError(f"--write-preset {args.write_preset}: expected a .yaml or .yml file "
                                     "name")
            if args.write_preset.exists() and not args.overwrite:
                raise CsvImportError(f"--write-preset {args.write_preset} already exists; choose another "
                                     "name or pass --overwrite")
        spec = spec_from_args(args)
        if args.write_preset is not None:
            spec = replace(spec, name=args.write_preset.stem)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # duty clipping: counted in the summary
            warnings.simplefilter("default", IdentWarning)  # rows dropped, cut, constant input: printed
            rec = _import(args, spec, target)
        if args.write_preset is not None:
            command = shlex.join(["csv_import", *(argv if argv is not None else sys.argv[1:])])
            write_preset_file(spec, args.write_preset, overwrite=args.overwrite, comment=(
                f"csv_import preset '{args.write_preset.stem}' (schema: docs/csv_import.md), written by\n"
                f"  {command}\n"
                f"use: csv_import LOG.csv --preset {args.write_preset.name}, or "
                f"LOG.csv:{args.write_preset.name} wherever a recording is given"))
    except (CsvImportError, BagError, OutputFolderError, RecordingInputError) as exc:
        print(f"csv_import: error: {exc}", file=sys.stderr)
        return 1
    text = summary(rec)
    for note in resampling_notes([rec]):
        text += f" {note[0].upper()}{note[1:]}."
    if args.output is not None:
        text += _bag_note(rec, args)
    if args.write_preset is not None:
        text += (f" Wrote preset {args.write_preset} (--preset {args.write_preset} or "
                 f"LOG.csv:{args.write_preset}).")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
