"""Conformance of a bridge node to the topic contract: the checks of ``bridge_check`` (no rclpy).

``bridge_check`` (:mod:`aeropend_bridge.bridge_check_node`) watches a running node — ``bridge``,
``sim_node`` or a lab's own bridge — while it drives it with duty commands, and records what it saw
in an :class:`Observation`; :func:`evaluate` turns that into one :class:`Finding` per contract
clause (docs/hardware.md, "Contract for bridge nodes"):

``graph``      publishes ``aeropend/joint_states`` (``sensor_msgs/msg/JointState``) and
               ``aeropend/armature`` (``sensor_msgs/msg/BatteryState``) in its namespace, subscribes
               ``aeropend/duty_cycle`` (``std_msgs/msg/Float64``);
``qos``        sample publishers and the command subscription volatile (no stale replays; a
               transient-local command reader would not match the controllers' volatile writers);
``layout``     joints ``pendulum, motor, propeller`` with three positions, velocities, efforts; NaN
               where the contract has no value (motor position, pendulum and propeller effort);
``units``      θ in rad within (−π, π]; applied τ (motor effort) a fraction in [0, 1]; speeds in
               rad/s (|ω| < :data:`MAX_OMEGA`);
``stamps``     both messages of a sample carry the same stamp; stamps strictly increasing, near
               the receive time (or ``/clock``), a steady rate;
``nan``        a channel the node does not measure is NaN, never an exact 0 held while the motor
               is driven;
``command``    the applied τ follows a valid command; NaN and out-of-range commands are ignored;
``silence``    the applied τ falls to 0 within the silence limit after the last command.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field

import numpy as np

#: Contract joints of ``joint_states``, in order.
JOINTS = ("pendulum", "motor", "propeller")
#: Speeds beyond this are not rad/s of an aeropendulum (≈ 190 000 rpm) [rad/s].
MAX_OMEGA = 2.0e4
#: A stamp further than this from the receive time (or /clock) is not the sample instant [s].
MAX_STAMP_AGE_S = 5.0
#: Tolerance of the applied τ against the commanded one (8-bit PWM: 1/255) [1].
DUTY_TOL = 0.01
#: Time the applied τ may take to follow a command [s].
FOLLOW_S = 0.5
#: A pause of the checker's own commands longer than this (its host starved) may trip a conforming
#: node's watchdog; the drive phase is not judged there [s].
PAUSE_S = 0.1
#: Delivery slack added to the silence limit (executor, DDS) [s].
SILENCE_SLACK_S = 0.1
#: Channel name -> (message, index) in :class:`Observation` arrays.
CHANNELS = {"theta_dot": "θ̇ (pendulum velocity)", "omega_rotor": "ω₁ (motor velocity)",
            "omega_prop": "ω₂ (propeller velocity)", "i_a": "i_a (armature current)",
            "v_a": "v_a (armature voltage)"}


@dataclass
class Observation:
    """What ``bridge_check`` saw of one node (host times in ns of one clock).

    Attributes
    ----------
    node : str
        Fully qualified node name.
    publishers, subscribers : dict
        Topic (absolute) -> list of type names of the node's publishers / subscriptions.
    qos : dict
        ``"pub <topic>"`` / ``"sub <topic>"`` -> (reliability, durability) names of the node's
        endpoints (``"RELIABLE"``, ``"VOLATILE"``, ...).
    js : list of tuple
        ``(recv_ns, stamp_ns, names, position, velocity, effort)`` per ``joint_states`` message.
    arm : list of tuple
        ``(recv_ns, stamp_ns, voltage, current)`` per ``armature`` message.
    clock_ns : list of tuple
        ``(recv_ns, clock_ns)`` per ``/clock`` message (empty: the stamps are checked against the
        receive time).
    commands : list of tuple
        ``(sent_ns, value)`` of every duty command sent (NaN and out-of-range ones included).
    namespace : str
        The node's namespace (its contract topics are relative to it).
    recv_to_ros_ns : int
        ROS (system) time minus the host clock of the receive times [ns]: the stamps are
        compared with ``recv + recv_to_ros_ns`` when no ``/clock`` is published.
    phases : dict
        Name -> (start_ns, end_ns) of the checker's schedule: ``drive`` (valid τ), ``invalid``
        (NaN and out-of-range commands among valid ones), ``silence``.
    duty : float
        The valid τ commanded.
    silence_limit_s : float
        Longest time from the last command to τ 0 on the topic [s].
    """

    node: str
    publishers: dict[str, list[str]] = field(default_factory=dict)
    subscribers: dict[str, list[str]] = field(default_factory=dict)
    qos: dict[str, tuple[str, str]] = field(default_factory=dict)
    js: list[tuple] = field(default_factory=list)
    arm: list[tuple] = field(default_factory=list)
    clock_ns: list[tuple[int, int]] = field(default_factory=list)
    commands: list[tuple[int, float]] = field(default_factory=list)
    phases: dict[str, tuple[int, int]] = field(default_factory=dict)
    duty: float = 0.3
    silence_limit_s: float = 0.25
    namespace: str = "/"
    recv_to_ros_ns: int = 0


@dataclass(frozen=True)
class Finding:
    """One contract clause: ``ok`` and what was measured or what departs (``detail``)."""

    check: str
    ok: bool
    detail: str


def _topic(ns: str, rel: str) -> str:
    ns = ns.strip("/")
    return f"/{ns}/{rel}" if ns else f"/{rel}"


def check_graph(o: Observation) -> list[Finding]:
    """Topics and types of the node (``graph``) and its endpoints' QoS (``qos``)."""
    out = []
    want = (("publishes", o.publishers, "aeropend/joint_states", "sensor_msgs/msg/JointState"),
            ("publishes", o.publishers, "aeropend/armature", "sensor_msgs/msg/BatteryState"),
            ("subscribes", o.subscribers, "aeropend/duty_cycle", "std_msgs/msg/Float64"))
    for verb, table, rel, typ in want:
        topic = _topic(o.namespace, rel)
        types = table.get(topic)
        if types is None:
            near = difflib.get_close_matches(topic, list(table), n=2, cutoff=0.7)
            hint = f" (it {verb} {near} instead)" if near else ""
            base = {"publishes": "publish", "subscribes": "subscribe"}[verb]
            out.append(Finding("graph", False, f"{o.node} does not {base} {topic} [{typ}]{hint}"))
        elif typ not in types:
            out.append(Finding("graph", False, f"{o.node} {verb} {topic} as {types}, expected {typ}"))
        else:
            out.append(Finding("graph", True, f"{verb} {topic} [{typ}]"))
    for key, (rel, dur) in sorted(o.qos.items()):
        if dur != "VOLATILE":
            why = ("replays stale samples to late subscribers" if key.startswith("pub")
                   else "does not match the controllers' volatile command writers")
            out.append(Finding("qos", False, f"{key}: durability {dur}, expected VOLATILE ({why})"))
        else:
            out.append(Finding("qos", True, f"{key}: {rel.lower()}, volatile"))
    return out


