"""Two simulated rigs side by side in different namespaces, each with its own controller.

Every node uses the contract topics relative to its namespace (``aeropend/joint_states``, ...),
so ``--ros-args -r __ns:=/rig1`` moves a rig's whole graph to ``/rig1/aeropend/*``. Each
controller's lock-step trace must be exactly the batch loop of its own plant and steps: a single
sample or command crossing between the rigs would change it.
"""

from __future__ import annotations

import csv
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")

from aeropend_control.controller_core import SIGNALS, ControllerLoop, make_settings
from aeropend_sim.contract import TOPIC_JOINT_STATES, namespaced
from aeropend_sim.params import load_rig
from aeropend_sim.ros.harness import isolated_env, node_command, private_node, random_domain, reap
from bench.fixtures.closed_loop import closed_loop

pytestmark = [pytest.mark.ros, pytest.mark.timeout(120)]

STEPS = {"/rig1": [0.0, 0.3], "/rig2": [0.0, 0.6]}


def test_namespaced_topic_names() -> None:
    assert namespaced(TOPIC_JOINT_STATES, "") == TOPIC_JOINT_STATES == "/aeropend/joint_states"
    assert namespaced(TOPIC_JOINT_STATES, "/rig2") == "/rig2/aeropend/joint_states"
    assert namespaced("aeropend/duty_cycle", "lab/rig2/") == "/lab/rig2/aeropend/duty_cycle"


def test_two_rigs_in_namespaces_each_with_its_controller(tmp_path: Path) -> None:
    domain = random_domain()
    env = isolated_env(domain)
    procs: list[subprocess.Popen] = []
    traces = {ns: tmp_path / f"{ns.strip('/')}.csv" for ns in STEPS}
    try:
        for ns, steps in STEPS.items():
            procs.append(subprocess.Popen(
                [*node_command("controller"), "--ros-args", "-r", f"__ns:={ns}", "-p", "mode:=lockstep",
                 "-p", "strategy:=fl_pid", "-p", f"steps:={steps}", "-p", "duration:=2.0",
                 "-p", f"trace:={traces[ns]}"],
                env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True))
            procs.append(subprocess.Popen(
                [*node_command("sim_node"), "--ros-args", "-r", f"__ns:={ns}", "-p", "mode:=lockstep",
                 "-p", "rig:=thesis_rig", "-p", "publish_clock:=false"],
                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        with private_node("test_graph", domain) as (node, ex):
            want = {namespaced(TOPIC_JOINT_STATES, ns) for ns in STEPS}
            deadline = time.monotonic() + 30.0
            names: set[str] = set()
            while not want <= names and time.monotonic() < deadline:
                ex.spin_once(timeout_sec=0.1)
                names = {n for n, _ in node.get_topic_names_and_types()}
            assert want <= names, sorted(names)
            assert TOPIC_JOINT_STATES not in names  # nothing left in the root namespace
        for ctl in procs[0::2]:
            out = ctl.communicate(timeout=90)[0]
            assert ctl.returncode == 0, out
    finally:
        reap(*procs)
    rig = load_rig("thesis_rig")
    for ns, steps in STEPS.items():
        data = np.array(list(csv.reader(traces[ns].open()))[1:], dtype=float)
        duty = data[:, SIGNALS.index("duty")]
        loop = ControllerLoop(make_settings(strategy="fl_pid", steps=steps, mode="lockstep"))
        assert loop.settings.rig == rig  # the plants ran thesis_rig
        ref = [d for _, d in closed_loop(loop, duty.size)]
        np.testing.assert_allclose(duty, ref, rtol=0, atol=1e-12, err_msg=ns)
        # each rig at its own set point
        assert abs(data[-1, SIGNALS.index("theta")] - steps[1]) < 0.05 * steps[1]
