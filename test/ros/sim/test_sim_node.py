"""Multi-process ROS 2 tests of the simulated plant node ``sim_node``.

The plant node runs in a subprocess; a subscriber / lock-step driver runs in the test process on
its own rclpy context. Each test uses a random ROS_DOMAIN_ID (1..100) and localhost-only
discovery so parallel runs do not cross-talk; subprocesses are killed in ``finally`` blocks.
"""

from __future__ import annotations

import math
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager

import numpy as np
import pytest

pytest.importorskip("rclpy")

from rcl_interfaces.msg import Log
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import BatteryState, JointState
from std_msgs.msg import Float64

from aeropend_sim.contract import (
    SAMPLE_RATE_HZ,
    TOPIC_ARMATURE,
    TOPIC_CLOCK,
    TOPIC_DUTY_CYCLE,
    TOPIC_JOINT_STATES,
    Sample,
)
from aeropend_sim.excitation import prbs
from aeropend_sim.params import load_rig, shipped_rigs
from aeropend_sim.ros.harness import (
    frozen_gc,
    isolate_process,
    isolated_env,
    node_command,
    private_node,
    random_domain,
    reap,
    stop,
    wait_for_server,
)
from aeropend_sim.ros.ros_contract import (
    CLOCK_QOS_LOCKSTEP,
    COMMAND_QOS,
    SAMPLE_QOS_LOCKSTEP,
    SAMPLE_SUB_QOS,
    sample_from_msgs,
)
from aeropend_sim.sim_core import to_sample
from aeropend_sim.simulation import PlantStepper

pytestmark = [pytest.mark.ros, pytest.mark.timeout(60)]

RIG = "thesis_rig" if "thesis_rig" in shipped_rigs() else "thesis_sim"
PERIOD_NS = 2_048_000
#: What rclpy publishes its log lines on /rosout with (reliable, transient local): earlier lines arrive too.
ROSOUT_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture
def domain(monkeypatch: pytest.MonkeyPatch) -> int:
    d = random_domain()
    isolate_process(monkeypatch, d)
    return d


