"""CDR codec of the contract messages (little-endian XCDR1, the encoding rclpy and rosbag2 use).

Batch encoders (:func:`encode_joint_states`, :func:`encode_armature`, :func:`encode_float64`,
:func:`encode_float64_array`) and decoders (:func:`decode_joint_states`, :func:`decode_armature`,
:func:`decode_float64`, :func:`decode_float64_array`):
the ``vectorized`` path decodes all messages of one layout at once with NumPy (the layout is
derived from the first message, re-encoded and checked byte for byte; a deviating message goes
through ``typestore().deserialize_cdr``, the reference path). Used by the bag reader
(:mod:`aeropend_ident.io.bags`) and writer (:mod:`aeropend_ident.io.bag_writer`).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from aeropend_sim.contract import (
    EXTRA_CHANNELS,
    JOINT_NAMES,
    SECOND_AXIS_FIELDS,
    SECOND_AXIS_JOINT,
    TYPE_ARMATURE,
    TYPE_DUTY_CYCLE,
    TYPE_EXTRA_CHANNELS,
    TYPE_JOINT_STATES,
    ContractError,
    check_extra_channel,
)

_NAN = math.nan


@lru_cache(maxsize=1)
def typestore() -> Any:
    """The ROS 2 Jazzy ``rosbags`` typestore (cached)."""
    return get_typestore(Stores.ROS2_JAZZY)


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
                        names: Sequence[str] = JOINT_NAMES, *, array: bool = False) -> Any:
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
    array : bool
        Return the messages as one ``uint8`` array of shape (N, size) (all have one size).

    Returns
    -------
    list of bytes or ndarray of uint8, shape (N, size)
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
    return arr if array else _rows(arr)


def encode_armature(stamps_ns: np.ndarray, voltage: np.ndarray, current: np.ndarray,
                    frame_id: str = "aeropend", *, array: bool = False) -> Any:
    """CDR-serialise a batch of ``sensor_msgs/msg/BatteryState`` armature messages.

    ``voltage`` [V] and ``current`` [A] (shape (N,)) are stored as float32 (the message's field
    type); every other float is NaN, status/health/technology unknown (0), ``present`` True.
    Returns a list of N ``bytes``, or with ``array`` one ``uint8`` array of shape (N, size).
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
    return arr if array else _rows(arr)


@lru_cache(maxsize=64)
def _float64_array_layout(dims: tuple[tuple[str, int, int], ...], data_offset: int, n_data: int) -> _Layout:
    buf = _Buf()
    buf.u32(len(dims))
    for label, size, stride in dims:
        buf.string(label)
        buf.u32(size)
        buf.u32(stride)
    buf.u32(data_offset)
    slots = {"data": (buf.f64_seq(n_data), "<f8", n_data)}
    return _Layout(bytes(buf.b), slots, tuple(buf.pads))


def encode_float64_array(values: np.ndarray, names: Sequence[str],
                         units: Sequence[str | None] | None = None) -> list[bytes]:
    """CDR-serialise a batch of labelled ``std_msgs/msg/Float64MultiArray`` messages.

    Parameters
    ----------
    values : ndarray, shape (N, K)
        One row per message (NaN allowed: a value not measured).
    names : sequence of str
        The K channel names: the layout's single dimension is labelled with the names joined by
        commas, each followed by its unit in brackets (:func:`label_entry`: ``thrust [N],x_acc
        [m/s^2]``), size = stride = K (the labelling of ``/aeropend/controller/signals``, with units).
    units : sequence of str, optional
        The K units (None: no units in the label).

    Returns
    -------
    list of bytes
        N serialised messages, byte-identical to ``typestore.serialize_cdr``.
    """
    values = np.asarray(values, dtype=float)
    k = len(names)
    values = values.reshape(len(values), k)
    label = ",".join(label_entry(n, u) for n, u in zip(names, units or [None] * k, strict=True))
    layout = _float64_array_layout(((label, k, k),), 0, k)
    arr = _tile(layout, len(values))
    _put(arr, layout, "data", values)
    return _rows(arr)


