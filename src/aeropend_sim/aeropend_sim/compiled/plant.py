"""A rig's compiled model at a sample period: parameter vectors, the sub-step plan, replays.

:class:`CompiledPlant` is what :func:`aeropend_sim.simulation.simulate` (``backend="compiled"``),
:func:`aeropend_sim.simulation.simulate_batch` and :class:`aeropend_sim.simulation.PlantStepper` run
on; a fit that replays one recording many times keeps one and calls :meth:`CompiledPlant.vectors`
(rig with these parameter values -> parameter vectors, no Python objects rebuilt) and
:func:`~aeropend_sim.simulation.simulate_batch`. Inputs are validated by those callers; this module
trusts them.

**Sub-steps.** Each sample period is integrated with K classical RK4 sub-steps (K + 1 with a
fractional input delay, split where the delayed command switches). K is at least
:data:`SUBSTEPS` and makes the sub-steps no longer than :data:`MAX_SUBSTEP` (the study's 6 per
2.048 ms: θ within 1e-6 rad of LSODA over 60 s of the thesis rig with every effect on,
docs/model.md), and large enough that every sub-step keeps |h·λ| ≤ :data:`STEP_BOUND` for the
eigenvalues λ of the plant's Jacobian at a few representative states (rest, the equilibria at
0.25, 0.75 and 1.25 rad, a state in end-stop contact): a stiff rig (a small L_a/R_a, a steep
friction regularisation) gets more sub-steps instead of an unstable replay. The plan is computed
for each parameter vector by the same code, so a batch row equals the single replay bit for bit.
"""

from __future__ import annotations

import itertools
import math
import os
import threading
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from aeropend_sim.compiled.source import Layout, family_module, layout
from aeropend_sim.components import registry
from aeropend_sim.components.assembly import effect_active
from aeropend_sim.components.base import Effect
from aeropend_sim.model import THETA, THETA_DOT, ModelError, PlantModel, plant_model
from aeropend_sim.params import Rig, RigFileError

#: Fewest RK4 sub-steps per sample (issue 37 study: K = 6 at the thesis rig's 2.048 ms keeps θ
#: within 1e-6 rad of LSODA).
SUBSTEPS = 6
#: Longest sub-step [s]: the one the study validated (2.048 ms / 6), so a rig sampled more slowly
#: gets more sub-steps per sample (100 Hz: 30), not longer ones.
MAX_SUBSTEP = 2.048e-3 / SUBSTEPS
#: Largest |h·λ| of a sub-step (RK4 is stable to 2.78 on the negative real axis; 0.5 keeps the
#: fast modes themselves accurate to 4e-4 per sub-step).
STEP_BOUND = 0.5
#: RK4's stability bound on the negative real axis (|R(z)| = 1 at z ≈ −2.785).
RK4_STABILITY = 2.785
#: Most sub-steps per sample; a plant that would need more is refused by the replay's caller.
MAX_SUBSTEPS = 4096
#: Angles [rad] of the equilibria among the representative states of the stiffness estimate.
PROBE_ANGLES = (0.25, 0.75, 1.25)

#: A batch of fewer row-samples than this is replayed in the calling thread (default ``threads``).
INLINE_STEPS = 50_000
_POOLS: dict[tuple[int, int], ThreadPoolExecutor] = {}
_POOLS_LOCK = threading.Lock()


def _replay_pool(n: int) -> ThreadPoolExecutor:
    """A thread pool of ``n`` workers kept for this process (:meth:`CompiledPlant.replay_batch`):
    a fit calls the replay tens of thousands of times, and a pool per call started 10 000 threads on
    one fit (jahoyosr's 44 windows). Keyed by the process id too: a forked child gets its own."""
    key = (os.getpid(), n)
    with _POOLS_LOCK:
        pool = _POOLS.get(key)
        if pool is None:
            pool = _POOLS[key] = ThreadPoolExecutor(max_workers=n, thread_name_prefix="aeropend-replay")
        return pool


def compiled_plant(rig: Rig, dt: float | None = None, substeps: int | None = None,
                   step_bound: float = STEP_BOUND) -> CompiledPlant:
    """The :class:`CompiledPlant` of ``rig`` (its plant model from :func:`aeropend_sim.model.plant_model`'s
    cache); parameters and errors as :class:`CompiledPlant`'s."""
    return CompiledPlant(plant_model(rig), dt, substeps, step_bound)


