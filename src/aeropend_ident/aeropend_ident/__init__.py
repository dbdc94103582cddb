"""Offline identification and sim-to-real gap diagnosis on rosbag2 files and CSV logs (no ROS needed).

The public API, by stage (docs/api.md; the subpackages :mod:`~aeropend_ident.io`,
:mod:`~aeropend_ident.sindy`, :mod:`~aeropend_ident.greybox` and :mod:`~aeropend_ident.gap`
export their own, larger, API)::

    from aeropend_ident import load_recording, run_gap
    from aeropend_sim import load_rig
    fit, held_out = load_recording("run_bag").split(0.7)   # a bag folder, or "log.csv:PRESET"
    result = run_gap(load_rig("thesis_sim"), [fit], [held_out])   # where -> which -> after

The recorder and player nodes (:mod:`aeropend_ident.nodes`) and the command-line front ends
(:mod:`aeropend_ident.cli`) are not part of it. Names are imported on first use (PEP 562):
``import aeropend_ident`` loads neither pysindy nor SciPy, and the console scripts start fast.
"""

from __future__ import annotations

from aeropend_sim.lazy_api import lazy_api

#: The public API: defining module -> its names (the one list: ``__all__``, the lazy lookup and
#: docs/api.md's check read it).
_API: dict[str, tuple[str, ...]] = {
    # errors
    "aeropend_ident.errors": (
        "IdentError", "IdentificationError", "BagError", "CsvImportError", "RecordingInputError",
        "GapError", "CompareError", "PipelineError", "IdentWarning",
    ),
    # recordings in and out
    "aeropend_ident.io.recording_input": ("load_recording", "load_and_split"),
    "aeropend_ident.io.bags": ("read_bag",),
    "aeropend_ident.io.bag_reader": ("RawBagReader",),
    "aeropend_ident.io.bag_writer": ("write_bag",),
    "aeropend_ident.io.csv_import": ("import_csv", "import_csv_runs", "csv_to_bag", "stream_csv_to_bag"),
    "aeropend_ident.io.csvspec.spec": ("CsvSpec", "load_preset_file", "write_preset_file"),
    "aeropend_ident.io.bag_recover": ("reindex",),
    # sparse identification
    "aeropend_ident.sindy.identify": ("identify",),
    "aeropend_ident.sindy.model": ("SindyModel", "IdentData", "free_run"),
    # grey-box parameters
    "aeropend_ident.greybox.fit": ("fit_greybox",),
    "aeropend_ident.greybox.fit_result": ("GreyBoxResult",),
    "aeropend_ident.greybox.baseline": ("baseline", "run_baseline"),
    "aeropend_ident.greybox.baseline_result": ("BaselineResult",),
    # the sim-to-real gap
    "aeropend_ident.gap.run": ("run_gap",),
    "aeropend_ident.gap.result": ("GapResult",),
    "aeropend_ident.gap.compare": ("compare", "CompareResult"),
}
__all__, __getattr__, __dir__ = lazy_api(__name__, globals(), _API)
