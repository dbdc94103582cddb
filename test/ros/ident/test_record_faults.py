"""Recording under faults (issue 62 items 1-2): ``record`` SIGKILLed at 20 points loses at most 1 s;
the loss ``record`` counts equals the loss found in the bag.

One publisher process sends ``joint_states`` at 50 Hz (stamped with the wall clock) on a private
ROS domain; 20 recorders run, at most :data:`AT_ONCE` at a time, and each is killed with SIGKILL at
its own time, 0.4 to 8 s after its first message reached the disk. A killed recorder leaves an
MCAP file without footer (and no ``metadata.yaml``); ``reindex`` rebuilds the metadata from it and
the recovered messages must reach within 1 s of the kill (the recorder flushes every 0.5 s by
default), with no gap inside. One more recorder uses SQLite3 storage (its transaction committed on
each flush).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.errors import BagError, BagLossWarning
from aeropend_ident.io.bag_reader import bag_metadata
from aeropend_ident.io.bag_recover import reindex, scan_storage
from aeropend_ident.io.bags import read_bag
from aeropend_ident.io.integrity.loss import LOSS_KEY
from aeropend_sim.ros.harness import isolated_env, node_command, random_domain, reap

pytest.importorskip("rclpy")
pytestmark = pytest.mark.ros

RECORD = node_command("record", "aeropend_ident.nodes.record")
#: SIGKILL times after each recorder's first flush [s]: 20 MCAP kill points, then one SQLite3.
KILL_AFTER = [0.4 + 0.4 * k for k in range(20)]
RATE_HZ = 50.0
PUBLISHER = """
import rclpy, sys, time
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
skip = int(sys.argv[1]) if len(sys.argv) > 1 else 0  # every 50 samples, this many not published
rclpy.init()
node = rclpy.create_node("fault_test_publisher")
pub = node.create_publisher(JointState, "/aeropend/joint_states", qos_profile_sensor_data)
k = [0]
t0 = node.get_clock().now().nanoseconds
def tick():
    k[0] += 1
    if k[0] % 50 < skip:
        return
    msg = JointState()
    stamp = t0 + k[0] * PERIOD_NS
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
    msg.name = ["pendulum", "motor", "propeller"]
    msg.position = [0.1, float("nan"), float("nan")]
    msg.velocity = [float("nan")] * 3
    msg.effort = [float("nan"), 0.3, float("nan")]
    pub.publish(msg)
node.create_timer(PERIOD_NS / 1e9, tick)
try:
    rclpy.spin(node)
except BaseException:
    pass
