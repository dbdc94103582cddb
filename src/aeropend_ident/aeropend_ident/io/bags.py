"""Contract bags <-> :class:`~aeropend_sim.recording.Recording` (pure Python, no rclpy).

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
:func:`write_bag` shifts forward, :func:`read_bag` shifts back. The first sample's effort is the
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
import math
import shutil
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
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
from rosbags.typesys import Stores, get_typestore

from aeropend_ident.errors import BagError
from aeropend_sim.contract import (
    COMMAND_QOS_DEPTH,
    JOINT_NAMES,
    SAMPLE_QOS_DEPTH,
    TOPIC_ARMATURE,
    TOPIC_DUTY_CYCLE,
    TOPIC_JOINT_STATES,
    TYPE_ARMATURE,
    TYPE_DUTY_CYCLE,
    TYPE_JOINT_STATES,
    ContractError,
    Sample,
)
from aeropend_sim.recording import MEASURED_CHANNELS, Recording, RecordingError

from .mcap_jazzy import JazzyWriter

__all__ = [
    "COMMAND_QOS",
    "SAMPLE_QOS",
    "SAMPLE_QOS_RELIABLE",
    "BagError",
    "BagSink",
    "BagTopic",
    "RawBagReader",
    "bag_metadata",
    "decode_armature",
    "decode_float64",
    "decode_joint_states",
    "encode_armature",
    "encode_float64",
    "encode_joint_states",
    "playback_deadlines",
    "qos_for_topic",
    "read_bag",
    "typestore",
    "write_bag",
]

Storage = Literal["mcap", "sqlite3"]

#: rmw "infinite" duration as rosbag2 (Jazzy) writes it into metadata.yaml.
_INFINITE = QosTime(sec=9223372036, nsec=854775807)


def _qos(reliability: QosReliability, depth: int, history: QosHistory = QosHistory.KEEP_LAST) -> Qos:
    return Qos(
        history=history,
        depth=depth,
        reliability=reliability,
        durability=QosDurability.VOLATILE,
        deadline=_INFINITE,
        lifespan=_INFINITE,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=_INFINITE,
        avoid_ros_namespace_conventions=False,
    )


#: Offered QoS of sample topics: ``qos_profile_sensor_data`` (best effort, keep last 5, volatile).
SAMPLE_QOS: Qos = _qos(QosReliability.BEST_EFFORT, SAMPLE_QOS_DEPTH)
#: Offered QoS of sample topics published in lock-step mode (reliable, keep all, volatile).
SAMPLE_QOS_RELIABLE: Qos = _qos(QosReliability.RELIABLE, 0, QosHistory.KEEP_ALL)
#: Offered QoS of the duty-cycle command topic (reliable, keep last 10, volatile).
COMMAND_QOS: Qos = _qos(QosReliability.RELIABLE, COMMAND_QOS_DEPTH)

_STORAGE_PLUGINS = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
_CUSTOM_META = "aeropend.meta"
_CUSTOM_RIG = "aeropend.rig_name"
_CUSTOM_SOURCE = "aeropend.source"
_NAN = math.nan


@lru_cache(maxsize=1)
def typestore() -> Any:
    """The ROS 2 Jazzy ``rosbags`` typestore (cached)."""
    return get_typestore(Stores.ROS2_JAZZY)


def qos_for_topic(topic: str, lockstep: bool = False) -> Qos:
    """Offered QoS the contract prescribes for ``topic``.

    Parameters
    ----------
    topic : str
        Topic name (a namespace prefix is allowed).
    lockstep : bool
        True for sample topics published by the simulator in lock-step mode (reliable).

    Returns
    -------
    rosbags.interfaces.Qos
        :data:`COMMAND_QOS` for the duty-cycle topic, else :data:`SAMPLE_QOS` (or
        :data:`SAMPLE_QOS_RELIABLE` when ``lockstep``).
    """
    if topic.endswith(TOPIC_DUTY_CYCLE):
        return COMMAND_QOS
    return SAMPLE_QOS_RELIABLE if lockstep else SAMPLE_QOS


# --------------------------------------------------------------------------------------------
# CDR codec (little-endian XCDR1, the encoding rclpy and rosbag2 use)
# --------------------------------------------------------------------------------------------

_CDR_LE = b"\x00\x01\x00\x00"


class _Buf:
    """Tiny CDR writer that records where each numeric slot lives (offsets include the 4-byte
    encapsulation header)."""

    def __init__(self) -> None:
        self.b = bytearray(_CDR_LE)
        self.pads: list[tuple[int, int]] = []  # (offset, length) of alignment padding

    def align(self, n: int) -> None:
        pad = (-(len(self.b) - 4)) % n
        if pad:
            self.pads.append((len(self.b), pad))
        self.b.extend(b"\x00" * pad)

    def u32(self, v: int) -> int:
        self.align(4)
        off = len(self.b)
        self.b.extend(struct.pack("<I", v))
        return off

    def string(self, s: str) -> None:
        data = s.encode("utf-8") + b"\x00"
        self.u32(len(data))
        self.b.extend(data)

    def slot(self, size: int, count: int = 1) -> int:
        self.align(size)
        off = len(self.b)
        self.b.extend(b"\x00" * (size * count))
        return off

    def f64_seq(self, n: int) -> int:
        self.u32(n)
        return self.slot(8, n) if n else len(self.b)


@dataclass(frozen=True)
class _Layout:
    """Byte layout of one message shape: template bytes and offsets of the variable slots."""

    template: bytes
    #: name -> (offset, dtype, count); stamp fields are "sec" (<i4) and "nanosec" (<u4).
    slots: dict[str, tuple[int, str, int]]
    #: alignment padding (offset, length): zero when we write, arbitrary in rclpy/Fast-CDR output.
    pads: tuple[tuple[int, int], ...] = ()

    @property
    def size(self) -> int:
        return len(self.template)

    def variable_mask(self) -> np.ndarray:
        mask = np.zeros(self.size, dtype=bool)
        for off, dtype, count in self.slots.values():
            mask[off:off + np.dtype(dtype).itemsize * count] = True
        for off, length in self.pads:
            mask[off:off + length] = True
        return mask


def _header(buf: _Buf, frame_id: str) -> dict[str, tuple[int, str, int]]:
    slots = {"sec": (buf.slot(4), "<i4", 1), "nanosec": (buf.slot(4), "<u4", 1)}
    buf.string(frame_id)
    return slots


@lru_cache(maxsize=64)
def _joint_state_layout(frame_id: str, names: tuple[str, ...], n_pos: int, n_vel: int, n_eff: int) -> _Layout:
    buf = _Buf()
    slots = _header(buf, frame_id)
    buf.u32(len(names))
    for name in names:
        buf.string(name)
    slots["position"] = (buf.f64_seq(n_pos), "<f8", n_pos)
    slots["velocity"] = (buf.f64_seq(n_vel), "<f8", n_vel)
    slots["effort"] = (buf.f64_seq(n_eff), "<f8", n_eff)
    return _Layout(bytes(buf.b), slots, tuple(buf.pads))


_BATTERY_FLOATS = ("voltage", "temperature", "current", "charge", "capacity", "design_capacity", "percentage")


@lru_cache(maxsize=64)
def _armature_layout(frame_id: str, n_cell_v: int, n_cell_t: int, location: str, serial: str) -> _Layout:
    buf = _Buf()
    slots = _header(buf, frame_id)
    for name in _BATTERY_FLOATS:
        slots[name] = (buf.slot(4), "<f4", 1)
    slots["status"] = (buf.slot(1, 4), "u1", 4)  # status, health, technology, present
    buf.u32(n_cell_v)
    if n_cell_v:
        slots["cell_voltage"] = (buf.slot(4, n_cell_v), "<f4", n_cell_v)
    buf.u32(n_cell_t)
    if n_cell_t:
        slots["cell_temperature"] = (buf.slot(4, n_cell_t), "<f4", n_cell_t)
    buf.string(location)
    buf.string(serial)
    return _Layout(bytes(buf.b), slots, tuple(buf.pads))


_FLOAT64_LAYOUT = _Layout(_CDR_LE + b"\x00" * 8, {"data": (4, "<f8", 1)})


def _tile(layout: _Layout, n: int) -> np.ndarray:
    return np.tile(np.frombuffer(layout.template, dtype=np.uint8), (n, 1))


def _put(arr: np.ndarray, layout: _Layout, name: str, values: np.ndarray) -> None:
    off, dtype, count = layout.slots[name]
    width = np.dtype(dtype).itemsize * count
    view = arr[:, off:off + width].view(dtype)
    view[...] = np.asarray(values).reshape(view.shape)


def _get(arr: np.ndarray, layout: _Layout, name: str) -> np.ndarray:
    off, dtype, count = layout.slots[name]
    width = np.dtype(dtype).itemsize * count
    return np.ascontiguousarray(arr[:, off:off + width]).view(dtype).reshape(arr.shape[0], count)


def _rows(arr: np.ndarray) -> list[bytes]:
    data = arr.tobytes()
    size = arr.shape[1]
    return [data[i:i + size] for i in range(0, len(data), size)]


def _split_stamps(stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    sec, nanosec = np.divmod(np.asarray(stamps_ns, dtype=np.int64), 1_000_000_000)
    return sec, nanosec


def encode_joint_states(stamps_ns: np.ndarray, position: np.ndarray, velocity: np.ndarray,
                        effort: np.ndarray, frame_id: str = "aeropend",
                        names: Sequence[str] = JOINT_NAMES) -> list[bytes]:
    """CDR-serialise a batch of ``sensor_msgs/msg/JointState`` messages.

    Parameters
    ----------
    stamps_ns : ndarray of int, shape (N,)
        Header stamps [ns].
    position, velocity, effort : ndarray, shape (N, J)
        Per-joint values (J = ``len(names)``).
    frame_id : str
        ``header.frame_id``.
    names : sequence of str
        Joint names (default the contract's ``pendulum, motor, propeller``).

    Returns
    -------
    list of bytes
        N serialised messages, byte-identical to ``typestore.serialize_cdr``.
    """
    n, j = len(stamps_ns), len(names)
    layout = _joint_state_layout(frame_id, tuple(names), j, j, j)
    arr = _tile(layout, n)
    sec, nanosec = _split_stamps(stamps_ns)
    _put(arr, layout, "sec", sec)
    _put(arr, layout, "nanosec", nanosec)
    for key, val in (("position", position), ("velocity", velocity), ("effort", effort)):
        _put(arr, layout, key, np.asarray(val, dtype=float).reshape(n, j))
    return _rows(arr)


def encode_armature(stamps_ns: np.ndarray, voltage: np.ndarray, current: np.ndarray,
                    frame_id: str = "aeropend") -> list[bytes]:
    """CDR-serialise a batch of ``sensor_msgs/msg/BatteryState`` armature messages.

    ``voltage`` [V] and ``current`` [A] (shape (N,)) are stored as float32 (the message's field
    type); every other float is NaN, status/health/technology unknown (0), ``present`` True.
    """
    n = len(stamps_ns)
    layout = _armature_layout(frame_id, 0, 0, "", "")
    arr = _tile(layout, n)
    sec, nanosec = _split_stamps(stamps_ns)
    _put(arr, layout, "sec", sec)
    _put(arr, layout, "nanosec", nanosec)
    for name in _BATTERY_FLOATS:
        _put(arr, layout, name, np.full(n, np.nan, dtype=np.float32))
    _put(arr, layout, "voltage", np.asarray(voltage, dtype=np.float32))
    _put(arr, layout, "current", np.asarray(current, dtype=np.float32))
    _put(arr, layout, "status", np.tile(np.array([0, 0, 0, 1], dtype=np.uint8), (n, 1)))
    return _rows(arr)


def encode_float64(values: np.ndarray) -> list[bytes]:
    """CDR-serialise a batch of ``std_msgs/msg/Float64`` messages (shape (N,))."""
    arr = _tile(_FLOAT64_LAYOUT, len(values))
    _put(arr, _FLOAT64_LAYOUT, "data", np.asarray(values, dtype=float))
    return _rows(arr)


@dataclass
class _Decoded:
    """Columns decoded from one topic; row order = message order."""

    columns: dict[str, np.ndarray]
    fallback: int = 0  # messages decoded by typestore.deserialize_cdr


def _stamp_ns(sec: np.ndarray, nanosec: np.ndarray) -> np.ndarray:
    return sec.astype(np.int64) * 1_000_000_000 + nanosec.astype(np.int64)


def _pick_joint(values: np.ndarray, names: list[str], joint: str, what: str) -> np.ndarray:
    """Column of ``joint`` from (N, J) values; NaN when the array is empty (contract rule)."""
    if values.shape[1] == 0:
        return np.full(values.shape[0], np.nan)
    if values.shape[1] != len(names):
        raise ContractError(f"joint_states.{what} has {values.shape[1]} entries, expected {len(names)} "
                            "(one per name)")
    return values[:, names.index(joint)].astype(float)


def _js_columns(stamps: np.ndarray, names: list[str], pos: np.ndarray, vel: np.ndarray,
                eff: np.ndarray) -> dict[str, np.ndarray]:
    missing = [j for j in JOINT_NAMES if j not in names]
    if missing:
        raise ContractError(f"joint_states lacks joint(s) {missing}; expected names {list(JOINT_NAMES)}, "
                            f"got {names}")
    return {
        "stamp": stamps,
        "theta": _pick_joint(pos, names, "pendulum", "position"),
        "theta_dot": _pick_joint(vel, names, "pendulum", "velocity"),
        "omega_rotor": _pick_joint(vel, names, "motor", "velocity"),
        "omega_prop": _pick_joint(vel, names, "propeller", "velocity"),
        "effort": _pick_joint(eff, names, "motor", "effort"),
    }


def _concat(parts: list[tuple[np.ndarray, dict[str, np.ndarray]]], n: int) -> dict[str, np.ndarray]:
    """Reassemble per-group columns into message order."""
    out: dict[str, np.ndarray] = {}
    for idx, cols in parts:
        for key, val in cols.items():
            if key not in out:
                out[key] = np.empty(n, dtype=val.dtype)
            out[key][idx] = val
    return out


def _group_by_length(raws: Sequence[bytes]) -> dict[int, np.ndarray]:
    lengths = np.fromiter((len(r) for r in raws), dtype=np.int64, count=len(raws))
    return {int(L): np.flatnonzero(lengths == L) for L in np.unique(lengths)}


def _decode_groups(raws: Sequence[bytes], msgtype: str, layout_of: Any, columns_of: Any,
                   vectorized: bool) -> _Decoded:
    """Shared driver: vectorised decoding per (length, layout) group, typestore fallback."""
    ts = typestore()
    n = len(raws)
    parts: list[tuple[np.ndarray, dict[str, np.ndarray]]] = []
    fallback = 0
    slow: list[int] = []
    groups = _group_by_length(raws) if vectorized else {-1: np.arange(n)}
    for length, idx in groups.items():
        if length < 0:
            slow.extend(idx.tolist())
            continue
        first = raws[int(idx[0])]
        layout = layout_of(ts.deserialize_cdr(first, msgtype)) if first[:4] == _CDR_LE else None
        # DDS pads serialised payloads to a multiple of 4 bytes: up to 3 trailing bytes are ignored
        if layout is None or not layout.size <= length < layout.size + 4:
            slow.extend(idx.tolist())
            continue
        arr = np.frombuffer(b"".join(raws[int(i)] for i in idx), dtype=np.uint8).reshape(len(idx), length)
        arr = arr[:, :layout.size]
        fixed = ~layout.variable_mask()
        tmpl = np.frombuffer(layout.template, dtype=np.uint8)[fixed]
        ok = np.all(arr[:, fixed] == tmpl, axis=1)
        if not ok.all():
            slow.extend(idx[~ok].tolist())
            arr, idx = arr[ok], idx[ok]
        if len(idx):
            parts.append((idx, columns_of(arr, layout)))
    if slow:
        fallback = len(slow)
        sidx = np.array(sorted(slow), dtype=np.int64)
        msgs = [ts.deserialize_cdr(raws[int(i)], msgtype) for i in sidx]
        parts.append((sidx, columns_of(msgs, None)))
    return _Decoded(_concat(parts, n), fallback)


def decode_joint_states(raws: Sequence[bytes], vectorized: bool = True) -> _Decoded:
    """Decode raw CDR ``JointState`` messages into contract columns.

    Returns
    -------
    _Decoded
        ``columns``: ``stamp`` (int64 ns), ``theta``, ``theta_dot``, ``omega_rotor``,
        ``omega_prop``, ``effort`` (wire duty), each shape (N,).

    Raises
    ------
    ContractError
        If a message lacks a contract joint or has inconsistent array lengths.
    """

    def layout_of(msg: Any) -> _Layout:
        return _joint_state_layout(msg.header.frame_id, tuple(msg.name), len(msg.position),
                                   len(msg.velocity), len(msg.effort))

    def columns_of(data: Any, layout: _Layout | None) -> dict[str, np.ndarray]:
        if layout is not None:
            names = [s.decode() for s in _names_from_template(layout)]
            stamps = _stamp_ns(_get(data, layout, "sec")[:, 0], _get(data, layout, "nanosec")[:, 0])
            return _js_columns(stamps, names, _get(data, layout, "position"), _get(data, layout, "velocity"),
                               _get(data, layout, "effort"))
        cols = [
            _js_columns(np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec],
                                 dtype=np.int64),
                        list(m.name), np.asarray(m.position, dtype=float).reshape(1, -1),
                        np.asarray(m.velocity, dtype=float).reshape(1, -1),
                        np.asarray(m.effort, dtype=float).reshape(1, -1))
            for m in data
        ]
        return {k: np.concatenate([c[k] for c in cols]) for k in cols[0]}

    return _decode_groups(raws, TYPE_JOINT_STATES, layout_of, columns_of, vectorized)


def _names_from_template(layout: _Layout) -> list[bytes]:
    """Joint names stored in a JointState layout's template."""
    b = layout.template
    off = 12  # after encapsulation + stamp
    (flen,) = struct.unpack_from("<I", b, off)
    off += 4 + flen
    off += (-(off - 4)) % 4
    (count,) = struct.unpack_from("<I", b, off)
    off += 4
    names = []
    for _ in range(count):
        off += (-(off - 4)) % 4
        (slen,) = struct.unpack_from("<I", b, off)
        names.append(b[off + 4:off + 4 + slen - 1])
        off += 4 + slen
    return names


def decode_armature(raws: Sequence[bytes], vectorized: bool = True) -> _Decoded:
    """Decode raw CDR ``BatteryState`` messages: columns ``stamp`` (int64 ns), ``v_a`` [V],
    ``i_a`` [A] (float32 on the wire, returned as float64), each shape (N,)."""

    def layout_of(msg: Any) -> _Layout:
        return _armature_layout(msg.header.frame_id, len(msg.cell_voltage), len(msg.cell_temperature),
                                msg.location, msg.serial_number)

    def columns_of(data: Any, layout: _Layout | None) -> dict[str, np.ndarray]:
        if layout is not None:
            return {
                "stamp": _stamp_ns(_get(data, layout, "sec")[:, 0], _get(data, layout, "nanosec")[:, 0]),
                "v_a": _get(data, layout, "voltage")[:, 0].astype(float),
                "i_a": _get(data, layout, "current")[:, 0].astype(float),
            }
        return {
            "stamp": np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in data],
                              dtype=np.int64),
            "v_a": np.array([m.voltage for m in data], dtype=np.float32).astype(float),
            "i_a": np.array([m.current for m in data], dtype=np.float32).astype(float),
        }

    return _decode_groups(raws, TYPE_ARMATURE, layout_of, columns_of, vectorized)


