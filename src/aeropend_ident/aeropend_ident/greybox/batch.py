"""Batched replays of rig variants on one recording: what the fits evaluate many times.

The grey-box fit (:func:`aeropend_ident.greybox.fit.fit_greybox`), the gap diagnosis' effect fits,
multi-starts and the held-out prediction's Monte-Carlo draws (:mod:`aeropend_ident.gap`) replay
one recorded duty-cycle sequence with many parameter sets. :class:`RigReplays` keeps, per
recording, one :class:`~aeropend_sim.compiled.plant.CompiledPlant` per model structure (actuator
family and effect switches) and replays a whole list of rigs in one call of
:meth:`~aeropend_sim.compiled.plant.CompiledPlant.replay_batch` (the compiled loop over parameter
rows, shared out to threads): no model, compiled plant or sub-step probe is rebuilt per
evaluation, and a finite-difference Jacobian (1 + n_p rows), a multi-start or 300 draws are one
call each.

**Rows are rigs.** A row is given as a :class:`~aeropend_sim.params.Rig` built by the code that
owns the mapping from fitted quantities to rig parameters (an effect's ``apply``, the grey-box
fit's :func:`~aeropend_ident.greybox.parameters.apply_parameters`: quantities that are no rig key, such as
the gap's J_scale, V_drop, θ offset and scale, are mapped there, once). Building such a rig costs
≈ 0.1 ms, a replay of 40 s at 490 Hz 10-40 ms. The row's parameter vector is the structure's
vector with the values that differ from the structure's first rig set through
:meth:`CompiledPlant.vectors` (validated as the rig format does); a rig whose values the plant
refuses is replayed on a plant of its own. Row b equals ``simulate(rigs[b], duty, x0[b], ...,
backend="compiled")`` at the same sub-step count bit for bit.

**Sub-steps of fit replays.** :func:`fit_substeps`: RK4 sub-steps no longer than
:data:`FIT_MAX_SUBSTEP` (1 per 2.048 ms sample; a 100 Hz log gets 5), and more where the plant's
stiffness needs them, |h·λ| ≤ :data:`FIT_STEP_BOUND` = 2 for the eigenvalues λ of the plant's
Jacobian at its representative states (the compiled plant's bound; RK4 is stable to 2.785 on the
negative real axis), instead of the reference simulator's 6 per sample and |h·λ| ≤ 0.5. A mode
that fast (an armature with L_a/R_a of a few tenths of a sample, a regularised dry friction's
slope at rest) settles within a sample; a fit sees its slow manifold, which the stable sub-steps
keep, not its transient. On the thesis rig with every effect on this keeps θ within 2e-5 rad of
the LSODA reference over 60 s (docs/findings/simulator_backends.md, K = 1 column), and within
1e-5 rad with a dry friction up to (T_c/J)/v_ε = 6000 s⁻¹ that holds the rod most of the time
(test_batch.py), over an order of magnitude below the noise of any recorded angle, with a sixth of
the reference's sub-steps; reports replay the fitted rig with
:func:`aeropend_sim.simulation.simulate` (docs/model.md, "Simulation backends").

Exact Jacobians are not available: numba compiles the replay, it does not differentiate it;
the fits use finite differences through the batch.

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np

from aeropend_sim.compiled.plant import MAX_SUBSTEPS, CompiledPlant, compiled_plant
from aeropend_sim.model import ModelError
from aeropend_sim.params import Rig, RigFileError

#: Longest RK4 sub-step [s] of a fit replay (module doc): 1 sub-step per 2.048 ms sample.
FIT_MAX_SUBSTEP = 2.048e-3
#: Fewest RK4 sub-steps per sample of a fit replay.
FIT_MIN_SUBSTEPS = 1
#: Largest |h·λ| of a fit replay's sub-step (module doc).
FIT_STEP_BOUND = 2.0
#: Environment variable: threads one batch is shared out to (default one per available core; a
#: pool or cluster worker running one case per core sets 1, :mod:`aeropend_ident.parallel`).
THREADS_ENV = "AEROPEND_REPLAY_THREADS"


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS/OpenMP limited to one thread inside the block (threadpoolctl).

    The fits multiply tall, thin matrices (residuals × parameters); OpenBLAS' threads then spin
    against other processes on a busy machine, which made such products up to 300× slower here.
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        yield


def single_blas(func: Callable[..., Any]) -> Callable[..., Any]:
    """Decorator: the function runs with :func:`one_blas_thread`."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with one_blas_thread():
            return func(*args, **kwargs)

    return wrapper


