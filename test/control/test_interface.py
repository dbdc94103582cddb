"""The strategy interface and registry (aeropend_control.strategies), and the package's public API.

* every registered strategy has one row in :data:`ROWS` and holds the simulated thesis rig at a
  set point through the controller loop (:class:`~aeropend_control.controller_core.ControllerLoop`,
  the node's core), with the class attributes the registry checks;
* a fifth strategy, defined here only (an open-loop hold at the model's equilibrium duty), is one
  class plus one row: registered through the public API, it runs through the same loop and the
  node's parameter validation accepts its name; unregistered, it is refused again;
* the names are written once in ``src`` (the classes), the shipped params file, the launch file
  and the node's parameter description read them from the registry;
* ``aeropend_control.__all__`` resolves, and the reference docs name every entry.
"""

from __future__ import annotations

import ast
import math
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

import aeropend_control
from aeropend_control.controller_core import SIGNALS, ControllerConfigError, ControllerLoop, make_settings
from aeropend_control.strategies import (
    CHANNELS,
    DEFAULT_STRATEGY,
    ControlOutput,
    Measurement,
    Strategy,
    StrategyError,
    make_strategy,
    register,
    strategy_class,
    strategy_names,
    unregister,
)
from aeropend_sim.model import PlantModel
from aeropend_sim.params import Rig, load_rig
from bench.fixtures.closed_loop import closed_loop

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "src"
PERIOD = 2.048e-3
RIG = load_rig("thesis_rig")

#: One row per strategy: (name, extra node settings, settling bound [s] of the step 0 → 0.4 rad).
#: A new strategy adds its row here (``test_every_registered_strategy_has_a_row`` checks it).
ROWS: list[tuple[str, dict[str, Any], float]] = [
    ("fl_pid", {}, 1.0),
    ("small_signal", {}, 1.0),
    ("small_signal_fixed", {"theta_op": 0.4}, 1.0),
    ("cascade", {}, 1.0),
    ("fl_cascade", {}, 1.0),
]


def _hold(name: str, extra: dict[str, Any], ts_max: float, r: float = 0.4) -> ControllerLoop:
    """Step 0 → r through the controller loop around the simulated thesis rig (for ts_max + 1.5 s);
    asserts the rod settles (2 % band) within ``ts_max`` and ends within 1 mrad of r."""
    loop = ControllerLoop(make_settings(strategy=name, steps=[0.0, r], mode="lockstep", **extra))
    run = closed_loop(loop, round((ts_max + 1.5) / PERIOD))
    theta = np.array([th for th, _ in run])
    outside = np.nonzero(np.abs(theta - r) > 0.02 * r)[0]
    ts = (outside[-1] + 1) * PERIOD
    assert ts <= ts_max, f"{name}: settles at {ts:.3f} s"
    assert abs(theta[-1] - r) < 1e-3, f"{name}: ends at {theta[-1]:.5f} rad"
    return loop


@pytest.mark.parametrize(("name", "extra", "ts_max"), ROWS, ids=[r[0] for r in ROWS])
def test_each_strategy_holds_the_rig_through_the_controller_loop(name: str, extra: dict,
                                                                 ts_max: float) -> None:
    loop = _hold(name, extra, ts_max)
    cls = strategy_class(name)
    assert isinstance(loop.strategy, cls) and loop.needs == cls.needs
    assert loop.strategy.nan_count == 0
    # the observer's estimates reach the signals (every shipped strategy runs the Kalman observer)
    row = dict(zip(SIGNALS, loop.rows[-1], strict=True))
    assert row["theta_hat"] == pytest.approx(0.4, abs=2e-3)


def test_every_registered_strategy_has_a_row_and_valid_class_attributes() -> None:
    assert [r[0] for r in ROWS] == list(strategy_names())
    assert DEFAULT_STRATEGY in strategy_names()
    for name in strategy_names():
        cls = strategy_class(name)
        assert cls.name == name and cls.description.strip() and "\n" not in cls.description
        assert set(cls.needs) <= set(CHANNELS) and "theta" in cls.needs
        assert cls.default_spec.omega_n > 0.0
        # the cascades read the motor channels, the others θ only
        assert ("i_a" in cls.needs) == (cls.drive_kind == "cascade")


