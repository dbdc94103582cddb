"""The packages' ROS parameters files (``src/<pkg>/config/*.yaml``) load into their nodes.

Each node is started as a process with ``--ros-args --params-file <shipped file>``; its
``get_parameters`` service must return every value the file sets (a key the node does not
declare comes back unset and fails the test). Then a copy of the simulator's file with other
values changes what the running plant publishes, and ``-p`` after ``--params-file`` overrides
the file (the order launch files rely on: arguments, then ``params_file``).
"""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

pytest.importorskip("rclpy")

from rcl_interfaces.srv import GetParameters
from rclpy.parameter import parameter_value_to_python
from sensor_msgs.msg import JointState

from aeropend_sim.contract import TOPIC_JOINT_STATES
from aeropend_sim.ros.harness import (
    isolated_env,
    node_command,
    private_node,
    random_domain,
    reap,
    stop,
    wait_for_server,
)
from aeropend_sim.ros.ros_contract import SAMPLE_QOS_LOCKSTEP

pytestmark = [pytest.mark.ros, pytest.mark.timeout(120)]
SRC = Path(__file__).resolve().parents[2] / "src"

#: (package, file, node name, console script, module, overrides given with -p after the file)
CASES = [
    ("aeropend_sim", "sim.yaml", "aeropend_sim", "sim_node", "aeropend_sim.ros.sim_node", {}),
    ("aeropend_control", "controller.yaml", "aeropend_controller", "controller",
     "aeropend_control.controller_node", {}),
    ("aeropend_bridge", "bridge.yaml", "aeropend_bridge", "bridge", "aeropend_bridge.bridge_node",
     {"autostart": False}),  # no serial device here: stay unconfigured
    ("aeropend_ident", "record.yaml", "aeropend_recorder", "record", "aeropend_ident.nodes.record", {}),
]


def _section(path: Path, node: str) -> dict[str, Any]:
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    return doc[f"/**/{node}"]["ros__parameters"]


def _get(node: Any, executor: Any, target: str, names: list[str], timeout: float = 20.0) -> dict[str, Any]:
    client = node.create_client(GetParameters, f"/{target}/get_parameters")
    # available both ways (the server has matched this client's response reader), then one request
    wait_for_server(client, executor, GetParameters.Request(names=[]), timeout)
    future = client.call_async(GetParameters.Request(names=names))
    end = time.monotonic() + timeout
    while not future.done() and time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    assert future.done(), f"/{target}/get_parameters did not answer"
    node.destroy_client(client)
    return {n: parameter_value_to_python(v) for n, v in zip(names, future.result().values, strict=True)}


def _as_compared(value: Any) -> Any:
    return list(value) if isinstance(value, (list, tuple)) or hasattr(value, "tolist") else value


@pytest.mark.parametrize(("pkg", "file", "name", "script", "module", "overrides"), CASES,
                         ids=[c[1] for c in CASES])
def test_shipped_params_file_loads_into_the_node(pkg: str, file: str, name: str, script: str, module: str,
                                                  overrides: dict[str, Any], tmp_path: Path) -> None:
    path = SRC / pkg / "config" / file
    expected = _section(path, name)
    assert expected, f"{path} sets no parameter of {name}"
    extra = [a for k, v in overrides.items() for a in ("-p", f"{k}:={str(v).lower()}")]
    expected.update(overrides)
    domain = random_domain(101, 200)
    proc = subprocess.Popen([*node_command(script, module), "--ros-args", "--params-file", str(path), *extra],
                            env=isolated_env(domain), cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        with private_node("params_file_client", domain) as (node, executor):
            got = _get(node, executor, name, sorted(expected))
        for key, value in expected.items():
            assert _as_compared(got[key]) == value, f"{file}: {name}.{key} = {got[key]!r}, expected {value!r}"
    finally:
        stop(proc, signal.SIGINT, timeout=15)
        reap(proc)


def test_params_file_values_drive_the_plant_and_p_after_it_wins(tmp_path: Path) -> None:
    doc = yaml.safe_load((SRC / "aeropend_sim" / "config" / "sim.yaml").read_text(encoding="utf-8"))
    params = doc["/**/aeropend_sim"]["ros__parameters"]
    # lock-step: sample 0 (the initial state) is published once this test's reader is matched,
    # so the first sample shows the initial angle whatever the machine's load
    params.update(frame_id="rig_from_file", seed=7, initial_theta=0.3, mode="lockstep", publish_clock=False,
                  noise=False)
    custom = tmp_path / "my_sim.yaml"
    custom.write_text(yaml.safe_dump(doc), encoding="utf-8")
    domain = random_domain(101, 200)
    proc = subprocess.Popen([*node_command("sim_node", "aeropend_sim.ros.sim_node"), "--ros-args", "-r",
                             "__ns:=/rig2", "--params-file", str(custom), "-p", "seed:=11"],
                            env=isolated_env(domain), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        with private_node("params_file_client", domain) as (node, executor):
            msgs: list[JointState] = []
            node.create_subscription(JointState, "/rig2" + TOPIC_JOINT_STATES, msgs.append,
                                     SAMPLE_QOS_LOCKSTEP)
            end = time.monotonic() + 20
            while not msgs and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)
            assert msgs, "no sample 0 from /rig2/aeropend/joint_states"
            # the /**/aeropend_sim section matched the node in /rig2 and its values are in use
            assert msgs[0].header.frame_id == "rig_from_file"
            assert msgs[0].header.stamp.sec == 0 and msgs[0].header.stamp.nanosec == 0  # sample 0
            assert msgs[0].position[0] == pytest.approx(0.3, abs=1e-12)  # the initial angle, noise off
            got = _get(node, executor, "rig2/aeropend_sim", ["seed", "initial_theta", "frame_id", "noise"])
        assert got == {"seed": 11, "initial_theta": 0.3, "frame_id": "rig_from_file", "noise": False}
    finally:
        stop(proc, signal.SIGINT, timeout=15)
        reap(proc)