def decode_float64(raws: Sequence[bytes], vectorized: bool = True) -> _Decoded:
    """Decode raw CDR ``std_msgs/Float64`` messages: column ``data``, shape (N,)."""

    def columns_of(data: Any, layout: _Layout | None) -> dict[str, np.ndarray]:
        if layout is not None:
            return {"data": _get(data, layout, "data")[:, 0].copy()}
        return {"data": np.array([m.data for m in data], dtype=float)}

    return _decode_groups(raws, TYPE_DUTY_CYCLE, lambda _m: _FLOAT64_LAYOUT, columns_of, vectorized)


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


def _prepare_target(path: Path, overwrite: bool) -> None:
    if not path.exists():
        return
    if not overwrite:
        raise BagError(f"bag '{path}' already exists; pass overwrite=True (or choose another path)")
    if path.is_dir() and ((path / "metadata.yaml").exists() or not any(path.iterdir())):
        shutil.rmtree(path)
        return
    raise BagError(f"refusing to overwrite '{path}': it exists and is not a rosbag2 directory "
                   "(no metadata.yaml)")


def _wire_arrays(rec: Recording) -> dict[str, np.ndarray]:
    """Per-message wire values of a recording (duty and v_a shifted by one sample)."""
    n = len(rec)
    nan = np.full(n, np.nan)
    ch = {name: rec.channels.get(name, nan) for name in MEASURED_CHANNELS}
    before_meta = rec.meta.get("duty_before_start")
    before = float(before_meta) if _is_number(before_meta) else np.nan
    effort = np.concatenate(([before], rec.duty[:-1]))
    v_wire = np.concatenate(([np.nan], ch["v_a"][:-1]))
    return {**ch, "effort": effort, "v_wire": v_wire}


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float, np.floating, np.integer)) and not isinstance(x, bool)


