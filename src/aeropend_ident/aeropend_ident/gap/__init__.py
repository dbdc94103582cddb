"""The sim-to-real gap diagnosis: where, which, drift and prediction, report, compare, synthetic checks.

``from aeropend_ident.gap import run_gap``; ``compare`` is :func:`aeropend_ident.compare` (here the
module of that name). Names are imported on first use (PEP 562). Reference: docs/api.md.
"""

from __future__ import annotations

from importlib import import_module

#: The public API: defining module -> its names (the one list: ``__all__``, the lazy lookup and
#: docs/api.md's check read it).
_API: dict[str, tuple[str, ...]] = {
    "aeropend_ident.gap.run": ("run_gap", "GapResult", "corrected_rig_dict"),
    "aeropend_ident.gap.report": ("write_report", "terminal_summary"),
    "aeropend_ident.gap.where": ("locate_gap", "WhereReport"),
    "aeropend_ident.gap.which.diagnosis": ("diagnose_effects", "EffectDiagnosis"),
    "aeropend_ident.gap.effects": ("catalog", "get_effect"),
    "aeropend_ident.gap.compare": ("CompareResult",),
    "aeropend_ident.gap.synth": ("make_case", "score_case"),
}
_WHERE = {name: module for module, names in _API.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> object:
    """Import the module that defines ``name`` on first use (PEP 562) and keep the value."""
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