def _arrays(o: Observation) -> dict[str, np.ndarray]:
    js = o.js
    n = len(js)
    a: dict[str, np.ndarray] = {"recv": np.array([m[0] for m in js], dtype=np.int64),
                                "stamp": np.array([m[1] for m in js], dtype=np.int64)}
    full = [m for m in js if len(m[3]) >= 3 and len(m[4]) >= 3 and len(m[5]) >= 3]
    if len(full) != n or n == 0:
        return a
    pos, vel, eff = (np.array([m[k] for m in js], dtype=float) for k in (3, 4, 5))
    a.update(theta=pos[:, 0], motor_pos=pos[:, 1], theta_dot=vel[:, 0], omega_rotor=vel[:, 1],
             omega_prop=vel[:, 2], duty=eff[:, 1], pend_eff=eff[:, 0], prop_eff=eff[:, 2])
    by_stamp = {m[1]: m for m in o.arm}
    a["i_a"] = np.array([by_stamp[s][3] if s in by_stamp else np.nan for s in a["stamp"]], dtype=float)
    a["v_a"] = np.array([by_stamp[s][2] if s in by_stamp else np.nan for s in a["stamp"]], dtype=float)
    return a


def check_layout_units(o: Observation, a: dict[str, np.ndarray]) -> list[Finding]:
    """Joint names and array sizes (``layout``), value ranges (``units``)."""
    if not o.js:
        return [Finding("layout", False, "no joint_states message received")]
    bad_names = {tuple(m[2]) for m in o.js if tuple(m[2][:3]) != JOINTS}
    if bad_names:
        return [Finding("layout", False,
                        f"joint names {sorted(bad_names)[0]}, expected {JOINTS} in this order")]
    if "theta" not in a:
        return [Finding("layout", False, "position, velocity and effort must each have 3 entries "
                                         f"(got {[len(x) for x in o.js[0][3:6]]})")]
    out = [Finding("layout", True, f"joints {', '.join(JOINTS)}; {len(o.js)} samples")]
    must_nan = {"motor position": a["motor_pos"], "pendulum effort": a["pend_eff"],
                "propeller effort": a["prop_eff"]}
    for name, v in must_nan.items():
        if not np.all(np.isnan(v)):
            out.append(Finding("layout", False,
                               f"{name} is {v[~np.isnan(v)][0]:g}; the contract has no value there: NaN"))
    th = a["theta"][np.isfinite(a["theta"])]
    if th.size == 0:
        out.append(Finding("units", False, "θ is never a number (the angle is the one channel every bridge "
                                           "measures; an encoder that homes on its index publishes NaN "
                                           "until the rod has passed it: turn the rod through it first)"))
    elif np.max(np.abs(th)) > math.pi + 1e-9:
        out.append(Finding("units", False, f"θ reaches {th[np.argmax(np.abs(th))]:g}: outside (−π, π] rad "
                                           "(degrees? not wrapped?)"))
    else:
        out.append(Finding("units", True, f"θ in rad, {th.min():+.4f} .. {th.max():+.4f}"))
    d = a["duty"]
    if np.any(np.isnan(d)) or np.any((d < 0) | (d > 1)):
        bad = d[np.isnan(d) | (d < 0) | (d > 1)][0]
        out.append(Finding("units", False, f"applied τ (motor effort) is {bad:g}: a fraction in [0, 1] "
                                           "(percent? 8-bit counts?)"))
    else:
        out.append(Finding("units", True, f"applied τ in [0, 1], max {d.max():.4f}"))
    for ch in ("theta_dot", "omega_rotor", "omega_prop"):
        v = a[ch][np.isfinite(a[ch])]
        if v.size and np.max(np.abs(v)) > MAX_OMEGA:
            out.append(Finding("units", False, f"{CHANNELS[ch]} reaches {np.max(np.abs(v)):g}: not rad/s "
                                               "(rpm? deg/s?)"))
    return out


