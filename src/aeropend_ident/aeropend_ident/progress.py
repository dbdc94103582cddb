"""Progress bars of the long commands (``gap``, ``identify``, ``gap-batch``, the benches).

One rule for every command: a tqdm bar on **stderr**, shown only when stderr is a terminal (a log
file or a pipe stays clean: no carriage returns, no bar redraws) unless :data:`FORCE_ENV` is set
to ``1`` (show it anyway) or ``0`` (never); ``-q`` hides it and the progress lines
(:func:`bar` / :func:`reporter` with ``quiet=True``). A bar counts steps (cases of a batch, stages
of a pipeline) and shows the current step as its postfix; the one-line progress messages the
commands print (``gap: where: ...``) go above it.

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from tqdm import tqdm

#: Environment variable: ``1`` shows the bars even when stderr is not a terminal, ``0`` hides them.
FORCE_ENV = "AEROPEND_PROGRESS"


def enabled(quiet: bool = False) -> bool:
    """Whether a bar is shown: not ``quiet``, and stderr a terminal or :data:`FORCE_ENV` = 1."""
    if quiet:
        return False
    force = os.environ.get(FORCE_ENV, "").strip()
    if force in ("0", "1"):
        return force == "1"
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # a closed or replaced stderr
        return False


def bar(total: int | None, desc: str, *, quiet: bool = False, unit: str = "step", **kwargs: Any) -> tqdm:
    """A tqdm bar on stderr following the module's rule (when disabled every call is a no-op).

    Parameters
    ----------
    total : int or None
        Steps expected (None: a counter without a bar).
    desc : str
        Short label (the command).
    quiet : bool
        Hide it (the commands' ``-q``).
    unit : str
        What one step is (``case``, ``stage``, ...).
    """
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, disable=not enabled(quiet),
                dynamic_ncols=True, **kwargs)


@contextmanager
def reporter(desc: str, stages: Sequence[str] = (), *, quiet: bool = False,
             line: Callable[[str], str] | None = None) -> Iterator[Callable[[str], None]]:
    """A progress callback for a pipeline: ``with reporter("gap", ("where", "which")) as say: ...``.

    ``say(message)`` prints ``line(message)`` (default ``desc: message``) on stderr, above the bar
    when there is one, nothing with ``quiet``. With ``stages``, a message that starts with
    ``<stage>:`` moves the bar to that stage; without, every message counts one step (a counter
    with the elapsed time). Leaving the block completes and closes the bar.
    """
    b = bar(len(stages) or None, desc, quiet=quiet, unit="stage" if stages else "step")
    order = {s: i for i, s in enumerate(stages)}

    def say(message: str) -> None:
        if quiet:
            return
        stage = message.split(":", 1)[0].strip()
        if not stages:
            b.update(1)
        elif stage in order and order[stage] > b.n:  # the stages before it are done
            b.update(order[stage] - b.n)
        b.set_postfix_str(message.strip()[:60], refresh=False)
        text = line(message) if line else f"{desc}: {message}"
        if b.disable:
            print(text, file=sys.stderr, flush=True)
        else:
            b.write(text, file=sys.stderr)

    try:
        yield say
        if stages and not b.disable:
            b.update(len(stages) - b.n)
    finally:
        b.close()
