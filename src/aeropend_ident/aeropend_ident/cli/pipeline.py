"""The main job: run the node graph on the simulated plant, record a bag, identify and report.

Command line of the main job ``pipeline`` (console script; ``scripts/run_main.sh``): argument
parsing and :func:`main` only; the steps are in :mod:`aeropend_ident.pipeline`. A non-empty report
folder is refused at once unless ``--overwrite`` is given. The run writes into a partial folder
beside the report folder (``.NAME.partial-run``) that replaces it only when the run has finished
(:meth:`aeropend_sim.output_folder.OutputFolder.write`): an earlier run stays whole until then, and
a run that fails or is interrupted leaves the earlier run as it was and its own bag and logs in the
partial folder, named on stderr, for the diagnosis.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

from aeropend_ident.errors import PipelineError
from aeropend_ident.pipeline import DEFAULT_SIGNAL, OUTPUTS, analyse, check_recording, run_graph
from aeropend_sim.output_folder import (
    OutputFolderError,
    claim_output_folder,
    exits_cleanly_on_faults,
    partial_folder,
)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="pipeline", description=__doc__.split("\n\n")[0])
    p.add_argument("-o", "--out", type=Path, default=Path("reports/main"), help="report folder")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the earlier main-job run in --out (only a folder that holds one)")
    p.add_argument("--plant-rig", default="thesis_rig",
                   help="rig simulated by the plant node (the 'real' rig)")
    p.add_argument("--nominal-rig", default="thesis_sim", help="simulator whose parameters are fitted")
    p.add_argument("--mode", choices=["lockstep", "realtime"], default="lockstep")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--no-noise", action="store_true", help="switch sensor noise and quantisation off")
    p.add_argument("--train-fraction", type=float, default=0.7)
    p.add_argument("--signal", nargs="*", default=DEFAULT_SIGNAL,
                   help="excitation parameters name:=value (default: thesis LHS steps)")
    p.add_argument("--namespace", default="",
                   help="ROS namespace of the node graph (topics <namespace>/aeropend/*; default root)")
    return p


def _run(out: Path, final: Path, args: argparse.Namespace) -> dict:
    """The whole main job into the (partial) folder ``out`` that becomes ``final``; returns the
    summary it wrote (paths in it and in the reports are those under ``final``).

    Raises
    ------
    PipelineError
        A node failed, the recording is incomplete or the analysis failed.
    """
    t0 = time.monotonic()
    print(f"[1/2] node graph: record + sim_node ({args.plant_rig}, {args.mode}) + excitation ...", flush=True)
    bag = run_graph(out, args.plant_rig, args.mode, args.seed, args.signal, not args.no_noise,
                    namespace=args.namespace)
    t_graph = time.monotonic() - t0
    completeness = check_recording(bag, out / OUTPUTS["logs"] / "sim_node.log", args.mode, args.namespace)
    if not completeness["complete"]:
        ticks = completeness["clock_ticks"]
        raise PipelineError(
            f"incomplete lock-step recording: {completeness['recorded']} of "
            f"{completeness['published']} published samples and {completeness['commands']} of "
            f"{(completeness['published'] or 1) - 1} commands"
            + (f", {ticks} /clock ticks (one per sample message expected)" if ticks is not None else "")
            + f" in {bag} (see docs/data_plane.md)")
    print(f"      bag {final / OUTPUTS['bag']} written in {t_graph:.1f} s", flush=True)
    print(f"[2/2] grey-box baseline of {args.nominal_rig} on the recording ...", flush=True)
    report = analyse(bag, out, args.nominal_rig, args.train_fraction, args.namespace,
                     source=str(final / OUTPUTS["bag"]))
    summary = {
        "bag": str(final / OUTPUTS["bag"]),
        "plant_rig": args.plant_rig,
        "nominal_rig": args.nominal_rig,
        "mode": args.mode,
        "graph_seconds": round(t_graph, 2),
        "total_seconds": round(time.monotonic() - t0, 2),
        "recording": {**report["recording"], **completeness},
        "baseline": report.get("summary", report),
    }
    (out / OUTPUTS["summary"]).write_text(json.dumps(summary, indent=2, default=float))
    return summary


@exits_cleanly_on_faults("pipeline")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        folder = claim_output_folder(args.out, args.overwrite, own=OUTPUTS.values(),
                                     looks_like="a main-job run", option="-o")
    except OutputFolderError as exc:
        print(f"pipeline: error: {exc}", file=sys.stderr)
        return 2
    stage = partial_folder(args.out, "run")
    if stage.exists():  # what an earlier failed run left (named on stderr then): this run starts afresh
        print(f"pipeline: removing {stage}, the bag and logs an earlier failed run left", file=sys.stderr)
        shutil.rmtree(stage)
    try:
        summary = folder.write(lambda out: _run(out, folder.path, args), stage=stage, keep=True)
    except OutputFolderError as exc:
        print(f"pipeline: error: {exc}", file=sys.stderr)
        return 2
    except PipelineError as exc:
        print(f"pipeline failed: {exc}", file=sys.stderr)
        print(f"pipeline: {args.out} is as it was; this run's bag and logs are in "
              f"{stage / folder.path.name}", file=sys.stderr)
        return 1
    print(json.dumps(summary, indent=2, default=float))
    print(f"report folder: {folder.path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
