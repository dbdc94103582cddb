"""Contract bags -> :class:`~aeropend_sim.recording.Recording` (pure Python, no rclpy): the reader.

Writing is :mod:`aeropend_ident.io.bag_writer`, the CDR codec :mod:`aeropend_ident.io.bag_codec`,
the raw (serialised) reading under both :mod:`aeropend_ident.io.bag_reader`; this module also
holds the contract QoS of bag topics.

A *contract bag* is a rosbag2 bag (MCAP or SQLite3 storage) holding the topics of
:mod:`aeropend_sim.contract`:

* ``/aeropend/joint_states`` (``sensor_msgs/msg/JointState``) and ``/aeropend/armature``
  (``sensor_msgs/msg/BatteryState``): one message each per acquisition sample, both with the
  **same header stamp** (the sample instant);
* ``/aeropend/duty_cycle`` (``std_msgs/msg/Float64``): the duty-cycle commands.

Wire convention vs. array convention
------------------------------------
On the wire the applied duty (``joint_states`` motor effort) and the armature voltage of a
sample describe the interval that *ends* at its stamp: sample ``k + 1`` carries ``duty[k]`` and
``v_a[k]`` of the :class:`Recording` (where ``duty[k]`` is held over ``[t_k, t_{k+1})``).
:func:`~aeropend_ident.io.bag_writer.write_bag` shifts forward,
:func:`read_bag` shifts back. The first sample's effort is the
duty before the recording started (``meta["duty_before_start"]``, NaN when unknown); the duty of
the last sample comes from the command topic (the last command received at most ten
sample periods after the last sample), else it is held from ``duty[N-2]``; ``v_a[N-1]`` is not
on the wire and is held from
``v_a[N-2]`` (both noted in ``meta["held_tail"]``).

Precision: ``BatteryState.voltage`` / ``current`` are ``float32`` on the wire, so ``v_a`` and
``i_a`` survive a round trip only to float32 precision (relative 6e-8); every ``JointState``
channel and the duty are float64 and survive bit-exactly. Stamps are integer nanoseconds:
``t`` survives to 0.5 ns.

Decoding
--------
:func:`read_bag` reads raw CDR bytes with ``rosbags``. The default ``decoder="vectorized"``
decodes all messages of one layout at once with NumPy (the layout is derived from the first
message, re-encoded and checked byte for byte; any message that deviates is decoded with
``typestore.deserialize_cdr``). ``decoder="typestore"`` decodes every message with
``typestore.deserialize_cdr`` (the reference path; both give identical results).
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin

from aeropend_ident.errors import BagError, BagLossWarning
from aeropend_ident.io.bag_codec import (
    decode_armature,
    decode_float64,
    decode_float64_array,
    decode_joint_states,
    split_label_entry,
    typestore,
)
from aeropend_ident.io.bag_reader import (
    RawBagReader,
    corruption_error,
)
from aeropend_ident.io.integrity.loss import loss_warning, stored_loss
from aeropend_sim.contract import (
    CLOCK_QOS_DEPTH,
    COMMAND_QOS_DEPTH,
    EXTRA_CHANNELS,
    REFERENCE_CHANNEL,
    SAMPLE_QOS_DEPTH,
    SECOND_AXIS_FIELDS,
    TOPIC_ARMATURE,
    TOPIC_CLOCK,
    TOPIC_DUTY_CYCLE,
    TOPIC_EXTRA_CHANNELS,
    TOPIC_JOINT_STATES,
    TOPIC_REFERENCE,
    TYPE_ARMATURE,
    TYPE_DUTY_CYCLE,
    TYPE_EXTRA_CHANNELS,
    TYPE_JOINT_STATES,
    TYPE_REFERENCE,
    ContractError,
)
from aeropend_sim.recording import Recording, RecordingError

__all__ = [
    "CLOCK_QOS",
    "CLOCK_QOS_RELIABLE",
    "COMMAND_QOS",
    "INFINITE_TIME",
    "SAMPLE_QOS",
    "SAMPLE_QOS_RELIABLE",
    "qos_for_topic",
    "read_bag",
]

#: rmw "infinite" duration (``RMW_DURATION_INFINITE``, 2^63 − 1 ns) as rosbag2 (Jazzy) writes it
#: into metadata.yaml.
INFINITE_TIME = QosTime(sec=9223372036, nsec=854775807)


def _qos(reliability: QosReliability, depth: int, history: QosHistory = QosHistory.KEEP_LAST) -> Qos:
    return Qos(
        history=history,
        depth=depth,
        reliability=reliability,
        durability=QosDurability.VOLATILE,
        deadline=INFINITE_TIME,
        lifespan=INFINITE_TIME,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=INFINITE_TIME,
        avoid_ros_namespace_conventions=False,
    )


#: Offered QoS of sample topics: ``qos_profile_sensor_data`` (best effort, keep last 5, volatile).
SAMPLE_QOS: Qos = _qos(QosReliability.BEST_EFFORT, SAMPLE_QOS_DEPTH)
#: Offered QoS of sample topics published in lock-step mode (reliable, keep all, volatile).
SAMPLE_QOS_RELIABLE: Qos = _qos(QosReliability.RELIABLE, 0, QosHistory.KEEP_ALL)
#: Offered QoS of the duty-cycle command topic (reliable, keep last 10, volatile).
COMMAND_QOS: Qos = _qos(QosReliability.RELIABLE, COMMAND_QOS_DEPTH)
#: Offered QoS of /clock published by ``play --clock`` or a real-time plant (reliable, keep last 10).
CLOCK_QOS: Qos = _qos(QosReliability.RELIABLE, CLOCK_QOS_DEPTH)
#: Offered QoS of the lock-step plant's /clock (reliable, keep all, volatile).
CLOCK_QOS_RELIABLE: Qos = _qos(QosReliability.RELIABLE, 0, QosHistory.KEEP_ALL)

_STORAGE_PLUGINS = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
_CUSTOM_META = "aeropend.meta"
_CUSTOM_RIG = "aeropend.rig_name"
_CUSTOM_SOURCE = "aeropend.source"
#: Key of the stored ``meta`` that holds the extra channels' units (written by ``write_bag``).
EXTRA_UNITS_META = "extra_units"


def qos_for_topic(topic: str, lockstep: bool = False) -> Qos:
    """Offered QoS the contract prescribes for ``topic``.

    Parameters
    ----------
    topic : str
        Topic name (a namespace prefix is allowed).
    lockstep : bool
        True for sample topics and /clock published by the simulator in lock-step mode (reliable).

    Returns
    -------
    rosbags.interfaces.Qos
        :data:`CLOCK_QOS` for ``/clock`` (:data:`CLOCK_QOS_RELIABLE` when ``lockstep``),
        :data:`COMMAND_QOS` for the duty-cycle and reference topics, else :data:`SAMPLE_QOS` (or
        :data:`SAMPLE_QOS_RELIABLE` when ``lockstep``).
    """
    if topic == TOPIC_CLOCK:
        return CLOCK_QOS_RELIABLE if lockstep else CLOCK_QOS
    if topic.endswith((TOPIC_DUTY_CYCLE, TOPIC_REFERENCE)):
        return COMMAND_QOS
    return SAMPLE_QOS_RELIABLE if lockstep else SAMPLE_QOS


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def _read_raw(path: Path, topics: Sequence[str]) -> tuple[dict[str, list[bytes]], dict[str, list[int]],
                                                         dict[str, str], dict[str, int], RawBagReader]:
    """Raw messages and log times per topic; also the bag's topic->type map, the message counts
    it declares and the (closed) reader, which tells the storage and any recovery."""
    raws: dict[str, list[bytes]] = {t: [] for t in topics}
    logs: dict[str, list[int]] = {t: [] for t in topics}
    with RawBagReader(path) as reader:
        types = {name: info.msgtype for name, info in reader.topics.items()}
        declared = {name: info.count for name, info in reader.topics.items()}
        wanted = [t for t in topics if t in reader.topics]
        if wanted:
            for topic, logtime, raw in reader.messages(wanted):
                raws[topic].append(raw)
                logs[topic].append(logtime)
    return raws, logs, types, declared, reader


def _read_contract_topics(
    path: Path, namespace: str, decoder: str,
) -> tuple[tuple[str, ...], dict[str, list[Any]], dict[str, list[int]], str, tuple[Any, ...]]:
    """The contract topics of a bag, checked and decoded (:func:`read_bag`, first step).

    Returns the topic names (joint_states, armature, duty_cycle, reference, extra_channels), the
    raw messages and log times per topic, the (closed) reader and the decoded columns (None for an
    absent topic other than joint_states).
    """
    t_js, t_arm, t_cmd, t_ref, t_ext = (namespace + t for t in (
        TOPIC_JOINT_STATES, TOPIC_ARMATURE, TOPIC_DUTY_CYCLE, TOPIC_REFERENCE, TOPIC_EXTRA_CHANNELS))
    raws, logs, types, declared, reader = _read_raw(path, [t_js, t_arm, t_cmd, t_ref, t_ext])
    expected = {t_js: TYPE_JOINT_STATES, t_arm: TYPE_ARMATURE, t_cmd: TYPE_DUTY_CYCLE, t_ref: TYPE_REFERENCE,
                t_ext: TYPE_EXTRA_CHANNELS}
    for topic, typ in expected.items():
        if topic in types and types[topic] != typ:
            raise BagError(f"bag '{path}': topic {topic} has type {types[topic]}, expected {typ}")
    if t_js not in types:
        raise BagError(f"bag '{path}' has no {t_js} topic (topics present: {sorted(types) or 'none'}); "
                       f"a contract bag needs {TYPE_JOINT_STATES} samples on it")
    for topic in expected:
        if topic in declared and declared[topic] != len(raws[topic]):
            raise BagError(f"bag '{path}' is truncated: its metadata declares {declared[topic]} message(s) "
                           f"on {topic} but only {len(raws[topic])} could be read")
    if len(raws[t_js]) < 2:
        raise BagError(f"bag '{path}': {t_js} has {len(raws[t_js])} message(s); need at least 2 samples")
    vec = decoder == "vectorized"
    if decoder not in ("vectorized", "typestore"):
        raise BagError(f"unknown decoder {decoder!r}; expected 'vectorized' or 'typestore'")
    try:
        js = decode_joint_states(raws[t_js], vec)
        arm = decode_armature(raws[t_arm], vec) if raws[t_arm] else None
        cmd = decode_float64(raws[t_cmd], vec) if raws[t_cmd] else None
        ref = decode_float64(raws[t_ref], vec) if raws[t_ref] else None
        ext = decode_float64_array(raws[t_ext], vec) if raws[t_ext] else None
    except ContractError as exc:
        raise BagError(f"bag '{path}': {exc}") from exc
    except Exception as exc:
        topic, k = _first_undecodable(raws, (t_js, t_arm, t_cmd, t_ref, t_ext))
        log = logs[topic][k] if topic is not None else None
        which = f"message {k} of {topic}" if topic is not None else "a message"
        raise corruption_error(path, f"{which} cannot be decoded ({type(exc).__name__}: {exc})", log) from exc
    return (t_js, t_arm, t_cmd, t_ref, t_ext), raws, logs, reader, (js, arm, cmd, ref, ext)


def _first_undecodable(raws: dict[str, list[Any]], topics: Sequence[str]) -> tuple[str | None, int]:
    """The first message the typestore cannot deserialise: (topic, index), or (None, -1)."""
    ts = typestore()
    types = dict(zip(topics, (TYPE_JOINT_STATES, TYPE_ARMATURE, TYPE_DUTY_CYCLE, TYPE_REFERENCE,
                              TYPE_EXTRA_CHANNELS), strict=True))
    for topic in topics:
        for k, raw in enumerate(raws.get(topic, [])):
            try:
                ts.deserialize_cdr(raw, types[topic])
            except Exception:
                return topic, k
    return None, -1


def _sample_of(js_log: np.ndarray, log: np.ndarray) -> np.ndarray:
    """The sample each message without a header belongs to, from log times (in order).

    One message per sample (what ``write_bag`` writes, replayed and re-recorded or not): the k-th
    belongs to sample k, whatever the order a recorder received the topics in. Otherwise (a live
    reference published when it changes, lost messages): the sample logged nearest to it.
    """
    if log.size == js_log.size:
        return np.arange(log.size)
    k = np.clip(np.searchsorted(js_log, log), 1, max(js_log.size - 1, 1))
    before = js_log[k - 1]
    return np.where(np.abs(log - before) <= np.abs(js_log[np.minimum(k, js_log.size - 1)] - log), k - 1, k)


def _extra_channels(cols: dict[str, np.ndarray], js_log: np.ndarray, ref: Any, ref_log: Sequence[int],
                    ext: Any, ext_log: Sequence[int], stored_units: Any) -> tuple[dict[str, np.ndarray],
                                                                               dict[str, str]]:
    """A bag's extra channels per sample (:func:`read_bag`) and their units.

    The second joint's φ, φ̇ come with the samples; a reference or labelled array message (no
    header stamp) belongs to its sample (:func:`_sample_of`); the
    reference then holds until the next one (latest wins, as a controller reads it; NaN before the
    first). All-NaN channels
    are left out. Units: :data:`~aeropend_sim.contract.EXTRA_CHANNELS`, else the array's label
    (``name [unit]``), else the bag's stored ``extra_units``, else ``"unknown"``.
    """
    n = js_log.size
    extra = {ch: cols[ch] for ch in SECOND_AXIS_FIELDS}
    if ref is not None:  # each message at its sample, then held (latest wins)
        r_log = np.asarray(ref_log, dtype=np.int64)
        r_order = np.argsort(r_log, kind="stable")
        at = _sample_of(js_log, r_log[r_order])
        last = np.full(n, -1)
        last[at] = np.arange(at.size)  # the last message per sample (log-time order)
        last = np.maximum.accumulate(last)
        values = np.full(n, np.nan)
        values[last >= 0] = ref.columns["data"][r_order][last[last >= 0]]
        extra[REFERENCE_CHANNEL] = values
    labelled: dict[str, str] = {}
    if ext is not None:
        k = _sample_of(js_log, np.asarray(ext_log, dtype=np.int64))
        ok = np.ones(k.size, dtype=bool)
        for entry, col in ext.columns.items():
            name, unit = split_label_entry(entry)
            values = extra.get(name, np.full(n, np.nan))
            values[k[ok & np.isfinite(col)]] = col[ok & np.isfinite(col)]
            extra[name] = values
            if unit:
                labelled[name] = unit
    extra = {k: v for k, v in extra.items() if np.isfinite(v).any()}
    stored = stored_units if isinstance(stored_units, dict) else {}
    units = {k: EXTRA_CHANNELS[k][0] if k in EXTRA_CHANNELS
             else str(labelled.get(k) or stored.get(k) or "unknown") for k in extra}
    return extra, units


def _drop_republished(path: Path, t_js: str, cols: dict[str, np.ndarray], order: np.ndarray,
                      stamps: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, int]:
    """Drop identical re-published samples (:func:`read_bag`); refuse two different ones at one stamp."""
    dup = np.flatnonzero(np.diff(stamps) == 0)
    republished = 0
    if dup.size:
        # A lock-step plant re-publishes its last sample while it waits for a command: identical
        # copies are dropped; two different samples with one stamp are a contract violation.
        same = np.ones(dup.size, dtype=bool)
        for v in cols.values():
            a, b = v[dup], v[dup + 1]
            same &= (a == b) | (np.isnan(a) & np.isnan(b)) if v.dtype.kind == "f" else a == b
        if not same.all():
            k = int(dup[np.flatnonzero(~same)[0]])
            raise BagError(f"bag '{path}': two different {t_js} samples share the stamp {int(stamps[k])} ns; "
                           "expected one sample per sample instant")
        keep = np.ones(stamps.size, dtype=bool)
        keep[dup + 1] = False
        order = order[keep]  # also selects the kept messages' log times below
        cols = {k: v[keep] for k, v in cols.items()}
        stamps = cols["stamp"]
        republished = int(dup.size)
        if stamps.size < 2:
            raise BagError(f"bag '{path}': {t_js} has {stamps.size} distinct sample(s) "
                           f"({republished} re-published copies dropped); need at least 2 samples")
    return cols, order, stamps, republished


def _pair_armature(arm: Any, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Armature v_a / i_a paired with the samples by identical stamp, which samples are paired and
    the orphan count (armature messages without a sample)."""
    n = stamps.size
    v_wire = np.full(n, np.nan)
    i_a = np.full(n, np.nan)
    hit = np.zeros(n, dtype=bool)
    orphan = 0
    if arm is not None:
        a_stamp = arm.columns["stamp"]
        a_order = np.argsort(a_stamp, kind="stable")
        a_stamp = a_stamp[a_order]
        pos = np.clip(np.searchsorted(a_stamp, stamps), 0, a_stamp.size - 1)
        hit = a_stamp[pos] == stamps
        v_wire[hit] = arm.columns["v_a"][a_order][pos[hit]]
        i_a[hit] = arm.columns["i_a"][a_order][pos[hit]]
        orphan = int(a_stamp.size - np.unique(pos[hit]).size)
    return v_wire, i_a, hit, orphan