@dataclass(frozen=True)
class Plan:
    """Sub-step plan of each parameter row (arrays of shape (B,)).

    Attributes
    ----------
    substeps : ndarray of int
        K of the row.
    whole : ndarray of int
        Whole samples of the input delay.
    n_a, n_b : ndarray of int
        Sub-steps before / after the delayed command switches inside a sample (n_a = 0 without a
        fractional delay).
    h_a, h_b : ndarray of float
        Their lengths [s].
    """

    substeps: np.ndarray
    whole: np.ndarray
    n_a: np.ndarray
    h_a: np.ndarray
    n_b: np.ndarray
    h_b: np.ndarray

    def row(self, b: int) -> tuple[int, int, float, int, float]:
        """(whole, n_a, h_a, n_b, h_b) of row ``b`` as Python numbers."""
        return (int(self.whole[b]), int(self.n_a[b]), float(self.h_a[b]), int(self.n_b[b]),
                float(self.h_b[b]))


@dataclass(frozen=True)
class _Map:
    """Precomputed placement of a tuple of parameter keys (:meth:`CompiledPlant.vectors`)."""

    keys: tuple[str, ...]
    index: np.ndarray
    params: tuple[Any, ...]
    conditional: tuple[Effect, ...]
    checked: tuple[Any, ...]


