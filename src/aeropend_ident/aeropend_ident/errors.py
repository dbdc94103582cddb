"""The one error hierarchy of ``aeropend_ident``: every error it raises is an :class:`IdentError`.

Each class also derives from the builtin it always derived from (``ValueError`` for bad input,
``RuntimeError`` for a failed pipeline stage), so ``except ValueError`` callers keep working. The
modules that raise them re-export them under their old names (``aeropend_ident.io.bags.BagError``
is this module's ``BagError``). :class:`aeropend_ident.sindy.model.NoEquationError` (an
:class:`IdentificationError` carrying the reasons per equation) lives beside its only raiser.
"""

from __future__ import annotations


class IdentError(Exception):
    """Base of every error ``aeropend_ident`` raises on input it cannot use or a step that failed."""


class IdentificationError(IdentError, ValueError):
    """Identification cannot be done on this data (missing channel or θ, NaN, unexcited, too short,
    bad option); raised by the SINDy and the grey-box fits alike."""


class BagError(IdentError, ValueError):
    """A bag cannot be read as (or written as) a contract bag; the message names the bag."""


class CsvImportError(IdentError, ValueError):
    """A CSV file cannot be imported; the message names file, line and column."""


class RecordingInputError(IdentError, ValueError):
    """A recording argument that cannot be read (missing file, unknown kind or preset)."""


class LibraryError(IdentError, ValueError):
    """A library cannot be evaluated on the given data (missing variable, NaN, bad shape)."""


class StaticEstimationError(IdentError, ValueError):
    """Bad input to a static estimator (NaN, non-positive current, too few rows, no step...)."""


class GapError(IdentError, ValueError):
    """Input the gap diagnosis cannot use (missing channel, NaNs, too short, unknown effect)."""


class CompareError(IdentError, ValueError):
    """A rig or recording ``compare`` cannot use (message names it)."""


class GapCliError(IdentError, ValueError):
    """A command-line input the gap tool cannot use."""


class PipelineError(IdentError, RuntimeError):
    """A stage of the main job failed; the message names the stage and its log file."""


class GapInputError(IdentificationError):
    """A recording or option the where-analysis cannot use (names the recording and the problem)."""
