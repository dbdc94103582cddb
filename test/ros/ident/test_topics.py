"""``topics list`` / ``topics echo`` against a running ``sim_node`` in another process (issue 34).

The plant runs in lock-step without a controller: once a subscriber is matched it publishes
sample 0 (stamp 0, θ = 0 at rest) and re-publishes it every 0.5 s of wall time while no command
comes (checked every 0.1 s, so every 0.5-0.6 s), so the topics, types, rates and message values
are known exactly, whatever the machine's load. Each test uses its own ROS domain.
"""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from aeropend_sim.ros.harness import isolated_env, node_command, random_domain, reap, stop

pytest.importorskip("rclpy")

pytestmark = [pytest.mark.ros, pytest.mark.timeout(120)]

TOPICS = node_command("topics", "aeropend_ident.nodes.topics")


def _sim(env: dict[str, str], *ros_args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([*node_command("sim_node"), "--ros-args", "-p", "mode:=lockstep", *ros_args],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True)


def _topics(env: dict[str, str], *args: str, timeout: float = 30) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*TOPICS, *args], env=env, capture_output=True, text=True, timeout=timeout)


def _table(text: str) -> dict[str, list[str]]:
    """``topics list`` output: topic -> its columns (type, rate..., pub, sub)."""
    lines = text.strip().splitlines()
    assert lines[0].split()[:2] == ["topic", "type"], text
    return {line.split()[0]: line.split()[1:] for line in lines[1:]}


def test_list_and_echo_a_running_plant(tmp_path: Path) -> None:
    domain = random_domain()
    env = isolated_env(domain)
    sim = _sim(env)
    try:
        # echo -n 2: two YAML documents, each followed by '---': the re-published sample 0
        # (echo waits up to --timeout for the topic: the plant may still be starting)
        done = _topics(env, "echo", "/aeropend/joint_states", "-n", "2", "--timeout", "30")
        assert done.returncode == 0, done.stderr
        assert done.stdout.count("---\n") == 2
        docs = [d for d in yaml.safe_load_all(done.stdout) if d is not None]
        assert len(docs) == 2
        for doc in docs:
            assert doc["header"] == {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": "aeropend"}
            assert doc["name"] == ["pendulum", "motor", "propeller"]
            assert doc["position"][0] == 0.0 and doc["velocity"][0] == 0.0

        # list: the plant's topics with their types, measured rates and endpoints
        done = _topics(env, "list", "--spin-time", "2", "--window", "4")
        assert done.returncode == 0, done.stderr
        table = _table(done.stdout)
        assert table["/aeropend/joint_states"][0] == "sensor_msgs/msg/JointState"
        assert table["/aeropend/armature"][0] == "sensor_msgs/msg/BatteryState"
        assert table["/clock"][0] == "rosgraph_msgs/msg/Clock"
        assert table["/aeropend/duty_cycle"] == ["std_msgs/msg/Float64", "no", "messages", "0", "1"]
        rate, unit, pub, sub = table["/aeropend/joint_states"][1:]
        # re-published every 0.5-0.6 s: 1.67-2 Hz (the window's first interval may start mid-way)
        assert unit == "Hz" and 1.5 <= float(rate) <= 2.1, done.stdout
        assert (pub, sub) == ("1", "0")  # this command's own subscription is not counted
        assert abs(float(table["/clock"][1]) - float(rate)) < 0.3  # one tick per (re-)published sample

        # an unknown topic: one line on stderr after the discovery wait, exit status 1 (which topics
        # the line lists depends on how far discovery got in the wait: not asserted)
        t0 = time.monotonic()
        done = _topics(env, "echo", "/aeropend/nope", "--timeout", "2")
        assert done.returncode == 1 and done.stdout == ""
        assert done.stderr.startswith("topics: error: topic /aeropend/nope not found after 2 s on "
                                      f"ROS_DOMAIN_ID {domain} (topics seen: ")
        assert done.stderr.endswith("; check the name, the namespace (-N) and ROS_DOMAIN_ID\n")
        assert done.stderr.count("\n") == 1 and time.monotonic() - t0 < 20

        # Ctrl-C while echoing: exit status 0, what was printed is whole documents
        echo = subprocess.Popen([*TOPICS, "echo", "/clock"], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        try:
            assert echo.stdout is not None
            first = [echo.stdout.readline() for _ in range(4)]  # clock: / sec: / nanosec: / ---
            assert first == ["clock:\n", "  sec: 0\n", "  nanosec: 0\n", "---\n"], first
            done = stop(echo, signal.SIGINT, timeout=10)
        finally:
            reap(echo)
        assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr

        # another ROS_DOMAIN_ID is another graph: the plant is not there
        other = random_domain()
        done = _topics(isolated_env(other), "list", "--window", "0")
        assert done.returncode == 0 and done.stdout == f"no topics on ROS_DOMAIN_ID {other} after 1 s\n"
    finally:
        reap(sim)


def test_namespaced_plant(tmp_path: Path) -> None:
    env = isolated_env(random_domain())
    sim = _sim(env, "-r", "__ns:=/rig2", "-p", "publish_clock:=false")
    try:
        # a relative topic name is resolved in the namespace: -N or the standard ROS remapping
        for ns_args in (["-N", "/rig2"], ["--ros-args", "-r", "__ns:=/rig2"]):
            done = _topics(env, "echo", "aeropend/joint_states", "--once", "--timeout", "30", *ns_args)
            assert done.returncode == 0, done.stderr
            doc = yaml.safe_load(done.stdout.split("---\n")[0])
            assert doc["name"] == ["pendulum", "motor", "propeller"]
        done = _topics(env, "list", "-N", "/rig2", "--spin-time", "4", "--window", "0")
        assert done.returncode == 0, done.stderr
        table = _table(done.stdout)
        assert set(table) == {f"/rig2/aeropend/{t}" for t in ("joint_states", "armature", "duty_cycle")}
        # no rate column with --window 0
        assert table["/rig2/aeropend/joint_states"] == ["sensor_msgs/msg/JointState", "1", "0"]
        done = _topics(env, "echo", "aeropend/joint_states", "--timeout", "1")  # root: not there
        assert done.returncode == 1 and "topic /aeropend/joint_states not found" in done.stderr
    finally:
        reap(sim)
