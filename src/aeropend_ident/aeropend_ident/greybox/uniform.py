"""A recording made ready for a grey-box fit: on a uniform grid, checked, decimated (:class:`UniformData`).

:func:`uniform_data` puts a recording on the fit's uniform grid (the one resampling of every tool,
:func:`aeropend_ident.io.resampling.uniform_recording`) and decimates it by blocks
(:func:`decimated`); :func:`check_recording` and :func:`check_excited` refuse recordings a fit cannot
use, naming why; :func:`rod_stiffness` is the rod's small-signal stiffness that sets the fit grid.
Used by :mod:`aeropend_ident.greybox.fit` and ``rig fit``.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from aeropend_ident.errors import IdentificationError, RecordingInputError
from aeropend_ident.io.resampling import grid_step, uniform_recording
from aeropend_sim.model import THETA, THETA_DOT, plant_model
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording

#: Fewest samples a fit accepts (after resampling/decimation).
MIN_SAMPLES = 50


@dataclass(frozen=True)
class UniformData:
    """θ and duty on a uniform time grid (what the simulator and the fit consume).

    Attributes
    ----------
    t : ndarray, shape (N,)
        t_k = k·dt [s].
    duty : ndarray, shape (N,)
        Duty cycle τ_k ∈ [0, 1] held over [t_k, t_{k+1}).
    theta : ndarray, shape (N,)
        Recorded angle [rad] in the recording's frame.
    dt : float
        Grid period [s].
    resampled : bool
        True if the recording was not uniform and was resampled.
    decimate : int
        Decimation factor applied.
    source : str
        The recording's source.
    segments : tuple of int
        Start index of every recording in the data (several recordings fitted together,
        :func:`concat_uniform`): each starts its own free run from its own initial state; (0,) for
        one recording.
    """

    t: np.ndarray
    duty: np.ndarray
    theta: np.ndarray
    dt: float
    resampled: bool
    decimate: int
    source: str
    segments: tuple[int, ...] = (0,)

    def __len__(self) -> int:
        return int(self.t.size)

    def bounds(self) -> list[tuple[int, int]]:
        """(start, stop) sample indices of every segment."""
        return list(itertools.pairwise([*self.segments, len(self)]))

    def window(self, start: int, stop: int) -> UniformData:
        """Samples [start, stop) as data of their own (time re-based to 0, one segment)."""
        return _window(self, start, stop)

    def parts(self) -> list[UniformData]:
        """Every segment as data of its own (time re-based to 0, one segment)."""
        if len(self.segments) == 1:
            return [self]
        names = self.source.split(" + ")
        out = []
        for k, (a, b) in enumerate(self.bounds()):
            part = _window(self, a, b)
            out.append(dataclasses.replace(part, source=names[k] if len(names) == len(self.segments) else
                                           f"{self.source}[{a}:{b}]"))
        return out


def concat_uniform(parts: Sequence[UniformData]) -> UniformData:
    """Several recordings on one grid as one data set with segments (each its own free run).

    Raises
    ------
    IdentificationError
        On an empty list or different grid steps (resample them onto one grid first:
        :func:`uniform_data` with ``dt``).
    """
    if not parts:
        raise IdentificationError("no recording to fit")
    if len(parts) == 1:
        return parts[0]
    dt = parts[0].dt
    for p in parts[1:]:
        if abs(p.dt - dt) > 1e-9 * dt:
            raise IdentificationError(f"{p.source}: grid step {p.dt:g} s differs from {dt:g} s of "
                                      f"{parts[0].source}; put the recordings on one grid "
                                      "(uniform_data(..., dt=...))")
    starts, n = [], 0
    for p in parts:
        starts.extend(n + k for k in p.segments)
        n += len(p)
    return UniformData(
        t=np.arange(n) * dt, duty=np.concatenate([p.duty for p in parts]),
        theta=np.concatenate([p.theta for p in parts]), dt=dt, resampled=any(p.resampled for p in parts),
        decimate=parts[0].decimate, source=" + ".join(p.source for p in parts), segments=tuple(starts),
    )


def check_recording(recording: Recording, min_samples: int = MIN_SAMPLES) -> None:
    """Refuse recordings that a θ-only grey-box fit cannot use.

    Raises
    ------
    IdentificationError
        If θ is missing, θ or the duty cycle has NaN/inf, the duty cycle is outside [0, 1], or
        there are fewer than ``min_samples`` samples. Whether the data excite the rig is decided on
        what is fitted (:func:`aeropend_ident.greybox.fit.fit_greybox`, :func:`check_excited`): a held-out
        part may be a
        constant hold.
    """
    src = recording.source or "<recording>"
    if "theta" not in recording.channels:
        raise IdentificationError(
            f"{src}: recording has no 'theta' channel (has {sorted(recording.channels)}); "
            "the grey-box fit compares simulated and recorded angles"
        )
    theta, duty = recording.channels["theta"], recording.duty
    for what, y in (("theta", theta), ("duty", duty)):
        bad = ~np.isfinite(y)
        if bad.any():
            raise IdentificationError(
                f"{src}: {what} has {int(bad.sum())} NaN/inf value(s), first at sample "
                f"{int(np.flatnonzero(bad)[0])} (t = {recording.t[np.flatnonzero(bad)[0]]:.4g} s); "
                "expected finite values (drop or repair those samples first)"
            )
    if len(recording) < min_samples:
        raise IdentificationError(
            f"{src}: only {len(recording)} samples; a grey-box fit needs at least {min_samples}"
        )
    out = (duty < 0.0) | (duty > 1.0)
    if out.any():
        k = int(np.flatnonzero(out)[0])
        raise IdentificationError(f"{src}: duty[{k}] = {float(duty[k])!r} is outside [0, 1] (a fraction)")


def check_excited(data: UniformData, reference: str | None = None) -> None:
    """Refuse fit data that do not excite the rig (identifiability decided on what is fitted).

    Each segment (recording) is checked by
    :func:`aeropend_ident.io.csvspec.constant_input.excitation_problem`: a segment whose constant
    duty cycle cannot explain θ (a driven log without its command, e.g. a closed loop's reference
    alone) is refused with the ``csv_import`` message; the data are refused as unexcited when no
    segment excites the rig (constant duty and θ at rest). A free decay or a step from rest under a
    constant duty is accepted.

    Raises
    ------
    IdentificationError
        Naming the recording and the reason.
    """
    from aeropend_ident.io.csvspec.constant_input import excitation_problem

    problems = []
    for part in data.parts():
        found = excitation_problem(part.t, part.duty, part.theta, reference)
        if found is not None and found[0] == "driven":
            raise IdentificationError(f"{part.source or '<recording>'}: {found[1]}")
        problems.append(found)
    if all(p is not None for p in problems):
        raise IdentificationError(f"{data.source or '<recording>'}: {problems[0][1]}")


def decimated(duty: np.ndarray, theta: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Every ``k``-th sample of a uniform grid: θ at each block's start, the duty cycle averaged over
    the block (an incomplete last block dropped); arrays of shape (N // k,)."""
    m = theta.size // k
    return duty[: m * k].reshape(m, k).mean(axis=1), theta[: m * k: k].copy()


