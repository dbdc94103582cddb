"""Console script ``rig`` (``ros2 run aeropend_ident rig``): make, fit and check a lab's rig file.

Usage::

    rig new --actuator {dc_hbridge,esc,voltage_amplifier} [--stated NAME=VALUE[unit] ...]
            [--name NAME] -o my_rig.yaml [--overwrite]
    rig fit my_rig.yaml INPUT... -o fitted.yaml [--preset NAME] [--overwrite] [-q]
    rig check my_rig.yaml [INPUT...] [--preset NAME]

``INPUT`` is a static table (a CSV with a header ``command,angle_rad[,angle_std_rad]`` or
``command,thrust_N[,thrust_std_N]``) or a recording (a bag, ``FILE.csv:PRESET``); see
docs/rig_command.md. The command lives in ``aeropend_ident`` beside what it runs (``rig fit`` is
:mod:`aeropend_ident.greybox.rig_fit`, ``rig check`` :mod:`aeropend_ident.greybox.rig_check`);
those modules are imported when their subcommand runs, so ``rig new`` and ``--help`` stay quick.
An existing output file is never replaced without ``--overwrite``
(:mod:`aeropend_sim.output_folder`).

Exit status: 0 on success, 2 on bad input (one line on stderr naming the problem).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from aeropend_sim.components import registry
from aeropend_sim.output_folder import (
    OutputFolderError,
    check_output_file,
    exits_cleanly_on_faults,
    is_fault,
    write_file_atomically,
)
from aeropend_sim.params import RigFileError, load_rig
from aeropend_sim.rigfile.template import new_rig_text, parse_stated


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``rig``."""
    p = argparse.ArgumentParser(prog="rig", description="Make a rig file for your own aeropendulum (new), "
                                "fit what it leaves to be fitted from your tables and recordings (fit), and "
                                "check what it states, fits and can reach (check).")
    sub = p.add_subparsers(dest="command", required=True, metavar="{new,fit,check}")
    families = [f.name for f in registry.families()]
    n = sub.add_parser("new", help="write a rig file with every parameter of an actuator family marked "
                       "stated / to be fitted / not modelled")
    n.add_argument("--actuator", required=True, choices=families, help="actuator family")
    n.add_argument("--stated", nargs="+", default=[], metavar="NAME=VALUE[unit]",
                   help="what you know, e.g. pendulum.mass=0.12kg motor.T_m=80ms (units converted)")
    n.add_argument("--name", default=None, help="rig name (default: the output file's stem)")
    n.add_argument("-o", "--out", required=True, type=Path, help="rig file to write (.yaml)")
    n.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    f = sub.add_parser("fit", help="fit every 'to be fitted' parameter from static tables and recordings")
    f.add_argument("rig", help="rig file (rig new's, edited)")
    f.add_argument("inputs", nargs="+", metavar="INPUT", help="static table CSV, bag or FILE.csv:PRESET")
    f.add_argument("-o", "--out", required=True, type=Path, help="fitted rig file to write (.yaml)")
    f.add_argument("--preset", default=None, help="CSV preset for recordings without :PRESET")
    f.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    f.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    c = sub.add_parser("check", help="what the rig file states, fits and defaults; sensitivity of "
                       "recordings; reach")
    c.add_argument("rig", help="rig file or shipped rig name")
    c.add_argument("inputs", nargs="*", metavar="INPUT", help="static table CSV, bag or FILE.csv:PRESET")
    c.add_argument("--preset", default=None, help="CSV preset for recordings without :PRESET")
    return p


def _new(args: argparse.Namespace) -> int:
    out = check_output_file(args.out, args.overwrite)
    if out.suffix not in (".yaml", ".yml"):
        raise RigFileError(f"-o {out}: a rig file ends in .yaml")
    stated = parse_stated(args.actuator, args.stated)
    text = new_rig_text(args.actuator, stated, name=args.name or out.stem, file=out.name)
    write_file_atomically(out, text)
    rig = load_rig(out)
    todo = sum(rig.status(k) == "to be fitted" for k in registry.family_params(rig.family))
    print(f"wrote {out}: {args.actuator} rig, {len(stated)} stated value(s), {todo} parameter(s) to be "
          "fitted")
    print(f"next: rig fit {out} TABLES_AND_RECORDINGS... -o fitted.yaml")
    return 0


def _fit(args: argparse.Namespace) -> int:
    out = check_output_file(args.out, args.overwrite)
    if out.resolve() == Path(args.rig).resolve() and not args.overwrite:
        raise RigFileError(f"-o {out} is the input rig file; choose another name")
    load_rig(args.rig)  # a bad rig file fails at once, before the identification modules load
    from aeropend_ident.greybox.rig_fit import fit_rig
    from aeropend_ident.greybox.rig_fit_result import write_fitted

    say = None if args.quiet else (lambda m: print(f"rig fit: {m}", flush=True))
    result = fit_rig(args.rig, args.inputs, preset=args.preset, progress=say)
    write_fitted(result, out)
    print(result.summary())
    print(f"wrote {out}")
    return 0


def _check(args: argparse.Namespace) -> int:
    load_rig(args.rig)  # a bad rig file fails at once, before the identification modules load
    from aeropend_ident.greybox.rig_check import check_rig

    print(check_rig(args.rig, args.inputs, preset=args.preset))
    return 0


@exits_cleanly_on_faults("rig")
def main(argv: Sequence[str] | None = None) -> int:
    """Run ``rig``; return the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return {"new": _new, "fit": _fit, "check": _check}[args.command](args)
    except (ValueError, OutputFolderError, OSError) as exc:
        if is_fault(exc):
            raise
        print(f"rig {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