""".replace("PERIOD_NS", str(round(1e9 / RATE_HZ)))


def _storage(bag: Path) -> Path | None:
    files = [p for p in bag.glob("*") if p.suffix in (".mcap", ".db3")] if bag.is_dir() else []
    return files[0] if files else None


def _messages_on_disk(bag: Path) -> bool:
    """Whether the recorder's storage file holds a message yet. Not its size: SQLite3 writes its
    schema (28 kB) when the recorder opens the bag, before any message (on a loaded machine the
    publisher may not even be discovered 3 s later: the CI run at 359ee84 killed such a recorder
    with 0 messages on disk)."""
    f = _storage(bag)
    if f is None or f.stat().st_size == 0:
        return False
    try:
        return scan_storage(f, keep_messages=False).total > 0
    except BagError:  # a file being written: its first block not yet whole
        return False


#: Recorders running at once: 21 rclpy recorders and the publisher on 2 cores (beside the other tests
#: of a parallel run) starved one recorder of CPU for over a second before its kill (1.05 s lost at
#: load 7-10); at most this many run at once, each still killed at its own time, and a new one starts
#: as soon as one is killed (in rounds of 6, each waiting for its last kill, the test took 37 s).
#: Six at once were still too many for 2 cores: in the fresh-clone CI of 0ed7fa8, run alone, a
#: recorder killed 1.2 s into its run had flushed 0.20 s (1.02 s lost) while the recorders started
#: beside it loaded Python and rclpy (about 1 s of CPU each), the same loss as 338c05d's beside the
#: suite. Three at once leave a core for the publisher and the recorders that are recording.
AT_ONCE = 3


def _kill_each(env: dict[str, str], bags: list[Path], storages: list[str], kill_after: list[float]
               ) -> list[int]:
    """Run one recorder per bag, at most :data:`AT_ONCE` at a time (the latest kills started first, so
    that no long run is left alone at the end), and SIGKILL each ``kill_after[k]`` s after its first
    flush reached the disk; returns the kill times [ns since the epoch]."""
    waiting = sorted(range(len(bags)), key=lambda k: -kill_after[k])
    running: dict[int, subprocess.Popen] = {}
    killed_ns: dict[int, int] = {}
    first_seen: dict[int, float] = {}
    try:
        deadline = time.monotonic() + 180
        while len(killed_ns) < len(bags) and time.monotonic() < deadline:
            while waiting and len(running) < AT_ONCE:
                k = waiting.pop(0)
                running[k] = subprocess.Popen([*RECORD, "-o", str(bags[k]), "-s", storages[k]], env=env,
                                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            now = time.monotonic()
            for k, proc in list(running.items()):
                if k not in first_seen:
                    if _messages_on_disk(bags[k]):  # the first flush reached the disk
                        first_seen[k] = now
                elif now - first_seen[k] >= kill_after[k]:
                    assert proc.poll() is None, f"recorder {k} ended by itself"
                    killed_ns[k] = time.time_ns()
                    os.kill(proc.pid, signal.SIGKILL)
                    proc.wait()
                    del running[k]
            time.sleep(0.01)
        assert len(killed_ns) == len(bags), \
            f"only {len(killed_ns)} of {len(bags)} recorders started recording"
    finally:
        reap(*running.values())
    return [killed_ns[k] for k in range(len(bags))]


@pytest.mark.exclusive  # real time: beside the parallel suite (clean-clone CI of 338c05d) a starved
# recorder had flushed 0.21 s of a 1.24 s run when killed; the bar is the recorder's, not the host's
def test_sigkill_at_20_points_loses_at_most_one_second(tmp_path: Path) -> None:
    env = isolated_env(random_domain())
    pub = subprocess.Popen([sys.executable, "-c", PUBLISHER], env=env, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    bags = [tmp_path / f"run{k}" for k in range(len(KILL_AFTER) + 1)]
    storages = ["mcap"] * len(KILL_AFTER) + ["sqlite3"]
    kill_after = [*KILL_AFTER, 3.0]
    try:
        killed_ns = _kill_each(env, bags, storages, kill_after)
    finally:
        reap(pub)
    losses = []
    for k, bag in enumerate(bags):
        assert not (bag / "metadata.yaml").exists()  # killed: never closed
        info = reindex(bag)[1]
        scan = scan_storage(_storage(bag))  # type: ignore[arg-type]
        logs = np.array([m[1] for m in scan.messages], dtype=np.int64)
        # a kill 0.4 s after the first flush (flush interval 0.5 s) may find only that flush's messages
        # on disk (on a loaded machine one): the bar is the recovered duration, checked below
        assert info["message_count"] == len(logs) >= 1, (k, storages[k], len(logs))
        recorded_s = (killed_ns[k] - logs[0]) / 1e9  # from its first message to the kill
        recovered_s = (logs[-1] - logs[0]) / 1e9
        losses.append(recorded_s - recovered_s)
        assert recovered_s >= recorded_s - 1.0, (k, storages[k], recorded_s, recovered_s)
        # nothing inside was left out: a killed recorder's file is only cut at its end (a gap in the log
        # times can be the publisher stalled on a loaded machine; a dropped part would be listed here)
        assert not scan.skipped, (k, storages[k], scan.skipped)
        assert info["duration"]["nanoseconds"] == logs[-1] - logs[0]
    print("losses [s]:", " ".join(f"{x:.2f}" for x in losses))
    assert max(losses) <= 1.0 and min(losses) >= 0.0, losses


def test_loss_counted_by_record_equals_the_loss_in_the_bag(tmp_path: Path) -> None:
    """A publisher that skips 5 of every 50 samples (10 %, as a plant that overruns): ``record`` prints
    and stores the loss; it equals the samples missing between the bag's stamps; readers warn."""
    env = isolated_env(random_domain())
    bag = tmp_path / "lossy"
    pub = subprocess.Popen([sys.executable, "-c", PUBLISHER, "5"], env=env, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    rec = subprocess.Popen([*RECORD, "-o", str(bag), "--max-samples", "400"], env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out, _ = rec.communicate(timeout=60)
    finally:
        reap(rec, pub)
    assert rec.returncode == 0, out
    stored = json.loads(bag_metadata(bag)["custom_data"][LOSS_KEY])["/aeropend/joint_states"]
    with pytest.warns(BagLossWarning, match=r"/aeropend/joint_states lost \d+ of \d+ \(\d+\.\d %, counted by "
                                            r"stamps\) in \d+ gap\(s\) at "):
        got = read_bag(bag)
    stamps = np.round(got.t / 0.02).astype(int)  # sample numbers from the first received
    missing = int(np.sum(np.diff(stamps) - 1))
    assert stored["received"] == len(got) == 400 and stored["lost"] == missing
    assert 35 <= missing <= 45 and stored["method"] == "stamps"
    assert stored["gaps"] == np.sum(np.diff(stamps) > 1)
    assert f"record: loss: /aeropend/joint_states {missing} of {400 + missing} lost" in out
    played = subprocess.run([*node_command("play", "aeropend_ident.nodes.play"), str(bag), "--rate", "20"],
                            env=env, capture_output=True, text=True, timeout=60)
    assert played.returncode == 0, played.stderr
    assert (f"play: warning: bag '{bag}': message loss above 1 %: /aeropend/joint_states lost {missing} of "
            f"{400 + missing}") in played.stderr