def _cut_tail(paired: np.ndarray, recovered: bool) -> int:
    """Samples at the end of a truncated bag that lost their armature message to the cut (the bag
    pairs the samples before them): :func:`read_bag` drops them rather than keep NaN v_a / i_a."""
    if not recovered or not paired.any():
        return 0
    return int(paired.size - 1 - np.flatnonzero(paired)[-1])


def _duty_of_samples(effort: np.ndarray, stamps: np.ndarray, js_log: np.ndarray, cmd: Any, cmd_log: Any
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """duty[k] of :func:`read_bag` (N,): the applied effort carried by sample k+1 (wire
    convention); where that is NaN (bags whose duty exists only as commands), the last command
    received before the interval [t_k, t_k+1) ended, judged on the recorder's clock (log times of
    joint_states and commands are comparable even when header stamps come from another clock).

    Returns
    -------
    duty, use_effort, use_command, gap_after : ndarray, shape (N,)
        The duty and, per sample, whether it came from the effort or from a command, and whether a
        gap in the stamps follows it.
    """
    d_next = np.concatenate((effort[1:], [np.nan]))
    dstamp = np.diff(stamps)
    gap_after = np.concatenate((dstamp > 1.5 * np.median(dstamp), [False]))
    d_cmd = np.full(stamps.size, np.nan)
    if cmd is not None:
        c_log = np.asarray(cmd_log, dtype=np.int64)
        c_val = cmd.columns["data"]
        c_order = np.argsort(c_log, kind="stable")
        c_log, c_val = c_log[c_order], c_val[c_order]
        log_step = int(np.median(np.diff(js_log)))
        # last sample: its command may trail it (recorder lag, DDS delivery order): allow 10 steps
        bound = np.concatenate((js_log[1:], [js_log[-1] + 10 * log_step]))
        bound[gap_after] = js_log[gap_after] + log_step
        j = np.searchsorted(c_log, bound, side="left") - 1  # last command logged before the bound
        d_cmd[j >= 0] = c_val[j[j >= 0]]
    use_eff = np.isfinite(d_next)
    use_cmd = ~use_eff & np.isfinite(d_cmd)
    duty = np.where(use_eff, d_next, d_cmd)
    return duty, use_eff, use_cmd, gap_after


def read_bag(path: str | Path, *, namespace: str = "",
             decoder: Literal["vectorized", "typestore"] = "vectorized",
             require_duty: bool = True) -> Recording:
    """Read a contract bag into a :class:`Recording`.

    Works on bags written by :func:`write_bag`, by the ``aeropend_recorder`` node or by
    ``ros2 bag record`` (MCAP or SQLite3; a bag directory or a bare ``.mcap`` / ``.db3`` file).

    Samples are the ``joint_states`` messages ordered by header stamp; ``armature`` messages are
    paired by identical stamp (unpaired samples keep NaN ``v_a`` / ``i_a`` and are counted in
    ``meta["unmatched_joint_states"]``; armature messages without a sample in
    ``meta["orphan_armature"]``). The applied duty ``duty[k]`` is the motor effort of sample
    ``k + 1`` (wire convention), and ``v_a[k]`` its armature voltage. Where that effort is NaN
    (bags whose duty exists only as commands) the last ``duty_cycle`` command *received before
    the interval ended* is used, comparing log (receive) times, which share one clock even when
    the stamps do not (replayed bags): the bound is the log time of sample ``k + 1`` (of sample
    ``k`` plus the median log step before a gap). Before a gap (stamp step > 1.5 × median, e.g.
    samples lost with best-effort QoS) the next received sample's effort is the duty applied at
    the *end* of the interval, which for lost samples may differ from the duty at its start;
    ``meta["duty_source"]["effort_after_gap"]`` counts those samples, ``meta["gaps"]`` the gaps.
    Channels that are NaN everywhere are absent from ``channels``.

    A truncated bag (storage cut short, :class:`RawBagReader`) is read as far as its messages
    are complete, with a :class:`~aeropend_ident.errors.BagTruncatedWarning`;
    ``meta["truncated"]`` says what was recovered and where the file ends, and samples at its end
    that lost their armature message to the cut are dropped (``incomplete_samples_dropped``).
    A bag directory without ``metadata.yaml`` is refused with a message naming its storage file
    (which can be given instead) and the ``reindex`` command.

    Parameters
    ----------
    path : str or Path
        Bag directory (or ``.mcap`` / ``.db3`` file).
    namespace : str
        Topic prefix used when the bag was recorded (e.g. ``"/rig1"``).
    decoder : {"vectorized", "typestore"}
        CDR decoding path (identical results; see module doc).
    require_duty : bool
        Raise when no duty information at all is in the bag.

    Returns
    -------
    Recording
        ``t`` [s] from the first sample, ``stamp0_ns`` its absolute stamp, ``source`` the bag
        path, ``meta`` the metadata stored by :func:`write_bag` (if any) plus read statistics.

    Raises
    ------
    BagError
        If ``path`` is not a bag, has no ``metadata.yaml``, is corrupt or truncated with fewer
        than 2 samples recoverable, ``joint_states`` is missing or
        has the wrong type, messages violate the contract, two samples share a stamp, theta
        has NaNs, or (``require_duty``) there is no duty information.
    """
    path = Path(path)
    (t_js, t_arm, t_cmd, t_ref, t_ext), raws, logs, reader, (js, arm, cmd, ref, ext) = _read_contract_topics(
        path, namespace, decoder)

    cols = js.columns
    order = np.argsort(cols["stamp"], kind="stable")
    cols = {k: v[order] for k, v in cols.items()}
    stamps = cols["stamp"]
    cols, order, stamps, republished = _drop_republished(path, t_js, cols, order, stamps)
    n = stamps.size
    bad = np.flatnonzero(~np.isfinite(cols["theta"]))
    if bad.size:
        raise BagError(f"bag '{path}': theta (pendulum position) is NaN/inf in {bad.size} of {n} samples, "
                       f"first at sample {int(bad[0])} (stamp {int(stamps[bad[0]])} ns); "
                       "the angle must be measured")

    meta: dict[str, Any] = _stored_meta(reader.custom_data)
    if reader.recovery is not None:
        meta["truncated"] = reader.recovery
    if republished:
        meta["republished_samples_dropped"] = republished
    v_wire, i_a, paired, orphan = _pair_armature(arm, stamps)
    cut = _cut_tail(paired, reader.recovery is not None)
    if cut and n - cut >= 2:
        n -= cut
        cols = {k: v[:n] for k, v in cols.items()}
        stamps, order, v_wire, i_a, paired = stamps[:n], order[:n], v_wire[:n], i_a[:n], paired[:n]
        meta["truncated"]["incomplete_samples_dropped"] = cut
    unmatched = int(n - paired.sum())

    # duty[k]: the effort sample k+1 carries, else the last command (_duty_of_samples)
    js_log = np.asarray(logs[t_js], dtype=np.int64)[order]
    effort = cols["effort"]
    duty, use_eff, use_cmd, gap_after = _duty_of_samples(effort, stamps, js_log, cmd,
                                                         None if cmd is None else logs[t_cmd])
    n_after_gap = int((gap_after & use_eff).sum())
    held: list[str] = []
    if not np.isfinite(duty[-1]) and np.isfinite(duty[-2]):
        duty[-1] = duty[-2]
        held.append("duty")
    n_cmd = int(use_cmd.sum())
    if require_duty and not np.isfinite(duty).any():
        raise BagError(f"bag '{path}' has no duty information: the motor effort of {t_js} is NaN in every "
                       f"sample and {t_cmd} has {len(raws[t_cmd])} message(s) before the last sample")
    v_a = np.concatenate((v_wire[1:], [np.nan]))
    if np.isfinite(v_a[-2]):
        v_a[-1] = v_a[-2]
        held.append("v_a")

    channels_all = {"theta": cols["theta"], "theta_dot": cols["theta_dot"],
                    "omega_rotor": cols["omega_rotor"], "omega_prop": cols["omega_prop"],
                    "i_a": i_a, "v_a": v_a}
    channels = {k: v for k, v in channels_all.items() if np.isfinite(v).any()}
    extra, units = _extra_channels(cols, js_log, ref, logs[t_ref], ext, logs[t_ext],
                                   meta.pop(EXTRA_UNITS_META, None))
    if np.isfinite(effort[0]):
        meta["duty_before_start"] = float(effort[0])
    meta.update({
        "bag": str(path),
        "storage": reader.storage,
        "message_counts": {t: len(raws[t]) for t in (t_js, t_arm, t_cmd, t_ref, t_ext)
                           if raws[t] or t in (t_js, t_arm, t_cmd)},
        "unmatched_joint_states": unmatched if arm is not None else n,
        "orphan_armature": orphan,
        "duty_source": {"effort": int(use_eff.sum()) - n_after_gap, "command": n_cmd,
                        "effort_after_gap": n_after_gap,
                        "missing": int((~np.isfinite(duty)).sum())},
        "gaps": int(gap_after.sum()),
        "held_tail": held,
        "cdr_fallback_messages": js.fallback + (arm.fallback if arm else 0) + (cmd.fallback if cmd else 0),
    })
    _check_loss(path, reader.custom_data, stamps, js_log, t_js, meta)
    try:
        return Recording(t=(stamps - stamps[0]) / 1e9, duty=duty, channels=channels, source=str(path),
                         stamp0_ns=int(stamps[0]), meta=meta, extra=extra, extra_units=units)
    except RecordingError as exc:  # pragma: no cover - stamps are checked above
        raise BagError(f"bag '{path}': {exc}") from exc


def _check_loss(path: Path, custom: dict[str, Any], stamps: np.ndarray, js_log: np.ndarray, t_js: str,
                meta: dict[str, Any]) -> None:
    """``meta["loss"]``: the loss ``record`` counted (:mod:`aeropend_ident.io.integrity.loss`), or for a
    recorded bag without that count (killed then reindexed, another recorder; not a bag written
    from a recording or a CSV log) the samples missing between the joint_states stamps; a
    :class:`~aeropend_ident.errors.BagLossWarning` above the threshold."""
    loss = stored_loss(custom)
    if loss is None and _CUSTOM_META not in custom and len(stamps) > 2:  # a recording, not an import
        step = np.diff(stamps)
        period = float(np.median(step))
        n_lost = np.where(step > 1.5 * period, np.round(step / period) - 1, 0).astype(np.int64)
        at = np.flatnonzero(n_lost)
        lost = int(n_lost.sum())
        base = int(js_log[0])
        loss = {t_js: {"received": len(stamps), "lost": lost, "expected": len(stamps) + lost,
                       "fraction": lost / (len(stamps) + lost), "method": "stamps", "period_s": period / 1e9,
                       "gaps": int(at.size),
                       "first_gaps": [[round((int(js_log[k]) - base) / 1e9, 4),
                                       round((int(js_log[k + 1]) - base) / 1e9, 4), int(n_lost[k])]
                                      for k in at[:20]]}}
    if loss is None:
        return
    meta["loss"] = loss
    text = loss_warning(f"bag '{path}'", loss)
    if text is not None:
        warnings.warn(text, BagLossWarning, stacklevel=3)


def _stored_meta(custom: dict[str, Any]) -> dict[str, Any]:
    """Metadata :func:`write_bag` stored in ``custom_data`` (empty for other bags)."""
    meta: dict[str, Any] = {}
    if _CUSTOM_META in custom:
        try:
            loaded = json.loads(custom[_CUSTOM_META])
            if isinstance(loaded, dict):
                meta.update(loaded)
        except json.JSONDecodeError:
            meta["custom_data_unparsed"] = custom[_CUSTOM_META]
    if _CUSTOM_RIG in custom:
        meta["rig_name"] = custom[_CUSTOM_RIG]
    if _CUSTOM_SOURCE in custom:
        meta.setdefault("original_source", custom[_CUSTOM_SOURCE])
    return meta