class CompiledPlant:
    """A rig's compiled model at a sample period (module doc).

    Parameters
    ----------
    model : PlantModel
        The rig's plant model (:func:`aeropend_sim.model.plant_model`; :func:`compiled_plant`
        builds both from a rig).
    dt : float, optional
        Sample period [s] (default ``model.rig.sample_period``).
    substeps : int, optional
        Fewest RK4 sub-steps per sample (default: :data:`SUBSTEPS`, or more to keep sub-steps
        within :data:`MAX_SUBSTEP`); the stiffness bound may add more (module doc).
    step_bound : float
        Largest |h·λ| of a sub-step (default :data:`STEP_BOUND`; a fit that needs only the slow
        manifold of modes faster than a sample may loosen it up to :data:`RK4_STABILITY`).

    Raises
    ------
    ValueError
        A sample period that is not a finite number > 0, a sub-step count outside
        [1, :data:`MAX_SUBSTEPS`] or a step bound outside (0, :data:`RK4_STABILITY`].

    Attributes
    ----------
    rig : Rig
        ``model.rig``.
    layout : Layout
        The family's parameter vector layout.
    module : module
        The family's generated module (:mod:`aeropend_sim.compiled.source`).
    p : ndarray, shape (P,)
        The rig's parameter vector.
    plan : Plan
        The sub-step plan of ``p`` (one row).
    channels : tuple of str
        Channel names :meth:`outputs` gives for this family.
    """

    def __init__(self, model: PlantModel, dt: float | None = None, substeps: int | None = None,
                 step_bound: float = STEP_BOUND) -> None:
        self.model = model
        self.rig = rig = model.rig
        self.dt = float(rig.sample_period if dt is None else dt)
        if not (self.dt > 0.0 and math.isfinite(self.dt)):
            raise ValueError(f"sample period dt = {self.dt!r} must be a finite number > 0")
        if substeps is None:
            substeps = min(max(SUBSTEPS, math.ceil(self.dt / MAX_SUBSTEP - 1e-9)), MAX_SUBSTEPS)
        if not (isinstance(substeps, int | np.integer) and 1 <= substeps <= MAX_SUBSTEPS):
            raise ValueError(f"substeps = {substeps!r}: expected an integer in [1, {MAX_SUBSTEPS}]")
        self.min_substeps = int(substeps)
        if not 0.0 < step_bound <= RK4_STABILITY:
            raise ValueError(f"step_bound = {step_bound!r}: expected a number in (0, {RK4_STABILITY}] "
                             "(RK4's stability bound on the negative real axis)")
        self.step_bound = float(step_bound)
        self.layout: Layout = layout(rig.family)
        self.states = self.model.states
        self.module = family_module(rig.family, self.states.extra_names)
        self.p = self.layout.vector(self.model.assembly)
        self._probe_x, self._probe_u = _probes(self.model)
        self._delay = self.layout.index("actuator.input_delay")
        self._codes = _codes(self.model)
        self.channels = tuple(self._codes)
        self._maps: dict[tuple[str, ...], _Map] = {}
        self.plan = self.plans(self.p[None, :])
        self._code_arrays: dict[tuple[str, ...], np.ndarray] = {}

    # ------------------------------------------------------------------ parameter vectors
    def vectors(self, keys: Sequence[str], values: Any) -> np.ndarray:
        """Parameter vectors of the rig with ``keys`` set to each row of ``values``.

        Row b equals the vector of ``rig.with_params(...)`` with those values (flags of effects
        whose activity depends on a value, e.g. the lag on T_a > 0, follow), without building a
        rig per row.

        Parameters
        ----------
        keys : sequence of str
            Parameter keys (``"pendulum.c_over_J"``) of the rig's family; an effect's parameter
            only when the effect is switched on in the rig.
        values : array_like, shape (B, len(keys)) or (len(keys),)

        Returns
        -------
        ndarray, shape (B, P)

        Raises
        ------
        RigFileError
            On an unknown key, a key of an effect that is off, a wrong shape, or a value its
            parameter does not allow (the message names the row, the key and the value).
        """
        m = self._map(tuple(keys))
        v = np.asarray(values, dtype=float)
        v = v[None, :] if v.ndim == 1 else v
        if v.ndim != 2 or v.shape[1] != len(m.keys):
            raise RigFileError(f"values of shape {np.shape(values)} for {len(m.keys)} key(s) {list(m.keys)}: "
                               f"expected (B, {len(m.keys)})")
        out = np.repeat(self.p[None, :], v.shape[0], axis=0)
        out[:, m.index] = v
        for j, par in enumerate(m.params):
            for value in np.unique(v[:, j]):
                msg = par.violation(float(value))
                if msg:
                    b = int(np.flatnonzero((v[:, j] == value) | (np.isnan(v[:, j]) & np.isnan(value)))[0])
                    raise RigFileError(f"parameter set {b}: {msg}")
        if m.conditional or m.checked:
            self._conditions(m, v, out)
        return out

    def _map(self, keys: tuple[str, ...]) -> _Map:
        if keys in self._maps:
            return self._maps[keys]
        owners = registry.owners()
        params = []
        for key in keys:
            if key not in self.layout.keys:
                raise RigFileError(f"{key!r} is not a parameter of a {self.rig.family} rig; expected one of "
                                   f"{list(self.layout.keys)}")
            owner = owners[key]
            if isinstance(owner, Effect) and not owner.is_on(getattr(self.rig.effects, owner.name)):
                raise RigFileError(f"{key}: the {owner.name} effect is off in rig {self.rig.name!r}; "
                                   "switch it on (Rig.with_effects) to vary its parameters")
            params.append(registry.param(key))
        touched = list({owners[k].name: owners[k] for k in keys}.values())  # parts, once each
        conditional = tuple(e for e in touched if isinstance(e, Effect) and e.active_when is not None)
        checked = tuple(p for p in touched if p.check is not None)
        m = _Map(keys, np.array([self.layout.index(k) for k in keys], dtype=int), tuple(params),
                 conditional, checked)
        self._maps[keys] = m
        return m

    def _conditions(self, m: _Map, v: np.ndarray, out: np.ndarray) -> None:
        """Effects whose activity depends on the new values, and cross-parameter checks, per row."""
        raw = self.rig.values()
        for b in range(v.shape[0]):
            values = dict(raw)
            values.update(zip(m.keys, v[b].tolist(), strict=True))
            for part in m.checked:
                msg = part.check(values)
                if msg:
                    raise RigFileError(f"parameter set {b}: {msg}")
            for eff in m.conditional:
                active = effect_active(eff, getattr(self.rig.effects, eff.name), values)
                if eff.name in self.layout.flags:
                    out[b, self.layout.flag_index(eff.name)] = 1.0 if active else 0.0
                if not active:
                    for par in eff.params:
                        if par.absent is not None:
                            out[b, self.layout.index(par.key)] = par.absent

    # ------------------------------------------------------------------ sub-step plan
    def plans(self, p: np.ndarray) -> Plan:
        """The sub-step plan of each row of ``p`` (B, P) (module doc)."""
        jac = self.module.jacobians(self._probe_x, self._probe_u, np.ascontiguousarray(p))
        rho = np.abs(np.linalg.eigvals(jac)).max(axis=(1, 2))
        rho = np.where(np.isfinite(rho), rho, 0.0)  # a non-finite plant fails in the replay, by name
        k = np.clip(np.ceil(self.dt * rho / self.step_bound), self.min_substeps, MAX_SUBSTEPS)
        k = k.astype(np.int64)
        n = p[:, self._delay] / self.dt
        whole = np.floor(n + 1e-9)
        frac = n - whole
        frac = np.where(frac < 1e-9, 0.0, frac)
        n_a = np.where(frac > 0.0, np.ceil(frac * k - 1e-9), 0.0).astype(np.int64)
        n_b = np.ceil((1.0 - frac) * k - 1e-9).astype(np.int64)
        h_a = np.where(n_a > 0, frac * self.dt / np.maximum(n_a, 1), 0.0)
        return Plan(k, whole.astype(np.int64), n_a, h_a, n_b, (1.0 - frac) * self.dt / n_b)

    # ------------------------------------------------------------------ replays
    def replay(self, duty: np.ndarray, x0: np.ndarray, tau_before: float = 0.0,
               p: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int]:
        """States (N, n) at the sample instants, the commands (2, N) the actuator sees there and
        just before (:meth:`outputs` takes them), and -1 or the first sample whose state is not
        finite.

        Parameters
        ----------
        duty : ndarray, shape (N,)
            Validated duty cycles.
        x0 : ndarray, shape (n,)
            The whole state (:attr:`states`).
        tau_before : float
            Command the actuator sees before the first delayed command.
        p : ndarray, shape (P,), optional
            A parameter vector (default: the rig's).
        """
        plan = self.plan if p is None else self.plans(p[None, :])
        p = self.p if p is None else p
        x0 = self._whole(x0)
        states = np.empty((duty.size, self.states.size))
        u_at = np.empty(duty.size)
        u_before = np.empty(duty.size)
        failed = self.module.replay(x0, duty, float(tau_before), *plan.row(0), p, states, u_at, u_before)
        return states, np.stack([u_at, u_before]), int(failed)

    def outputs(self, states: np.ndarray, u: np.ndarray, names: Sequence[str] | None = None,
                p: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Noise-free channels (N,) of a replay, by name (default :attr:`channels`).

        ``u`` is what :meth:`replay` returns, shape (2, N): the command the actuator sees at each
        instant and the one it saw just before (the quasi-static armature current follows the
        latter, :func:`aeropend_sim.compiled.kernels.outputs`); a shape (N,) array is both."""
        names = self.channels if names is None else tuple(names)
        u = np.asarray(u, dtype=float)
        u_at, u_before = (u[0], u[1]) if u.ndim == 2 else (u, u)
        out = np.empty((len(names), u_at.size))
        self.module.outputs(states, np.ascontiguousarray(u_at), np.ascontiguousarray(u_before),
                            self.p if p is None else p, self._code_array(names), out)
        return dict(zip(names, out, strict=True))

    def codes(self, names: Sequence[str]) -> np.ndarray:
        """Output codes of channel names (:mod:`aeropend_sim.compiled.kernels`).

        Raises
        ------
        ValueError
            On a channel this family does not have (the message lists the ones it has).
        """
        bad = [n for n in names if n not in self._codes]
        if bad:
            raise ValueError(f"channel(s) {bad} do not exist for a {self.rig.family} rig; expected some of "
                             f"{list(self._codes)}")
        return np.array([self._codes[n] for n in names], dtype=np.int64)

    def _code_array(self, names: tuple[str, ...]) -> np.ndarray:
        """:meth:`codes` of ``names``, made once per tuple of names (a stepper asks for the same
        channels at every sample); the array is only read."""
        got = self._code_arrays.get(names)
        if got is None:
            got = self._code_arrays[names] = self.codes(names)
        return got

    def replay_batch(self, duty: np.ndarray, p: np.ndarray, x0: np.ndarray, tau_before: float,
                     names: Sequence[str], threads: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Channels (B, C, N) of one replay per row of ``p`` (B, P) from ``x0`` (B, n), and the
        failure index per row (-1: none).

        The rows are split into ``threads`` contiguous ranges (default: one per available core, at
        most one per row), each replayed by the compiled loop in a thread of its own: the kernel
        releases the GIL, so the ranges run at once. numba's ``parallel=True`` is not used: its
        default threading layers abort on parallel calls from two Python threads (workqueue) or
        hang a process forked after them (GNU OpenMP), and the fits run inside such pools.
        """
        plan = self.plans(p)
        codes = self.codes(names)
        p = np.ascontiguousarray(p)
        x0 = self._whole(x0)
        out = np.empty((p.shape[0], len(names), duty.size))
        failed = np.empty(p.shape[0], dtype=np.int64)
        args = (x0, duty, float(tau_before), plan.whole, plan.n_a, plan.h_a, plan.n_b, plan.h_b, p, codes,
                out, failed)
        n = min(p.shape[0], int(threads) if threads is not None else len(os.sched_getaffinity(0)))
        if threads is None and p.shape[0] * duty.size < INLINE_STEPS:
            n = 1  # a short window's few rows: starting threads would cost more than the replay
        if n <= 1:
            self.module.replay_batch(*args, 0, p.shape[0])
            return out, failed
        bounds = np.linspace(0, p.shape[0], n + 1).round().astype(int)
        pool = _replay_pool(n)
        for job in [pool.submit(self.module.replay_batch, *args, int(a), int(b))
                    for a, b in itertools.pairwise(bounds)]:
            job.result()
        return out, failed

    def step(self, x: np.ndarray, u_old: float, u_new: float) -> np.ndarray:
        """The state one sample after ``x``: ``u_old`` over the first ``frac·dt`` (a fractional
        input delay), ``u_new`` over the rest (:meth:`replay`'s scheme for one sample)."""
        _, n_a, h_a, n_b, h_b = self._row0
        return self.module.step(self._whole(x), float(u_old), float(u_new), self.p, n_a, h_a, n_b, h_b)

    @cached_property
    def _row0(self) -> tuple[int, int, float, int, float]:
        """:attr:`plan`'s row of the rig's parameters (:meth:`step` reads it at every sample)."""
        return self.plan.row(0)

    def _whole(self, x: np.ndarray) -> np.ndarray:
        """``x`` (…, n) as the kernels read it: the rig's whole state, C-contiguous floats. The
        compiled kernels do not check bounds, so a state of the chain's five given to a rig with an
        effect state of its own would read its T_m from memory past the row (gap fits of a heated
        rig gave run-to-run different residuals that way): completed here, any other length refused
        (:meth:`~aeropend_sim.components.states.StateLayout.complete`)."""
        return np.ascontiguousarray(self.states.complete(x), dtype=float)


def derivatives(model: PlantModel, x: Any, u: Any) -> tuple[np.ndarray, np.ndarray]:
    """The right-hand side of ``model`` at many states, by the compiled loop.

    Row j equals ``model.rhs(0.0, x[j], u[j])`` bit for bit (test_compiled.py), without a Python
    call per row; a recording's equation-error terms evaluate it at every sample.

    Parameters
    ----------
    model : PlantModel
    x : array_like, shape (N, n)
        States (``model.states``).
    u : array_like, shape (N,)
        Duty cycles τ reaching the actuator (after the input delay).

    Returns
    -------
    f : ndarray, shape (N, n)
        dx/dt in the state's units per second.
    drive : ndarray, shape (N,)
        The drive quantity at each row: v_a [V] of the voltage families, the ESC's rotor-speed
        set-point ω_ss [rad/s] (:meth:`PlantModel.drive` of the command past the lag).

    Raises
    ------
    ValueError
        On shapes other than (N, n) and (N,).
    """
    x = np.ascontiguousarray(x, dtype=float)
    u = np.ascontiguousarray(u, dtype=float)
    n = model.states.size
    if x.ndim != 2 or x.shape[1] != n or u.shape != (x.shape[0],):
        raise ValueError(f"states of shape {x.shape} and commands of shape {u.shape}: expected (N, {n}) and "
                         "(N,)")
    f = np.empty((x.shape[0], n))
    drive = np.empty(x.shape[0])
    module = family_module(model.family, model.states.extra_names)
    module.derivatives(x, u, layout(model.family).vector(model.assembly), f, drive)
    return f, drive


def _codes(model: PlantModel) -> dict[str, int]:
    """Channel name -> output code of the rig (kernels' CODE_* constants): a state's code is its
    index in the layout, the derived channels follow the state. A dynamic armature current is its
    state, read directly; only a quasi-static one is the derived CODE_I_A (computed from the command
    held before the instant, :func:`aeropend_sim.compiled.kernels.outputs`)."""
    st = model.states
    n = st.size
    codes = {name: st.index(name) for name in ("theta", "theta_dot", "omega_rotor", "tau_f")}
    codes.update({model.assembly.drive_name: n, "omega_prop": n + 2, "thrust": n + 3})
    if model.assembly.armature:
        codes["i_a"] = st.index("i_a") if model.dynamic_current else n + 1
    codes.update({s.name: st.index(s.name) for s in st.extra})
    return codes


def _probes(model: PlantModel) -> tuple[np.ndarray, np.ndarray]:
    """Representative states (R, n) and commands (R,) of the stiffness estimate (module doc)."""
    rest = model.states.initial()
    xs = [rest, rest.copy()]
    us = [0.0, 1.0]
    for theta in PROBE_ANGLES:
        try:
            x, tau = model.equilibrium(theta)
        except ModelError:
            continue
        xs.append(x)
        us.append(tau)
    values = model.assembly.values
    if model.stops:
        for side, sign in (("pendulum.theta_max", 1.0), ("pendulum.theta_min", -1.0)):
            if math.isfinite(values[side]):
                x = rest.copy()
                x[THETA] = values[side] + sign * 0.01
                x[THETA_DOT] = sign * 0.1
                xs.append(x)
                us.append(0.0)
    return np.array(xs), np.array(us)
