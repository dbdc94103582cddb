"""The choices of the ``identify`` command, in one light module (no numpy, no pysindy).

``identify --help`` and its argument checks read them before anything heavy is imported;
:mod:`aeropend_ident.sindy.identify` uses the same names.
"""

from __future__ import annotations

#: The files every ``identify`` run writes into its results folder (the plots come on top; the
#: command's ``--overwrite`` replaces only a folder that holds one of these).
OUTPUT_FILES = ("model.yaml", "summary.json")
#: Candidate libraries of ``--library``: ``physics-structured`` (default: which variable may enter which
#: equation, θ̈ in the second-order weak form from θ alone), ``structured`` (per-equation, every effect's
#: terms), ``physics`` (one library of named physical terms for every equation), ``thesis`` /
#: ``full`` (the thesis' unrestricted 31-term library, for discovery and discrepancy SINDy).
LIBRARIES = ("physics-structured", "structured", "physics", "thesis", "full")
#: Estimators of ``--method``.
METHODS = ("weak", "weak-iv", "sindy", "ensemble")
