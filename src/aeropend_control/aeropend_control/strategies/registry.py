"""The strategy registry: the one place that lists the shipped strategies and maps names to classes.

The controller node's ``strategy`` parameter (its validation and description), the launch
file's ``strategy`` argument (choices and help) and the benches read the names from here; each
name is written once, as the ``name`` of its class.

Adding a strategy: write a :class:`~aeropend_control.strategies.base.Strategy` subclass in its own
module and either list it in :data:`BUILTIN` (shipped with aeropend) or call :func:`register` on
it (a lab's own strategy; :func:`register` works as a class decorator too).
"""

from __future__ import annotations

import inspect
import re

from aeropend_control.design import PoleSpec
from aeropend_control.drive_design import DRIVES
from aeropend_control.strategies.base import CHANNELS, Strategy, StrategyError
from aeropend_control.strategies.cascade import SmallSignalCascade
from aeropend_control.strategies.fl_cascade import FLCascade
from aeropend_control.strategies.fl_pid import FeedbackLinearizationPID
from aeropend_control.strategies.small_signal import SmallSignalFixedPID, SmallSignalPID
from aeropend_sim.params import Rig

#: The strategies shipped with aeropend, in the order the node's help lists them.
BUILTIN: tuple[type[Strategy], ...] = (FeedbackLinearizationPID, SmallSignalPID, SmallSignalFixedPID,
                                       SmallSignalCascade, FLCascade)
#: Strategy the controller node runs when its ``strategy`` parameter is not set.
DEFAULT_STRATEGY: str = FeedbackLinearizationPID.name
_NAME = re.compile(r"[a-z][a-z0-9_]*")
_REGISTRY: dict[str, type[Strategy]] = {}


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
    unknown = [c for c in cls.needs if c not in CHANNELS]
    if unknown or not cls.needs:
        raise StrategyError(f"{label}.needs = {cls.needs!r}; expected channels of {CHANNELS}")
    if not isinstance(cls.default_spec, PoleSpec):
        raise StrategyError(f"{label}.default_spec = {cls.default_spec!r}; expected a PoleSpec")
    if cls.drive_kind is not None and cls.drive_kind not in DRIVES:
        raise StrategyError(f"{label}.drive_kind = {cls.drive_kind!r}; expected None or one of {DRIVES}")
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
    """Names of the registered strategies, in registration order (shipped ones first)."""
    return tuple(_REGISTRY)


def strategy_class(name: str) -> type[Strategy]:
    """The class registered as ``name``.

    Raises
    ------
    StrategyError
        On an unknown name (the message lists the registered ones).
    """
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise StrategyError(f"strategy = {name!r}; expected one of {strategy_names()}") from None


def strategy_help() -> str:
    """Every registered strategy as ``name: description``, joined by `` | `` (parameter help)."""
    return " | ".join(f"{name}: {cls.description}" for name, cls in _REGISTRY.items())


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


for _cls in BUILTIN:
    register(_cls)