def _ref_ns(o: Observation, recv: np.ndarray) -> tuple[np.ndarray, str]:
    if not o.clock_ns:
        return recv + o.recv_to_ros_ns, "the receive time"
    rc = np.array(o.clock_ns, dtype=np.int64)
    idx = np.clip(np.searchsorted(rc[:, 0], recv) - 1, 0, len(rc) - 1)
    return rc[idx, 1], "/clock"


def check_stamps(o: Observation, a: dict[str, np.ndarray]) -> list[Finding]:
    """One stamp per sample on both topics, increasing, current, at a steady rate (``stamps``)."""
    if len(o.js) < 3:
        return [Finding("stamps", False, f"only {len(o.js)} joint_states messages: stamps not checkable")]
    out = []
    st = a["stamp"]
    js_stamps = set(st.tolist())
    arm_stamps = np.array(sorted(m[1] for m in o.arm), dtype=np.int64)
    matched = np.isin(arm_stamps, st)
    if arm_stamps.size == 0:
        out.append(Finding("stamps", False, "no armature message received"))
    elif matched.mean() < 0.9:
        first = arm_stamps[~matched][0]
        d = first - st[np.argmin(np.abs(st - first))]  # from the nearest joint_states stamp
        out.append(Finding("stamps", False,
                           f"{(~matched).sum()} of {arm_stamps.size} armature stamps match no joint_states "
                           f"stamp (e.g. {d / 1e6:+.3f} ms off): both messages of a sample carry the sample "
                           "instant"))
    else:
        out.append(Finding("stamps", True, f"{matched.sum()} of {arm_stamps.size} armature stamps equal a "
                                           f"joint_states stamp ({len(js_stamps)} samples)"))
    dt = np.diff(st)
    if np.any(dt <= 0):
        out.append(Finding("stamps", False, f"{int((dt <= 0).sum())} joint_states stamps do not increase "
                                            f"(first step {dt[dt <= 0][0] / 1e6:+.3f} ms)"))
    ref, what = _ref_ns(o, a["recv"])
    age = (ref - st) / 1e9
    worst = float(age[np.argmax(np.abs(age))])
    if abs(worst) > MAX_STAMP_AGE_S:
        out.append(Finding("stamps", False, f"stamps are {worst:+.3f} s from {what}: a stamp is the sample "
                                            "instant on the node's clock (sim time: /clock)"))
    else:
        period = float(np.median(dt)) / 1e9 if dt.size else math.nan
        out.append(Finding("stamps", True, f"stamps within {abs(worst) * 1e3:.1f} ms of {what}, median "
                                           f"period {period * 1e3:.3f} ms ({1 / period:.1f} Hz)"))
    return out


