"""Sparse identification (SINDy, weak SINDy, output-error refinement) of the plant.

The ``identify`` pipeline is :func:`aeropend_ident.identify` (here the module of that name).
Names are imported on first use (PEP 562): pysindy loads when a fit is first called.
Reference: docs/api.md.
"""

from __future__ import annotations

from aeropend_sim.lazy_api import lazy_api

#: The public API: defining module -> its names (the one list: ``__all__``, the lazy lookup and
#: docs/api.md's check read it).
_API: dict[str, tuple[str, ...]] = {
    "aeropend_ident.sindy.core": ("fit",),
    "aeropend_ident.sindy.sweep": ("sweep_threshold", "select_threshold"),
    "aeropend_ident.sindy.model": (
        "IdentData", "SindyModel", "NoEquationError", "data_from_trajectory", "free_run",
        "structure_errors", "save_model",
    ),
    "aeropend_ident.sindy.libraries": ("physics_library", "thesis_library", "CandidateLibrary"),
    "aeropend_ident.sindy.preprocess": ("differentiate", "add_derivatives"),
    "aeropend_ident.sindy.output_error": ("refine_output_error",),
}
__all__, __getattr__, __dir__ = lazy_api(__name__, globals(), _API)
