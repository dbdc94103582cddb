"""Excitation node (console script ``excitation``): publish a duty-cycle signal as commands.

Builds a signal with :func:`aeropend_sim.excitation.make_signal` and publishes it on
``/aeropend/duty_cycle``, then exits.

Modes
-----
``realtime``
    One command per sample period of wall time (dedicated thread, absolute deadlines), after a
    subscriber (the plant) has appeared. For the real-time simulated plant or the hardware.
``lockstep``
    One command per *new* sample received on ``/aeropend/joint_states`` (reliable QoS): the
    plant ↔ excitation ping-pong of deterministic open-loop lock-step runs
    (``sim_node --ros-args -p mode:=lockstep``). Sample k (stamp k·T_s) is answered with
    ``duty[k]``; a re-published sample (same stamp: the plant saw no command for 0.5 s) is
    answered again with the same command.

Usage::

    excitation --ros-args -p signal:=lhs -p seed:=1 -p mode:=lockstep
    excitation --signal staircase --levels 0.3 0.5 --hold 2 --mode realtime
    excitation --print --signal prbs --order 7 --clock 5 > prbs.csv      # no ROS needed
    excitation --signal file --file design/design.csv --mode realtime    # play a CSV of t,duty
    excitation --design-for gap_report run1 --rig my_rig.yaml -o design  # design the next experiment

``--design-for`` (no ROS) hands over to the installed ``excitation_design`` command (experiment
design, :mod:`aeropend_ident.design.cli`), found by its console-script entry point: aeropend_sim
imports no package above it, and a machine with the simulator alone keeps every other mode.

Parameters (``-p name:=value``; the friendly ``--flags`` override them): :data:`OPTION_PARAMETERS`
and :data:`SIGNAL_PARAMETERS` (also printed by ``excitation --help``).

Exit status: 0 signal sent, 1 no plant / interrupted, 2 invalid signal or parameter.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from aeropend_sim.contract import REL_DUTY_CYCLE, REL_JOINT_STATES, LockstepRepeats
from aeropend_sim.excitation import SIGNALS, ExcitationError, ExcitationSignal, make_signal
from aeropend_sim.files.safe_yaml import YamlRefusedError, parse_yaml
from aeropend_sim.output_folder import exits_cleanly_on_faults
from aeropend_sim.ros.node_usage import NodeParameter, NodeUsage, contract_topic, strip_ros_args

NODE_NAME = "aeropend_excitation"
MODES = ("realtime", "lockstep")
#: How the signal is published (node parameters; ``--flag`` spellings override them).
OPTION_PARAMETERS: tuple[NodeParameter, ...] = (
    NodeParameter("signal", "str", "lhs", "",
                  "signal kind: " + ", ".join(sorted(SIGNALS)) + " (density_prbs: fast binary holds whose "
                  "density follows a slow APRBS, the identifiability design; lhs: thesis 5.1 "
                  "Latin-hypercube steps)"),
    NodeParameter("mode", "str", "realtime", "",
                  "realtime: one command per sample period of wall time once a subscriber (the plant) is "
                  "there; lockstep: one command per new sample on joint_states (reliable), the ping-pong of "
                  "deterministic lock-step runs with sim_node mode:=lockstep"),
    NodeParameter("zero_at_end", "bool", None, "",
                  "send duty 0 after the signal and on shutdown (unset: true in realtime, false in lockstep, "
                  "where an extra command would advance the plant one more sample)"),
    NodeParameter("wait_timeout", "float", 30.0, "s", "give up (exit status 1) if no plant appears within "
                  "this time"),
    NodeParameter("min_subscribers", "int", 1, "",
                  "send the first command only once this many subscriptions (plant, recorder, ...) are "
                  "matched on duty_cycle, so a recorder started alongside misses nothing"),
)
#: Arguments of the signal kinds (:func:`aeropend_sim.excitation.make_signal`; unset = the
#: generator's default, a kind refuses an argument it does not take).
SIGNAL_PARAMETERS: tuple[NodeParameter, ...] = (
    NodeParameter("level", "float", None, "", "step: final duty"),
    NodeParameter("duration", "float", None, "s", "step/aprbs: length"),
    NodeParameter("initial", "float", None, "", "step: duty before the step"),
    NodeParameter("step_time", "float", None, "s", "step: instant of the step"),
    NodeParameter("levels", "float[]", None, "", "staircase: duty levels"),
    NodeParameter("hold", "float[]", None, "s", "staircase: hold time(s), one or one per level"),
    NodeParameter("order", "int", None, "", "prbs: register length m"),
    NodeParameter("lo", "float", None, "", "prbs/aprbs/density_prbs: low duty"),
    NodeParameter("hi", "float", None, "", "prbs/aprbs/density_prbs: high duty"),
    NodeParameter("clock", "int", None, "", "prbs: samples per bit"),
    NodeParameter("periods", "int", None, "", "prbs: number of periods"),
    NodeParameter("min_hold", "float", None, "s", "aprbs/density_prbs: shortest hold"),
    NodeParameter("max_hold", "float", None, "s", "aprbs/density_prbs: longest hold"),
    NodeParameter("n", "int", None, "", "lhs: number of steps"),
    NodeParameter("tau_min", "float", None, "", "lhs: lowest duty"),
    NodeParameter("tau_max", "float", None, "", "lhs: highest duty"),
    NodeParameter("hold_min", "float", None, "s", "lhs: shortest step"),
    NodeParameter("hold_max", "float", None, "s", "lhs: longest step"),
    NodeParameter("density_lo", "float", None, "", "density_prbs: lowest probability of the high level"),
    NodeParameter("density_hi", "float", None, "", "density_prbs: highest probability of the high level"),
    NodeParameter("density_min_hold", "float", None, "s", "density_prbs: shortest hold of the slow density"),
    NodeParameter("density_max_hold", "float", None, "s", "density_prbs: longest hold of the slow density"),
    NodeParameter("file", "str", None, "", "file: CSV of t [s], duty [1] to play (excitation_design's "
                  "design.csv, excitation --print's output; uniform t)"),
    NodeParameter("seed", "int", None, "", "seed of the random signals"),
    NodeParameter("dt", "float", None, "s", "sample period (unset: 2.048 ms)"),
)
#: Every argument name of every signal kind (declared as node parameters).
SIGNAL_ARGS: tuple[str, ...] = tuple(p.name for p in SIGNAL_PARAMETERS)
#: Node options besides the signal arguments: name -> default.
OPTIONS: dict[str, Any] = {p.name: p.default for p in OPTION_PARAMETERS}

#: ``excitation --help`` (the flags are added by :func:`build_arg_parser`).
USAGE = NodeUsage(
    command="excitation",
    node_name=NODE_NAME,
    summary="Publish a duty-cycle excitation signal (aeropend_sim.excitation) as commands on the "
            "duty_cycle topic, then exit; --print writes the signal as CSV without ROS.",
    topics=(contract_topic("publishes", REL_DUTY_CYCLE, "one command per sample period (realtime) or per "
                           "new sample (lockstep)"),
            contract_topic("subscribes", REL_JOINT_STATES, "lockstep mode only: the plant's samples")),
    parameters=OPTION_PARAMETERS + SIGNAL_PARAMETERS,
    examples=("excitation --ros-args -p signal:=lhs -p seed:=1 -p mode:=lockstep",
              "excitation --signal staircase --levels 0.3 0.5 --hold 2 --mode realtime",
              "excitation --print --signal prbs --order 7 --clock 5 > prbs.csv      # no ROS needed",
              "excitation --signal file --file design/design.csv --mode realtime",
              "excitation --design-for gap_report run1 --rig my_rig.yaml -o design   # excitation_design"),
    notes="Exit status: 0 signal sent, 1 no plant / interrupted, 2 invalid signal or parameter.",
)


# ---------------------------------------------------------------------------------- pure part
@dataclass(frozen=True)
class ExcitationConfig:
    """Validated configuration: the signal and how to publish it."""

    signal: ExcitationSignal
    mode: str
    zero_at_end: bool
    wait_timeout: float
    min_subscribers: int = 1


def build_arg_parser() -> argparse.ArgumentParser:
    """Friendly command-line flags (every flag is optional and overrides a ROS parameter of the same
    name, :data:`OPTION_PARAMETERS` and :data:`SIGNAL_PARAMETERS`)."""
    ap = USAGE.parser()
    ap.add_argument("--signal", choices=sorted(SIGNALS), help="signal kind (default lhs)")
    ap.add_argument("--mode", choices=MODES, help="realtime (wall clock) or lockstep (one per sample)")
    ap.add_argument("--print", action="store_true", help="print the signal as CSV (t,duty) and exit; no ROS")
    ap.add_argument("--zero-at-end", dest="zero_at_end", action="store_true", default=None,
                    help="send duty 0 after the signal and on shutdown")
    ap.add_argument("--no-zero-at-end", dest="zero_at_end", action="store_false")
    ap.add_argument("--wait-timeout", dest="wait_timeout", type=float, help="seconds to wait for the plant")
    ap.add_argument("--min-subscribers", dest="min_subscribers", type=int,
                    help="matched duty-cycle subscribers needed before the first command (default 1)")
    g = ap.add_argument_group("signal arguments (the ROS parameters of the same name, see below)")
    for p in SIGNAL_PARAMETERS:
        typ = {"int": int, "str": str}.get(p.type, float)
        unit = f" [{p.unit}]" if p.unit else ""
        g.add_argument(f"--{p.name.replace('_', '-')}", dest=p.name, type=typ,
                       nargs="+" if p.type.endswith("[]") else None, help=p.description + unit)
    return ap


def ros_param_overrides(argv: list[str]) -> dict[str, Any]:
    """``-p name:=value`` pairs inside ``--ros-args`` sections (values parsed as YAML).

    Used by ``--print`` so the same parameter syntax works without starting ROS.

    Raises
    ------
    ExcitationError
        On a ``-p`` item without ``:=``, or a value holding a YAML alias
        (:mod:`aeropend_sim.files.safe_yaml`).
    """
    out: dict[str, Any] = {}
    in_ros = False
    it = iter(argv)
    for tok in it:
        if tok == "--ros-args":
            in_ros = True
        elif tok == "--":
            in_ros = False
        elif in_ros and tok in ("-p", "--param"):
            item = next(it, "")
            name, sep, value = item.partition(":=")
            if not sep:
                raise ExcitationError(f"parameter {item!r} is not of the form name:=value")
            try:
                out[name] = parse_yaml(value, f"parameter {name}", "a parameter value")
            except YamlRefusedError as exc:
                raise ExcitationError(str(exc)) from None
    return out


def resolve_config(params: dict[str, Any], flags: argparse.Namespace | None = None) -> ExcitationConfig:
    """Merge parameters and flags (flags win), build and validate the signal.

    Parameters
    ----------
    params : dict
        Node parameters (``None`` = not set); keys from :data:`OPTIONS` and :data:`SIGNAL_ARGS`.
    flags : argparse.Namespace, optional
        Parsed friendly flags (``None`` attributes = not given).

    Raises
    ------
    ExcitationError
        On an unknown mode, a bad ``wait_timeout`` or any signal error (unknown kind, argument
        that the kind does not take, invalid value).
    """
    merged = {k: v for k, v in params.items() if v is not None}
    if flags is not None:
        merged.update({k: v for k, v in vars(flags).items() if v is not None and k != "print"})
    unknown = sorted(set(merged) - set(OPTIONS) - set(SIGNAL_ARGS))
    if unknown:
        raise ExcitationError(
            f"unknown parameter(s) {unknown}; expected some of {sorted(OPTIONS) + list(SIGNAL_ARGS)}"
        )
    kind = str(merged.pop("signal", OPTIONS["signal"]))
    mode = str(merged.pop("mode", OPTIONS["mode"])).strip().lower()
    if mode not in MODES:
        raise ExcitationError(f"mode = {mode!r}; expected one of {list(MODES)}")
    zero = merged.pop("zero_at_end", None)
    if zero is None:
        zero = mode == "realtime"
    elif not isinstance(zero, bool):
        raise ExcitationError(f"zero_at_end = {zero!r}; expected true or false")
    wait = merged.pop("wait_timeout", OPTIONS["wait_timeout"])
    try:
        wait = float(wait)
    except (TypeError, ValueError) as exc:
        raise ExcitationError(f"wait_timeout = {wait!r} is not a number of seconds") from exc
    if not (math.isfinite(wait) and wait > 0.0):
        raise ExcitationError(f"wait_timeout = {wait!r} s; expected a duration > 0")
    min_subs = merged.pop("min_subscribers", OPTIONS["min_subscribers"])
    if isinstance(min_subs, bool) or not isinstance(min_subs, int) or min_subs < 1:
        raise ExcitationError(f"min_subscribers = {min_subs!r}; expected an integer >= 1")
    for key in ("levels", "hold"):  # ROS double arrays arrive as array.array
        if key in merged and not isinstance(merged[key], int | float | str):
            merged[key] = [float(v) for v in merged[key]]
    signal = make_signal(kind, **merged)
    return ExcitationConfig(signal=signal, mode=mode, zero_at_end=bool(zero), wait_timeout=wait,
                            min_subscribers=min_subs)


class LockstepFeeder:
    """Which command answers which sample in lock-step mode.

    ``on_sample(stamp)`` returns ``duty[k]`` for the k-th new stamp (strictly increasing), None for
    an older stamp or once the signal is exhausted, and for a repeated stamp (the plant re-publishes
    its last sample while it waits for a command) the previous command again. With ``matched`` (the
    duty readers matched now) only when :class:`~aeropend_sim.contract.LockstepRepeats` says so: a
    reader matched since the last answer was published (:meth:`mark_published`); otherwise that
    answer arrived, and a second one would make the plant advance twice on one command and shift the
    signal by one sample. Without ``matched`` every repeat is answered again.

    Parameters
    ----------
    duty : ndarray, shape (N,)
        The commands in order.

    Attributes
    ----------
    sent, resent, skipped : int
        New commands answered, repeats answered again, repeats not answered (the answer arrived).
    """

    def __init__(self, duty: np.ndarray) -> None:
        self.duty = np.asarray(duty, dtype=float)
        self.sent = 0
        self.resent = 0
        self.skipped = 0
        self._last_stamp: int | None = None
        self._repeats = LockstepRepeats()

    @property
    def last_stamp(self) -> int | None:
        """Stamp [ns] of the last sample answered (None before the first)."""
        return self._last_stamp

    @property
    def done(self) -> bool:
        """True once every command has been sent."""
        return self.sent >= self.duty.size

    def mark_published(self, matched: int) -> None:
        """Record that the last answer goes out now to ``matched`` duty readers
        (:meth:`LockstepRepeats.published <aeropend_sim.contract.LockstepRepeats.published>`)."""
        self._repeats.published(matched)

    def on_sample(self, stamp_ns: int, matched: int | None = None) -> float | None:
        """Command to publish in reply to the sample stamped ``stamp_ns`` (or None); ``matched``:
        duty readers matched now (see the class doc)."""
        if self._last_stamp is not None and stamp_ns == self._last_stamp:
            if self.sent == 0:
                return None
            if matched is not None and not self._repeats.answer_again(matched):
                self.skipped += 1
                return None
            self.resent += 1
            return float(self.duty[self.sent - 1])
        if (self._last_stamp is not None and stamp_ns < self._last_stamp) or self.done:
            return None
        self._last_stamp = stamp_ns
        value = float(self.duty[self.sent])
        self.sent += 1
        return value


# ---------------------------------------------------------------------------------- ROS part
def _send_realtime(cfg: ExcitationConfig, pub: Any, float64: Any, executor: Any, stop: threading.Event,
                   spin_until: Any, log: Any) -> int | tuple[int, bool]:
    """Realtime mode of the node: wait for the duty readers, then publish one command per period on
    a wall-clock schedule (a sender thread, deadlines absolute); (commands sent, interrupted), or
    the exit status when no reader came."""
    import rclpy

    from aeropend_sim.sim_core import RealtimeSchedule

    sig = cfg.signal
    if not spin_until(lambda: pub.get_subscription_count() >= cfg.min_subscribers, cfg.wait_timeout):
        if not stop.is_set():
            log.error(
                f"{pub.get_subscription_count()} of {cfg.min_subscribers} subscriber(s) on "
                f"{pub.topic_name} within {cfg.wait_timeout:g} s; is the plant up?"
            )
        return 1
    sent = [0]

    def worker() -> None:
        period_ns = round(sig.dt * 1e9)
        sched = RealtimeSchedule(period_ns, time.monotonic_ns())
        for k, u in enumerate(sig.duty):
            while (rem := sched.deadline_ns(k) - time.monotonic_ns()) > 0 and not stop.is_set():
                time.sleep(min(rem * 1e-9, 0.05))
            if stop.is_set():
                return
            sched.on_wake(k, time.monotonic_ns())
            pub.publish(float64(data=float(u)))
            sent[0] += 1
        if sched.overruns:
            log.warn(f"{sched.overruns} overrun(s), {sched.dropped_ns / 1e6:.1f} ms behind schedule")

    thread = threading.Thread(target=worker, name="excitation_sender", daemon=True)
    thread.start()
    while thread.is_alive() and not stop.is_set() and rclpy.ok():
        executor.spin_once(timeout_sec=0.05)
    stop_requested = stop.is_set()
    stop.set()
    thread.join(timeout=1.0)
    n_sent = sent[0]
    return n_sent, stop_requested


def _send_lockstep(cfg: ExcitationConfig, node: Any, pub: Any, float64: Any, joint_state: Any, executor: Any,
                   stop: threading.Event, spin_until: Any, log: Any) -> int | tuple[int, bool]:
    """Lockstep mode of the node: answer each plant sample (``joint_states``) with the next command
    (:class:`LockstepFeeder`); (commands sent, interrupted), or the exit status when no sample came."""
    import rclpy

    from aeropend_sim.ros.ros_contract import SAMPLE_QOS_LOCKSTEP

    feeder = LockstepFeeder(cfg.signal.duty)
    pending: list[float] = []

    def on_sample(msg: Any) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if pending and stamp == feeder.last_stamp:
            return  # re-published sample whose answer is still waiting to be sent
        value = feeder.on_sample(stamp, pub.get_subscription_count())
        if value is not None:
            pending.append(value)
            flush()

    def flush() -> None:
        matched = pub.get_subscription_count()
        if pending and matched >= cfg.min_subscribers:
            feeder.mark_published(matched)
            for value in pending:
                pub.publish(float64(data=value))
            pending.clear()

    sub = node.create_subscription(joint_state, REL_JOINT_STATES, on_sample, SAMPLE_QOS_LOCKSTEP)
    node.create_timer(0.01, flush)
    if not spin_until(lambda: feeder.sent > 0, cfg.wait_timeout):
        if not stop.is_set():
            log.error(
                f"no sample on {sub.topic_name} within {cfg.wait_timeout:g} s; "
                "is the plant up in lockstep mode?"
            )
        return 1
    while not stop.is_set() and rclpy.ok() and not (feeder.done and not pending):
        executor.spin_once(timeout_sec=0.05)
    stop_requested = stop.is_set() and not (feeder.done and not pending)
    n_sent = feeder.sent
    if feeder.resent:
        log.warn(f"re-sent {feeder.resent} command(s) for re-published samples "
                 "(a duty reader matched late)")
    if feeder.skipped:
        log.info(f"{feeder.skipped} re-published sample(s) not answered again: their command had "
                 "reached every matched reader")
    return n_sent, stop_requested


def _run_ros(argv: list[str], flags: argparse.Namespace) -> int:
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from aeropend_sim.ros.node_shell import declare_parameter_table, run_node, wait_acknowledged
    from aeropend_sim.ros.ros_contract import COMMAND_QOS, COMMAND_QOS_LOCKSTEP

    def run(node: Any, executor: Any, stop: threading.Event) -> int:
        log = node.get_logger()
        params = declare_parameter_table(node, USAGE.parameters)
        try:
            cfg = resolve_config(params, flags)
        except ExcitationError as exc:
            log.error(f"invalid excitation: {exc}")
            return 2
        sig = cfg.signal
        if cfg.mode == "realtime":
            # the real-time schedule's module loads the simulator (0.4-0.6 s, holding the GIL): before the
            # command topic is offered, not between a plant's match and the first command
            import aeropend_sim.sim_core  # noqa: F401
        pub = node.create_publisher(Float64, REL_DUTY_CYCLE,
                                    COMMAND_QOS_LOCKSTEP if cfg.mode == "lockstep" else COMMAND_QOS)
        log.info(
            f"signal {sig.kind} {sig.params}: {len(sig)} samples, {sig.duration:.3f} s, "
            f"duty in [{sig.duty.min():.4g}, {sig.duty.max():.4g}], mode {cfg.mode}"
        )

        def spin_until(cond: Any, timeout: float) -> bool:
            end = time.monotonic() + timeout
            while not stop.is_set() and rclpy.ok() and time.monotonic() < end:
                if cond():
                    return True
                executor.spin_once(timeout_sec=0.01)
            return bool(cond())

        if cfg.mode == "realtime":
            out = _send_realtime(cfg, pub, Float64, executor, stop, spin_until, log)
        else:
            out = _send_lockstep(cfg, node, pub, Float64, JointState, executor, stop, spin_until, log)
        if isinstance(out, int):
            return out
        n_sent, stop_requested = out
        if cfg.zero_at_end and rclpy.ok():
            pub.publish(Float64(data=0.0))
        if rclpy.ok():  # a lagging recorder must get the last commands before the writer is gone
            wait_acknowledged(node, [pub])
        if stop_requested:
            log.warn(f"interrupted after {n_sent} of {len(sig)} commands")
            return 1
        tail = " + duty 0" if cfg.zero_at_end else ""
        log.info(f"sent {n_sent} commands ({sig.duration:.3f} s of signal){tail}")
        return 0

    return run_node(NODE_NAME, ["excitation", *argv], lambda: rclpy.create_node(NODE_NAME), body=run,
                    interrupt_status=1)


def _design(argv: list[str]) -> int:
    """``excitation --design-for ...``: the installed ``excitation_design`` command (experiment design,
    in aeropend_ident), found by its console-script entry point and called with the arguments; no
    import of a package above this one (module doc)."""
    from importlib.metadata import entry_points

    found = entry_points(group="console_scripts", name="excitation_design")
    if not found:
        print("excitation: --design-for needs the excitation_design command of aeropend_ident (colcon build, "
              "or scripts/setup_env.sh)", file=sys.stderr)
        return 2
    design_main = next(iter(found)).load()
    return design_main(argv, prog="excitation")


@exits_cleanly_on_faults("excitation")
def main(argv: list[str] | None = None) -> int:
    """Entry point of ``excitation``; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if any(a == "--design-for" or a.startswith("--design-for=") for a in argv):
        return _design(argv)
    parser = build_arg_parser()
    flags = parser.parse_args(strip_ros_args(argv))
    if flags.print:
        try:
            cfg = resolve_config(ros_param_overrides(argv), flags)
        except ExcitationError as exc:
            print(f"excitation: invalid excitation: {exc}", file=sys.stderr)
            return 2
        sys.stdout.write(cfg.signal.to_csv())
        return 0
    return _run_ros(argv, flags)


if __name__ == "__main__":
    sys.exit(main())
