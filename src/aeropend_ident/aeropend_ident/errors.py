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


class IdentWarning(UserWarning):
    """Base of the warnings ``aeropend_ident`` gives on input it could use only in part; the
    command-line tools print them as one line (:func:`print_warnings_as_lines`)."""


class BagTruncatedWarning(IdentWarning):
    """A bag's storage is cut short and only its readable messages were used (message: how many,
    where the file ends)."""


class BagLossWarning(IdentWarning):
    """A bag lost more messages than the stated threshold while it was recorded (message: how many
    per topic, counted how, and where the gaps are)."""


class CsvRowWarning(IdentWarning):
    """A CSV row that may be wrong (a last line without its newline) or rows that were dropped."""


class ConstantInputWarning(IdentWarning):
    """A CSV log without actuator column was imported with a constant input (a free decay or a step
    from rest); the message says what θ does and that a changing actuator must be logged."""


def print_warnings_as_lines(prog: str) -> None:
    """Make :class:`IdentWarning` s print as one ``PROG: warning: MESSAGE`` line on stderr.

    For a command line's ``main``: the default Python format adds the source file, line and code of
    the ``warnings.warn`` call, which mean nothing to the user. Other warnings keep the default
    format. Python's default filter still applies (a message repeated from one place prints once).
    """
    import sys
    import warnings

    default = warnings.showwarning

    def show(message: Warning | str, category: type[Warning], filename: str, lineno: int,
             file: object = None, line: str | None = None) -> None:
        if issubclass(category, IdentWarning):
            print(f"{prog}: warning: {message}", file=sys.stderr, flush=True)
        else:
            default(message, category, filename, lineno, file, line)  # type: ignore[arg-type]

    warnings.showwarning = show
