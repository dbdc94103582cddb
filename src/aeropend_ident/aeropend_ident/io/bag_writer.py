"""Contract bags from recordings (:func:`write_bag`) and the recorder's incremental writer (:class:`BagSink`).

The wire convention (duty and v_a shifted forward one sample) and the precision notes are in
:mod:`aeropend_ident.io.bags`, which reads what this module writes.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from rosbags.interfaces import (
    Qos,
)

from aeropend_ident.errors import BagError
from aeropend_ident.io.bag_codec import (
    _NAN,
    encode_armature,
    encode_float64,
    encode_float64_array,
    encode_joint_states,
    typestore,
)
from aeropend_ident.io.bag_reader import Storage
from aeropend_ident.io.bags import (
    _CUSTOM_META,
    _CUSTOM_RIG,
    _CUSTOM_SOURCE,
    _STORAGE_PLUGINS,
    COMMAND_QOS,
    EXTRA_UNITS_META,
    qos_for_topic,
)
from aeropend_sim.contract import (
    JOINT_NAMES,
    REFERENCE_CHANNEL,
    SECOND_AXIS_FIELDS,
    SECOND_AXIS_JOINT,
    TOPIC_ARMATURE,
    TOPIC_DUTY_CYCLE,
    TOPIC_EXTRA_CHANNELS,
    TOPIC_JOINT_STATES,
    TOPIC_REFERENCE,
    TYPE_ARMATURE,
    TYPE_DUTY_CYCLE,
    TYPE_EXTRA_CHANNELS,
    TYPE_JOINT_STATES,
    TYPE_REFERENCE,
    Sample,
)
from aeropend_sim.output_folder import OutputFolder, OutputFolderError, claim_output_folder, is_fault
from aeropend_sim.recording import MEASURED_CHANNELS, Recording

from .mcap_jazzy import JazzyMcapWriter, JazzyWriter

#: What a rosbag2 bag folder holds at its top level (:func:`claim_bag_folder`: an existing folder is
#: replaced only if it holds one of these).
BAG_FILES = ("metadata.yaml", "*.mcap", "*.db3")


def claim_bag_folder(path: str | Path, overwrite: bool, *, inputs: Sequence[str | Path] = (),
                     option: str = "path", flag: str = "overwrite=True") -> OutputFolder:
    """Claim the folder of a new bag (:func:`aeropend_sim.output_folder.claim_output_folder`).

    A missing or empty folder is used; a non-empty one only with ``overwrite`` and only if it looks
    like a bag (holds one of :data:`BAG_FILES`) and is no protected place. Call
    ``.prepare(create=False)`` on the result right before writing (the writer creates the folder).

    Parameters
    ----------
    path : str or Path
        Bag folder to create.
    overwrite : bool
        Replace an existing bag there.
    inputs : sequence of str or Path
        The command's inputs (a folder holding one is never emptied).
    option, flag : str
        How messages name the output option and the overwrite switch (a command line passes
        ``-o`` and ``--overwrite``).

    Raises
    ------
    aeropend_sim.output_folder.OutputFolderError
        If the folder must not be written (the message says why and what to pass).
    """
    return claim_output_folder(path, overwrite, own=BAG_FILES, looks_like="a rosbag2 bag", inputs=inputs,
                               option=option, flag=flag, kind="bag folder")


def _prepare_target(path: Path, overwrite: bool) -> None:
    try:
        claim_bag_folder(path, overwrite).prepare(create=False)
    except OutputFolderError as exc:
        raise BagError(str(exc)) from exc


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


def _extra_messages(rec: Recording) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, list[str]]:
    """Where a recording's extra channels go in a bag (:data:`aeropend_sim.contract.EXTRA_CHANNELS`).

    Returns the ``joint_states`` joint names (the contract's, plus the second joint when the
    recording has φ or φ̇), that joint's (position, velocity) columns (NaN where absent) and the
    names of the channels of the labelled Float64MultiArray (every extra channel but the
    second axis and the reference).
    """
    nan = np.full(len(rec), np.nan)
    second = {f: rec.extra.get(ch, nan) for ch, f in SECOND_AXIS_FIELDS.items()}
    names = JOINT_NAMES + ((SECOND_AXIS_JOINT,) if any(ch in rec.extra for ch in SECOND_AXIS_FIELDS) else ())
    rest = [ch for ch in rec.extra if ch not in SECOND_AXIS_FIELDS and ch != REFERENCE_CHANNEL]
    return names, second["position"], second["velocity"], rest


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

    Extra channels (``rec.extra``, :data:`aeropend_sim.contract.EXTRA_CHANNELS`): ``phi`` /
    ``phi_dot`` as a fourth ``joint_states`` joint ``phi``; ``theta_ref`` as ``std_msgs/Float64`` on
    ``/aeropend/reference`` (finite values; the topic a controller reads its reference from); every
    other one in a ``std_msgs/Float64MultiArray`` per sample on ``/aeropend/extra_channels``,
    labelled with the channel names and units (``thrust [N],x_acc [m/s^2]``). Log time = the
    sample's stamp; the units are also stored in the bag's metadata (``meta["extra_units"]``).

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
        Replace an existing bag at ``path`` (a folder holding other files is never emptied, see
        :func:`claim_bag_folder`); without it an existing non-empty folder is an error.
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
        On an unknown storage, an existing non-empty target (without ``overwrite``, or one that
        is not a bag), or stamps that are not strictly increasing after rounding to nanoseconds.
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
    joints, phi, phi_dot = _extra_messages(rec)[:3]
    if encoder == "vectorized":
        nan = np.full(len(rec), np.nan)
        second = len(joints) > len(JOINT_NAMES)
        js = encode_joint_states(
            stamps,
            position=np.column_stack([w["theta"], nan, nan, *([phi] if second else [])]),
            velocity=np.column_stack([w["theta_dot"], w["omega_rotor"], w["omega_prop"],
                                      *([phi_dot] if second else [])]),
            effort=np.column_stack([nan, w["effort"], nan, *([nan] if second else [])]),
            frame_id=frame_id,
            names=joints,
        )
        arm = encode_armature(stamps, w["v_wire"], w["i_a"], frame_id=frame_id)
        cmds = encode_float64(rec.duty[cmd_idx])
    elif encoder == "typestore":
        js, arm, cmds = _encode_via_samples(stamps, w, rec.duty[cmd_idx], frame_id, joints, phi, phi_dot)
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
        extra = _ExtraTopics(writer, rec, namespace, sample_qos)
        meta = dict(rec.meta)
        if rec.extra:
            meta[EXTRA_UNITS_META] = dict(rec.extra_units)
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
            extra.write(k, stamp)
    finally:
        if writer.storage is not None:
            writer.close()
    return path


class BagStream:
    """A contract bag written block by block (memory: one block), as :func:`write_bag` writes it.

    Each :meth:`write` takes the next samples (time from the first, duty, contract channels);
    the wire convention (duty and v_a shifted forward one sample) runs across the blocks. Extra
    channels are not written (:func:`write_bag` takes those). MCAP storage gets whole chunks
    built with NumPy (:meth:`~aeropend_ident.io.mcap_jazzy.JazzyWriter.write_rows`).

    Parameters
    ----------
    path : Path
        Bag folder to create (absent or empty).
    storage : {"mcap", "sqlite3"}
        rosbag2 storage plugin.
    stamp0_ns : int
        Absolute stamp of ``t = 0`` [ns].
    frame_id : str
        ``header.frame_id`` of the sample messages.

    Raises
    ------
    BagError
        Unknown storage; the bag cannot be created.
    """

    def __init__(self, path: Path, storage: Storage = "mcap", stamp0_ns: int = 0,
                 frame_id: str = "aeropend") -> None:
        if storage not in _STORAGE_PLUGINS:
            raise BagError(f"bag '{path}': unknown storage {storage!r}; "
                           f"expected one of {sorted(_STORAGE_PLUGINS)}")
        self.path, self.stamp0_ns, self.frame_id = Path(path), int(stamp0_ns), frame_id
        self._writer = JazzyWriter(self.path, version=9, storage_plugin=_STORAGE_PLUGINS[storage])
        self._writer.open()
        ts = typestore()
        qos = qos_for_topic(TOPIC_JOINT_STATES, False)
        self._conns = [self._writer.add_connection(TOPIC_JOINT_STATES, TYPE_JOINT_STATES, typestore=ts,
                                                   offered_qos_profiles=[qos]),
                       self._writer.add_connection(TOPIC_ARMATURE, TYPE_ARMATURE, typestore=ts,
                                                   offered_qos_profiles=[qos]),
                       self._writer.add_connection(TOPIC_DUTY_CYCLE, TYPE_DUTY_CYCLE, typestore=ts,
                                                   offered_qos_profiles=[COMMAND_QOS])]
        self._last = (np.nan, np.nan, -1)  # duty, v_a, stamp of the previous sample
        self.samples = self.commands = 0

    def write(self, t: np.ndarray, duty: np.ndarray, channels: dict[str, np.ndarray]) -> None:
        """Append samples: ``t`` [s] from the bag's ``t = 0``, shape (n,); ``duty`` in [0, 1]
        (NaN: no command sent); ``channels`` the contract channels present (SI).

        Raises
        ------
        BagError
            Stamps not strictly increasing after rounding to nanoseconds.
        """
        n = len(t)
        if not n:
            return
        stamps = self.stamp0_ns + np.round(np.asarray(t) * 1e9).astype(np.int64)
        d = np.diff(np.concatenate(([self._last[2]], stamps)))
        if np.any(d <= 0):
            k = int(np.flatnonzero(d <= 0)[0])
            raise BagError(f"bag '{self.path}': stamps not strictly increasing at sample {self.samples + k} "
                           "after rounding to ns")
        nan = np.full(n, np.nan)
        ch = {name: channels.get(name, nan) for name in MEASURED_CHANNELS}
        effort = np.concatenate(([self._last[0]], duty[:-1]))
        v_wire = np.concatenate(([self._last[1]], ch["v_a"][:-1]))
        self._last = (float(duty[-1]), float(ch["v_a"][-1]), int(stamps[-1]))
        velocity = np.column_stack([ch["theta_dot"], ch["omega_rotor"], ch["omega_prop"]])
        js = encode_joint_states(stamps, position=np.column_stack([ch["theta"], nan, nan]), velocity=velocity,
                                 effort=np.column_stack([nan, effort, nan]), frame_id=self.frame_id,
                                 array=True)
        arm = encode_armature(stamps, v_wire, ch["i_a"], frame_id=self.frame_id, array=True)
        sent = np.isfinite(duty)
        if sent.all():
            self._writer.write_rows(self._conns, stamps, [js, arm, encode_float64(duty, array=True)])
        else:
            self._writer.write_rows(self._conns[:2], stamps, [js, arm])
            self._writer.write_rows(self._conns[2:], stamps[sent], [encode_float64(duty[sent], array=True)])
        self.samples += n
        self.commands += int(sent.sum())

    def close(self, meta: dict[str, Any], source: str, rig_name: str | None = None) -> Path:
        """Store ``meta`` (JSON in ``custom_data``), the source and rig name; finish the bag."""
        meta = dict(meta)
        if rig_name is not None:
            self._writer.set_custom_data(_CUSTOM_RIG, str(rig_name))
            meta["rig_name"] = rig_name
        self._writer.set_custom_data(_CUSTOM_SOURCE, str(source))
        self._writer.set_custom_data(_CUSTOM_META, json.dumps(meta, default=_json_default))
        self._writer.close()
        return self.path

    def abort(self) -> None:
        """Close the file and remove the bag folder (nothing partial is left)."""
        import shutil

        storage = getattr(self._writer, "storage", None)
        try:
            if storage is not None:
                bio = getattr(storage, "bio", None)
                if bio is not None:
                    bio.close()
                db = getattr(storage, "conn", None)
                if db is not None:
                    db.close()
        finally:
            shutil.rmtree(self.path, ignore_errors=True)


class _ExtraTopics:
    """The extra channels' topics of a bag being written: the reference (``std_msgs/Float64``, its
    finite values) and the labelled ``Float64MultiArray`` of the other channels, one per sample."""

    def __init__(self, writer: Any, rec: Recording, namespace: str, sample_qos: Qos) -> None:
        self.writer = writer
        self.ref: dict[int, bytes] = {}
        self.arrays: list[bytes] = []
        self.c_ref = self.c_arr = None
        rest = _extra_messages(rec)[3]
        ts = typestore()
        if REFERENCE_CHANNEL in rec.extra:
            ref = rec.extra[REFERENCE_CHANNEL]
            idx = np.flatnonzero(np.isfinite(ref))
            self.ref = dict(zip(idx.tolist(), encode_float64(ref[idx]), strict=True))
            self.c_ref = writer.add_connection(namespace + TOPIC_REFERENCE, TYPE_REFERENCE, typestore=ts,
                                               offered_qos_profiles=[qos_for_topic(TOPIC_REFERENCE)])
        if rest:
            self.arrays = encode_float64_array(np.column_stack([rec.extra[n] for n in rest]), rest,
                                               [rec.extra_units.get(n) for n in rest])
            self.c_arr = writer.add_connection(namespace + TOPIC_EXTRA_CHANNELS, TYPE_EXTRA_CHANNELS,
                                               typestore=ts, offered_qos_profiles=[sample_qos])

    def write(self, k: int, stamp: int) -> None:
        """Write sample ``k``'s extra messages with log time ``stamp``."""
        if self.c_ref is not None and k in self.ref:
            self.writer.write(self.c_ref, stamp, self.ref[k])
        if self.c_arr is not None:
            self.writer.write(self.c_arr, stamp, self.arrays[k])


