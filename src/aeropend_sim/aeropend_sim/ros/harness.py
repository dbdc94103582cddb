"""Run ROS 2 nodes as processes on a private domain and read what they report (no rclpy at import).

The process harness of aeropend's multi-process tests, its benchmarks and the main job
(:mod:`aeropend_ident.pipeline`), and of a lab's own integration tests of its node graph: a
private ROS domain with localhost-only discovery (claimed, so concurrent runs on one host never
share it: :mod:`aeropend_sim.ros.domain`), the command line of a node's console script, stopping a
node with a signal and collecting its output, killing whatever is still running in a ``finally``
block, parsing a node's shutdown ``summary: key=value ...`` line, an rclpy node on its own context
in the calling process, and waiting until a service answers both ways.

rclpy is imported only inside :func:`private_node`, so a process without ROS can import this
module (the main job's analysis half, tests that skip without rclpy). Example::

    from aeropend_sim.ros.harness import isolated_env, node_command, random_domain, stop, summary_fields

    env = isolated_env(random_domain())
    plant = subprocess.Popen([*node_command("sim_node"), "--ros-args", "-p", "rig:=thesis_rig"],
                             env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ...
    done = stop(plant)                     # SIGTERM, wait, collect the output
    summary_fields(done.stdout)["samples"]  # e.g. "2448"
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from aeropend_sim.ros.domain import DomainClaim, DomainError, claim_domain

if TYPE_CHECKING:
    from rclpy.client import Client
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

class SetEnv(Protocol):
    """Anything that sets an environment variable (pytest's ``monkeypatch``)."""

    def setenv(self, name: str, value: str) -> None: ...


#: Folder of the running interpreter: the venv's ``bin`` holding the console scripts.
BIN = Path(sys.executable).parent
#: Localhost-only discovery: parallel runs on other domains and other hosts do not interfere.
DISCOVERY = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}

#: Domain claims of this process (released by the kernel when it exits).
_CLAIMS: list[DomainClaim] = []
_SUMMARY_LINE = re.compile(r"summary: (.*)")
_SUMMARY_FIELD = re.compile(r"(\w+)=([\w.]+)")


def random_domain(first: int = 1, last: int = 100) -> int:
    """A ROS_DOMAIN_ID in ``first..last`` claimed for the rest of this process.

    The ID is drawn from the OS entropy source among the IDs no other aeropend process on this
    host holds (:func:`aeropend_sim.ros.domain.claim_domain`: a lock file per ID), so a test and a
    benchmark running at the same time never share a domain (two random draws did once and saw
    each other's commands). The claim is kept until this process exits.

    Parameters
    ----------
    first, last : int
        Inclusive bounds, 0 <= first <= last <= 232 (the valid DDS domain IDs).

    Returns
    -------
    int
        The domain ID.

    Raises
    ------
    ValueError
        If the bounds are outside 0..232, ``first > last`` or every ID in the range is claimed.
    """
    try:
        claim = claim_domain(first, last)
    except DomainError as exc:
        raise ValueError(str(exc)) from exc
    _CLAIMS.append(claim)
    return claim.domain_id


def claimed_domains() -> int:
    """How many domain IDs :func:`random_domain` has claimed in this process and still holds."""
    return len(_CLAIMS)


def release_domains(keep: int = 0) -> None:
    """Give back the domain IDs :func:`random_domain` claimed after the first ``keep`` ones.

    For a long-lived process that runs one graph after another (a pytest worker): without it every
    claim is held until the process exits, and several test runs and benchmarks on one host
    (parallel workers, other checkouts) fill a range between them. Call it only once the nodes on
    those domains have been stopped. ``test/conftest.py`` releases each test's claims after it.

    Parameters
    ----------
    keep : int
        Claims to keep (the oldest), e.g. :func:`claimed_domains` before the test started.
    """
    while len(_CLAIMS) > keep:
        _CLAIMS.pop().release()


def isolated_env(domain: int) -> dict[str, str]:
    """Environment for a node subprocess: this process's environment on a private ROS domain.

    Parameters
    ----------
    domain : int
        ROS_DOMAIN_ID, e.g. from :func:`random_domain`.

    Returns
    -------
    dict[str, str]
        ``os.environ`` plus ``ROS_DOMAIN_ID=<domain>``, localhost-only discovery and
        ``PYTHONUNBUFFERED=1`` (log lines reach a pipe as they are written).
    """
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED="1", **DISCOVERY)