def test_unknown_names_and_invalid_classes_are_refused_with_the_value() -> None:
    with pytest.raises(StrategyError, match=r"strategy = 'pd'; expected one of \('fl_pid'"):
        make_strategy("pd", RIG)
    with pytest.raises(StrategyError, match="'pd'"):
        unregister("pd")

    class Abstract(Strategy):
        name = "abstract"
        description = "no step"

    with pytest.raises(StrategyError, match=r"does not implement \['build', 'reset', 'step'\]"):
        register(Abstract)
    with pytest.raises(StrategyError, match="already registered"):
        register(type("Impostor", (_EquilibriumHold,), {"name": "fl_pid"}))
    with pytest.raises(StrategyError, match=r"name = 'Bad Name'"):
        register(type("BadName", (_EquilibriumHold,), {"name": "Bad Name"}))
    with pytest.raises(StrategyError, match=r"needs = \('theta', 'v_a'\)"):
        register(type("BadNeeds", (_EquilibriumHold,), {"needs": ("theta", "v_a")}))
    with pytest.raises(StrategyError, match=r"default = True, but 'fl_pid' is already the default"):
        register(type("SecondDefault", (_EquilibriumHold,), {"name": "second_default", "default": True}))
    with pytest.raises(StrategyError, match=r"listed = 'first'; expected a number"):
        register(type("BadListed", (_EquilibriumHold,), {"name": "bad_listed", "listed": "first"}))
    with pytest.raises(StrategyError, match="is not a Strategy subclass"):
        register(dict)  # type: ignore[arg-type]
    assert "equilibrium_hold" not in strategy_names()


def test_shipped_strategies_are_discovered_from_their_modules_not_listed() -> None:
    """Every concrete strategy class declared in a module of aeropend_control/strategies is
    registered, found by importing the package's modules (no list of shipped strategies exists)."""
    import importlib
    import inspect
    import pkgutil

    import aeropend_control.strategies as package
    from aeropend_control.strategies import registry

    assert not hasattr(registry, "BUILTIN")
    declared = set()
    for info in pkgutil.iter_modules(package.__path__, prefix=package.__name__ + "."):
        module = importlib.import_module(info.name)
        for _, cls in inspect.getmembers(module, inspect.isclass):
            if issubclass(cls, Strategy) and cls.__module__ == info.name and not inspect.isabstract(cls) \
                    and "name" in vars(cls):
                declared.add(cls.name)
    assert declared == set(strategy_names()) - {"equilibrium_hold"}
    assert len(declared) == 5


# --------------------------------------------------------------------- a fifth strategy
class _EquilibriumHold(Strategy):
    """Open loop: the duty that holds the model at the reference (no feedback; test only)."""

    name = "equilibrium_hold"
    description = "open loop: the model's equilibrium duty of the reference (test only)"

    def __init__(self, rig: Rig) -> None:
        self.model = PlantModel(rig)
        self.reset()

    @classmethod
    def build(cls, rig: Rig, spec: object = None, **options: object) -> _EquilibriumHold:
        return cls(rig)  # no pole pattern, allocator or estimator: ignored

    def reset(self) -> None:
        self._r, self._duty, self._nan = math.nan, 0.0, 0

    @property
    def nan_count(self) -> int:
        return self._nan

    def step(self, r: float, y: Measurement) -> ControlOutput:
        if not (math.isfinite(r) and math.isfinite(y.theta)):
            self._nan += 1
            return ControlOutput(self._duty, math.nan, math.nan, math.nan, math.nan, 0, True)
        if r != self._r:
            self._r, self._duty = r, float(self.model.equilibrium(r)[1])
        return ControlOutput(self._duty, r - y.theta, math.nan, math.nan, math.nan, 0)


@pytest.fixture
def fifth() -> Iterator[type[Strategy]]:
    """:class:`_EquilibriumHold` registered for the test, unregistered after it."""
    register(_EquilibriumHold)
    try:
        yield _EquilibriumHold
    finally:
        unregister(_EquilibriumHold.name)