def write_bag(rec: Recording, path: str | Path, storage: Storage = "mcap", rig_name: str | None = None, *,
              frame_id: str = "aeropend", namespace: str = "", lockstep_qos: bool = False,
              stamp0_ns: int | None = None, overwrite: bool = False,
              encoder: Literal["vectorized", "typestore"] = "vectorized") -> Path:
    """Write a :class:`Recording` as a contract bag.

    Per sample k: a ``JointState`` on ``/aeropend/joint_states`` and a ``BatteryState`` on
    ``/aeropend/armature`` with the same header stamp ``stamp0_ns + round(t_k · 1e9)``, built
    like :meth:`aeropend_sim.contract.Sample.joint_state_fields` / ``armature_fields`` (channels
    the recording lacks are NaN; the duty and v_a shifted to the wire convention, see module
    doc), and the duty command ``duty[k]`` as ``std_msgs/Float64`` on ``/aeropend/duty_cycle``
    (NaN duties are not sent: NaN is not a valid command). Log time = header stamp.

    Parameters
    ----------
    rec : Recording
        The recording; ``rec.meta`` is stored as JSON in the bag's ``custom_data``.
    path : str or Path
        Bag directory to create.
    storage : {"mcap", "sqlite3"}
        rosbag2 storage plugin.
    rig_name : str, optional
        Rig name stored in ``custom_data`` (``aeropend.rig_name``).
    frame_id : str
        ``header.frame_id`` of the sample messages.
    namespace : str
        Prefix for every topic (e.g. ``"/rig1"``).
    lockstep_qos : bool
        Offer reliable QoS on the sample topics (what the simulator does in lock-step mode)
        instead of ``sensor_data`` (best effort).
    stamp0_ns : int, optional
        Absolute stamp of ``t = 0`` [ns] (default ``rec.stamp0_ns``).
    overwrite : bool
        Replace an existing bag directory at ``path``.
    encoder : {"vectorized", "typestore"}
        ``"typestore"`` builds every message from :class:`~aeropend_sim.contract.Sample`
        (``joint_state_fields()``, ``armature_fields()``) and ``typestore.serialize_cdr`` (the
        reference path); ``"vectorized"`` encodes all samples at once with NumPy. The bytes are
        identical.

    Returns
    -------
    Path
        The bag directory.

    Raises
    ------
    BagError
        On an unknown storage, an existing target, or stamps that are not strictly increasing
        after rounding to nanoseconds.
    """
    path = Path(path)
    if storage not in _STORAGE_PLUGINS:
        raise BagError(f"bag '{path}': unknown storage {storage!r}; "
                       f"expected one of {sorted(_STORAGE_PLUGINS)}")
    _prepare_target(path, overwrite)
    s0 = rec.stamp0_ns if stamp0_ns is None else int(stamp0_ns)
    stamps = s0 + np.round(rec.t * 1e9).astype(np.int64)
    if np.any(np.diff(stamps) <= 0):
        k = int(np.flatnonzero(np.diff(stamps) <= 0)[0]) + 1
        raise BagError(f"bag '{path}': stamps not strictly increasing at sample {k} after rounding to ns")
    w = _wire_arrays(rec)
    cmd_idx = np.flatnonzero(np.isfinite(rec.duty))
    if encoder == "vectorized":
        nan = np.full(len(rec), np.nan)
        js = encode_joint_states(
            stamps,
            position=np.column_stack([w["theta"], nan, nan]),
            velocity=np.column_stack([w["theta_dot"], w["omega_rotor"], w["omega_prop"]]),
            effort=np.column_stack([nan, w["effort"], nan]),
            frame_id=frame_id,
        )
        arm = encode_armature(stamps, w["v_wire"], w["i_a"], frame_id=frame_id)
        cmds = encode_float64(rec.duty[cmd_idx])
    elif encoder == "typestore":
        js, arm, cmds = _encode_via_samples(stamps, w, rec.duty[cmd_idx], frame_id)
    else:
        raise BagError(f"unknown encoder {encoder!r}; expected 'vectorized' or 'typestore'")
    ts = typestore()
    writer = JazzyWriter(path, version=9, storage_plugin=_STORAGE_PLUGINS[storage])
    try:
        writer.open()
        sample_qos = qos_for_topic(TOPIC_JOINT_STATES, lockstep_qos)
        c_js = writer.add_connection(namespace + TOPIC_JOINT_STATES, TYPE_JOINT_STATES, typestore=ts,
                                     offered_qos_profiles=[sample_qos])
        c_arm = writer.add_connection(namespace + TOPIC_ARMATURE, TYPE_ARMATURE, typestore=ts,
                                      offered_qos_profiles=[sample_qos])
        c_cmd = writer.add_connection(namespace + TOPIC_DUTY_CYCLE, TYPE_DUTY_CYCLE, typestore=ts,
                                      offered_qos_profiles=[COMMAND_QOS])
        meta = dict(rec.meta)
        if rig_name is not None:
            writer.set_custom_data(_CUSTOM_RIG, str(rig_name))
            meta["rig_name"] = rig_name
        writer.set_custom_data(_CUSTOM_SOURCE, str(rec.source))
        writer.set_custom_data(_CUSTOM_META, json.dumps(meta, default=_json_default))
        stamp_list = stamps.tolist()
        cmd_set = set(cmd_idx.tolist())
        cmd_iter = iter(cmds)
        for k, stamp in enumerate(stamp_list):
            writer.write(c_js, stamp, js[k])
            writer.write(c_arm, stamp, arm[k])
            if k in cmd_set:
                writer.write(c_cmd, stamp, next(cmd_iter))
    finally:
        if writer.storage is not None:
            writer.close()
    return path


