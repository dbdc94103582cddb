"""Grey-box fitting of the physical model parameters, the baseline report, static estimators.

The baseline report is :func:`aeropend_ident.baseline` (here the module of that name) or
:func:`run_baseline`. Names are imported on first use (PEP 562). Reference: docs/api.md.
"""

from __future__ import annotations

from aeropend_sim.lazy_api import lazy_api

#: The public API: defining module -> its names (the one list: ``__all__``, the lazy lookup and
#: docs/api.md's check read it).
_API: dict[str, tuple[str, ...]] = {
    "aeropend_ident.greybox.fit": ("fit_greybox", "free_run_theta", "error_metrics"),
    "aeropend_ident.greybox.fit_result": ("GreyBoxResult", "ParameterEstimate"),
    "aeropend_ident.greybox.baseline": ("run_baseline", "fitted_rig_dict"),
    "aeropend_ident.greybox.baseline_result": ("BaselineResult",),
    "aeropend_ident.greybox.static": (
        "armature_resistance", "armature_time_constant", "back_emf_constant", "fit_hbridge_map",
        "fit_thrust_law",
    ),
}
__all__, __getattr__, __dir__ = lazy_api(__name__, globals(), _API)
