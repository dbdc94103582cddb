"""The launch files, evaluated without a ROS installation.

``launch`` / ``launch_ros`` do not install from the package index here (no ``ros-jazzy-launch-ros``
wheel), so each launch file is executed against minimal stand-ins of the launch API that record
what it declares: its arguments, and, for a given set of argument values, the nodes its
``OpaqueFunction`` returns (package, executable, name, namespace, parameters). Checked: every file
imports and builds its description; every node of every file takes the ``namespace`` argument
(two rigs side by side); every executable it starts is a console script of the package named;
every package it starts is an ``exec_depend`` of the launch file's package.
"""

from __future__ import annotations

import importlib.util
import re
import sys
import tempfile
import types
from pathlib import Path
from typing import Any

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
LAUNCH_FILES = sorted(SRC.glob("*/launch/*.launch.py"))


class _Action:
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args, self.kwargs = args, kwargs


class _Config:
    def __init__(self, name: str) -> None:
        self.name = name

    def perform(self, context: dict[str, str]) -> str:
        return context[self.name]


def _fake_launch() -> dict[str, types.ModuleType]:
    mods = {n: types.ModuleType(n) for n in ("launch", "launch.actions", "launch.substitutions",
                                             "launch.events", "launch.event_handlers", "launch_ros",
                                             "launch_ros.actions")}
    mods["launch"].LaunchDescription = lambda entities: list(entities)
    for name in ("DeclareLaunchArgument", "OpaqueFunction", "SetEnvironmentVariable", "EmitEvent",
                 "RegisterEventHandler"):
        setattr(mods["launch.actions"], name, type(name, (_Action,), {}))
    mods["launch.substitutions"].LaunchConfiguration = _Config
    mods["launch.events"].Shutdown = type("Shutdown", (_Action,), {})
    mods["launch.event_handlers"].OnProcessExit = type("OnProcessExit", (_Action,), {})
    mods["launch_ros.actions"].Node = type("Node", (_Action,), {})
    return mods