def _encode_via_samples(stamps: np.ndarray, w: dict[str, np.ndarray], commands: np.ndarray,
                        frame_id: str) -> tuple[list[bytes], list[bytes], list[bytes]]:
    """Reference encoder: one :class:`Sample` per wire message, serialised by the typestore."""
    ts = typestore()
    T = ts.types["builtin_interfaces/msg/Time"]
    H = ts.types["std_msgs/msg/Header"]
    JS = ts.types[TYPE_JOINT_STATES]
    BS = ts.types[TYPE_ARMATURE]
    F64 = ts.types[TYPE_DUTY_CYCLE]
    js_out, arm_out = [], []
    for k, stamp in enumerate(stamps.tolist()):
        sample = Sample(stamp_ns=stamp, theta=float(w["theta"][k]), theta_dot=float(w["theta_dot"][k]),
                        omega_rotor=float(w["omega_rotor"][k]), omega_prop=float(w["omega_prop"][k]),
                        i_a=float(w["i_a"][k]), v_a=float(w["v_wire"][k]), duty=float(w["effort"][k]))
        sec, nanosec = divmod(stamp, 1_000_000_000)
        header = H(stamp=T(sec=sec, nanosec=nanosec), frame_id=frame_id)
        f = sample.joint_state_fields()
        js_out.append(bytes(ts.serialize_cdr(
            JS(header=header, name=list(f["name"]), position=np.array(f["position"], dtype=float),
               velocity=np.array(f["velocity"], dtype=float), effort=np.array(f["effort"], dtype=float)),
            TYPE_JOINT_STATES)))
        a = sample.armature_fields()
        arm_out.append(bytes(ts.serialize_cdr(
            BS(header=header, voltage=a["voltage"], temperature=_NAN, current=a["current"], charge=_NAN,
               capacity=_NAN, design_capacity=_NAN, percentage=_NAN, power_supply_status=0,
               power_supply_health=0, power_supply_technology=0, present=True,
               cell_voltage=np.array([], dtype=np.float32), cell_temperature=np.array([], dtype=np.float32),
               location="", serial_number=""),
            TYPE_ARMATURE)))
    cmd_out = [bytes(ts.serialize_cdr(F64(data=float(v)), TYPE_DUTY_CYCLE)) for v in commands]
    return js_out, arm_out, cmd_out


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return str(obj)


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def bag_metadata(path: str | Path) -> dict[str, Any]:
    """``rosbag2_bagfile_information`` of a bag directory's ``metadata.yaml``.

    Raises
    ------
    BagError
        If ``path`` has no readable ``metadata.yaml``.
    """
    import yaml

    path = Path(path)
    meta_file = path / "metadata.yaml"
    try:
        doc = yaml.safe_load(meta_file.read_text(encoding="utf-8"))
        return dict(doc["rosbag2_bagfile_information"])
    except (OSError, yaml.YAMLError, KeyError, TypeError) as exc:
        raise BagError(f"bag '{path}': cannot read {meta_file.name}: {exc}") from exc