def fit_substeps(dt: float) -> int:
    """Fewest RK4 sub-steps per sample of a fit replay at sample period ``dt`` [s] (module doc)."""
    return min(max(FIT_MIN_SUBSTEPS, math.ceil(float(dt) / FIT_MAX_SUBSTEP - 1e-9)), MAX_SUBSTEPS)


#: Per-thread limit of :func:`replay_threads` (:func:`one_replay_thread`).
_thread_limit = threading.local()


@contextmanager
def one_replay_thread() -> Iterator[None]:
    """Batch replays started by this thread inside the block run on this thread alone.

    For work that is itself shared out to one thread per core (the diagnosis' independent fits,
    :func:`aeropend_ident.gap.which.context._each`): splitting each of its replays over the cores again
    would run twice as many compute threads as cores, and every replay thread that finished would
    wait for the GIL held by the other fit's Python (measured on the independent benchmark's
    median cases: the threaded fits took no less wall time than one fit after the other).
    """
    before = getattr(_thread_limit, "n", None)
    _thread_limit.n = 1
    try:
        yield
    finally:
        _thread_limit.n = before


def replay_threads() -> int | None:
    """Threads of a batch replay: 1 inside :func:`one_replay_thread`, else :data:`THREADS_ENV` if set
    (>= 1), else None (one per core)."""
    limit = getattr(_thread_limit, "n", None)
    if limit is not None:
        return limit
    raw = os.environ.get(THREADS_ENV, "").strip()
    if not raw:
        return None
    try:
        n = int(raw)
    except ValueError:
        return None
    return n if n >= 1 else None


def structure(rig: Rig) -> tuple:
    """What a compiled plant is built for: the actuator family and every effect switch."""
    eff = rig.effects
    return (rig.family, tuple(getattr(eff, f.name) for f in dataclasses.fields(eff)))