def test_a_fifth_strategy_is_one_class_plus_one_row(fifth: type[Strategy]) -> None:
    assert strategy_names()[-1] == fifth.name
    # its row: no extra setting; open loop, the rod settles in 3.6 s (thesis §4: 3.53 s at τ = 43 %)
    loop = _hold(fifth.name, {}, 4.0)
    assert isinstance(loop.strategy, fifth) and loop.needs == ("theta",)
    row = dict(zip(SIGNALS, loop.rows[-1], strict=True))
    assert row["duty"] == pytest.approx(PlantModel(RIG).equilibrium(0.4)[1], abs=1e-12)
    assert math.isnan(row["theta_hat"])  # no observer: the signal says so
    assert loop.on_sample(10**12, math.nan) == row["duty"] and loop.strategy.nan_count == 1
    # retune is refused by the base class: the node keeps the running loop
    with pytest.raises(ControllerConfigError, match="cannot be retuned"):
        loop.retune(make_settings(strategy=fifth.name, steps=[0.0, 0.4], mode="lockstep", omega_n=5.0))


def test_an_unregistered_strategy_is_refused_by_the_node_settings(fifth: type[Strategy]) -> None:
    assert make_settings(strategy=fifth.name).strategy == fifth.name
    unregister(fifth.name)
    try:
        with pytest.raises(ControllerConfigError, match="strategy = 'equilibrium_hold'"):
            make_settings(strategy=fifth.name)
    finally:
        register(fifth)  # the fixture unregisters it


@pytest.mark.ros
def test_the_node_accepts_a_registered_strategy_and_subscribes_what_it_needs(fifth: type[Strategy]) -> None:
    """In-process ``ControllerNode``: the fifth strategy's name passes the node's parameter
    validation; the node subscribes to the armature topic only for a strategy that needs i_a."""
    rclpy = pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter

    from aeropend_control.controller_node import ControllerNode
    from aeropend_sim.contract import REL_ARMATURE
    from aeropend_sim.ros.harness import random_domain

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=random_domain())
    try:
        topics = {}
        for name in (fifth.name, "fl_cascade"):
            node = ControllerNode(context=ctx, parameter_overrides=[Parameter("strategy", value=name),
                                                                   Parameter("mode", value="lockstep")])
            try:
                assert type(node.loop.strategy).name == name
                topics[name] = {s.topic_name.lstrip("/") for s in node.subscriptions}
            finally:
                node.destroy_node()
        assert REL_ARMATURE not in topics[fifth.name] and REL_ARMATURE in topics["fl_cascade"]
    finally:
        rclpy.shutdown(context=ctx)


# --------------------------------------------------------------------- names written once
def _string_constants(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)]


def test_strategy_names_are_written_once_in_src() -> None:
    """Each name is a string literal in ``src`` exactly once: its class's ``name`` (``cascade`` is
    also a drive kind of :mod:`aeropend_control.drive_design`, so it is not counted)."""
    from aeropend_control.drive_design import DRIVES

    literals = [s for path in SRC.rglob("*.py") for s in _string_constants(path)]
    for name in strategy_names():
        if name not in DRIVES:
            assert literals.count(name) == 1, name


def test_params_file_and_node_parameters_take_the_names_from_the_registry() -> None:
    """The shipped ``controller.yaml`` is data: its ``strategy`` is the node's default, a registered
    name (the file is not generated; its comment points to ``ros2 param describe``)."""
    path = SRC / "aeropend_control" / "config" / "controller.yaml"
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    assert doc["/**/aeropend_controller"]["ros__parameters"]["strategy"] == DEFAULT_STRATEGY
    pytest.importorskip("rclpy")
    from aeropend_control.controller_node import parameter_table

    param = next(p for p in parameter_table() if p.name == "strategy")
    assert param.default == DEFAULT_STRATEGY
    assert [part.split(":")[0] for part in param.description.split(" | ")] == list(strategy_names())


# --------------------------------------------------------------------- public API
def test_public_api_resolves_and_the_reference_docs_name_it() -> None:
    names = aeropend_control.__all__
    assert len(set(names)) == len(names)
    assert [n for n in names if not hasattr(aeropend_control, n)] == []
    # the functional core: importing the package loads no rclpy
    probe = "import sys, aeropend_control; print('rclpy' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120).stdout.strip() == "False"
    docs = (ROOT / "docs" / "control.md").read_text(encoding="utf-8")
    reference = docs[:docs.index("\n## ", docs.index("## Controllers"))]
    assert [n for n in names if f"`{n}`" not in reference] == []