def _open_error(path: Path, exc: BaseException) -> BagError:
    if path.is_dir() or path.suffix in (".mcap", ".db3"):
        return BagError(f"bag '{path}' is truncated or corrupt: its storage cannot be opened "
                        f"({type(exc).__name__}: {exc})")
    return BagError(f"'{path}' is not a readable rosbag2 bag ({type(exc).__name__}: {exc}); expected a bag "
                    "directory with metadata.yaml and .mcap/.db3 storage, or a .mcap/.db3 file")


def _read_raw(path: Path, topics: Sequence[str]) -> tuple[dict[str, list[bytes]], dict[str, list[int]],
                                                         dict[str, str], dict[str, int], str]:
    """Raw messages and log times per topic; also the bag's topic->type map and declared counts."""
    from rosbags.highlevel import AnyReader

    if not path.exists():
        raise BagError(f"bag '{path}' does not exist")
    if path.is_dir() and not (path / "metadata.yaml").exists():
        raise BagError(f"'{path}' is not a rosbag2 bag: directory has no metadata.yaml")
    raws: dict[str, list[bytes]] = {t: [] for t in topics}
    logs: dict[str, list[int]] = {t: [] for t in topics}
    try:
        reader = AnyReader([path], default_typestore=typestore())
        reader.open()
    except Exception as exc:
        raise _open_error(path, exc) from exc
    try:
        types = {c.topic: c.msgtype for c in reader.connections}
        declared: dict[str, int] = {}
        for c in reader.connections:
            declared[c.topic] = declared.get(c.topic, 0) + int(c.msgcount)
        storage = "mcap" if any(p.suffix == ".mcap" for p in _files(path)) else "sqlite3"
        conns = [c for c in reader.connections if c.topic in raws]
        if conns:
            try:
                for conn, logtime, raw in reader.messages(connections=conns):
                    raws[conn.topic].append(bytes(raw))
                    logs[conn.topic].append(int(logtime))
            except Exception as exc:
                read = sum(len(v) for v in raws.values())
                raise BagError(f"bag '{path}' is truncated or corrupt: reading failed after {read} "
                               f"message(s) ({type(exc).__name__}: {exc})") from exc
    finally:
        try:
            reader.close()
        except Exception:
            pass
    return raws, logs, types, declared, storage


