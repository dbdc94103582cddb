"""The one lazy public-API hook of every package ``__init__`` (PEP 562).

A package's ``__init__`` keeps one table, ``_API`` (defining module -> the names it exports), and
gets ``__all__``, ``__getattr__`` and ``__dir__`` from :func:`lazy_api`::

    _API = {"aeropend_ident.gap.run": ("run_gap", "GapResult")}
    __all__, __getattr__, __dir__ = lazy_api(__name__, globals(), _API)

A name is imported from its module on first use and kept in the package's namespace, so importing
the package costs nothing and the console scripts start fast. docs/api.md; test/test_api.py checks
that every name resolves once and no submodule is hidden. No rclpy import.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, MutableMapping
from importlib import import_module
from typing import Any


def lazy_api(package: str, namespace: MutableMapping[str, Any], api: Mapping[str, tuple[str, ...]]
             ) -> tuple[list[str], Callable[[str], object], Callable[[], list[str]]]:
    """``__all__``, ``__getattr__`` and ``__dir__`` of a package whose public names load on first use.

    Parameters
    ----------
    package : str
        The package's ``__name__`` (named in the ``AttributeError`` of an unknown name).
    namespace : mutable mapping
        The package's ``globals()``: a name, once imported, is kept there.
    api : mapping of str to tuple of str
        Defining module -> the names the package exports from it.

    Returns
    -------
    tuple
        ``(__all__, __getattr__, __dir__)``: the sorted public names; the PEP 562 hook that imports
        a name's module on first use (``AttributeError`` for a name not in ``api``); the listing of
        the namespace plus the public names.

    Raises
    ------
    ValueError
        If ``api`` exports one name from two modules.
    """
    where: dict[str, str] = {}
    for module, names in api.items():
        for name in names:
            if where.setdefault(name, module) != module:
                raise ValueError(f"{package}: {name!r} is exported from both {where[name]} and {module}")
    public = sorted(where)

    def __getattr__(name: str) -> object:  # noqa: N807 (the PEP 562 name)
        """Import the module that defines ``name`` on first use (PEP 562) and keep the value."""
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(module), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:  # noqa: N807 (the PEP 562 name)
        return sorted({*namespace, *public})

    return public, __getattr__, __dir__
