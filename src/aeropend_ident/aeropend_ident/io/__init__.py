"""Recording I/O: rosbag2 reader/writer, CSV import and its presets, one ``load_recording``.

Names are imported on first use (PEP 562): the recorder node imports :mod:`.bags` without the CSV
import's dependencies. Reference: docs/api.md.
"""

from __future__ import annotations

from aeropend_sim.lazy_api import lazy_api

#: The public API: defining module -> its names (the one list: ``__all__``, the lazy lookup and
#: docs/api.md's check read it).
_API: dict[str, tuple[str, ...]] = {
    "aeropend_ident.io.recording_input": ("load_recording", "load_and_split", "uniform_recording"),
    "aeropend_ident.io.bags": ("read_bag",),
    "aeropend_ident.io.bag_reader": ("RawBagReader", "bag_metadata"),
    "aeropend_ident.io.bag_writer": ("write_bag", "BagSink"),
    "aeropend_ident.io.bag_recover": ("reindex", "is_truncated"),
    "aeropend_ident.io.csv_import": ("import_csv", "import_csv_runs", "csv_to_bag", "stream_csv_to_bag"),
    "aeropend_ident.io.csvspec.spec": ("CsvSpec", "load_preset_file", "write_preset_file", "find_preset"),
    "aeropend_ident.io.csvspec.input_kinds": ("InputKind", "input_map"),
    "aeropend_ident.io.split": ("validation_split", "time_ordered", "interleaved_blocks", "split_runs"),
    "aeropend_ident.io.jsonutil": ("jsonable",),
}
__all__, __getattr__, __dir__ = lazy_api(__name__, globals(), _API)