@contextmanager
def plant(domain: int, *params: str) -> Iterator[subprocess.Popen]:
    """Run ``sim_node --ros-args -p ...`` in a subprocess; kill it on exit."""
    args = [*node_command("sim_node", "aeropend_sim.ros.sim_node"), "--ros-args", "-p", f"rig:={RIG}"]
    for p in params:
        args += ["-p", p]
    proc = subprocess.Popen(args, env=isolated_env(domain), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        yield proc
    finally:
        reap(proc)


class Client:
    """Subscriber of both sample topics (+ duty publisher) on a private rclpy context."""

    def __init__(self, domain: int, lockstep: bool) -> None:
        self._stack = ExitStack()
        self.node, self.executor = self._stack.enter_context(private_node("test_client", domain))
        qos = SAMPLE_QOS_LOCKSTEP if lockstep else SAMPLE_SUB_QOS
        self.js: list[tuple[int, int, JointState]] = []  # (stamp ns, arrival ns, msg)
        # stamp ns -> the middleware's source timestamp [ns, the plant's system clock at publication]
        self.sent: dict[int, int] = {}
        self.arm: dict[int, BatteryState] = {}
        self.node.create_subscription(JointState, TOPIC_JOINT_STATES, self._on_js, qos)
        self.node.create_subscription(BatteryState, TOPIC_ARMATURE, self._on_arm, qos)
        self.pub = self.node.create_publisher(Float64, TOPIC_DUTY_CYCLE, COMMAND_QOS)

    def _on_js(self, msg: JointState, info: dict) -> None:
        now = time.monotonic_ns()
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self.js.append((stamp, now, msg))
        self.sent[stamp] = int(info["source_timestamp"])

    def _on_arm(self, msg: BatteryState) -> None:
        self.arm[msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec] = msg

    def spin_until(self, cond: Callable[[], bool], timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if cond():
                return True
            self.executor.spin_once(timeout_sec=0.005)
        return cond()

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.005)

    def samples(self) -> dict[int, Sample]:
        """Samples by stamp (JointState + the BatteryState of the same stamp)."""
        return {st: sample_from_msgs(msg, self.arm[st]) for st, _, msg in self.js if st in self.arm}

    def close(self) -> None:
        self._stack.close()


@contextmanager
def client(domain: int, lockstep: bool) -> Iterator[Client]:
    c = Client(domain, lockstep)
    try:
        yield c
    finally:
        c.close()


# ------------------------------------------------------------------------------------- (a) realtime
def _production_rate(c: Client) -> tuple[float, float, str]:
    """The plant's production rate [Hz] over the samples ``c`` received, the rate its arrivals at
    this subscriber suggest [Hz], and a description of both for a failure message.

    Sample slots k covered by the stamps (stamps are start + k·T_s; an overrun re-anchors the plant's
    wall schedule, so lost wall time shows up here) per second of the plant's own publication times
    (the middleware's source timestamps). Not per second of arrival at this subscriber: the
    subscriber's callback time includes its own backlog, up to its queue's 0.2 s, and a subscriber
    behind at the last sample reads a plant on time as slow
    (``test_a_subscriber_behind_at_the_end_reads_the_plants_rate_from_its_publication_times``; one
    CI run of 2026-11-27 read 468 Hz from the arrivals)."""
    stamps = np.array([s for s, _, _ in c.js], dtype=np.int64)
    arrivals = np.array([a for _, a, _ in c.js], dtype=np.int64)
    sources = np.array([c.sent[s] for s in stamps], dtype=np.int64)
    slots = int((stamps[-1] - stamps[0]) // PERIOD_NS)
    span_source = (sources[-1] - sources[0]) * 1e-9
    span_arrival = (arrivals[-1] - arrivals[0]) * 1e-9
    lag_ms = (arrivals - stamps) * 1e-6 - float(np.median((arrivals - stamps) * 1e-6))
    text = (f"{slots} slots over {span_source:.3f} s of publication times ({slots / span_source:.1f} Hz) "
            f"and {span_arrival:.3f} s of arrivals here ({slots / span_arrival:.1f} Hz); first / last "
            f"arrival lag {lag_ms[0]:+.2f} / {lag_ms[-1]:+.2f} ms against the median")
    return slots / span_source, slots / span_arrival, text


# real time, with the machine to itself (run alone after the parallel suite, as test_bridge_node): the
# Python subscriber of this process takes 488 samples a second over best effort. Beside the parallel
# suite it lost samples (the fresh-clone CI of 909e8d6 received 94.1 % while the plant's own rate was
# on time). This test run beside busy processes (2026-12-01): alone 100 % in 4 of 4 runs; beside one
# to three CPU hogs 11 of 14 runs failed (89-94 %, or under 1500 samples). bench/repro/
# sim_node_subscriber_load.py measures the same subscriber beside 0-3 hogs.
@pytest.mark.exclusive
def test_realtime_rate_and_stamps(domain):
    # SCHED_FIFO for the sampler thread (falls back to normal scheduling with a warning where not
    # permitted): on a loaded 2-CPU machine normal scheduling loses 1-4 % of the wall-clock
    # samples to overruns (see bench/bench_sim_node.py), which this ±2 % check would catch.
    # the subscriber runs in the pytest process: its garbage collector must not stall it
    # (bench/repro/subscriber_heap.py; failed twice on fresh clones before, 1249 of ~1709 received)
    with plant(domain, "mode:=realtime", "rt_priority:=20") as proc, client(domain, lockstep=False) as c:
        assert c.spin_until(lambda: len(c.js) > 0, 20.0), "no sample within 20 s"
        with frozen_gc() as gc_pauses:
            c.spin_for(0.3)  # the freeze's own collection is over: samples queued meanwhile drained
            c.js.clear()
            c.arm.clear()
            c.spin_for(3.5)
        assert proc.poll() is None
        done = stop(proc, signal.SIGTERM)
    status, err = done.returncode, done.stderr
    stamps = np.array([s for s, _, _ in c.js], dtype=np.int64)
    assert stamps.size > 1500, f"{stamps.size} samples received; full GC pauses in the window: {gc_pauses}"
    span_stamp = (stamps[-1] - stamps[0]) * 1e-9
    assert span_stamp >= 3.0
    rate_plant, _, how = _production_rate(c)
    summary = [line for line in err.splitlines() if "summary: mode=realtime" in line]
    assert rate_plant == pytest.approx(SAMPLE_RATE_HZ, rel=0.02), f"plant rate: {how}; plant: {summary}"
    slots = (stamps[-1] - stamps[0]) // PERIOD_NS
    assert slots * PERIOD_NS * 1e-9 == pytest.approx(span_stamp)
    # delivery to a Python subscriber over best-effort QoS, with the machine to itself: at most 5 % lost
    received = (stamps.size - 1) / slots
    assert received >= 0.95, f"subscriber received only {received:.1%} of the samples"
    # stamps on the k·T_s grid, strictly increasing
    assert np.all(np.diff(stamps) > 0)
    assert np.all((stamps - stamps[0]) % PERIOD_NS == 0)
    # JointState and BatteryState of one sample carry the identical stamp
    matched = [s for s in stamps if s in c.arm]
    assert len(matched) >= 0.98 * stamps.size
    # a BatteryState whose JointState was lost on the way (best effort: the 5 % above) carries that
    # lost sample's stamp, on the grid. Fresh-clone CI of 1f6a0e9: 7 JointStates lost, their
    # BatteryStates received; an exact subset check failed on them. The window's edges are cut on
    # the two topics at one instant, while each subscription may still hold a different number of
    # samples: in the fresh-clone CI of 282892e a BatteryState two periods before the first JointState
    # kept arrived after the cut (its JointState before the cut, or lost): an edge is no window of one period.
    first = int(stamps[0])
    lone = sorted(set(c.arm) - set(stamps.tolist()))
    off = [s for s in lone if (s - first) % PERIOD_NS != 0]
    assert not off, f"BatteryState stamps of no sample: {off[:5]} (grid {first} + k·{PERIOD_NS} ns)"
    # clean shutdown on SIGTERM, summary logged
    assert status == 0, err
    assert "Traceback" not in err
    assert "summary: mode=realtime" in err


def test_a_subscriber_behind_at_the_end_reads_the_plants_rate_from_its_publication_times(domain):
    """A subscriber that is not scheduled for 150 ms just before its window ends takes its last
    samples from its queue, 150 ms old: their arrivals read the plant 4 % slow (what the rate check
    measured until 2026-11-27), their publication times read it on time."""
    with plant(domain, "mode:=realtime", "rt_priority:=20") as proc, client(domain, lockstep=False) as c:
        assert c.spin_until(lambda: len(c.js) > 0, 20.0), "no sample within 20 s"
        with frozen_gc():
            c.spin_for(0.3)
            c.js.clear()
            c.arm.clear()
            c.spin_for(3.2)
            time.sleep(0.15)  # the subscriber's process is not scheduled: 73 samples queue (depth 100)
            for _ in range(4):  # the oldest few of them, each taken at once
                c.executor.spin_once(timeout_sec=0.0)
        assert proc.poll() is None
        stop(proc, signal.SIGTERM)
    rate_plant, rate_arrivals, how = _production_rate(c)
    assert rate_plant == pytest.approx(SAMPLE_RATE_HZ, rel=0.02), how
    assert rate_arrivals < 0.975 * SAMPLE_RATE_HZ, how


# ------------------------------------------------------------------------------------- (b) lockstep
def _drive_lockstep(domain: int, commands: np.ndarray, seed: int,
                    before: dict[int, Callable[[Client], None]] | None = None) -> list[Sample]:
    """Start a fresh lock-step plant, ping-pong ``commands``; return samples 0..N by stamp.
    ``before[k]`` is called with the client before command k is sent."""
    with plant(domain, "mode:=lockstep", f"seed:={seed}", "noise:=true") as proc, \
            client(domain, lockstep=True) as c:
        got = c.samples
        assert c.spin_until(lambda: 0 in got(), 20.0), "sample 0 not received within 20 s"
        assert c.spin_until(lambda: c.pub.get_subscription_count() > 0, 10.0)
        for k, u in enumerate(commands):
            if before and k in before:
                before[k](c)
            c.pub.publish(Float64(data=float(u)))
            want = (k + 1) * PERIOD_NS
            assert c.spin_until(lambda w=want: w in got(), 10.0), f"sample {k + 1} not received"
        samples = got()
        assert proc.poll() is None
        done = stop(proc, signal.SIGINT)
        status, err = done.returncode, done.stderr
        assert status == 0 and "Traceback" not in err, err
    return [samples[k * PERIOD_NS] for k in range(len(commands) + 1)]


def _as_array(samples: list[Sample]) -> np.ndarray:
    return np.array([[s.stamp_ns, s.theta, s.theta_dot, s.omega_rotor, s.omega_prop, s.i_a, s.v_a, s.duty]
                     for s in samples], dtype=float)


def test_lockstep_is_deterministic_and_matches_stepper(domain):
    commands = prbs(5, lo=0.35, hi=0.65, clock=10, seed=2).duty[:300]
    first = _drive_lockstep(domain, commands, seed=7)
    second = _drive_lockstep(domain, commands, seed=7)
    a, b = _as_array(first), _as_array(second)
    assert a.tobytes() == b.tobytes()  # bit-identical, stamps included
    assert [s.stamp_ns for s in first] == [k * PERIOD_NS for k in range(301)]
    # duty on the wire = command of the interval that ended at the stamp
    assert first[0].duty == 0.0
    np.testing.assert_array_equal([s.duty for s in first[1:]], commands)
    # the node is exactly a PlantStepper with the same rig, seed and noise switches
    rig = load_rig(RIG).with_effects(sensor_noise=True, quantisation=True)
    stepper = PlantStepper(rig, seed=7)
    ref = [to_sample(0, stepper.sample(), 0.0)]
    ref += [to_sample((k + 1) * PERIOD_NS, stepper.step(u), u) for k, u in enumerate(commands)]
    expected = _as_array(ref)
    expected[:, 5:7] = expected[:, 5:7].astype(np.float32)  # BatteryState current/voltage are float32
    assert expected.tobytes() == a.tobytes()
    # noise is really on: the rod is at rest at sample 0, yet θ̇ reads non-zero
    assert first[0].theta_dot != 0.0
    # and the plant moved: the rod rose under 0.35-0.65 duty
    assert max(s.theta for s in first) > 0.01


def _set_parameters(c: Client, **values: object) -> list:
    """``ros2 param set`` from the test client: SetParameters on the plant node, answered."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    from aeropend_sim.ros.sim_node import NODE_NAME

    cli = c.node.create_client(SetParameters, f"/{NODE_NAME}/set_parameters")
    wait_for_server(cli, c.executor, SetParameters.Request(parameters=[]), 10.0)  # an empty set: no change
    fut = cli.call_async(SetParameters.Request(
        parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]))
    assert c.spin_until(fut.done, 10.0), f"set_parameters {values} not answered"
    c.node.destroy_client(cli)
    return fut.result().results


def test_live_effects_and_noise_continue_the_running_plant(domain):
    """Live parameters mid-run: switching the propeller drag and the noise off at sample 150 makes the
    plant continue from its state with the new rig (exactly a PlantStepper that switches rig
    there); a read-only parameter and an unknown effect are refused with a reason."""
    commands = prbs(5, lo=0.35, hi=0.65, clock=10, seed=4).duty[:300]
    answers: dict[str, list] = {}

    def change(c: Client) -> None:
        answers["seed"] = _set_parameters(c, seed=9)
        answers["bad"] = _set_parameters(c, effects=["warp_drive=true"])
        answers["ok"] = _set_parameters(c, effects=["propeller_drag=false"], noise=False)

    got = _drive_lockstep(domain, commands, seed=5, before={150: change})
    (seed,), (bad,), ok = answers["seed"], answers["bad"], answers["ok"]
    assert not seed.successful and "read-only" in seed.reason
    assert not bad.successful and "warp_drive" in bad.reason
    assert all(r.successful for r in ok), [r.reason for r in ok]

    def reference(switch: bool) -> np.ndarray:
        stepper = PlantStepper(load_rig(RIG).with_effects(sensor_noise=True, quantisation=True), seed=5)
        ref = [to_sample(0, stepper.sample(), 0.0)]
        for k, u in enumerate(commands):
            if k == 150 and switch:
                stepper.set_rig(load_rig(RIG).with_effects(propeller_drag=False, sensor_noise=False,
                                                           quantisation=False))
            ref.append(to_sample((k + 1) * PERIOD_NS, stepper.step(u), u))
        out = _as_array(ref)
        out[:, 5:7] = out[:, 5:7].astype(np.float32)
        return out

    a = _as_array(got)
    assert reference(switch=True).tobytes() == a.tobytes()
    unchanged = reference(switch=False)
    assert unchanged[:151].tobytes() == a[:151].tobytes()
    # without drag the rotor runs faster: ω₁ follows the new rig (not only the noise)
    assert np.mean(a[200:, 3] - unchanged[200:, 3]) > 1.0


def _no_sample_zero(c: Client, why: str) -> None:
    """Once the plant is up (its sample publisher discovered), 2 s pass without sample 0."""
    up = c.spin_until(lambda: c.node.count_publishers(TOPIC_JOINT_STATES) > 0, 60.0)
    assert up, "the plant never came up"
    c.spin_for(2.0)
    assert c.js == [], f"sample 0 published {why}"


def test_lockstep_sample_zero_waits_for_every_named_subscriber(domain):
    # a subscriber matched after sample 0 would miss the samples before it (volatile QoS): the
    # main job names both consumers (excitation, recorder) and the run starts only once both match
    # the 2 s with one subscriber start once the plant is up (its sample publisher discovered): on
    # a slow machine the node took over 2 s to start, the second subscriber was there before it
    # waited at all, and the log this test reads was never written
    with plant(domain, "mode:=lockstep", "min_subscribers:=2") as proc, \
            client(domain, lockstep=True) as first:
        _no_sample_zero(first, "with 1 of 2 subscribers matched")
        with client(domain, lockstep=True) as second:
            assert second.spin_until(lambda: any(s == 0 for s, _, _ in second.js), 20.0)
            assert first.spin_until(lambda: any(s == 0 for s, _, _ in first.js), 5.0)
        assert proc.poll() is None
        done = stop(proc, signal.SIGINT)
    assert done.returncode == 0
    assert "lock-step: waiting for subscriptions to match (joint_states " in done.stderr


def test_lockstep_sample_zero_waits_for_the_clock_readers_it_is_told_of(domain):
    # the main job's recorder creates its /clock reader after its sample readers, and the plant
    # waited only for /clock readers its graph already showed: one that matched the sample readers
    # first started the run without the /clock reader, whose bag then lacked the first ticks (the
    # one path found for test_main_job's /clock check failing on a loaded CI machine). Here the
    # /clock reader comes 2 s late: with min_clock_subscribers 1 sample 0 waits for it, and it gets
    # one tick per sample from sample 0 on (with 0, sample 0 goes out without it).
    with plant(domain, "mode:=lockstep", "min_clock_subscribers:=1") as proc, \
            client(domain, lockstep=True) as c:
        _no_sample_zero(c, "with no /clock reader matched")
        # the plant has looked and waits for the /clock reader (its log line on /rosout) before the
        # reader exists: under parallel test workers a plant starved of CPU first looked after the
        # reader had matched, started at once (rightly) and never wrote the line asserted below
        waits: list[str] = []
        c.node.create_subscription(Log, "/rosout", lambda m: waits.append(m.msg) if "/clock 0 of 1" in m.msg
                                   else None, ROSOUT_QOS)
        assert c.spin_until(lambda: bool(waits), 60.0), "the plant did not say that it waits for /clock"
        ticks: list[int] = []
        c.node.create_subscription(ClockMsg, TOPIC_CLOCK,
                                   lambda m: ticks.append(m.clock.sec * 1_000_000_000 + m.clock.nanosec),
                                   CLOCK_QOS_LOCKSTEP)
        assert c.spin_until(lambda: any(s == 0 for s, _, _ in c.js), 20.0), "sample 0 not received"
        assert c.spin_until(lambda: c.pub.get_subscription_count() > 0, 10.0)
        for k in range(20):
            c.pub.publish(Float64(data=0.4))
            assert c.spin_until(lambda w=(k + 1) * PERIOD_NS: w in ticks and any(s == w for s, _, _ in c.js),
                                10.0), f"sample {k + 1} or its tick not received"
        assert sorted(set(ticks)) == [k * PERIOD_NS for k in range(21)]
        done = stop(proc, signal.SIGINT)
    assert done.returncode == 0
    assert "/clock 0 of 1; min_subscribers 1, min_clock_subscribers 1" in done.stderr


# ------------------------------------------------------------------------------------- (c) bad commands
def test_nan_and_out_of_range_commands_are_rejected(domain):
    with plant(domain, "mode:=lockstep") as proc, client(domain, lockstep=True) as c:
        assert c.spin_until(lambda: any(s == 0 for s, _, _ in c.js), 20.0)
        assert c.spin_until(lambda: c.pub.get_subscription_count() > 0, 10.0)
        # rejection warnings are throttled to one per second: space the two bad commands
        c.pub.publish(Float64(data=math.nan))
        c.spin_for(1.1)
        c.pub.publish(Float64(data=1.5))
        c.spin_for(1.1)
        assert {s for s, _, _ in c.js} == {0}  # no sample advance in lock-step
        assert len(c.js) >= 3  # sample 0 re-published every 0.5 s while idle
        assert proc.poll() is None
        c.pub.publish(Float64(data=0.5))
        assert c.spin_until(lambda: PERIOD_NS in c.samples(), 10.0)
        assert c.samples()[PERIOD_NS].duty == 0.5
        assert proc.poll() is None
        done = stop(proc)
    status, err = done.returncode, done.stderr
    assert status == 0
    assert "rejected duty command nan" in err
    assert "rejected duty command 1.5" in err and "outside [0, 1]" in err
    assert "rejected=2" in err and "commands=1" in err and "samples=2" in err


# ------------------------------------------------------------------------------------- (d) bad parameters
@pytest.mark.parametrize(
    "param, needle",
    [
        ("rig:=nope", "'nope'"),
        ("mode:=fast", "'fast'"),
        ("effects:=[warp_drive=true]", "'warp_drive'"),
        ("initial_state:=[0.1,0.2]", "[0.1, 0.2]"),
        ("command_timeout:=-1.0", "command_timeout = -1"),
    ],
)
def test_bad_parameter_exits_nonzero_naming_value(domain, param, needle):
    with plant(domain, param) as proc:
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 2
    assert "invalid parameter" in err and needle in err, err
    assert "Traceback" not in err