def isolate_process(monkeypatch: SetEnv, domain: int) -> None:
    """Put the calling process itself (and children started with ``os.environ``) on ``domain``.

    Parameters
    ----------
    monkeypatch : object with ``setenv(name, value)``
        Where the variables are set: pytest's ``monkeypatch`` fixture, so both are undone after
        the test.
    domain : int
        ROS_DOMAIN_ID, e.g. from :func:`random_domain`.
    """
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    for key, value in DISCOVERY.items():
        monkeypatch.setenv(key, value)


def node_command(name: str, module: str | None = None) -> list[str]:
    """Command line that starts the console script ``name``.

    Looked up next to the running interpreter first (the venv's ``bin``, where
    ``scripts/setup_env.sh`` installs the packages), then as ``python -m module`` when ``module``
    is given, then on ``PATH`` (a sourced colcon ``install/setup.bash``).

    Parameters
    ----------
    name : str
        Console script (``sim_node``, ``controller``, ``bridge``, ``excitation``, ``record``, ...).
    module : str, optional
        Module to run with ``python -m`` when the script is not installed next to
        ``sys.executable``.

    Returns
    -------
    list[str]
        ``[<bin>/name]``, ``[sys.executable, "-m", module]`` or ``[<PATH entry>/name]``.

    Raises
    ------
    FileNotFoundError
        If the script is found nowhere and no ``module`` is given.
    """
    exe = shutil.which(name, path=str(BIN))
    if exe is not None:
        return [exe]
    if module is not None:
        return [sys.executable, "-m", module]
    exe = shutil.which(name)
    if exe is not None:
        return [exe]
    raise FileNotFoundError(f"console script {name!r} is neither in {BIN} nor on PATH: run "
                            "scripts/setup_env.sh or source install/setup.bash")


def stop(proc: subprocess.Popen, sig: int = signal.SIGTERM, timeout: float = 10.0, *,
         kill_on_timeout: bool = False) -> subprocess.CompletedProcess:
    """Send ``sig`` to a running process, wait for it to exit and collect its output.

    Parameters
    ----------
    proc : subprocess.Popen
        The process; if it has already exited only its remaining output is collected.
    sig : int
        Signal to send (``signal.SIGTERM``, ``signal.SIGINT``).
    timeout : float
        Seconds to wait for the exit after the signal.
    kill_on_timeout : bool
        What happens when the process is still running after ``timeout``: it is always killed
        and reaped; then ``False`` re-raises the timeout (a node that does not stop is a
        failure), ``True`` returns what it wrote (clean-up of a helper process).

    Returns
    -------
    subprocess.CompletedProcess
        ``returncode`` and the ``stdout`` / ``stderr`` text (``None`` for streams not piped).

    Raises
    ------
    subprocess.TimeoutExpired
        If the process outlived ``timeout`` and ``kill_on_timeout`` is False.
    """
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate(timeout=10)
        if not kill_on_timeout:
            raise
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def reap(*procs: subprocess.Popen | None, timeout: float = 10.0) -> None:
    """Kill every process still running, then collect each one's output (for ``finally`` blocks).

    Collecting also closes the pipes of a process that exited by itself; for one whose output
    was already collected it returns at once.

    Parameters
    ----------
    *procs : subprocess.Popen or None
        Processes in the order to reap them; ``None`` (never started) is skipped.
    timeout : float
        Seconds to wait for each process to be reaped.
    """
    for proc in procs:
        if proc is None:
            continue
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=timeout)


def summary_line(text: str) -> str | None:
    """The last ``summary: ...`` line a node logged, without the ``summary: `` prefix.

    Parameters
    ----------
    text : str
        The node's captured stdout/stderr.

    Returns
    -------
    str or None
        The rest of the line, or ``None`` if the node logged no summary.
    """
    lines = _SUMMARY_LINE.findall(text)
    return lines[-1] if lines else None


def summary_fields(text: str) -> dict[str, str]:
    """``key=value`` pairs of a node's last summary line (``sim_node``, ``bridge``, ``controller``).

    Parameters
    ----------
    text : str
        Captured output, as for :func:`summary_line`.

    Returns
    -------
    dict[str, str]
        Field name -> value text (``"29299"``, ``"0.447"``, ``"realtime"``); empty if the node
        logged no summary.
    """
    line = summary_line(text)
    return dict(_SUMMARY_FIELD.findall(line)) if line is not None else {}


