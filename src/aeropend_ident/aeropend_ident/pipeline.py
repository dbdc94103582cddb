"""The main job: run the node graph on the simulated plant, record a bag, identify and report.

Steps (each node is a separate process, exactly as a lab would run them):

1. ``record`` (rosbags recorder), ``sim_node`` (simulated plant, lock-step or real time) and
   ``excitation`` (thesis §5.1 Latin-hypercube duty-cycle steps by default) on a private
   ``ROS_DOMAIN_ID`` (claimed in 100..200 unless set; :mod:`aeropend_sim.ros.domain`) with
   localhost-only discovery unless ``ROS_AUTOMATIC_DISCOVERY_RANGE`` is set;
2. when the excitation has sent its last command, the recorder and the plant are stopped with
   SIGINT (clean shutdown, valid bag);
3. the bag is read back (``aeropend_ident.io.bags.read_bag``) and the grey-box baseline
   (``aeropend_ident.greybox.baseline``) fits the nominal simulator's pendulum + actuator parameters on
   the first part and replays the held-out part: ``report.json`` and ``overlay.png``;
4. a one-screen summary is printed and ``summary.json`` written.

Usage::

    pipeline --out reports/main                         # thesis_rig plant, thesis_sim as simulator
    pipeline --out reports/rt --mode realtime --plant-rig thesis_rig --nominal-rig thesis_rig
"""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aeropend_ident.errors import BagError, PipelineError
from aeropend_ident.io.bag_reader import RawBagReader
from aeropend_ident.io.bag_writer import claim_bag_folder
from aeropend_ident.io.bags import read_bag
from aeropend_sim.contract import TOPIC_CLOCK, TOPIC_DUTY_CYCLE, TOPIC_JOINT_STATES, namespaced
from aeropend_sim.output_folder import OutputFolderError
from aeropend_sim.ros.domain import claim_domain
from aeropend_sim.ros.harness import DISCOVERY, node_command, stop, summary_fields

#: What the main job writes into its report folder: the bag, the node logs, the grey-box baseline
#: report and the summary (``pipeline --overwrite`` replaces only a folder that holds one of them).
OUTPUTS = {"bag": "run_bag", "logs": "logs", "baseline": "baseline", "summary": "summary.json"}

#: Default excitation: thesis §5.1 Latin-hypercube steps (10 steps, τ ∈ [0.3, 0.8], 1-3 s each).
DEFAULT_SIGNAL = ["signal:=lhs", "n:=10", "tau_min:=0.3", "tau_max:=0.8", "hold_min:=1.0",
                  "hold_max:=3.0"]


@dataclass
class Stage:
    """A node process of the graph and its log file."""

    name: str
    cmd: list[str]
    log: Path
    proc: subprocess.Popen | None = None
    started: float = field(default_factory=time.monotonic)

    def start(self, env: dict[str, str]) -> None:
        self.log.parent.mkdir(parents=True, exist_ok=True)
        fh = self.log.open("w")
        self.proc = subprocess.Popen(self.cmd, stdout=fh, stderr=subprocess.STDOUT, env=env,
                                     start_new_session=True)
        fh.close()

    def stop(self, timeout: float = 15.0) -> int:
        """SIGINT (the node's clean shutdown), SIGKILL if it has not exited within ``timeout``
        seconds; returns the exit status."""
        if self.proc is None:
            return 0
        return int(stop(self.proc, signal.SIGINT, timeout, kill_on_timeout=True).returncode)


def _exe(name: str) -> list[str]:
    """Console script of the current environment (:func:`aeropend_sim.ros.harness.node_command`)."""
    try:
        return node_command(name)
    except FileNotFoundError as exc:
        raise PipelineError(str(exc)) from exc


