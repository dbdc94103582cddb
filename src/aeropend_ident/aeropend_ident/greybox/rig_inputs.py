"""What a lab hands ``rig fit``: static characterisation tables and recordings, each told apart.

**Static tables** are CSV files with a header row naming their columns (docs/rig_command.md):

==================  ======================================================================
column              meaning
==================  ======================================================================
``command``         the command as a fraction of its range, the duty cycle τ ∈ [0, 1] (the
                    same map as the recordings' CSV preset; ``duty`` is read the same)
``angle_rad``       balance angle θ [rad] held at that command (0 = hanging); or
``angle_deg``       the same in degrees
``angle_std_rad``   optional: standard error of each angle [rad] (e.g. the std of the averaged
                    window over √n); ``angle_std_deg`` in degrees
``thrust_N``        thrust [N] from a load cell at that command (a thrust table)
``thrust_std_N``    optional: standard error of each thrust [N]
==================  ======================================================================

A table with an angle column is a **balance table** (command vs angle: the static map up to a
scale, and the dead zone or idle throttle); one with a thrust column a **thrust table** (thrust
vs command: K_q and the map). A CSV with a ``command``/``duty`` column, one of those columns and
no time column is a table; anything else is a recording for
:func:`aeropend_ident.io.recording_input.load_recording` (bags, ``FILE.csv:PRESET``).

**Recordings** are classified by their input: a constant command is a **free decay** (the rod
released and left to swing); a recording with the controller's reference
(:data:`aeropend_sim.contract.REFERENCE_CHANNEL`) is a **closed-loop** log; otherwise a few long
holds are **steps** and many short ones **PRBS/APRBS**. :func:`shortest_hold` says how fast the
command changed, which decides whether timing parameters can be determined.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.errors import RecordingInputError
from aeropend_ident.greybox.fit import measurement_noise
from aeropend_ident.greybox.uniform import UniformData, decimated, rod_stiffness
from aeropend_ident.io.recording_input import load_recording, split_preset
from aeropend_ident.io.resampling import uniform_recording
from aeropend_sim.contract import REFERENCE_CHANNEL
from aeropend_sim.recording import Recording

#: Column names of a table's command (a fraction in [0, 1]).
COMMAND_COLUMNS = ("command", "duty")
#: Value columns: name -> (kind, factor to SI).
VALUE_COLUMNS = {"angle_rad": ("balance", 1.0), "angle_deg": ("balance", math.pi / 180.0),
                 "thrust_N": ("thrust", 1.0)}
#: Optional standard-error columns: name -> factor to SI.
STD_COLUMNS = {"angle_std_rad": 1.0, "angle_std_deg": math.pi / 180.0, "thrust_std_N": 1.0}
#: Fewest rows of a table.
MIN_ROWS = 3
#: Recordings with at most this many distinct holds are called steps (more: PRBS/APRBS).
MAX_STEP_HOLDS = 12

KINDS = {
    "balance": "balance table (static map: command vs angle)",
    "thrust": "thrust table (load cell: thrust vs command)",
    "free decay": "free decay (output error of the swing)",
    "steps": "steps (output error, free run)",
    "PRBS": "PRBS/APRBS (output error, free run)",
    "closed loop": "closed-loop log (output error, free run of the logged command)",
}


@dataclass(frozen=True)
class StaticTable:
    """A static characterisation table (module docstring).

    Attributes
    ----------
    kind : str
        ``"balance"`` or ``"thrust"``.
    command : ndarray, shape (M,)
        τ ∈ [0, 1].
    value : ndarray, shape (M,)
        Balance angle [rad] or thrust [N].
    std : ndarray or None, shape (M,)
        Standard error of each value (None: estimated from the fit's residual).
    source : str
        File name.
    """

    kind: str
    command: np.ndarray
    value: np.ndarray
    std: np.ndarray | None
    source: str

    @property
    def label(self) -> str:
        """Method label for provenance."""
        return KINDS[self.kind]


@dataclass(frozen=True)
class TimeSeries:
    """A recording on a uniform grid with its kind (free decay, steps, PRBS, closed loop)."""

    kind: str
    data: UniformData
    source: str
    #: White measurement noise σ of θ [rad], estimated on the recorded samples (before the
    #: resampling: a stretch it interpolates across a gap is a straight line without noise, and
    #: would pull the estimate on the uniform grid towards 0).
    noise: float = 0.0
    #: The recording on its own uniform grid when ``data`` is the coarser fit grid
    #: (:func:`fit_grid`); the reported figures replay this one (the one replay of every command).
    full: UniformData | None = None

    @property
    def replayed(self) -> UniformData:
        """The data every reported figure replays: the recording on its own uniform grid."""
        return self.full if self.full is not None else self.data

    @property
    def label(self) -> str:
        """Method label for provenance."""
        return KINDS[self.kind]


def _header(path: Path) -> list[str] | None:
    if path.suffix.lower() != ".csv" or not path.is_file():
        return None
    with path.open(encoding="utf-8", newline="") as fh:
        first = fh.readline()
    return [c.strip() for c in first.strip().split(",")] if first else None


def is_table(arg: str | Path) -> bool:
    """Whether an input argument is a static table (a ``.csv`` with a command and a value column,
    no time column, no ``:PRESET``)."""
    path, preset = split_preset(arg)
    head = _header(path) if preset is None else None
    if not head:
        return False
    return (any(c in head for c in COMMAND_COLUMNS) and any(c in head for c in VALUE_COLUMNS)
            and not any(c.lower().startswith("time") or c.lower() in ("t", "t_s") for c in head))


def read_table(path: str | Path) -> StaticTable:
    """Read a static table (module docstring).

    Raises
    ------
    RecordingInputError
        No command or value column, both an angle and a thrust column, a non-number, a command
        outside [0, 1], a non-positive std, or fewer than :data:`MIN_ROWS` rows (the message names
        the file, the row and the column).
    """
    path = Path(path)
    with path.open(encoding="utf-8", newline="") as fh:
        rows = list(csv.reader(fh))
    head = [c.strip() for c in rows[0]] if rows else []
    cmd = next((c for c in COMMAND_COLUMNS if c in head), None)
    vals = [c for c in VALUE_COLUMNS if c in head]
    kinds = {VALUE_COLUMNS[c][0] for c in vals}
    if cmd is None or not vals or len(kinds) > 1:
        raise RecordingInputError(
            f"{path.name}: a static table needs a header with one command column {COMMAND_COLUMNS} and the "
            f"value columns of one kind ({sorted(VALUE_COLUMNS)}); got {head}")
    col = vals[0]
    std_col = next((c for c in STD_COLUMNS if c in head and c.split("_std")[0] == col.split("_")[0]), None)
    data: dict[str, list[float]] = {cmd: [], col: [], **({std_col: []} if std_col else {})}
    for k, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        for name in data:
            cell = row[head.index(name)].strip() if head.index(name) < len(row) else ""
            try:
                v = float(cell)
            except ValueError:
                raise RecordingInputError(f"{path.name}: row {k}, column {name}: {cell!r} is not a "
                                          "number") from None
            if not math.isfinite(v):
                raise RecordingInputError(f"{path.name}: row {k}, column {name}: {cell!r} is not finite")
            data[name].append(v)
    command = np.array(data[cmd])
    if command.size < MIN_ROWS:
        raise RecordingInputError(f"{path.name}: {command.size} row(s); a static table needs at least "
                                  f"{MIN_ROWS}")
    bad = (command < 0.0) | (command > 1.0)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise RecordingInputError(f"{path.name}: {cmd} = {command[k]!r} in data row {k + 1} is outside "
                                  "[0, 1] (a fraction of the command range)")
    kind, factor = VALUE_COLUMNS[col]
    std = None
    if std_col:
        std = np.array(data[std_col]) * STD_COLUMNS[std_col]
        if np.any(std <= 0.0):
            raise RecordingInputError(f"{path.name}: {std_col} must be > 0 in every row")
    return StaticTable(kind=kind, command=command, value=np.array(data[col]) * factor, std=std,
                       source=path.name)


def holds(duty: np.ndarray, dt: float) -> np.ndarray:
    """Lengths [s] of the runs of constant command (the first and last runs included)."""
    change = np.flatnonzero(np.abs(np.diff(duty)) > 1e-9) + 1
    edges = np.concatenate([[0], change, [duty.size]])
    return np.diff(edges) * dt


def shortest_hold(series: list[TimeSeries]) -> float:
    """Shortest inner hold [s] of the command over the recordings that change it (inf if none)."""
    out = math.inf
    for s in series:
        h = holds(s.data.duty, s.data.dt)
        if h.size > 2:
            out = min(out, float(np.min(h[1:-1])))
        elif h.size == 2:  # one step: the command held before it and after it
            out = min(out, float(np.min(h)))
    return out


def classify(rec: Recording) -> str:
    """Kind of a recording: ``"free decay"``, ``"closed loop"``, ``"steps"`` or ``"PRBS"``."""
    if float(np.ptp(rec.duty)) == 0.0:
        return "free decay"
    if REFERENCE_CHANNEL in rec.extra:
        return "closed loop"
    n = np.count_nonzero(np.abs(np.diff(rec.duty)) > 1e-9) + 1
    return "steps" if n <= MAX_STEP_HOLDS else "PRBS"


def recorded_noise(t: np.ndarray, theta: np.ndarray) -> float:
    """Noise σ of θ [rad] on the recorded samples (:func:`~aeropend_ident.greybox.fit.measurement_noise`).

    Only second differences over three samples at the recording's regular interval count: one
    across a gap (a logger that writes in bursts) holds the motion of the whole gap, not noise.
    """
    t = np.asarray(t, dtype=float)
    theta = np.asarray(theta, dtype=float)
    if t.size < 5:
        return measurement_noise(theta)
    dt = np.diff(t)
    med = float(np.median(dt))
    regular = np.abs(dt - med) <= 0.25 * med
    keep = regular[:-1] & regular[1:]
    if np.count_nonzero(keep) < 3:
        return measurement_noise(theta)
    return measurement_noise(theta, keep=keep)


#: Samples per small-signal swing period of the rod on the fit grid (:func:`fit_grid`).
FIT_SAMPLES_PER_SWING = 50
#: The fit grid is never coarser than this [s] (timing parameters of tens of ms stay resolved).
FIT_GRID_MAX = 0.005


def fit_grid(rig: Any) -> float:
    """The fit grid step [s] the rig's dynamics ask for: :data:`FIT_SAMPLES_PER_SWING` per period of
    the rod's small-signal swing about the hanging rest, at most :data:`FIT_GRID_MAX`.

    θ is the rod's response, a double integral of the thrust: a logger's faster samples add no
    information a grid this fine loses, only simulation steps (a 600 Hz log is 6× the work of 100 Hz).
    A recording logged on a coarser grid keeps its own. The rod's stiffness comes from the rig's
    starting values (``rig new``'s values are within a factor of a few: the rule has a margin).
    """
    try:
        k = rod_stiffness(rig)
    except Exception:  # a rig the model cannot linearise: the cap
        return FIT_GRID_MAX
    if not (math.isfinite(k) and k > 0.0):
        return FIT_GRID_MAX
    return min(FIT_GRID_MAX, 2.0 * math.pi / math.sqrt(k) / FIT_SAMPLES_PER_SWING)


def time_series(rec: Recording, grid: float | None = None) -> TimeSeries:
    """A recording on its uniform grid (the one resampling of every command) with its kind.

    Parameters
    ----------
    rec : Recording
    grid : float, optional
        Fit grid step [s] (:func:`fit_grid`): a recording logged more than 1.5× finer is fitted on
        every k-th sample of its uniform grid (k = ⌊grid / dt⌋; θ at the block starts, the duty cycle
        averaged over each block), its own grid kept in ``full`` for the reported figures.

    Raises
    ------
    RecordingInputError
        No θ, NaNs, out-of-order stamps (:func:`~aeropend_ident.io.resampling.uniform_recording`),
        or fewer than 20 samples.
    """
    u = uniform_recording(rec)
    if len(u) < 20:
        raise RecordingInputError(f"{rec.source}: {len(u)} samples; rig fit needs at least 20 per recording")
    t = u.t - u.t[0]
    dt = float(np.median(np.diff(t)))
    data = UniformData(t=t, duty=np.clip(u.duty, 0.0, 1.0), theta=u.channels["theta"].copy(), dt=dt,
                       resampled=u is not rec, decimate=1, source=rec.source)
    full = None
    k = int(grid // dt) if grid is not None and grid > 1.5 * dt else 1
    if k > 1 and len(data) // k >= 20:
        duty, theta = decimated(data.duty, data.theta, k)
        full, data = data, UniformData(t=np.arange(theta.size) * dt * k, duty=duty, theta=theta, dt=dt * k,
                                       resampled=data.resampled, decimate=k, source=rec.source)
    return TimeSeries(kind=classify(u), data=data, source=Path(str(rec.source)).name or str(rec.source),
                      noise=recorded_noise(rec.t, rec.channels["theta"]), full=full)


def read_inputs(args: list[str], preset: str | None = None, grid: float | None = None
                ) -> tuple[list[StaticTable], list[TimeSeries]]:
    """Tables and recordings of ``rig fit``'s / ``rig check``'s arguments, each told apart
    (``grid``: the fit grid step [s] of :func:`time_series`).

    Raises
    ------
    RecordingInputError, BagError, CsvImportError, RecordingError
        From the readers (a missing file, an unknown kind, a bad table).
    """
    tables, series = [], []
    for a in args:
        if is_table(a):
            tables.append(read_table(split_preset(a)[0]))
        else:
            series.append(time_series(load_recording(a, preset), grid))
    return tables, series
