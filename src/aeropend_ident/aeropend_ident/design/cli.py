"""``excitation_design`` (and ``excitation --design-for``): design the next experiment.

::

    excitation_design --design-for GAP_REPORT RECORDING ... --rig RIG -o OUT [--overwrite]
        [--duration 40] [--rate HZ] [--seed 0] [--max-evaluations N] [--budget 120] [--max-effects 3]
        [--preset NAME]
        [--duty-min X] [--duty-max X] [--max-slew PER_S] [--theta-min RAD] [--theta-max RAD]
    excitation_design --design-for GAP_REPORT RECORDING ... -o OUT --mode reference
        [--controller CONTROLLER_PARAMS.yaml] [--strategy NAME] [...]
    excitation_design --design-for FITTED_RIG.yaml RECORDING ... -o OUT [--parameters KEY ...] [...]
    excitation_design --outcome NEW_GAP_REPORT --design OUT [DESIGNED_RECORDING] [--no-refit]

``GAP_REPORT`` is a ``gap`` output folder (its ``report.json``): a **discrimination** design between
the candidates built from its diagnosis (:mod:`aeropend_ident.design.candidates`), fitted on the
RECORDINGs (the earlier fit recordings, as ``gap`` took them) against ``--rig`` (the nominal rig
``gap`` was given). ``FITTED_RIG.yaml`` is a ``rig fit`` result: a **D-optimal** design for the
parameters it left undetermined (``STILL TO BE FITTED`` or ``AT SEARCH BOUND``, or
``--parameters``). The RECORDINGs give the noise σ per logged channel, the angle quantum, the
logging rate (unless ``--rate``) and the default limits (angle range ± 0.15 rad, commands from 0 to
their largest).

``--mode reference`` is for a rig that runs under feedback: set points for the lab's controller node
(its parameters file, ``--controller``; the node's defaults on the rig otherwise), predicted with
that controller in closed loop on every candidate (or on the fitted rig), written as
``design_controller.yaml`` (the node's ``steps``) and ``design.csv`` (``t,reference``)
(:mod:`aeropend_ident.design.reference`). A discrimination design's closed loops (the controller
run sample by sample) run in worker processes, one per core, and an open-loop one scores each
search generation in one thread per core (``AEROPEND_DESIGN_WORKERS=N`` sets how many; 1 runs them
in the command's own thread); the design does not depend on their number.

``--outcome`` compares a design's prediction with a ``gap`` report made with the
designed recording among its fit recordings (and, given the designed recording, ranks the
candidates on it and says what it names: the candidates as fitted on the earlier recordings, or,
when none of them explains it as sized, refitted on the earlier recordings and it together, and
while none explains it the sets one swap further on too,
:func:`aeropend_ident.design.discriminate.refit_evidence`; ``--no-refit`` stops at the first).

``OUT`` is checked before the search and written at its end in one step: an existing, non-empty
folder is refused unless ``--overwrite`` is given and it holds an earlier design (``design.*``),
and a fault while writing (a full disk, Ctrl-C) leaves the earlier design as it was
(:mod:`aeropend_sim.output_folder`).

Exit status: 0 written, 2 bad input (message on stderr), 1 a fault while writing, 130 Ctrl-C.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.design.sequence import BUDGET_S, MODES, DesignError, check_mode
from aeropend_ident.errors import IdentError
from aeropend_sim.output_folder import OutputFolder, claim_output_folder, exits_cleanly_on_faults, is_fault


class DesignCliError(IdentError):
    """Bad input to ``excitation_design``."""


def build_parser(prog: str = "excitation_design") -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n", 1)[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recordings", nargs="*", help="earlier recordings (bag, .mcap, .db3, FILE.csv[:PRESET])")
    ap.add_argument("--design-for", dest="design_for", help="gap report folder or rig fit result (.yaml)")
    ap.add_argument("--rig", help="nominal rig (name or file) the gap report was made against")
    ap.add_argument("-o", "--out", type=Path,
                    help="output folder (refused if it exists and is not empty, unless --overwrite)")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace an earlier design in -o (only a folder holding design.* files)")
    ap.add_argument("--duration", type=float, default=40.0, help="length of the design [s] (≤ 60)")
    ap.add_argument("--rate", type=float, help="logging rate [Hz] (default: the recordings')")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--budget", type=float, default=BUDGET_S,
                    help="wall-time safety net of the search [s]; a search it cuts says so (another machine "
                         "or load would give another design)")
    ap.add_argument("--max-evaluations", dest="max_evaluations", type=int,
                    help="most sequences scored (default: a fixed amount of replay work, e.g. 1851 "
                         "sequences for five parameters and a 40 s design at 100 Hz, 437 for six candidates "
                         "at 490 Hz; docs/design.md): the same seed then gives the same design on any "
                         "machine")
    ap.add_argument("--max-effects", dest="max_effects", type=int, default=3)
    ap.add_argument("--parameters", nargs="+", help="rig keys section.name to determine (rig fit results)")
    ap.add_argument("--preset", help="CSV preset of the recordings")
    ap.add_argument("--mode", choices=MODES, default="open_loop",
                    help="open_loop: a command sequence played open loop; reference: set points for the "
                         "lab's controller node, for a rig that runs only in closed loop (both kinds of "
                         "design; docs/design.md, 'Closed loop'); a discrimination design's closed "
                         "loops run in one worker process per core, its open-loop sequences in one "
                         "thread per core (AEROPEND_DESIGN_WORKERS=N sets the number, the design does "
                         "not depend on it)")
    ap.add_argument("--controller",
                    help="with --mode reference: the controller node's ROS parameters file (strategy, "
                         "omega_n, zeta, rho, ...) the lab runs; default the node's defaults on the gap "
                         "report's rig (or on the rig fit result)")
    ap.add_argument("--strategy",
                    help="with --mode reference: the controller's strategy (over --controller's)")
    for name, help_ in (("duty-min", "lowest command"), ("duty-max", "highest command"),
                        ("max-slew", "largest command change per second [1/s]"),
                        ("theta-min", "lowest angle [rad]"), ("theta-max", "highest angle [rad]")):
        ap.add_argument(f"--{name}", dest=name.replace("-", "_"), type=float, help=help_)
    ap.add_argument("--outcome", help="gap report made with the designed recording (compare prediction)")
    ap.add_argument("--design", type=Path, help="design folder (with --outcome)")
    ap.add_argument("--no-refit", action="store_true",
                    help="with --outcome: when no candidate explains the designed recording as sized on the "
                         "earlier recordings, say so and stop (default: refit them on both and judge again, "
                         "searching on swap by swap while none explains it)")
    return ap


def _recordings(args: argparse.Namespace, offset: float) -> list[Any]:
    from aeropend_ident.gap.run import to_model_frame
    from aeropend_ident.greybox.rig_inputs import is_table
    from aeropend_ident.io.recording_input import check_length, load_recording
    from aeropend_ident.io.resampling import uniform_recording

    # the inputs rig fit and gap take are accepted as they are: a static table (balance / thrust)
    # holds no command sequence to replay, so the design's earlier information is the recordings'
    tables = [p for p in args.recordings if is_table(p)]
    paths = [p for p in args.recordings if not is_table(p)]
    if tables:
        names = ", ".join(_input_path(t).name for t in tables)
        print(f"{names}: static table(s), read by rig fit and gap; the design replays the recordings only",
              file=sys.stderr)
    if not paths:
        raise DesignCliError("give the earlier recordings (the ones the report or the fit used)"
                             + (": static tables alone hold no command sequence" if tables else ""))
    recs = []
    for p in paths:
        r = uniform_recording(load_recording(p, args.preset))
        check_length(r, "earlier recording")
        recs.append(to_model_frame(r, offset) if offset else r)
    return recs


def _input_path(arg: str) -> Path:
    """The file of an input argument (``FILE``, ``FILE:PRESET`` or a table's ``FILE:kind``)."""
    return Path(arg.partition(":")[0])


def _resolved(inputs: Sequence[str]) -> list[str]:
    """The inputs as absolute paths (a ``:PRESET`` or ``:kind`` suffix kept): design.json's
    ``earlier``, what ``--outcome`` refits on."""
    out = []
    for x in inputs:
        path, sep, rest = x.partition(":")
        out.append(str(Path(path).resolve()) + sep + rest)
    return out


def _limits(args: argparse.Namespace, recs: Sequence[Any], offset: float = 0.0) -> Any:
    """Default limits from the recordings and the static tables given beside them (a balance
    table's commands and the angles they held, a thrust table's commands: the lab has driven its
    rig there), the lab's stated limits over them."""
    from aeropend_ident.design.sequence import Limits
    from aeropend_ident.greybox.rig_inputs import is_table, read_table
    from aeropend_ident.io.resampling import detect_quantum

    dt = 1.0 / args.rate if args.rate else float(np.median([r.dt for r in recs]))
    # a closed-loop design's command is the lab's controller's: its range and slew are the
    # controller's own (saturation at 0 and 1, no slew limit) unless the lab states them
    stated: dict[str, float] = ({"duty_min": 0.0, "duty_max": 1.0, "max_slew": 1.0 / dt}
                                if getattr(args, "mode", "open_loop") == "reference" else {})
    stated.update({k: getattr(args, k) for k in ("duty_min", "duty_max", "max_slew", "theta_min", "theta_max")
                   if getattr(args, k) is not None})
    q = max(detect_quantum(np.asarray(r.channels["theta"])) for r in recs)
    thetas, duties = [r.channels["theta"] for r in recs], [r.duty for r in recs]
    for t in (read_table(_input_path(x)) for x in args.recordings if is_table(x)):
        duties.append(t.command)
        if t.kind == "balance":
            thetas.append(t.value + offset)
    return Limits.from_recordings(thetas, duties, dt, quantum=q, stated=stated)


def _channels(recs: Sequence[Any]) -> list[str]:
    common = set.intersection(*(set(r.channels) for r in recs))
    return sorted(common & {"theta", "i_a", "v_a", "omega_rotor"})


def discrimination(args: argparse.Namespace, out: OutputFolder) -> dict[str, Any]:
    """The discrimination design of a gap report (module doc); writes ``out``, returns design.json."""
    from aeropend_ident.design.candidates import channel_noise, diagnosis_candidates, diagnosis_view
    from aeropend_ident.design.discriminate import design_discrimination, rank_first_probability
    from aeropend_ident.design.report import write_design
    from aeropend_ident.design.sequence import AprbsShape, check_limits
    from aeropend_ident.gap.compare import load_model

    report = json.loads((Path(args.design_for) / "report.json").read_text(encoding="utf-8"))
    if report.get("tool") != "aeropend_ident gap":
        raise DesignCliError(f"{args.design_for}/report.json is not a gap report")
    rig_ref = args.rig or report["inputs"]["rig"]["ref"]
    model = load_model(rig_ref)
    recs = _recordings(args, model.measurement.theta_offset)
    limits = _limits(args, recs, model.measurement.theta_offset)
    channels = _channels(recs)
    sigma = channel_noise(recs, channels)
    chosen, _ranking = diagnosis_view(report)
    cands, rows = diagnosis_candidates(report, model.rig, recs, max_effects=args.max_effects)
    if len(cands) < 2:
        raise DesignCliError("the earlier recordings leave one candidate standing "
                             f"({cands[0].name}): nothing to discriminate; candidate fits: {rows}")
    doc = {"kind": "discrimination", "design_for": str(args.design_for), "rig": rig_ref, "mode": args.mode,
           "earlier": _resolved(args.recordings), "preset": args.preset,
           "seed": args.seed, "duration_s": args.duration, "limits": limits.as_dict(),
           "channels": channels, "sigma": sigma, "chosen_before": chosen,
           "candidates": [c.as_dict() for c in cands], "candidate_fits": rows}
    if args.mode == "reference":
        return _reference_design(args, out, doc, cands, sigma, limits)
    shape = AprbsShape.for_duration(args.duration)
    d = design_discrimination(cands, sigma, limits, shape, seed=args.seed, budget_s=args.budget,
                              max_evaluations=args.max_evaluations)
    from aeropend_ident.design.discriminate import Predictor

    th = Predictor(cands, ("theta",), limits.dt, d.duty.size)(d.duty)["theta"]
    doc.update({"shape": vars(shape),
                "predicted": rank_first_probability(cands, d.duty, sigma, limits, seed=args.seed),
                "predicted_baseline_aprbs": rank_first_probability(cands, d.baseline, sigma, limits,
                                                                   seed=args.seed),
                "min_divergence": d.min_divergence, "baseline_min_divergence": d.baseline_min_divergence,
                "criterion": d.value, "baseline_criterion": d.baseline_value,
                "limits_check": check_limits(d.duty, limits, th.ravel()),
                "evaluations": d.evaluations, "stopped_by": d.stopped_by, "elapsed_s": d.elapsed_s})
    out.write(lambda folder: write_design(folder, doc, d.duty, limits.dt, cands))
    return doc


def _controller_params(args: argparse.Namespace) -> dict[str, Any]:
    """The lab's controller node parameters: ``--controller``'s file, ``--strategy`` over it."""
    from aeropend_ident.design.reference import read_controller_params

    params = read_controller_params(args.controller) if args.controller else {}
    if args.strategy:
        params["strategy"] = args.strategy
    return params


def _controller_doc(args: argparse.Namespace, loop: Any) -> dict[str, Any]:
    """design.json's ``controller``: the loop the prediction assumed."""
    st = loop.settings
    return {"strategy": st.strategy, "rig": st.rig_file, "omega_n": st.spec.omega_n, "zeta": st.spec.zeta,
            "rho": st.spec.rho, "allocator": st.allocator, "estimator": st.estimator, "reach_rad": loop.reach,
            "from": str(args.controller or ""),
            # the command limits the lab did not state are the controller's own
            "sets": [k for k in ("duty_min", "duty_max", "max_slew") if getattr(args, k) is None]}


def _reference_design(args: argparse.Namespace, out: OutputFolder, doc: dict[str, Any], cands: Sequence[Any],
                      sigma: dict[str, float], limits: Any) -> dict[str, Any]:
    """``--mode reference``: set points for the lab's controller (:mod:`aeropend_ident.design.reference`)."""
    from aeropend_ident.design import reference
    from aeropend_ident.design.report import write_design
    from aeropend_ident.design.sequence import check_limits

    loop = reference.lab_controller(doc["rig"], _controller_params(args), limits.dt)
    shape = reference.reference_shape(args.duration)
    # one set of worker processes for the search's loops and the prediction's (each candidate's)
    with reference.lab_predictor(cands, loop, sigma, limits, shape) as pred:
        d = reference.design_reference(cands, loop, sigma, limits, shape, seed=args.seed,
                                       budget_s=args.budget, max_evaluations=args.max_evaluations,
                                       predictor=pred)
        # the seeded set points are compared by their divergences on the driver's loop only: a prediction
        # runs the loop on every candidate, as long again as the design's own (docs/design.md, "Closed loop")
        predicted = reference.rank_first_probability(cands, loop, d.steps, pred.n, sigma, limits,
                                                     seed=args.seed, predictor=pred)
    doc.update({"shape": vars(shape), "controller": _controller_doc(args, loop),
                "steps": d.steps, "baseline_steps": d.baseline_steps, "driver": d.driver,
                "predicted": predicted,
                "min_divergence": d.min_divergence, "baseline_min_divergence": d.baseline_min_divergence,
                "criterion": d.value, "baseline_criterion": d.baseline_value,
                "limits_check": check_limits(d.duty, limits, d.theta),
                "evaluations": d.evaluations, "stopped_by": d.stopped_by, "elapsed_s": d.elapsed_s})
    doc["limits_check"]["angle_range"] = doc["limits_check"]["angle_range"] and all(
        r["status"] == "ok" and limits.theta_min <= r["theta_extremes"][0] and r["theta_extremes"][1]
        <= limits.theta_max for r in doc["predicted"]["loop"].values())
    doc["limits_check"]["ok"] = all(doc["limits_check"][k] for k in ("command_range", "slew", "angle_range"))
    out.write(lambda folder: write_design(folder, doc, d.reference, limits.dt, cands, column="reference",
                                          steps=d.steps))
    return doc


def parameters(args: argparse.Namespace, out: OutputFolder) -> dict[str, Any]:
    """The D-optimal design of a rig fit result (module doc); writes ``out``, returns design.json."""
    from aeropend_ident.design.candidates import channel_noise
    from aeropend_ident.design.parameters import design_parameters, fitted_keys, weak_keys
    from aeropend_ident.design.report import write_design
    from aeropend_ident.design.sequence import AprbsShape, check_limits
    from aeropend_sim.params import load_rig

    path = Path(args.design_for)
    rig = load_rig(str(path))
    text = path.read_text(encoding="utf-8")
    keys = list(args.parameters or weak_keys(text))
    values = rig.values()
    nuisance = [k for k in fitted_keys(text) if k not in keys and values.get(k, 0.0) > 0.0]
    if not keys:
        raise DesignCliError(f"{path}: no parameter left undetermined (no STILL TO BE FITTED or AT SEARCH "
                             "BOUND line); name some with --parameters")
    recs = _recordings(args, 0.0)
    limits = _limits(args, recs)
    channels = _channels(recs)
    sigma = channel_noise(recs, channels)
    loop, shape = None, AprbsShape.for_duration(args.duration)
    if args.mode == "reference":
        from aeropend_ident.design import reference

        loop = reference.lab_controller(str(path), _controller_params(args), limits.dt)
        shape = reference.reference_shape(args.duration)
    d = design_parameters(rig, keys, sigma, limits, shape, earlier=[(r.duty, r.dt) for r in recs],
                          nuisance=nuisance, seed=args.seed, budget_s=args.budget,
                          max_evaluations=args.max_evaluations, mode=args.mode, loop=loop)
    doc = {"kind": "parameters", "design_for": str(path), "mode": args.mode, "seed": args.seed,
           "duration_s": shape.duration, "shape": vars(shape), "limits": limits.as_dict(),
           "channels": channels,
           "sigma": sigma, "parameters": list(keys), "nuisance": nuisance, "sd_before": d.sd_before,
           "sd_after": d.sd_after,
           "sd_after_baseline": d.sd_after_baseline, "logdet": d.logdet, "baseline_logdet": d.baseline_logdet,
           "limits_check": check_limits(d.duty, limits, d.theta), "angle_margin_rad": d.angle_margin,
           "angle_margin_held": d.angle_margin_held, "angle_spread_rad": d.angle_spread,
           "angle_limits_assured": d.angle_limits_assured,
           "evaluations": d.evaluations,
           "stopped_by": d.stopped_by, "elapsed_s": d.elapsed_s}
    if loop is None:
        out.write(lambda folder: write_design(folder, doc, d.duty, limits.dt))
        return doc
    from aeropend_ident.design.reference import on_grid

    doc.update({"controller": _controller_doc(args, loop), "steps": d.steps,
                "baseline_steps": d.baseline_steps})
    grid = on_grid(d.steps or [], d.duty.size, limits.dt)
    out.write(lambda folder: write_design(folder, doc, grid, limits.dt, column="reference", steps=d.steps))
    return doc


def outcome(args: argparse.Namespace) -> dict[str, Any]:
    """``--outcome``: the prediction of ``--design`` against a new gap report (module doc)."""
    from aeropend_ident.design.discriminate import evidence
    from aeropend_ident.design.report import compare_outcome, load_candidates

    if args.design is None:
        raise DesignCliError("--outcome needs --design DESIGN_FOLDER")
    design = json.loads((args.design / "design.json").read_text(encoding="utf-8"))
    if design.get("kind") != "discrimination":
        raise DesignCliError("--outcome compares discrimination designs (a parameter design's outcome is the "
                             "new rig fit's standard errors)")
    report = json.loads((Path(args.outcome) / "report.json").read_text(encoding="utf-8"))
    ev = refit = None
    if args.recordings:
        from aeropend_ident.gap.compare import load_model

        model = load_model(design["rig"])
        offset = model.measurement.theta_offset
        rec = _recordings(args, offset)[0]
        ev = evidence(load_candidates(args.design), rec.duty, rec.channels, design["sigma"], rec.dt)
        if ev["unexplained"] and not args.no_refit:
            refit = _refit(design, model, rec)
    return compare_outcome(design, report, ev, refit)


def _refit(design: dict[str, Any], model: Any, rec: Any) -> dict[str, Any]:
    """``--outcome`` on a designed recording no candidate explains as sized: the candidates refitted
    on the earlier recordings (design.json's ``earlier``) and the designed one
    (:func:`aeropend_ident.design.discriminate.refit_evidence`)."""
    from aeropend_ident.design.discriminate import refit_evidence

    gone = [x for x in design.get("earlier") or [] if not _input_path(x).exists()]
    if gone or not design.get("earlier"):
        why = f"the earlier recording(s) {', '.join(gone)} are gone" if gone else \
            "design.json does not name the earlier recordings (a design made before they were kept)"
        return {"skipped": f"no refit: {why}"}
    ns = argparse.Namespace(recordings=design["earlier"], preset=design.get("preset"))
    recs = _recordings(ns, model.measurement.theta_offset)
    return refit_evidence(model.rig, recs, rec, [c["effects"] for c in design["candidates"]], design["sigma"])


@exits_cleanly_on_faults("excitation_design")
def main(argv: Sequence[str] | None = None, prog: str = "excitation_design") -> int:
    """Entry point; returns the exit status."""
    args = build_parser(prog).parse_args(argv)
    try:
        if args.outcome:
            res = outcome(args)
            print(json.dumps(res, indent=1, default=float))
            return 0
        if not args.design_for or args.out is None:
            raise DesignCliError("give --design-for REPORT and -o OUT (or --outcome REPORT --design FOLDER)")
        target = Path(args.design_for)
        check_mode(args.mode, ("open_loop", "reference"))
        if args.mode != "reference" and (args.controller or args.strategy):
            raise DesignCliError("--controller and --strategy describe the lab's controller of a --mode "
                                 "reference design")
        if not 1.0 < args.duration <= 60.0:
            raise DesignCliError(f"--duration {args.duration}: expected more than 1 s and at most 60 s")
        from aeropend_ident.design.report import DESIGN_FILES

        # checked before the search (fail fast), written at its end in one step: an earlier
        # design is replaced only with --overwrite, and never left half replaced
        inputs = [target, *(_input_path(x) for x in args.recordings),
                  *([args.controller] if args.controller else [])]
        out = claim_output_folder(args.out, args.overwrite, own=DESIGN_FILES,
                                  looks_like="an experiment design", inputs=inputs)
        doc = discrimination(args, out) if target.is_dir() else parameters(args, out)
    except (IdentError, DesignError, ValueError, OSError, KeyError) as exc:
        if is_fault(exc):  # a full disk or a refused write: one line, exit 1 (exits_cleanly_on_faults)
            raise
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print((args.out / "design.md").read_text(encoding="utf-8"))
    if not doc["limits_check"]["ok"]:
        lim = doc["limits"]
        print(f"{prog}: warning: no sequence the search found keeps every predicted angle within "
              f"{lim['theta_min']:.3g} … {lim['theta_max']:.3g} rad with commands up to "
              f"{lim['duty_max']:.3g} (design.md: OUTSIDE): do not play it as it is; state a lower "
              "--duty-max or the angle range the rig may reach (--theta-min/--theta-max)", file=sys.stderr)
    elif doc.get("angle_margin_held") is False:
        print(f"{prog}: warning: no sequence the search found keeps the predicted angle ± its uncertainty "
              f"({doc['angle_margin_rad']:.3g} rad) inside the angle limits: the design stays as far inside "
              "as it could, and its information was not the goal; state a lower --duty-max or the angle "
              "range the rig may reach", file=sys.stderr)
    if doc.get("angle_limits_assured") is False:
        print(f"{prog}: warning: the limits are not assured: the predicted angle depends by up to "
              f"{doc['angle_spread_rad']:.3g} rad (1σ) on parameters the earlier recordings do not "
              "determine, more than the margin the design keeps; record it with the rig watched and a "
              "lower --duty-max, or state those parameters first", file=sys.stderr)
    if doc.get("stopped_by") == "budget":
        print(f"{prog}: warning: the search was cut by --budget {args.budget:g} s after {doc['evaluations']} "
              "sequences, before its number of evaluations: this seed gives another design on another "
              "machine or load (a smaller --max-evaluations or a larger --budget makes it reproducible)",
              file=sys.stderr)
    print(f"{prog}: wrote {args.out}/design.csv, design.json, design.md ({doc['elapsed_s']:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
