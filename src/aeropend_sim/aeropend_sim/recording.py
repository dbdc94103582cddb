"""In-memory recording of a plant run: the array form of a contract bag or an imported CSV.

Alignment convention (the batch convention of :func:`aeropend_sim.simulation.simulate`):
``duty[k]`` is the duty cycle held over [t_k, t_{k+1}) and every channel ``y[k]`` is the value at
t_k. On the wire (contract topics) the applied duty of a sample describes the interval that
*ends* at its stamp; the bag reader shifts it by one sample into this convention.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeropend_sim.contract import CHANNELS, ContractError, check_extra_channel

#: Measured channels a recording may carry (everything in :data:`CHANNELS` except duty).
MEASURED_CHANNELS: tuple[str, ...] = tuple(c for c in CHANNELS if c != "duty")


class RecordingError(ValueError):
    """A recording is inconsistent (lengths, NaNs, time base) or lacks a needed channel."""


@dataclass
class Recording:
    """Uniformly or non-uniformly sampled run: time, duty-cycle input and measured channels.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample instants [s], strictly increasing, starting at 0.
    duty : ndarray, shape (N,)
        Duty cycle τ_k ∈ [0, 1] held over [t_k, t_{k+1}).
    channels : dict[str, ndarray]
        Measured channels (names from :data:`MEASURED_CHANNELS`), each shape (N,), SI units.
        A channel that was not measured is absent (never filled with zeros).
    source : str
        Where the data came from (file path, bag, simulation).
    stamp0_ns : int
        Absolute time of t = 0 [ns] (ROS time of the first sample; 0 if unknown).
    meta : dict
        Free-form provenance (rig name, column mapping, licence note, ...).
    extra : dict[str, ndarray]
        Channels beyond the contract's, each shape (N,), stored under their own names
        (:data:`aeropend_sim.contract.EXTRA_CHANNELS`, e.g. ``phi`` of a 2-DOF rig, the reference
        ``theta_ref`` of a closed-loop log, or a lab's own name): kept, written to bags and read
        back, and ignored by the tools that do not use them. NaN where not measured.
    extra_units : dict[str, str]
        Unit of every extra channel (filled from ``EXTRA_CHANNELS`` for its names).
    duty_before : ndarray, shape (M,), optional
        The duty cycles of the same run before t = 0, oldest first, at this recording's sample
        period: set by :meth:`slice` on a later part of a run (a validation stretch carved from a
        session), so that a replay can carry a state no channel holds (a winding temperature)
        across the cut. None for a recording that starts its run.
    """

    t: np.ndarray
    duty: np.ndarray
    channels: dict[str, np.ndarray]
    source: str = ""
    stamp0_ns: int = 0
    meta: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    extra_units: dict[str, str] = field(default_factory=dict)
    duty_before: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        self.duty = np.asarray(self.duty, dtype=float)
        n = self.t.size
        if self.duty_before is not None:
            self.duty_before = np.asarray(self.duty_before, dtype=float)
            if self.duty_before.ndim != 1:
                raise RecordingError(f"{self.source}: duty_before has shape {self.duty_before.shape}, "
                                     "expected (M,)")
        if self.t.ndim != 1 or n < 2:
            raise RecordingError(f"{self.source}: need at least 2 samples, got t of shape {self.t.shape}")
        if not np.all(np.diff(self.t) > 0):
            k = int(np.flatnonzero(np.diff(self.t) <= 0)[0])
            raise RecordingError(
                f"{self.source}: time not strictly increasing at sample {k + 1} "
                f"(t = {self.t[k]:.6g} then {self.t[k + 1]:.6g} s)"
            )
        if self.duty.shape != (n,):
            raise RecordingError(f"{self.source}: duty has shape {self.duty.shape}, expected ({n},)")
        for name, y in list(self.channels.items()):
            if name not in MEASURED_CHANNELS:
                raise RecordingError(
                    f"{self.source}: unknown channel {name!r}; expected one of {MEASURED_CHANNELS}"
                )
            y = np.asarray(y, dtype=float)
            if y.shape != (n,):
                raise RecordingError(f"{self.source}: channel {name} has shape {y.shape}, expected ({n},)")
            self.channels[name] = y
        units: dict[str, str] = {}
        for name, y in list(self.extra.items()):
            try:
                units[name] = check_extra_channel(name, self.extra_units.get(name))
            except ContractError as exc:
                raise RecordingError(f"{self.source}: {exc}") from None
            y = np.asarray(y, dtype=float)
            if y.shape != (n,):
                raise RecordingError(f"{self.source}: extra channel {name} has shape {y.shape}, "
                                     f"expected ({n},)")
            self.extra[name] = y
        stray = sorted(set(self.extra_units) - set(self.extra))
        if stray:
            raise RecordingError(f"{self.source}: units given for channel(s) {stray} that are not in extra "
                                 f"(has {sorted(self.extra)})")
        self.extra_units = units

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def dt(self) -> float:
        """Median sample period [s]."""
        return float(np.median(np.diff(self.t)))

    def require(self, *names: str) -> None:
        """Raise :class:`RecordingError` unless every named channel is present and finite."""
        missing = [n for n in names if n not in self.channels]
        if missing:
            raise RecordingError(
                f"{self.source}: recording lacks channel(s) {missing} (has {sorted(self.channels)})"
            )
        for n in names:
            bad = ~np.isfinite(self.channels[n])
            if bad.any():
                raise RecordingError(
                    f"{self.source}: channel {n} has {int(bad.sum())} non-finite value(s), "
                    f"first at sample {int(np.flatnonzero(bad)[0])}"
                )

    def slice(self, start: int, stop: int) -> Recording:
        """Samples [start, stop) as a new recording with time re-based to 0; the duty cycles before
        ``start`` become its :attr:`duty_before` (a view of this recording's, not a copy, when this
        one starts its run)."""
        t = self.t[start:stop]
        start = int(start) if start >= 0 else len(self) + int(start)
        if start == 0:
            before = self.duty_before
        elif self.duty_before is None:
            before = self.duty[:start]
        else:
            before = np.concatenate([self.duty_before, self.duty[:start]])
        return Recording(
            t=t - t[0],
            duty=self.duty[start:stop].copy(),
            channels={k: v[start:stop].copy() for k, v in self.channels.items()},
            source=f"{self.source}[{start}:{stop}]",
            stamp0_ns=self.stamp0_ns + round(self.t[start] * 1e9),
            meta=dict(self.meta),
            extra={k: v[start:stop].copy() for k, v in self.extra.items()},
            extra_units=dict(self.extra_units),
            duty_before=before,
        )

    def split(self, train_fraction: float) -> tuple[Recording, Recording]:
        """Time-ordered split: first ``train_fraction`` for training, the rest held out."""
        if not 0.0 < train_fraction < 1.0:
            raise RecordingError(f"train_fraction {train_fraction} must be in (0, 1)")
        k = round(train_fraction * len(self))
        return self.slice(0, k), self.slice(k, len(self))

    @classmethod
    def from_trajectory(cls, traj: Any, source: str = "simulation", channels: tuple[str, ...] | None = None,
                        meta: dict[str, Any] | None = None) -> Recording:
        """Recording of a :class:`aeropend_sim.simulation.Trajectory` (measured channels).

        Parameters
        ----------
        channels : tuple of str, optional
            Channels to keep (default every measured channel the trajectory has: no armature
            channels for an ESC rig), e.g. ``("theta",)`` to mimic a rig that logs only the angle.
        """
        all_ch = traj.channels()
        names = tuple(n for n in MEASURED_CHANNELS if n in all_ch) if channels is None else channels
        missing = [n for n in names if n not in all_ch]
        if missing:
            raise RecordingError(f"{source}: the trajectory has no channel(s) {missing} "
                                 f"(has {sorted(all_ch)})")
        return cls(t=traj.t.copy(), duty=traj.duty.copy(), channels={n: all_ch[n].copy() for n in names},
                   source=source, meta=dict(meta or {}))