def _same(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


class RigReplays:
    """Replays of many rigs on one duty-cycle sequence (module doc).

    Parameters
    ----------
    duty : ndarray, shape (N,)
        Duty cycles τ_k ∈ [0, 1] (validated by the caller, e.g. a prepared recording).
    dt : float
        Sample period [s].
    tau_before : float
        Command the actuator sees before the first delayed command.
    substeps : int, optional
        Fewest RK4 sub-steps per sample (default :func:`fit_substeps`).
    """

    def __init__(self, duty: np.ndarray, dt: float, tau_before: float = 0.0,
                 substeps: int | None = None) -> None:
        self.duty = np.ascontiguousarray(duty, dtype=float)
        self.dt = float(dt)
        self.tau_before = float(tau_before)
        self.substeps = fit_substeps(self.dt) if substeps is None else int(substeps)
        self._plants: dict[tuple, tuple[CompiledPlant, dict[str, float]]] = {}
        #: Replayed rows, for the record (benchmarks count them).
        self.rows = 0
        # the fits of one diagnosis step may replay on one recording from several threads at once
        self._lock = threading.Lock()

    def __getstate__(self) -> dict[str, Any]:  # a lock does not pickle: a copy gets its own
        return {k: v for k, v in self.__dict__.items() if k != "_lock"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()

    def plant(self, rig: Rig) -> tuple[CompiledPlant, dict[str, float]]:
        """The compiled plant of ``rig``'s structure (built on first use, once also when several
        threads ask for it) and its base values."""
        key = structure(rig)
        with self._lock:
            if key not in self._plants:
                plant = compiled_plant(rig, self.dt, substeps=self.substeps, step_bound=FIT_STEP_BOUND)
                self._plants[key] = (plant, rig.values())
            return self._plants[key]

    def _vectors(self, plant: CompiledPlant, base: dict[str, float], rigs: Sequence[Rig]) -> np.ndarray:
        values = [r.values() for r in rigs]
        # a key outside the family's vector (a sensor setting) never reaches the replay
        keys = sorted({k for v in values for k in plant.layout.keys if not _same(v[k], base[k])})
        table = np.array([[v[k] for k in keys] for v in values]).reshape(len(rigs), len(keys))
        return plant.vectors(keys, table)

    def run(self, rigs: Sequence[Rig], x0: np.ndarray, channels: Sequence[str],
            carried: Sequence[Mapping[str, float] | None] | None = None
            ) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """Replay every rig from its initial state.

        Parameters
        ----------
        rigs : sequence of Rig
            Noise-free rigs (measurement effects are the caller's).
        x0 : ndarray, shape (B, n) or (B, 5)
            Initial states: each rig's whole state, or the chain's five (an effect's own state, a
            winding temperature, then starts at its initial value).
        channels : sequence of str
            Channel names (:func:`aeropend_sim.simulation.simulate_batch`).
        carried : sequence of (mapping or None), optional
            Per row, values of some of the rig's own effect states by name (a winding temperature
            [K] carried over from an earlier part of the run), set in the completed state; None (or
            a row's None) leaves them at their initial values.

        Returns
        -------
        (dict, ndarray)
            Channel -> (B, N) noise-free values (NaN rows for failed replays), and the (B,) mask of
            rows whose replay succeeded (a value the rig format refuses, a plant that cannot be
            built, or a replay that diverges fails its row only).
        """
        n_rows = len(rigs)
        out = {c: np.full((n_rows, self.duty.size), np.nan) for c in channels}
        ok = np.zeros(n_rows, dtype=bool)
        x0 = np.asarray(x0, dtype=float).reshape(n_rows, -1)
        groups: dict[tuple, list[int]] = {}
        for b, r in enumerate(rigs):
            groups.setdefault(structure(r), []).append(b)
        for rows in groups.values():
            try:
                plant, base = self.plant(rigs[rows[0]])
                p = self._vectors(plant, base, [rigs[b] for b in rows])
            except (RigFileError, ModelError, ValueError):
                for b in rows:  # one by one: only the rows the format or the model refuses fail
                    self._single(rigs[b], x0, channels, out, ok, b, carried)
                continue
            self._replay(plant, p, rows, x0, channels, out, ok, carried)
        with self._lock:
            self.rows += n_rows
        return out, ok

    def _single(self, rig: Rig, x0: np.ndarray, channels: Sequence[str], out: dict[str, np.ndarray],
                ok: np.ndarray, b: int, carried: Sequence[Mapping[str, float] | None] | None) -> None:
        """Replay row ``b`` alone (``x0``: the whole (B, n) array of initial states, as in :meth:`run`)."""
        try:
            plant, base = self.plant(rig)
            p = self._vectors(plant, base, [rig])
        except (RigFileError, ModelError, ValueError):
            try:
                plant = compiled_plant(rig, self.dt, substeps=self.substeps, step_bound=FIT_STEP_BOUND)
            except (RigFileError, ModelError, ValueError):
                return
            p = plant.p[None, :]
        self._replay(plant, p, [b], x0, channels, out, ok, carried)

    def _replay(self, plant: CompiledPlant, p: np.ndarray, rows: Sequence[int], x0: np.ndarray,
                channels: Sequence[str], out: dict[str, np.ndarray], ok: np.ndarray,
                carried: Sequence[Mapping[str, float] | None] | None = None) -> None:
        xs = np.ascontiguousarray(x0[list(rows)])  # a chain-only state: completed by the plant
        if carried is not None and any(carried[b] for b in rows):
            xs = np.array([plant.states.with_values(x, carried[b]) for x, b in zip(xs, rows, strict=True)])
        if not np.isfinite(xs).all():
            good = np.isfinite(xs).all(axis=1)
            rows = [b for b, g in zip(rows, good, strict=True) if g]
            p, xs = p[good], np.ascontiguousarray(xs[good])
            if not rows:
                return
        vals, failed = plant.replay_batch(self.duty, p, xs, self.tau_before, tuple(channels),
                                          replay_threads())
        for i, b in enumerate(rows):
            if failed[i] < 0:
                ok[b] = True
                for c, name in enumerate(channels):
                    out[name][b] = vals[i, c]