def check_nan(o: Observation, a: dict[str, np.ndarray]) -> list[Finding]:
    """Unmeasured channels are NaN, not a held exact 0 (``nan``): checked while τ ≥ 0.2 is applied."""
    if "duty" not in a:
        return []
    on = a["duty"] >= 0.2
    if on.sum() < 20:
        return [Finding("nan", False, f"the motor was never driven (applied τ ≥ 0.2 in {on.sum()} samples): "
                                      "zeros for unmeasured channels cannot be told from a stopped motor")]
    out = []
    for ch, label in CHANNELS.items():
        v = a[ch][on]
        if np.all(np.isnan(v)):
            out.append(Finding("nan", True, f"{label}: NaN (not measured)"))
        elif np.all(v == 0.0):
            tau = np.median(a["duty"][on])
            msg = (f"{label} is exactly 0 in all {v.size} samples while τ {tau:.2f} drives the motor: "
                   "a channel the node does not measure must be NaN, never 0")
            out.append(Finding("nan", False, msg))
        else:
            out.append(Finding("nan", True, f"{label}: measured ({np.nanmin(v):.4g} .. {np.nanmax(v):.4g})"))
    return out


def check_commands(o: Observation, a: dict[str, np.ndarray]) -> list[Finding]:
    """The applied τ follows valid commands, ignores invalid ones (``command``) and falls to 0 when
    the commands stop (``silence``)."""
    if "duty" not in a or not o.phases:
        return []
    out = []
    recv, duty = a["recv"], a["duty"]
    d0, d1 = o.phases["drive"]
    # a pause in the checker's own command stream (a starved host) may trip a conforming node's
    # watchdog (the contract bounds it by the silence limit; a node may fall to 0 sooner): those
    # stretches, and the follow time after them, are not judged, in the drive phase and the invalid one
    sent = np.sort(np.array([t for t, _ in o.commands], dtype=np.int64))
    judged = np.ones(recv.shape, dtype=bool)
    paused = 0
    if sent.size > 1:
        gaps = np.flatnonzero(np.diff(sent) > PAUSE_S * 1e9)
        paused = gaps.size
        for k in gaps:
            judged &= ~((recv > sent[k]) & (recv < sent[k + 1] + FOLLOW_S * 1e9))
    late = (recv >= d0 + FOLLOW_S * 1e9) & (recv < d1) & judged
    if not late.any() or np.any(np.abs(duty[late] - o.duty) > DUTY_TOL):
        got = np.unique(np.round(duty[late], 4))[:5] if late.any() else "no samples"
        out.append(Finding("command", False, f"applied τ {got} {FOLLOW_S:g} s after τ = {o.duty:g} was "
                                             f"commanded (within {DUTY_TOL:g}): the node does not apply "
                                             "duty_cycle as a fraction"))
    else:
        t_on = recv[(recv >= d0) & (np.abs(duty - o.duty) <= DUTY_TOL)]
        note = (f" (the checker's commands paused {paused} time(s) over {PAUSE_S:g} s: those stretches "
                "not judged)") if paused else ""
        out.append(Finding("command", True, f"τ = {o.duty:g} applied {(t_on[0] - d0) / 1e6:.0f} ms after the "
                                            "first command" + note))
    if "invalid" in o.phases:
        i0, i1 = o.phases["invalid"]
        during = (recv >= i0 + 0.1e9) & (recv < i1) & judged
        bad = duty[during][np.abs(duty[during] - o.duty) > DUTY_TOL]
        if bad.size:
            out.append(Finding("command", False, f"applied τ became {bad[0]:g} while NaN and out-of-range "
                                                 "commands were sent: they must be rejected"))
        else:
            out.append(Finding("command", True, "NaN and out-of-range commands rejected"))
    last_cmd = max(t for t, _ in o.commands)
    after = recv >= last_cmd
    zero = after & (duty == 0.0)
    if not after.any():
        out.append(Finding("silence", False, "no samples after the commands stopped (a lock-step node? the "
                                             "contract's loss-of-controller clause needs a real-time node)"))
    elif not zero.any():
        waited = (recv[-1] - last_cmd) / 1e9
        msg = (f"applied τ still {duty[after][-1]:g} {waited:.2f} s after the last command: it must "
               f"fall to 0 within {o.silence_limit_s:g} s")
        out.append(Finding("silence", False, msg))
    else:
        lat = (recv[zero][0] - last_cmd) / 1e9
        stays = np.all(duty[recv >= recv[zero][0]] == 0.0)
        ok = lat <= o.silence_limit_s + SILENCE_SLACK_S and stays
        why = "" if ok else (f" (limit {o.silence_limit_s:g} s)" if stays else " but did not stay at 0")
        out.append(Finding("silence", ok, f"applied τ 0 {lat * 1e3:.0f} ms after the last command{why}"))
    return out


def evaluate(o: Observation) -> list[Finding]:
    """Every contract clause for one observation, in report order.

    Parameters
    ----------
    o : Observation
        What the checker saw.

    Returns
    -------
    list of Finding
        One or more per clause; ``ok`` False for each departure.
    """
    a = _arrays(o)
    return (check_graph(o) + check_layout_units(o, a) + check_stamps(o, a) + check_nan(o, a)
            + check_commands(o, a))


def report(o: Observation, findings: list[Finding]) -> str:
    """The text report: one line per finding, then the verdict."""
    lines = [f"bridge_check {o.node}"]
    lines += [f"  {'ok  ' if f.ok else 'FAIL'} {f.check:<8} {f.detail}" for f in findings]
    bad = [f for f in findings if not f.ok]
    lines.append(f"{o.node}: " + ("conforms to the bridge contract (docs/hardware.md)" if not bad else
                                  f"{len(bad)} departure(s) from the bridge contract (docs/hardware.md)"))
    return "\n".join(lines)
