"""The shortest constant-duty hold that steady-state errors and step metrics are read from.

A light module (no numpy): the ``compare`` command's ``--min-hold`` default is read from here before
anything heavy is imported, so ``compare --help`` answers at once; ``gap``'s where-analysis
(:func:`aeropend_ident.gap.residual_tests.constant_holds`) reads the same value.
"""

from __future__ import annotations

#: Shortest constant-duty hold used for steady-state errors and step metrics [s].
MIN_HOLD = 1.0