def _encode_via_samples(stamps: np.ndarray, w: dict[str, np.ndarray], commands: np.ndarray, frame_id: str,
                        joints: Sequence[str] = JOINT_NAMES, phi: np.ndarray | None = None,
                        phi_dot: np.ndarray | None = None) -> tuple[list[bytes], list[bytes], list[bytes]]:
    """Reference encoder: one :class:`Sample` per wire message, serialised by the typestore (a second
    joint, when ``joints`` has one, appended with position ``phi`` and velocity ``phi_dot``)."""
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
        if len(joints) > len(JOINT_NAMES):
            f = {"name": [*f["name"], SECOND_AXIS_JOINT], "position": [*f["position"], float(phi[k])],
                 "velocity": [*f["velocity"], float(phi_dot[k])], "effort": [*f["effort"], _NAN]}
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
    flush_interval_s : float
        Longest time [s] a written message stays only in memory: :meth:`write` and
        :meth:`flush_if_due` then close the MCAP chunk (commit the SQLite transaction) and
        ``fsync`` the file, so a recorder killed (or a power cut) loses at most this much.
        0: only on :meth:`close`.

    Raises
    ------
    BagError
        If the storage is unknown or the bag cannot be created (e.g. ``path`` exists).
    """

    def __init__(self, path: str | Path, storage: Storage = "mcap",
                 custom_data: dict[str, str] | None = None, flush_interval_s: float = 0.0) -> None:
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
            if is_fault(exc):  # a full disk, a read-only folder: the command's one-line fault report
                raise
            raise BagError(f"bag '{self.path}': cannot create ({type(exc).__name__}: {exc})") from exc
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(key, str(value))
        self._conns: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self.closed = False
        self.flush_interval_ns = round(float(flush_interval_s) * 1e9)
        self._flushed_ns = time.monotonic_ns()
        self.flushes = 0
        self._dirty = False  # messages written since the last flush

    def set_custom_data(self, key: str, value: str) -> None:
        """Set a ``custom_data`` entry of ``metadata.yaml`` (written on :meth:`close`)."""
        self._writer.set_custom_data(key, str(value))

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
            if is_fault(exc):
                raise
            raise BagError(f"bag '{self.path}': cannot add topic {topic} of type {msgtype} "
                           f"({type(exc).__name__}: {exc})") from exc
        self.counts[topic] = 0

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """Append one serialised message with log time ``timestamp_ns`` (then :meth:`flush_if_due`)."""
        self._writer.write(self._conns[topic], int(timestamp_ns), data)
        self.counts[topic] += 1
        self._dirty = True
        self.flush_if_due()

    def flush_if_due(self) -> None:
        """:meth:`flush` when ``flush_interval_s`` has passed since the last one."""
        if self.flush_interval_ns and not self.closed and \
                time.monotonic_ns() - self._flushed_ns >= self.flush_interval_ns:
            self.flush()

    def flush(self) -> None:
        """Put everything written so far on disk: the MCAP chunk closed (the SQLite transaction
        committed) and the file ``fsync``-ed."""
        storage = self._writer.storage
        self._flushed_ns = time.monotonic_ns()
        if storage is None or self.closed or not self._dirty:
            return
        self._dirty = False
        if isinstance(storage, JazzyMcapWriter):
            storage.flush()
        else:
            storage.conn.commit()
        self.flushes += 1

    def close(self) -> None:
        """Finish the bag (writes ``metadata.yaml``); safe to call twice."""
        if not self.closed:
            self.closed = True
            self._writer.close()