def _files(path: Path) -> list[Path]:
    return [path] if path.is_file() else sorted(path.iterdir())


def _read_contract_topics(
    path: Path, namespace: str, decoder: str,
) -> tuple[tuple[str, str, str], dict[str, list[Any]], dict[str, list[int]], str, tuple[Any, Any, Any]]:
    """The three contract topics of a bag, checked and decoded (:func:`read_bag`, first step).

    Returns the topic names (joint_states, armature, duty_cycle), the raw messages and log times
    per topic, the storage plugin and the decoded columns (armature and commands None when absent).
    """
    t_js, t_arm, t_cmd = (namespace + t for t in (TOPIC_JOINT_STATES, TOPIC_ARMATURE, TOPIC_DUTY_CYCLE))
    raws, logs, types, declared, storage = _read_raw(path, [t_js, t_arm, t_cmd])
    expected = {t_js: TYPE_JOINT_STATES, t_arm: TYPE_ARMATURE, t_cmd: TYPE_DUTY_CYCLE}
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
    except ContractError as exc:
        raise BagError(f"bag '{path}': {exc}") from exc
    except Exception as exc:
        raise BagError(f"bag '{path}' is corrupt: a message cannot be decoded "
                       f"({type(exc).__name__}: {exc})") from exc
    return (t_js, t_arm, t_cmd), raws, logs, storage, (js, arm, cmd)


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


