"""The shortest constant-duty hold that ``compare`` and ``baseline`` read steady states and steps from.

A light module (no numpy): the ``compare`` command's ``--min-hold`` default is read from here before
anything heavy is imported, so ``compare --help`` answers at once.
"""

from __future__ import annotations

#: Shortest constant-duty hold used for steady-state errors and step metrics [s].
MIN_HOLD = 1.0
