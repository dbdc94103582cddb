"""The one YAML loader of aeropend: every YAML file the project reads goes through here.

Rig files, CSV presets, parameter values given on a command line, a bag's ``metadata.yaml``, a
``gap-batch`` manifest: all are small, hand-written or tool-written mappings, and none of the
shipped ones uses YAML anchors and aliases (``&name`` / ``*name``; ``test/sim/test_safe_yaml.py``
checks every shipped file). A file that does is refused, as is one above :data:`MAX_YAML_BYTES`:

* **aliases** are refused at the first one, before anything is built. A "billion laughs" file
  (nine lists of nine aliases to the list before) is a few hundred bytes that expands to 10⁹
  strings; ``yaml.safe_load`` builds it as shared references, but whatever walks it afterwards
  (a rig check, a JSON dump) hangs and fills the memory. Refusing aliases altogether is the
  simple rule: a count budget would not do (81 aliases already expand to 9⁹ nodes);
* **size**: a file above the limit is refused from its size on disk, before it is read (a 2 GB
  file of NUL bytes is refused in microseconds);
* a NUL byte (a binary file) is refused before parsing.

The refusal names the file, the line and column of the alias and what was expected, and comes in
well under a second (the scan is libyaml's C parser when PyYAML has it). Syntax errors are PyYAML's
``yaml.YAMLError`` as before, so callers keep their own messages with the line.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

#: Largest YAML input accepted, in bytes (a rig file is 3-10 kB, a bag's metadata.yaml a few kB).
MAX_YAML_BYTES = 1 << 20

_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class YamlRefusedError(ValueError):
    """A YAML input refused before it is built: an alias, a size above the limit, a binary file.

    The message names the input, what was found and what was expected.
    """


def _size_text(n: int) -> str:
    return f"{n / (1 << 20):.1f} MB" if n >= 1 << 20 else f"{n} bytes"


def parse_yaml(text: str, where: str, expected: str = "a YAML file", *,
               max_bytes: int = MAX_YAML_BYTES) -> Any:
    """Parse YAML text with the project's rules: no aliases, at most ``max_bytes``, no NUL byte.

    Parameters
    ----------
    text : str
        The YAML document (one document; an empty text gives None).
    where : str
        The input as messages name it (a file path, "parameter amplitude").
    expected : str
        What the input should be, for the refusal ("a rig file", "a CSV preset").
    max_bytes : int
        Size limit of the UTF-8 text, bytes.

    Returns
    -------
    object
        What ``yaml.safe_load`` returns for the text (dict, list, str, number, bool or None).

    Raises
    ------
    YamlRefusedError
        On the first alias (``*name``, merge keys ``<<: *name`` included), a text above
        ``max_bytes`` or a NUL byte; the message names ``where`` and ``expected``.
    yaml.YAMLError
        Invalid YAML (PyYAML's message with the line and column).
    """
    size = len(text.encode("utf-8", errors="replace")) if len(text) * 4 > max_bytes else len(text)
    if size > max_bytes:
        raise YamlRefusedError(f"{where}: refused: {_size_text(size)}, above the {_size_text(max_bytes)} "
                               f"limit for {expected}")
    if "\0" in text:
        line = text.count("\n", 0, text.index("\0")) + 1
        raise YamlRefusedError(f"{where}: refused: a NUL byte on line {line} (a binary file?); expected "
                               f"{expected} (YAML text)")
    try:
        for event in yaml.parse(text, Loader=_Loader):
            if isinstance(event, yaml.AliasEvent):
                raise _alias_refused(event, where, expected)
        return yaml.load(text, Loader=_Loader)  # a safe loader: CSafeLoader or SafeLoader
    except yaml.YAMLError:
        # invalid YAML: parsed again in Python for PyYAML's own message (libyaml words it otherwise)
        loader = _NoAliasLoader(text)
        loader.where, loader.expected = where, expected
        try:
            return loader.get_single_data()
        finally:
            loader.dispose()


def _alias_refused(event: yaml.AliasEvent, where: str, expected: str) -> YamlRefusedError:
    mark = event.start_mark
    return YamlRefusedError(
        f"{where}:{mark.line + 1}:{mark.column + 1}: refused: YAML alias *{event.anchor}; {expected} is "
        "read without anchors and aliases (&name / *name): write the value out where it is used")


class _NoAliasLoader(yaml.SafeLoader):
    """PyYAML's pure-Python safe loader, refusing the first alias (for invalid YAML's messages)."""

    where = "YAML text"
    expected = "a YAML file"

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            raise _alias_refused(self.peek_event(), self.where, self.expected)
        return super().compose_node(parent, index)


def load_yaml(path: str | Path, expected: str = "a YAML file", *, max_bytes: int = MAX_YAML_BYTES) -> Any:
    """Read and parse a YAML file with the project's rules (:func:`parse_yaml`).

    The size is checked on disk first, so an oversized file is never read.

    Parameters
    ----------
    path : str or Path
        The file (UTF-8).
    expected : str
        What the file should be ("a rig file"), for the refusal message.
    max_bytes : int
        Size limit, bytes.

    Returns
    -------
    object
        The parsed document.

    Raises
    ------
    YamlRefusedError
        A file above ``max_bytes`` (from its size on disk), an alias or a NUL byte.
    OSError
        The file cannot be read (missing, a folder, no permission).
    UnicodeDecodeError
        Not UTF-8 text.
    yaml.YAMLError
        Invalid YAML.
    """
    p = Path(path)
    size = os.stat(p).st_size
    if size > max_bytes:
        raise YamlRefusedError(f"{p}: refused: {_size_text(size)}, above the {_size_text(max_bytes)} "
                               f"limit for {expected}")
    with open(p, encoding="utf-8") as fh:
        text = fh.read(max_bytes + 1)  # a pipe or special file may grow past its stat size
    return parse_yaml(text, str(p), expected, max_bytes=max_bytes)
