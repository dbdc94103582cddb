"""The sim-to-real gap diagnosis: where, which, drift and prediction, report, compare.

``from aeropend_ident.gap import run_gap``; ``compare`` is :func:`aeropend_ident.compare` (here the
module of that name). Names are imported on first use (PEP 562). Reference: docs/api.md.
"""

from __future__ import annotations

from aeropend_sim.lazy_api import lazy_api

#: The public API: defining module -> its names (the one list: ``__all__``, the lazy lookup and
#: docs/api.md's check read it).
_API: dict[str, tuple[str, ...]] = {
    "aeropend_ident.gap.run": ("run_gap",),
    "aeropend_ident.gap.result": ("GapResult", "corrected_rig_dict"),
    "aeropend_ident.gap.report": ("write_report", "terminal_summary"),
    "aeropend_ident.gap.where": ("locate_gap",),
    "aeropend_ident.gap.where_report": ("WhereReport",),
    "aeropend_ident.gap.which.diagnosis": ("diagnose_effects", "EffectDiagnosis"),
    "aeropend_ident.gap.effects": ("catalog", "get_effect"),
    "aeropend_ident.gap.compare": ("CompareResult",),
}
__all__, __getattr__, __dir__ = lazy_api(__name__, globals(), _API)