def summary_count(text: str, key: str) -> int:
    """Integer field ``key`` of a node's last summary line (e.g. ``commands``, ``samples``).

    Raises
    ------
    ValueError
        If there is no summary line or it has no integer ``key=`` field (message shows the
        end of ``text``).
    """
    value = summary_fields(text).get(key)
    if value is None or not value.isdigit():
        raise ValueError(f"no integer '{key}=' in the summary line of:\n{text[-2000:]}")
    return int(value)


@contextmanager
def private_node(name: str, domain: int) -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    """An rclpy node with a single-threaded executor on its own context and ``domain``.

    The context is independent of the global one, so several tests (or the same test twice)
    can create and shut down nodes without interfering. On exit the executor is shut down, the
    node destroyed and the context shut down.

    Parameters
    ----------
    name : str
        Node name.
    domain : int
        ROS_DOMAIN_ID of the context.

    Yields
    ------
    (rclpy.node.Node, rclpy.executors.SingleThreadedExecutor)
        The node, already added to the executor.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    try:
        node = rclpy.create_node(name, context=ctx)
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        try:
            yield node, executor
        finally:
            executor.shutdown()
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


@contextmanager
def gc_pauses() -> Iterator[list[float]]:
    """Record the durations [s] of the generation-2 garbage collections run inside the block."""
    import gc

    pauses: list[float] = []
    start = [0.0]

    def watch(phase: str, info: dict) -> None:
        if info.get("generation") == 2:
            if phase == "start":
                start[0] = time.perf_counter()
            else:
                pauses.append(time.perf_counter() - start[0])

    gc.callbacks.append(watch)
    try:
        yield pauses
    finally:
        gc.callbacks.remove(watch)


@contextmanager
def frozen_gc() -> Iterator[list[float]]:
    """Keep this process' cyclic garbage collector from pausing a real-time subscriber.

    Late in a full test run the pytest process holds millions of objects; a generation-2
    collection scans them all for hundreds of milliseconds, during which an in-process subscriber
    takes no samples and its best-effort queue overflows (``bench/repro/subscriber_heap.py``:
    543-653 ms and 10-12 % of the samples lost with 8 million objects). ``gc.freeze()`` moves the
    existing heap to the permanent generation, as ``sim_node`` and the controller do for their
    real-time threads; the collector still runs on new objects.

    Yields
    ------
    list of float
        Durations [s] of the generation-2 collections that ran inside the block (for messages).
    """
    import gc

    gc.collect()
    gc.freeze()
    try:
        with gc_pauses() as pauses:
            yield pauses
    finally:
        gc.unfreeze()


def wait_for_server(client: Client, executor: SingleThreadedExecutor, probe: object, timeout: float = 20.0,
                    resend_s: float = 0.5) -> int:
    """Wait until ``client``'s service is available **both ways**; returns the probe responses lost.

    ``wait_for_service`` in rmw_fastrtps checks only the client's half of the match (the client
    has discovered the server's request reader and response writer). When the server has not yet
    discovered the client's response reader, its ``rmw_send_response`` waits 100 ms for it and
    then drops the response ("failed to send response ... client will not receive response",
    ros2/rmw_fastrtps#390/#467): the first request after a client's creation can go unanswered
    on a loaded machine (``bench/repro/param_service.py``: 1 in 150 under load). So after
    ``wait_for_service`` an **idempotent, state-free** ``probe`` request (an empty
    ``GetParameters`` / ``SetParameters``, a ``GetState``) is sent until one is answered — each
    probe answered or re-sent after ``resend_s`` — which proves the server has matched this
    client's response reader. The request under test is then sent once and never repeated.

    Parameters
    ----------
    client : rclpy.client.Client
    executor : rclpy.executors.SingleThreadedExecutor
        Spins the client's node.
    probe : request message
        A request the service answers without changing anything.
    timeout : float
        Total time for the service and a probe answer [s].
    resend_s : float
        Time after which an unanswered probe is sent again [s].

    Returns
    -------
    int
        Probes whose response was lost before one was answered (0 on an unloaded machine).

    Raises
    ------
    TimeoutError
        If the service is not available or no probe is answered within ``timeout``.
    """
    end = time.monotonic() + timeout
    if not client.wait_for_service(timeout_sec=timeout):
        raise TimeoutError(f"no service {client.srv_name} within {timeout} s")
    lost = 0
    while time.monotonic() < end:
        future = client.call_async(probe)
        until = min(time.monotonic() + resend_s, end)
        while not future.done() and time.monotonic() < until:
            executor.spin_once(timeout_sec=0.01)
        if future.done():
            return lost
        client.remove_pending_request(future)
        lost += 1
    raise TimeoutError(f"{client.srv_name}: no probe answered within {timeout} s ({lost} lost)")


#: Share of the machine's CPU time that the hypervisor gave to other guests ("steal" in
#: ``/proc/stat``) during a real-time test above which a failure of that test says nothing about
#: aeropend: its loop lost the CPU to the host, not to anything the test runs (docs/testing.md).
STEAL_LIMIT = 0.02


def _cpu_ticks(stat_text: str | None = None) -> list[int] | None:
    """The first ticks (up to 8: user, nice, system, idle, iowait, irq, softirq, steal) of all CPUs from
    ``/proc/stat``'s ``cpu`` line (``stat_text``: the file's text; default: read it); None where the
    file or the line cannot be read."""
    if stat_text is None:
        try:
            with open("/proc/stat", encoding="ascii") as f:
                stat_text = f.readline()
        except OSError:
            return None
    fields = stat_text.split("\n", 1)[0].split()
    if not fields or fields[0] != "cpu":
        return None
    try:
        return [int(v) for v in fields[1:9]]
    except ValueError:
        return None


def cpu_times(stat_text: str | None = None) -> tuple[int, int] | None:
    """CPU steal and total time of all CPUs, in clock ticks, from ``/proc/stat``.

    Parameters
    ----------
    stat_text : str, optional
        The file's text (default: read ``/proc/stat``).

    Returns
    -------
    (steal, total) : tuple of int, or None
        None where there is no such file or its ``cpu`` line lacks the steal field (Linux < 2.6.11,
        other systems). ``total`` sums user, nice, system, idle, iowait, irq, softirq and steal (guest
        time is already counted in user and nice).
    """
    ticks = _cpu_ticks(stat_text)
    if ticks is None or len(ticks) < 8:
        return None
    return ticks[7], sum(ticks)


#: Busy share of all CPUs [0, 1] under which the machine counts as idle (:func:`wait_until_idle`).
IDLE_LIMIT = 0.15


def busy_share(window: float = 0.25, stat: Callable[[], str] | None = None) -> float | None:
    """Share [0, 1] of all CPUs' time over ``window`` seconds that was not idle (user, system, irq,
    steal ...; idle and iowait are idle), from two readings of ``/proc/stat``'s ``cpu`` line; None
    where it cannot be read. ``stat`` returns the line (default: the file's)."""
    def ticks() -> tuple[int, int] | None:
        values = _cpu_ticks(stat() if stat is not None else None)
        if values is None or len(values) < 5:
            return None
        return sum(values) - values[3] - values[4], sum(values)

    before = ticks()
    time.sleep(window)
    after = ticks()
    if before is None or after is None or after[1] <= before[1]:
        return None
    return (after[0] - before[0]) / (after[1] - before[1])


def wait_until_idle(limit: float = IDLE_LIMIT, timeout: float = 20.0, window: float = 0.25) -> float:
    """Wait until the CPUs were busy less than ``limit`` over one ``window`` (processes of an earlier
    part of a run still exiting, writing back or shutting a cluster down), at most ``timeout`` s.

    Returns
    -------
    float
        Seconds waited (about ``window`` when the machine was idle at once; ``timeout`` or more when
        it never was, or /proc/stat cannot be read: the caller goes on either way).
    """
    start = time.monotonic()
    while True:
        share = busy_share(window)
        if share is None or share < limit or time.monotonic() - start >= timeout:
            return time.monotonic() - start


def steal_share(before: tuple[int, int] | None, after: tuple[int, int] | None) -> float | None:
    """Share [0, 1] of the CPU time between two :func:`cpu_times` readings that was stolen (None when
    either reading is missing or no time passed)."""
    if before is None or after is None or after[1] <= before[1]:
        return None
    return (after[0] - before[0]) / (after[1] - before[1])