def _load(path: Path, monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    for name, mod in _fake_launch().items():
        monkeypatch.setitem(sys.modules, name, mod)
    # an ament prefix holding aeropend_sim, as after sourcing install/setup.bash (RViz config lookup)
    prefix = Path(tempfile.gettempdir()) / "aeropend_test_launch_prefix"
    marker = prefix / "share" / "ament_index" / "resource_index" / "packages" / "aeropend_sim"
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.touch()
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    spec = importlib.util.spec_from_file_location(path.stem.replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


def _nodes(entities: list[Any], **values: str) -> list[Any]:
    args = {e.args[0]: e.kwargs["default_value"] for e in entities
            if type(e).__name__ == "DeclareLaunchArgument"}
    context = {**args, **values}
    out = []
    for e in entities:
        if type(e).__name__ == "OpaqueFunction":
            out += [n for n in e.kwargs["function"](context) if type(n).__name__ == "Node"]
    return out


def _console_scripts(package: str) -> set[str]:
    text = (SRC / package / "setup.py").read_text(encoding="utf-8")
    return set(re.findall(r"['\"](\w+)\s*=\s*[\w.]+:\w+['\"]", text))


def _exec_depends(package: str) -> set[str]:
    text = (SRC / package / "package.xml").read_text(encoding="utf-8")
    return set(re.findall(r"<(?:exec_)?depend>([\w-]+)</(?:exec_)?depend>", text))


def test_there_are_launch_files() -> None:
    assert len(LAUNCH_FILES) >= 5, LAUNCH_FILES


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_launch_file_nodes_take_the_namespace_and_exist(path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    entities = _load(path, monkeypatch)
    default = _nodes(entities)
    assert default, f"{path.name} starts no node"
    assert all(n.kwargs.get("namespace") is None for n in default)  # root namespace by default
    rig2 = _nodes(entities, namespace="rig2")
    assert [n.kwargs.get("namespace") for n in rig2] == ["rig2"] * len(rig2)
    owner = path.parents[1].name
    for n in default:
        pkg, exe = n.kwargs["package"], n.kwargs["executable"]
        if (SRC / pkg).is_dir():  # a package of this workspace: the executable is one of its scripts
            assert exe in _console_scripts(pkg), f"{path.name}: {pkg} has no executable {exe!r}"
        assert pkg == owner or pkg in _exec_depends(owner), f"{owner}/package.xml does not depend on {pkg}"
    assert {"launch", "launch_ros"} <= _exec_depends(owner), f"{owner}/package.xml lacks launch, launch_ros"


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=lambda p: p.name)
def test_launch_file_nodes_take_the_params_file_last(path: Path, monkeypatch: pytest.MonkeyPatch,
                                                     tmp_path: Path) -> None:
    entities = _load(path, monkeypatch)
    configured = [n for n in _nodes(entities) if "parameters" in n.kwargs]  # RViz takes none
    assert configured and all(len(n.kwargs["parameters"]) == 1 for n in configured)  # no file by default
    params_file = tmp_path / "lab.yaml"
    params_file.write_text("/**:\n  ros__parameters:\n    rig: thesis_sim\n", encoding="utf-8")
    nodes = [n for n in _nodes(entities, params_file=str(params_file)) if "parameters" in n.kwargs]
    assert len(nodes) == len(configured)
    # launch_ros applies the entries in order: the file comes last, so its values win
    assert [n.kwargs["parameters"][-1] for n in nodes] == [str(params_file)] * len(nodes)
    assert all(isinstance(n.kwargs["parameters"][0], dict) for n in nodes)
    with pytest.raises(FileNotFoundError, match=re.escape("params_file:='/nonexistent.yaml' is not a file")):
        _nodes(entities, params_file="/nonexistent.yaml")


def test_every_package_ships_a_params_file_for_its_launch_files_nodes() -> None:
    import yaml

    for path in LAUNCH_FILES:
        owner = path.parents[1].name
        configs = sorted((SRC / owner / "config").glob("*.yaml"))
        assert configs, f"{owner} has no config/*.yaml"
        for config in configs:
            doc = yaml.safe_load(config.read_text(encoding="utf-8"))
            assert doc and all(key.startswith("/**") and "ros__parameters" in value
                               for key, value in doc.items()), config


def test_description_launch_publishes_the_rigs_urdf_from_the_contract_joint_states(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from aeropend_sim.contract import REL_JOINT_STATES
    from aeropend_sim.description import urdf_for_rig

    entities = _load(SRC / "aeropend_sim" / "launch" / "description.launch.py", monkeypatch)
    rsp, rviz = _nodes(entities)
    assert (rsp.kwargs["package"], rviz.kwargs["package"]) == ("robot_state_publisher", "rviz2")
    params = rsp.kwargs["parameters"][0]
    assert params["robot_description"] == urdf_for_rig("thesis_rig")
    assert params["frame_prefix"] == ""
    assert rsp.kwargs["remappings"] == [("joint_states", REL_JOINT_STATES)]
    assert rviz.kwargs["arguments"][-1].endswith("share/aeropend_sim/rviz/aeropend.rviz")
    rsp2, = _nodes(entities, namespace="rig2", rig="thesis_sim", rviz="false")
    assert rsp2.kwargs["parameters"][0]["frame_prefix"] == "rig2/"  # two rigs: rig2/base_link, ...
    assert rsp2.kwargs["parameters"][0]["robot_description"] == urdf_for_rig("thesis_sim")


def test_closed_loop_strategy_argument_reads_the_strategy_registry(monkeypatch: pytest.MonkeyPatch) -> None:
    """Default, choices (launch refuses any other value before a node starts) and help of the
    ``strategy`` argument come from the registry; the value reaches the controller node."""
    from aeropend_control.strategies import DEFAULT_STRATEGY, strategy_class, strategy_names

    entities = _load(SRC / "aeropend_control" / "launch" / "closed_loop.launch.py", monkeypatch)
    arg = next(e for e in entities if type(e).__name__ == "DeclareLaunchArgument" and e.args[0] == "strategy")
    assert arg.kwargs["default_value"] == DEFAULT_STRATEGY
    assert arg.kwargs["choices"] == list(strategy_names())
    assert all(f"{n}: {strategy_class(n).description}" in arg.kwargs["description"] for n in strategy_names())
    last = strategy_names()[-1]
    ctrl = [n for n in _nodes(entities, strategy=last) if n.kwargs["executable"] == "controller"]
    assert [n.kwargs["parameters"][0]["strategy"] for n in ctrl] == [last]