def run_graph(out: Path, plant_rig: str, mode: str, seed: int, signal_params: list[str],
              noise: bool, timeout: float = 240.0, namespace: str = "") -> Path:
    """Run recorder + simulated plant + excitation as separate processes; return the bag path.

    ``namespace`` ("" = root) puts the three nodes and their topics there (``-r __ns:=``): the bag
    then holds ``<namespace>/aeropend/*``.

    Raises
    ------
    PipelineError
        If a node fails or the excitation does not finish within ``timeout`` seconds; the
        message names the node and its log file.
    """
    bag = out / OUTPUTS["bag"]
    try:  # never a silent replacement: the caller clears an earlier run (pipeline --overwrite)
        claim_bag_folder(bag, False, option="--out", flag="--overwrite").prepare(create=False)
    except OutputFolderError as exc:
        raise PipelineError(str(exc)) from exc
    env = dict(os.environ)
    # a private domain unless the user chose one: claimed, so concurrent aeropend runs never share it
    claim = None if "ROS_DOMAIN_ID" in env else claim_domain(100, 200)
    if claim is not None:
        env["ROS_DOMAIN_ID"] = str(claim.domain_id)
    # the demo's DDS traffic stays on this host unless the user chose otherwise (Jazzy variable)
    for key, value in DISCOVERY.items():
        env.setdefault(key, value)
    env.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    logs = out / OUTPUTS["logs"]
    remap = ["-r", f"__ns:=/{namespace.strip('/')}"] if namespace.strip("/") else []
    ros = ["--ros-args", *remap, "-p"]
    # lock-step samples are published reliably; the plant's simulated time (/clock, which the header
    # stamps follow) goes into the bag beside the wall-clock log times, as ros2 bag record does
    reliable = ["--reliable", "--clock"] if mode == "lockstep" else []
    recorder = Stage("record", [*_exe("record"), "-o", str(bag), *reliable, *(["--ros-args", *remap] if remap
                                                                              else [])], logs / "record.log")
    # lock-step: sample 0 (and so the run) waits until both sample consumers and the recorder's
    # /clock reader are matched
    clock_reader = ["-p", "min_clock_subscribers:=1"] if mode == "lockstep" else []
    plant = Stage("sim_node", _exe("sim_node") + ros + [f"rig:={plant_rig}", "-p", f"mode:={mode}", "-p",
                  f"seed:={seed}", "-p", f"noise:={'true' if noise else 'false'}", "-p",
                  "min_subscribers:=2", *clock_reader], logs / "sim_node.log")
    exc_args: list[str] = []
    # wait for both listeners of the command topic (plant and recorder) so the bag starts at sample 0
    for p in [*signal_params, f"seed:={seed}", f"mode:={mode}", "min_subscribers:=2"]:
        exc_args += ["-p", p]
    excitation = Stage("excitation", [*_exe("excitation"), "--ros-args", *remap, *exc_args],
                       logs / "excitation.log")
    stages = [recorder, plant, excitation]
    try:
        recorder.start(env)  # no head start needed: sample 0 waits for the recorder's subscription
        plant.start(env)
        excitation.start(env)
        t0 = time.monotonic()
        while excitation.proc.poll() is None:
            for st in (recorder, plant):
                if st.proc.poll() is not None:
                    raise PipelineError(
                        f"{st.name} exited early with status {st.proc.returncode}; see {st.log}")
            if time.monotonic() - t0 > timeout:
                raise PipelineError(f"excitation did not finish within {timeout:.0f} s; see {excitation.log}")
            time.sleep(0.2)
        if excitation.proc.returncode != 0:
            raise PipelineError(
                f"excitation failed with status {excitation.proc.returncode}; see {excitation.log}")
    finally:
        for st in reversed(stages):  # the plant first (its summary counts what it published), then
            st.stop()                # the recorder, which writes what is still queued before closing
        if claim is not None:
            claim.release()
    if not (bag / "metadata.yaml").is_file():
        raise PipelineError(f"the recorder left no valid bag at {bag}; see {recorder.log}")
    return bag


def plant_sample_count(log: Path) -> int | None:
    """Number of samples the plant node says it published (its shutdown ``summary:`` line)."""
    if not log.is_file():
        return None
    samples = summary_fields(log.read_text(errors="replace")).get("samples", "")
    return int(samples) if samples.isdigit() else None


def check_recording(bag: Path, log: Path, mode: str, namespace: str = "") -> dict[str, Any]:
    """Completeness guard: samples the plant published (its summary) vs samples in the bag.

    A lock-step run is complete by construction (the plant waits for both sample consumers,
    reliable keep-all QoS, the recorder drains before closing; docs/data_plane.md); this guard
    reports, it does not repeat the run.

    Returns
    -------
    dict
        ``published`` (None if the plant logged no summary), ``recorded`` (distinct sample
        stamps in the bag, the last sample included), ``commands`` (duty-cycle messages in the
        bag: one per sample but the last in lock-step), ``clock_ticks`` (``/clock`` messages in
        the bag, None when it holds no ``/clock``) and ``complete``: every published sample and
        every command recorded and, with ``/clock``, one tick per ``joint_states`` message
        (lock-step), or no published count to compare with (real time: best effort).
    """
    published = plant_sample_count(log)
    clock_ticks = None
    try:
        rec = read_bag(bag, require_duty=False, namespace=_ns(namespace))
        recorded = len(rec)
        with RawBagReader(bag) as reader:
            counts = {name: topic.count for name, topic in reader.topics.items()}
        commands = counts.get(namespaced(TOPIC_DUTY_CYCLE, namespace), 0)
        sample_messages = counts.get(namespaced(TOPIC_JOINT_STATES, namespace), 0)
        clock_ticks = counts.get(TOPIC_CLOCK)
    except BagError:
        recorded = commands = sample_messages = 0
    complete = mode != "lockstep" or (published is not None and recorded == published
                                      and commands == published - 1
                                      and clock_ticks in (None, sample_messages))
    return {"published": published, "recorded": recorded, "commands": commands, "clock_ticks": clock_ticks,
            "complete": complete}


def _ns(namespace: str) -> str:
    """Topic prefix of a namespace for :func:`read_bag` ("" for the root)."""
    return f"/{namespace.strip('/')}" if namespace.strip("/") else ""


def analyse(bag: Path, out: Path, nominal_rig: str, train_fraction: float,
            namespace: str = "", source: str | None = None) -> dict[str, Any]:
    """Read the bag and run the grey-box baseline; returns the baseline report dictionary.

    ``source`` names the recording in the report (default: ``bag``; the command passes the bag's
    final place when it runs in a partial folder that replaces the report folder at the end).
    """
    from aeropend_ident.greybox.baseline import run_baseline

    rec = read_bag(bag, namespace=_ns(namespace))
    if source is not None:
        rec = dataclasses.replace(rec, source=source)
    report = run_baseline(rec, nominal_rig, out / OUTPUTS["baseline"], train_fraction=train_fraction)
    report["recording"] = {"samples": len(rec), "duration_s": float(rec.t[-1]),
                           "first_theta_rad": float(rec.channels["theta"][0]),
                           "gaps": rec.meta.get("gaps", 0)}
    return report