def encode_float64(values: np.ndarray, *, array: bool = False) -> Any:
    """CDR-serialise a batch of ``std_msgs/msg/Float64`` messages (shape (N,)): a list of N
    ``bytes``, or with ``array`` one ``uint8`` array of shape (N, 16)."""
    arr = _tile(_FLOAT64_LAYOUT, len(values))
    _put(arr, _FLOAT64_LAYOUT, "data", np.asarray(values, dtype=float))
    return arr if array else _rows(arr)


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
    cols = {
        "stamp": stamps,
        "theta": _pick_joint(pos, names, "pendulum", "position"),
        "theta_dot": _pick_joint(vel, names, "pendulum", "velocity"),
        "omega_rotor": _pick_joint(vel, names, "motor", "velocity"),
        "omega_prop": _pick_joint(vel, names, "propeller", "velocity"),
        "effort": _pick_joint(eff, names, "motor", "effort"),
    }
    arrays = {"position": pos, "velocity": vel}
    for channel, what in SECOND_AXIS_FIELDS.items():  # a 2-DOF rig's second joint, NaN when absent
        cols[channel] = (_pick_joint(arrays[what], names, SECOND_AXIS_JOINT, what)
                         if SECOND_AXIS_JOINT in names else np.full(stamps.shape[0], np.nan))
    return cols


def _concat(parts: list[tuple[np.ndarray, dict[str, np.ndarray]]], n: int) -> dict[str, np.ndarray]:
    """Reassemble per-group columns into message order."""
    out: dict[str, np.ndarray] = {}
    for idx, cols in parts:
        for key, val in cols.items():
            if key not in out:  # a column some groups lack (a labelled channel) is NaN there
                out[key] = np.full(n, np.nan) if val.dtype.kind == "f" else np.empty(n, dtype=val.dtype)
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
        ``omega_prop``, ``effort`` (wire duty) and the second joint's ``phi``, ``phi_dot`` (NaN
        without that joint), each shape (N,).

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


_FLOAT64_LAYOUT = _Layout(_CDR_LE + b"\x00" * 8, {"data": (4, "<f8", 1)})


def label_entry(name: str, unit: str | None) -> str:
    """One channel of a Float64MultiArray's label: ``name [unit]`` (``name`` without a unit, or one
    the label cannot carry: a ``,``, ``[`` or ``]`` in it)."""
    return f"{name} [{unit}]" if unit and not set(unit) & set(",[]") else name


def split_label_entry(entry: str) -> tuple[str, str | None]:
    """``name [unit]`` -> (name, unit); ``name`` -> (name, None)."""
    entry = entry.strip()
    if entry.endswith("]") and " [" in entry:
        name, _, unit = entry[:-1].partition(" [")
        return name.strip(), unit.strip() or None
    return entry, None


def _array_names(dims: Sequence[tuple[str, int, int]], n_data: int) -> list[str]:
    """Channel entries (``name [unit]``) of a Float64MultiArray: its single dimension's comma-separated
    label when that names every value with valid extra-channel names, else ``value_0``, ``value_1``, ..."""
    if len(dims) == 1 and dims[0][1] == n_data:
        entries = [x.strip() for x in dims[0][0].split(",")]
        names = [split_label_entry(x)[0] for x in entries]
        try:
            for name in names:
                check_extra_channel(name, None if name in EXTRA_CHANNELS else "?")
        except ContractError:
            names = []
        if len(names) == n_data and len(set(names)) == n_data:
            return entries
    return [f"value_{i}" for i in range(n_data)]


def decode_float64_array(raws: Sequence[bytes], vectorized: bool = True) -> _Decoded:
    """Decode labelled ``std_msgs/Float64MultiArray`` messages (:func:`encode_float64_array`).

    Returns
    -------
    _Decoded
        ``columns``: one float column per label entry (``name [unit]``, :func:`_array_names`,
        :func:`split_label_entry`), shape (N,); NaN in the messages that do not carry it.
    """

    def layout_of(msg: Any) -> _Layout:
        dims = tuple((d.label, int(d.size), int(d.stride)) for d in msg.layout.dim)
        return _float64_array_layout(dims, int(msg.layout.data_offset), len(msg.data))

    def columns_of(data: Any, layout: _Layout | None) -> dict[str, np.ndarray]:
        if layout is not None:
            msg = typestore().deserialize_cdr(layout.template, TYPE_EXTRA_CHANNELS)
            values = _get(data, layout, "data")
            dims = [(d.label, int(d.size), int(d.stride)) for d in msg.layout.dim]
            names = _array_names(dims, values.shape[1])
            return {name: values[:, i].copy() for i, name in enumerate(names)}
        out: dict[str, np.ndarray] = {}
        for k, m in enumerate(data):
            names = _array_names([(d.label, int(d.size), int(d.stride)) for d in m.layout.dim], len(m.data))
            for name, v in zip(names, np.asarray(m.data, dtype=float), strict=True):
                out.setdefault(name, np.full(len(data), np.nan))[k] = v
        return out

    return _decode_groups(raws, TYPE_EXTRA_CHANNELS, layout_of, columns_of, vectorized)
