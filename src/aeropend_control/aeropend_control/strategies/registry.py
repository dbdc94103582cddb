"""The strategy registry: strategies are declared, discovered and checked when they are declared.

The controller node's ``strategy`` parameter (its validation and description), the launch
file's ``strategy`` argument (choices and help) and the benches read the names from here; each
name is written once, as the ``name`` of its class.

Adding a strategy — shipped or a lab's own, the same way: a
:class:`~aeropend_control.strategies.base.Strategy` subclass decorated with :func:`register`.
:func:`register` checks the class when it is declared (a bad ``name``, ``needs``, ``default_spec``
... is refused at import, naming the attribute). A shipped strategy is a module of this package:
the registry imports every module of the package on first use (:func:`_discover`), so the module
is the whole change (plus its row in ``test/control/test_interface.py``). A lab's strategy lives
in the lab's own module, registered when that module is imported.
"""

from __future__ import annotations

import inspect
import pkgutil
import re
from importlib import import_module
from pathlib import Path

from aeropend_control.design import PoleSpec
from aeropend_control.drive_design import DRIVES
from aeropend_control.strategies.base import CHANNELS, Strategy, StrategyError
from aeropend_sim.params import Rig

_NAME = re.compile(r"[a-z][a-z0-9_]*")
_REGISTRY: dict[str, type[Strategy]] = {}
_discovered = False


def _discover() -> None:
    """Import every module of this package once, so that the shipped strategies declare themselves.

    Raises
    ------
    StrategyError
        If no module registered :data:`DEFAULT_STRATEGY`.
    """
    global _discovered
    if _discovered:
        return
    _discovered = True
    package = __name__.rpartition(".")[0]
    for info in pkgutil.iter_modules([str(Path(__file__).parent)], prefix=package + "."):
        import_module(info.name)


def default_strategy() -> str:
    """Name of the strategy the controller node runs when its ``strategy`` parameter is not set:
    the registered class that declares ``default = True`` (also ``DEFAULT_STRATEGY``).

    Raises
    ------
    StrategyError
        If no registered strategy declares itself the default.
    """
    _discover()
    for name, cls in _REGISTRY.items():
        if cls.default:
            return name
    raise StrategyError("no registered strategy declares default = True")


def __getattr__(name: str) -> object:
    """``DEFAULT_STRATEGY`` (:func:`default_strategy`), read when it is first asked for (PEP 562)."""
    if name == "DEFAULT_STRATEGY":
        return default_strategy()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _listed() -> list[tuple[str, type[Strategy]]]:
    """The registered strategies in listing order: by ``listed``, then in registration order."""
    _discover()
    order = {name: k for k, name in enumerate(_REGISTRY)}
    return sorted(_REGISTRY.items(), key=lambda item: (item[1].listed, order[item[0]]))


def register(cls: type[Strategy]) -> type[Strategy]:
    """Register a strategy class under its ``name`` (returns ``cls``: usable as a class decorator).

    Raises
    ------
    StrategyError
        If ``cls`` is not a concrete :class:`Strategy` subclass, its class attributes are invalid
        (``name`` not lower-case ``[a-z][a-z0-9_]*``, ``description`` not one non-empty line, ``needs``
        not channels of :class:`~aeropend_control.strategies.base.Measurement`, ``default_spec`` not
        a :class:`PoleSpec`, ``drive_kind`` not None or a drive kind), or another class is
        registered under that name.
    """
    if not (isinstance(cls, type) and issubclass(cls, Strategy)):
        raise StrategyError(f"{cls!r} is not a Strategy subclass")
    label = cls.__qualname__
    if inspect.isabstract(cls):
        raise StrategyError(f"{label} does not implement {sorted(cls.__abstractmethods__)}")
    name = getattr(cls, "name", None)
    if not (isinstance(name, str) and _NAME.fullmatch(name)):
        raise StrategyError(f"{label}.name = {name!r}; expected a lower-case name [a-z][a-z0-9_]*")
    desc = getattr(cls, "description", None)
    if not (isinstance(desc, str) and desc.strip() and "\n" not in desc):
        raise StrategyError(f"{label}.description = {desc!r}; expected one non-empty line")
    listed = getattr(cls, "listed", None)
    if not isinstance(listed, (int, float)) or isinstance(listed, bool) or listed != listed:
        raise StrategyError(f"{label}.listed = {listed!r}; expected a number (its place in the listing)")
    unknown = [c for c in cls.needs if c not in CHANNELS]
    if unknown or not cls.needs:
        raise StrategyError(f"{label}.needs = {cls.needs!r}; expected channels of {CHANNELS}")
    if not isinstance(cls.default_spec, PoleSpec):
        raise StrategyError(f"{label}.default_spec = {cls.default_spec!r}; expected a PoleSpec")
    if cls.drive_kind is not None and cls.drive_kind not in DRIVES:
        raise StrategyError(f"{label}.drive_kind = {cls.drive_kind!r}; expected None or one of {DRIVES}")
    if getattr(cls, "default", False):
        other = next((n for n, c in _REGISTRY.items() if c.default and n != name), None)
        if other is not None:
            raise StrategyError(f"{label}.default = True, but {other!r} is already the default strategy")
    held = _REGISTRY.get(name)
    if held is not None and held is not cls:
        raise StrategyError(f"strategy {name!r} is already registered ({held.__qualname__})")
    _REGISTRY[name] = cls
    return cls


def unregister(name: str) -> type[Strategy]:
    """Remove strategy ``name`` from the registry; returns its class.

    Raises
    ------
    StrategyError
        If no strategy of that name is registered.
    """
    cls = strategy_class(name)
    del _REGISTRY[name]
    return cls


def strategy_names() -> tuple[str, ...]:
    """Names of the registered strategies, in listing order (shipped ones first, by ``listed``)."""
    return tuple(name for name, _ in _listed())


def strategy_class(name: str) -> type[Strategy]:
    """The class registered as ``name``.

    Raises
    ------
    StrategyError
        On an unknown name (the message lists the registered ones).
    """
    _discover()
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise StrategyError(f"strategy = {name!r}; expected one of {strategy_names()}") from None


def strategy_help() -> str:
    """Every registered strategy as ``name: description``, joined by `` | `` (parameter help)."""
    return " | ".join(f"{name}: {cls.description}" for name, cls in _listed())


def make_strategy(name: str, rig: Rig, **options: object) -> Strategy:
    """Build strategy ``name`` for ``rig``: :meth:`Strategy.build` of its class.

    Parameters
    ----------
    name : str
        A registered name (:func:`strategy_names`).
    rig : Rig
    **options
        ``spec`` (a :class:`PoleSpec`) is accepted by every strategy; the others go to the class
        (e.g. ``allocator``, ``estimator``, ``tf``, ``theta_op``; the cascades take
        ``cascade_design``, FL ones ``design``).

    Raises
    ------
    StrategyError
        On an unknown name or an invalid option (e.g. ``small_signal_fixed`` without ``theta_op``).
    """
    return strategy_class(name).build(rig, **options)  # type: ignore[arg-type]