def rod_stiffness(rig: Rig, theta: float = 0.0) -> float:
    """Linearised restoring stiffness −∂θ̈/∂θ [1/s²] of the rod at angle θ [rad], at rest: the square
    of its small-signal swing frequency (:meth:`aeropend_sim.model.PlantModel.jacobian`)."""
    a, _ = plant_model(rig).jacobian([theta, 0.0, 0.0, 0.0, 0.0], 0.0)
    return float(-a[THETA_DOT, THETA])


def uniform_data(
    recording: Recording, dt: float | None = None, decimate: int = 1, min_samples: int = MIN_SAMPLES
) -> UniformData:
    """Validate a recording and put θ and the duty cycle on a uniform grid.

    Parameters
    ----------
    recording : Recording
        Needs ``theta``; t may be non-uniform.
    dt : float, optional
        Grid period [s]; default the recording's median interval. A ``dt`` different from the
        recording's forces resampling.
    decimate : int
        Keep every ``decimate``-th sample (duty averaged over each block); 1 = no decimation.
    min_samples : int
        Fewest samples accepted, after decimation.

    Returns
    -------
    UniformData

    Raises
    ------
    IdentificationError
        See :func:`check_recording`; also on ``dt`` <= 0 or ``decimate`` < 1.
    """
    check_recording(recording, min_samples=2)
    if int(decimate) != decimate or decimate < 1:
        raise IdentificationError(f"decimate = {decimate!r}; expected an integer >= 1")
    decimate = int(decimate)
    t = recording.t - recording.t[0]
    theta, duty = recording.channels["theta"], recording.duty
    grid_dt = grid_step(t) if dt is None else float(dt)
    if not (math.isfinite(grid_dt) and grid_dt > 0.0):
        raise IdentificationError(f"grid period dt = {dt!r}; expected a finite value > 0 s")
    # the one resampling of every tool (io/recording_input.py: θ interpolated, or its nearest sample
    # when quantised; the duty cycle held), on θ and the duty cycle only
    try:
        grid = uniform_recording(
            Recording(t=t, duty=duty, channels={"theta": theta}, source=recording.source), dt=grid_dt)
    except RecordingInputError as exc:
        raise IdentificationError(str(exc)) from exc
    tu, th, du = grid.t.copy(), grid.channels["theta"].copy(), grid.duty.copy()
    uniform = "resampling" not in grid.meta
    if decimate > 1:
        if tu.size // decimate < 1:
            raise IdentificationError(f"decimate = {decimate} leaves no sample of {tu.size}")
        du, th = decimated(du, th, decimate)
        tu = np.arange(th.size) * grid_dt * decimate
    data = UniformData(
        t=tu, duty=np.clip(du, 0.0, 1.0), theta=th, dt=grid_dt * decimate, resampled=not uniform,
        decimate=decimate, source=recording.source,
    )
    if len(data) < min_samples:
        raise IdentificationError(
            f"{recording.source or '<recording>'}: only {len(data)} samples on the fit grid "
            f"(dt = {data.dt:.4g} s); a grey-box fit needs at least {min_samples}"
        )
    return data


def _window(data: UniformData, start: int, stop: int) -> UniformData:
    """Samples [start, stop) of a uniform data set, time re-based to 0."""
    return dataclasses.replace(
        data, t=data.t[start:stop] - data.t[start], duty=data.duty[start:stop], theta=data.theta[start:stop],
        segments=(0,),
    )