def _pair_armature(arm: Any, stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Armature v_a / i_a paired with the samples by identical stamp, unmatched and orphan counts."""
    n = stamps.size
    v_wire = np.full(n, np.nan)
    i_a = np.full(n, np.nan)
    unmatched, orphan = n, 0
    if arm is not None:
        a_stamp = arm.columns["stamp"]
        a_order = np.argsort(a_stamp, kind="stable")
        a_stamp = a_stamp[a_order]
        pos = np.clip(np.searchsorted(a_stamp, stamps), 0, a_stamp.size - 1)
        hit = a_stamp[pos] == stamps
        v_wire[hit] = arm.columns["v_a"][a_order][pos[hit]]
        i_a[hit] = arm.columns["i_a"][a_order][pos[hit]]
        unmatched = int(n - hit.sum())
        orphan = int(a_stamp.size - np.unique(pos[hit]).size)
    return v_wire, i_a, unmatched, orphan


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
        If ``path`` is not a bag, the bag is truncated/corrupt, ``joint_states`` is missing or
        has the wrong type, messages violate the contract, two samples share a stamp, theta
        has NaNs, or (``require_duty``) there is no duty information.
    """
    path = Path(path)
    (t_js, t_arm, t_cmd), raws, logs, storage, (js, arm, cmd) = _read_contract_topics(
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

    meta: dict[str, Any] = _stored_meta(path)
    if republished:
        meta["republished_samples_dropped"] = republished
    v_wire, i_a, unmatched, orphan = _pair_armature(arm, stamps)

    # duty[k]: the applied effort carried by sample k+1 (wire convention). Where that is NaN (bags
    # whose duty exists only as commands), the last command received before the interval
    # [t_k, t_k+1) ended, judged on the recorder's clock: log times of joint_states and commands are
    # comparable even when header stamps come from another clock (a replayed bag).
    js_log = np.asarray(logs[t_js], dtype=np.int64)[order]
    effort = cols["effort"]
    d_next = np.concatenate((effort[1:], [np.nan]))
    dstamp = np.diff(stamps)
    gap_after = np.concatenate((dstamp > 1.5 * np.median(dstamp), [False]))
    d_cmd = np.full(n, np.nan)
    if cmd is not None:
        c_log = np.asarray(logs[t_cmd], dtype=np.int64)
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
    if np.isfinite(effort[0]):
        meta["duty_before_start"] = float(effort[0])
    meta.update({
        "bag": str(path),
        "storage": storage,
        "message_counts": {t: len(raws[t]) for t in (t_js, t_arm, t_cmd)},
        "unmatched_joint_states": unmatched if arm is not None else n,
        "orphan_armature": orphan,
        "duty_source": {"effort": int(use_eff.sum()) - n_after_gap, "command": n_cmd,
                        "effort_after_gap": n_after_gap,
                        "missing": int((~np.isfinite(duty)).sum())},
        "gaps": int(gap_after.sum()),
        "held_tail": held,
        "cdr_fallback_messages": js.fallback + (arm.fallback if arm else 0) + (cmd.fallback if cmd else 0),
    })
    try:
        return Recording(t=(stamps - stamps[0]) / 1e9, duty=duty, channels=channels, source=str(path),
                         stamp0_ns=int(stamps[0]), meta=meta)
    except RecordingError as exc:  # pragma: no cover - stamps are checked above
        raise BagError(f"bag '{path}': {exc}") from exc


def _stored_meta(path: Path) -> dict[str, Any]:
    """Metadata :func:`write_bag` stored in ``custom_data`` (empty for other bags)."""
    if not path.is_dir():
        return {}
    try:
        custom = bag_metadata(path).get("custom_data") or {}
    except BagError:
        return {}
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


# --------------------------------------------------------------------------------------------
# Incremental raw writing / reading (ROS-free core of the recorder and player nodes)
# --------------------------------------------------------------------------------------------


class BagSink:
    """Incremental rosbag2 writer of already-serialised (CDR) messages.

    Topics are registered lazily (:meth:`add_topic`, typically on the first message, once the
    publishers' offered QoS is known); :meth:`close` writes ``metadata.yaml`` and is idempotent.

    Parameters
    ----------
    path : str or Path
        Bag directory to create (must not exist).
    storage : {"mcap", "sqlite3"}
        Storage plugin.
    custom_data : dict of str, optional
        ``custom_data`` entries of ``metadata.yaml``.

    Raises
    ------
    BagError
        If the storage is unknown or the bag cannot be created (e.g. ``path`` exists).
    """

    def __init__(self, path: str | Path, storage: Storage = "mcap",
                 custom_data: dict[str, str] | None = None) -> None:
        self.path = Path(path)
        if storage not in _STORAGE_PLUGINS:
            raise BagError(f"bag '{self.path}': unknown storage {storage!r}; "
                           f"expected one of {sorted(_STORAGE_PLUGINS)}")
        if self.path.exists():
            raise BagError(f"bag '{self.path}' already exists; choose another output path")
        self.storage = storage
        typestore()  # build the typestore now (~0.1 s): doing it on the first message would drop samples
        self._writer = JazzyWriter(self.path, version=9, storage_plugin=_STORAGE_PLUGINS[storage])
        try:
            self._writer.open()
        except Exception as exc:
            raise BagError(f"bag '{self.path}': cannot create ({type(exc).__name__}: {exc})") from exc
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(key, str(value))
        self._conns: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self.closed = False

    def has_topic(self, topic: str) -> bool:
        """Whether ``topic`` is registered."""
        return topic in self._conns

    def add_topic(self, topic: str, msgtype: str, qos: Sequence[Qos] = ()) -> None:
        """Register ``topic`` of ``msgtype`` (e.g. ``sensor_msgs/msg/JointState``) with its offered QoS."""
        if topic in self._conns:
            return
        try:
            self._conns[topic] = self._writer.add_connection(topic, msgtype, typestore=typestore(),
                                                             offered_qos_profiles=list(qos))
        except Exception as exc:
            raise BagError(f"bag '{self.path}': cannot add topic {topic} of type {msgtype} "
                           f"({type(exc).__name__}: {exc})") from exc
        self.counts[topic] = 0

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """Append one serialised message with log time ``timestamp_ns``."""
        self._writer.write(self._conns[topic], int(timestamp_ns), data)
        self.counts[topic] += 1

    def close(self) -> None:
        """Finish the bag (writes ``metadata.yaml``); safe to call twice."""
        if not self.closed:
            self.closed = True
            self._writer.close()


@dataclass(frozen=True)
class BagTopic:
    """A topic of a bag: message type, offered QoS profiles and message count."""

    name: str
    msgtype: str
    qos: tuple[Qos, ...]
    count: int


class RawBagReader:
    """Raw (serialised) messages of a bag in log-time order, for replay.

    Parameters
    ----------
    path : str or Path
        Bag directory or ``.mcap`` / ``.db3`` file.
    topics : sequence of str, optional
        Topics to read (default all).

    Raises
    ------
    BagError
        If ``path`` is not a readable bag or a requested topic is not in it.
    """

    def __init__(self, path: str | Path, topics: Sequence[str] | None = None) -> None:
        from rosbags.highlevel import AnyReader

        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"bag '{self.path}' does not exist")
        if self.path.is_dir() and not (self.path / "metadata.yaml").exists():
            raise BagError(f"'{self.path}' is not a rosbag2 bag: directory has no metadata.yaml")
        try:
            self._reader = AnyReader([self.path], default_typestore=typestore())
            self._reader.open()
        except Exception as exc:
            raise _open_error(self.path, exc) from exc
        conns = self._reader.connections
        present = sorted({c.topic for c in conns})
        if topics:
            missing = [t for t in topics if t not in present]
            if missing:
                self.close()
                raise BagError(f"bag '{self.path}' has no topic(s) {missing} (topics present: {present})")
            conns = [c for c in conns if c.topic in topics]
        self._conns = conns
        self.topics: dict[str, BagTopic] = {}
        for c in conns:
            qos = tuple(getattr(c.ext, "offered_qos_profiles", ()) or ())
            old = self.topics.get(c.topic)
            self.topics[c.topic] = BagTopic(c.topic, c.msgtype, qos if old is None else old.qos + qos,
                                            int(c.msgcount) + (old.count if old else 0))

    def messages(self) -> Any:
        """Yield ``(topic, log_time_ns, raw_bytes)`` in log-time order.

        Raises
        ------
        BagError
            If the storage turns out to be truncated or corrupt while reading.
        """
        try:
            for conn, logtime, raw in self._reader.messages(connections=self._conns):
                yield conn.topic, int(logtime), bytes(raw)
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f"bag '{self.path}' is truncated or corrupt: reading failed "
                           f"({type(exc).__name__}: {exc})") from exc

    def close(self) -> None:
        """Close the underlying reader."""
        try:
            self._reader.close()
        except Exception:
            pass

    def __enter__(self) -> RawBagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def playback_deadlines(log_times_ns: Sequence[int] | np.ndarray, rate: float) -> np.ndarray:
    """Wall-clock offsets [ns] from the start at which each message is due on replay.

    Parameters
    ----------
    log_times_ns : array of int, shape (M,)
        Log times of the messages, in replay order.
    rate : float
        Playback speed factor (> 0; 2.0 = twice as fast).

    Returns
    -------
    ndarray of int64, shape (M,)
        ``(log_k − log_0) / rate``, rounded to ns. Sleeping until ``start + offset_k`` (absolute
        deadlines) keeps timing errors from accumulating.

    Raises
    ------
    ValueError
        If ``rate`` is not a positive finite number.
    """
    if not (rate > 0 and math.isfinite(rate)):
        raise ValueError(f"playback rate {rate!r} must be a positive finite number")
    t = np.asarray(log_times_ns, dtype=np.int64)
    if t.size == 0:
        return t
    return np.round((t - t[0]) / rate).astype(np.int64)
