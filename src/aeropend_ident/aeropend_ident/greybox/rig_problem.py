"""The joint weighted least-squares problem of ``rig fit``: one residual block per input.

Each input contributes a block of residuals in its own unit, divided by that block's noise σ_b:

* :class:`BalanceBlock` — a balance table: θ_model(τ_i) − θ_i, θ_model the angle the model holds
  at command τ_i (:meth:`aeropend_sim.model.PlantModel.equilibrium`, inverted by Brent's method);
* :class:`ThrustBlock` — a thrust table: f_model(τ_i) − f_i, the steady thrust of the model at τ_i
  (:func:`aeropend_ident.greybox.fit.motor_equilibrium`, :meth:`~aeropend_sim.model.PlantModel.thrust`);
* :class:`TimeBlock` — a recording (free decay, steps, PRBS, closed loop): the free-run θ of the
  model driven by the recorded command (:func:`aeropend_ident.greybox.fit.free_run_theta`) minus
  the recorded θ, with the initial angle and velocity as the block's own nuisance parameters.

The physics is the model's (one home); this module only stacks the blocks. Parameters are rig keys
(``"section.name"``) or the rod's inertia ``pendulum.inertia`` when the rig file gives the rod's
geometry (mgd/J and L/J then follow from it through the rod's own derivation). Coordinates are
those of :class:`aeropend_ident.greybox.parameters.ParameterSpec` (log for positive parameters).

Standard errors: cov = (JᵀJ)⁻¹ of the weighted residuals at the optimum (σ_b re-estimated from each
block's residual, or the table's stated standard errors, and for time series inflated by the
residual's autocorrelation, :func:`autocorrelation_factor`), mapped to parameter units by the delta
method. :func:`weak_directions` finds what the blocks cannot determine (the right singular vectors
of J whose standard error exceeds one coordinate unit, a factor e of a log parameter).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import brentq, least_squares, minimize
from scipy.stats import qmc

from aeropend_ident.errors import IdentificationError
from aeropend_ident.greybox.batch import RigReplays
from aeropend_ident.greybox.fit import (
    free_run_theta,
    initial_state,
    initial_velocity,
    measurement_noise,
    motor_equilibrium,
)
from aeropend_ident.greybox.parameters import ParameterSpec, apply_parameters
from aeropend_ident.greybox.uniform import UniformData
from aeropend_sim.components import registry
from aeropend_sim.model import ModelError, PlantModel, plant_model
from aeropend_sim.params import Rig

#: The rod's inertia, fitted instead of mgd/J and L/J when the rig file gives the geometry.
INERTIA = "pendulum.inertia"
#: Largest angle of a balance [rad] (the thrust only lifts the rod to the horizontal).
THETA_CAP = math.pi / 2 - 1e-6
#: Tolerance [rad] of the actuator's reach (:func:`_reach`).
REACH_XTOL = 1e-12


#: What a model evaluation at a trial point may raise: the residual gets the block's penalty there.
MODEL_FAILURES = (IdentificationError, ModelError, ValueError, ZeroDivisionError, OverflowError)

#: Points of the global screen before a local solve (:meth:`Problem.screen`; a power of 2 keeps the
#: Sobol sequence balanced).
SCREEN_POINTS = 64
#: Local solves started from the best screened points.
SCREEN_STARTS = 2
#: Cost evaluations of each derivative-free search along the open directions (:meth:`Problem.screen_open`).
OPEN_NFEV = 40

def _rod():
    return next(c for c in registry.components() if getattr(c, "geometry", ()))


def apply_values(base: Rig, geometry: Mapping[str, float], values: Mapping[str, float]) -> Rig:
    """``base`` with parameter values (rig keys, and the inertia through the rod's derivation).

    Raises
    ------
    IdentificationError
        On a value the rig format refuses.
    """
    vals = dict(values)
    if INERTIA in vals:
        given = {**geometry, INERTIA: vals.pop(INERTIA)}
        vals.update({k: v for k, (v, _) in _rod().derive(given).items()})
    return apply_parameters(base, vals)[0]


# ------------------------------------------------------------------------------ blocks
@dataclass
class Block:
    """A residual block (subclasses): its name, method label, noise σ and nuisance coordinates."""

    source: str
    label: str
    sigma: float = 1.0
    nuisance: list[ParameterSpec] = field(default_factory=list)
    static: bool = False   # a steady-state table: timing parameters do not act on it
    sigma_known: bool = False
    #: The least σ a residual re-estimate may give [the block's unit]: a recording's measured noise
    #: floor (a window where the model sits exactly on a quantised, constant angle has a residual of 0,
    #: and a σ of 0 would weigh it 1e12-fold and make every other direction look blind).
    floor: float = 0.0

    def residual(self, rig: Rig, nuis: Sequence[float]) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def size(self) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def scale(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError


@dataclass
class BalanceBlock(Block):
    """Balance table: the angle the model holds at each command [rad]."""

    command: np.ndarray = field(default_factory=lambda: np.zeros(0))
    angle: np.ndarray = field(default_factory=lambda: np.zeros(0))
    std: np.ndarray | None = None

    def size(self) -> int:
        return int(self.command.size)

    def scale(self) -> float:
        return max(float(np.ptp(self.angle)), 1e-3)

    def residual(self, rig: Rig, nuis: Sequence[float]) -> np.ndarray:
        model = plant_model(rig)
        # τ(θ) by angle: every command's root search starts from the bracket's ends 0 and `top`,
        # whose holding commands are the lo and hi below (10-22 % of the solves on the shipped rigs,
        # each a root search of its own inside PlantModel.equilibrium)
        known: dict[float, float] = {}

        def tau(theta: float) -> float:
            if theta in known:
                return known[theta]
            try:
                value = float(model.equilibrium(theta)[1])
            except (ModelError, ValueError, ZeroDivisionError, OverflowError):
                value = math.inf
            known[theta] = value
            return value

        top = THETA_CAP if math.isfinite(tau(THETA_CAP)) else _reach(model, tau)
        lo, hi = tau(0.0), tau(top)
        out = np.empty(self.command.size)
        for i, (c, a) in enumerate(zip(self.command, self.angle, strict=True)):
            if c <= lo or not math.isfinite(lo):
                th = 0.0
            elif c >= hi:
                th = top
            else:
                th = brentq(lambda x, c=c: tau(x) - c, 0.0, top, xtol=1e-10)
            out[i] = th - a
        return out / (self.std if self.std is not None else 1.0)


def _reach(model: PlantModel, tau: Callable[[float], float]) -> float:
    """The largest angle below :data:`THETA_CAP` whose holding command τ(θ) is finite: the actuator's
    reach, where the unclipped holding duty (:meth:`~aeropend_sim.model.PlantModel.holding_duty`)
    crosses 1, by Brent's method (about 10 evaluations, where the bisection of :func:`_last_finite`
    takes 40); that bisection where the unclipped duty does not cross 1 on [0, THETA_CAP] or the
    root's own τ is not finite."""
    def excess(theta: float) -> float:
        try:
            return model.holding_duty(theta) - 1.0
        except MODEL_FAILURES:
            return math.nan

    lo, hi = excess(0.0), excess(THETA_CAP)
    if lo < 0.0 < hi:  # both finite, a crossing between
        theta = brentq(excess, 0.0, THETA_CAP, xtol=REACH_XTOL)
        for _ in range(4):  # the root may lie a rounding past τ = 1 + 1e-12 (what equilibrium accepts)
            if math.isfinite(tau(theta)):
                return theta
            theta -= REACH_XTOL
    return _last_finite(tau)


def _last_finite(tau: Callable[[float], float]) -> float:
    """The largest angle whose holding command τ(θ) is finite (the actuator's reach), by bisection."""
    lo, hi = 0.0, THETA_CAP
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if math.isfinite(tau(mid)) else (lo, mid)
    return lo


@dataclass
class ThrustBlock(Block):
    """Thrust table: the model's steady thrust at each command [N]."""

    command: np.ndarray = field(default_factory=lambda: np.zeros(0))
    thrust: np.ndarray = field(default_factory=lambda: np.zeros(0))
    std: np.ndarray | None = None

    def size(self) -> int:
        return int(self.command.size)

    def scale(self) -> float:
        return max(float(np.max(np.abs(self.thrust))), 1e-6)

    def residual(self, rig: Rig, nuis: Sequence[float]) -> np.ndarray:
        model = plant_model(rig)
        f = np.array([model.thrust(motor_equilibrium(rig, float(c))[1]) for c in self.command])
        return (f - self.thrust) / (self.std if self.std is not None else 1.0)


@dataclass
class TimeBlock(Block):
    """A recording: free-run θ minus recorded θ [rad], initial angle and velocity as nuisance.

    The free run is the fit replay of :class:`aeropend_ident.greybox.batch.RigReplays` (the noise-free
    θ, RK4 sub-steps of at most 2.048 ms, as every other fit in aeropend; the figures the fitted rig
    is reported with replay it with :func:`aeropend_sim.simulation.simulate`), and many rigs are one
    batched replay (:meth:`residual_rows`: the Jacobian's columns). A stretch of several segments
    runs through :func:`free_run_theta` instead.
    """

    data: UniformData | None = None
    kind: str = ""

    def __post_init__(self) -> None:
        d = self.data
        if d is None:
            raise ValueError(f"{self.source}: a time block needs its recording")
        noise = max(measurement_noise(d.theta), 1e-4)
        th0, thd0 = float(d.theta[0]), initial_velocity(d.theta, d.dt)
        self.nuisance = [
            ParameterSpec(f"{self.source}: θ(0)", "rad", th0, th0 - 0.5, th0 + 0.5, False, max(noise, 1e-3)),
            ParameterSpec(f"{self.source}: θ̇(0)", "rad/s", thd0, thd0 - 5.0, thd0 + 5.0, False, 0.05),
        ]
        self.sigma = noise
        self.floor = noise
        self._replays: RigReplays | None = None

    def size(self) -> int:
        return len(self.data)  # type: ignore[arg-type]

    def scale(self) -> float:
        return max(float(np.ptp(self.data.theta)), 1e-3)  # type: ignore[union-attr]

    def residual(self, rig: Rig, nuis: Sequence[float]) -> np.ndarray:
        r = self.residual_rows([rig], [nuis])[0]
        if r is None:
            raise IdentificationError(f"{self.source}: the free run of this rig failed")
        return r

    def residual_rows(self, rigs: Sequence[Rig], nuis: Sequence[Sequence[float]]) -> list[np.ndarray | None]:
        """Free-run θ minus recorded θ [rad] of each rig with its own nuisance values (initial angle,
        velocity), one batched replay; None for a row whose initial state or replay fails."""
        d = self.data
        assert d is not None
        if len(d.segments) > 1:
            out: list[np.ndarray | None] = []
            for rig, v in zip(rigs, nuis, strict=True):
                try:
                    out.append(free_run_theta(rig, d, 0.0, float(v[1]), float(v[0])) - d.theta)
                except MODEL_FAILURES:
                    out.append(None)
            return out
        if self._replays is None:
            self._replays = RigReplays(d.duty, d.dt, tau_before=float(d.duty[0]))
        x0 = np.full((len(rigs), 5), np.nan)
        for k, (rig, v) in enumerate(zip(rigs, nuis, strict=True)):
            try:
                x0[k] = initial_state(rig, d.theta, d.duty, d.dt, 0.0, float(v[1]), float(v[0]))
            except MODEL_FAILURES:
                pass  # a non-finite initial state fails its row in the replay
        theta, ok = self._replays.run(list(rigs), x0, ["theta"])
        return [theta["theta"][k] - d.theta if ok[k] else None for k in range(len(rigs))]


# ------------------------------------------------------------------------------ the problem
@dataclass
class Problem:
    """Parameters (``specs``), fixed values (``fixed``), blocks, and the rig they apply to."""

    base: Rig
    geometry: dict[str, float]
    specs: list[ParameterSpec]
    blocks: list[Block]
    fixed: dict[str, float] = field(default_factory=dict)
    timing: frozenset[str] = frozenset()

    def __post_init__(self) -> None:
        self._cache: tuple[bytes, list[np.ndarray]] | None = None

    # coordinates: main parameters, then each block's nuisance
    def z_bounds(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        specs = self.all_specs()
        return (np.array([s.to_z(s.initial) for s in specs]), np.array([s.to_z(s.lower) for s in specs]),
                np.array([s.to_z(s.upper) for s in specs]))

    def all_specs(self) -> list[ParameterSpec]:
        return [*self.specs, *(s for b in self.blocks for s in b.nuisance)]

    def values(self, z: np.ndarray) -> dict[str, float]:
        return {**self.fixed, **{s.name: s.from_z(zi) for s, zi in zip(self.specs, z, strict=False)}}

    def rig(self, z: np.ndarray) -> Rig:
        return apply_values(self.base, self.geometry, self.values(z))

    def nuisance_values(self, z: np.ndarray) -> list[list[float]]:
        """Each block's nuisance values (initial angle, velocity) at coordinates ``z``."""
        out, k = [], len(self.specs)
        for b in self.blocks:
            out.append([s.from_z(z[k + j]) for j, s in enumerate(b.nuisance)])
            k += len(b.nuisance)
        return out

    def _penalty(self, b: Block) -> np.ndarray:
        return np.full(b.size(), 10.0 * b.scale() / b.sigma + 10.0)

    def block_residuals(self, z: np.ndarray, only: Sequence[int] | None = None) -> list[np.ndarray]:
        """Weighted residual of each block (``only``: those indices; the others are empty)."""
        rig = self._rig_or_none(z)
        nuis = self.nuisance_values(z)
        return [np.zeros(0) if only is not None and i not in only else self._weighted(b, rig, nuis[i])
                for i, b in enumerate(self.blocks)]

    def _weighted(self, b: Block, rig: Rig | None, nuis: Sequence[float]) -> np.ndarray:
        """Block ``b``'s residual divided by its σ; the penalty where the rig, the model or the
        replay fails or a residual is not finite."""
        try:
            r = b.residual(rig, nuis) / b.sigma if rig is not None else self._penalty(b)
        except MODEL_FAILURES:
            r = self._penalty(b)
        return r if np.all(np.isfinite(r)) else self._penalty(b)

    def _weighted_rows(self, b: Block, rigs: Sequence[Rig | None], nuis: Sequence[Sequence[float]]
                       ) -> list[np.ndarray]:
        """:meth:`_weighted` of many rigs: a recording's rows in one batched replay."""
        if not isinstance(b, TimeBlock):
            return [self._weighted(b, r, v) for r, v in zip(rigs, nuis, strict=True)]
        rows = [k for k, r in enumerate(rigs) if r is not None]
        got = b.residual_rows([rigs[k] for k in rows], [nuis[k] for k in rows])  # type: ignore[misc]
        out = [self._penalty(b)] * len(rigs)
        for k, r in zip(rows, got, strict=True):
            if r is not None and np.all(np.isfinite(r)):
                out[k] = r / b.sigma
        return out

    def fun(self, z: np.ndarray) -> np.ndarray:
        parts = self.block_residuals(z)
        self._cache = (z.tobytes(), parts)
        return np.concatenate(parts)

    def jac(self, z: np.ndarray, lo: np.ndarray, hi: np.ndarray, step: float = 1e-5,
            blocks: Sequence[int] | None = None) -> np.ndarray:
        """Forward differences, block by block: a nuisance coordinate moves its own block only, a
        timing parameter no steady-state table; ``blocks``: only these blocks' rows (the others
        stay zero and are not simulated)."""
        if self._cache is None or self._cache[0] != z.tobytes():
            self.fun(z)
        base = self._cache[1]  # type: ignore[index]
        sizes = [p.size for p in base]
        offsets = np.concatenate([[0], np.cumsum(sizes)])
        n_main = len(self.specs)
        J = np.zeros((int(offsets[-1]), z.size))
        owner = [None] * n_main + [i for i, b in enumerate(self.blocks) for _ in b.nuisance]
        steps, points, touched = [], [], []
        for j in range(z.size):
            h = step * max(1.0, abs(z[j]))
            if z[j] + h > hi[j]:
                h = -h
            zz = z.copy()
            zz[j] += h
            if owner[j] is not None:
                only = [owner[j]]
            else:
                timing = self.specs[j].name in self.timing
                only = [i for i, b in enumerate(self.blocks) if not (timing and b.static)]
            if blocks is not None:
                only = [i for i in only if i in blocks]
            steps.append(h)
            points.append(zz)
            touched.append(only)
        # each column's rig (a nuisance coordinate leaves the rig as it is at z), then per block one
        # batched replay of every column that moves it
        base_rig = self._rig_or_none(z)
        rigs = [self._rig_or_none(points[j]) if j < n_main and touched[j] else base_rig
                for j in range(z.size)]
        nuis = [self.nuisance_values(points[j]) if touched[j] else [] for j in range(z.size)]
        for i, b in enumerate(self.blocks):
            cols = [j for j in range(z.size) if i in touched[j]]
            if not cols:
                continue
            rows = self._weighted_rows(b, [rigs[j] for j in cols], [nuis[j][i] for j in cols])
            for j, r in zip(cols, rows, strict=True):
                J[offsets[i]:offsets[i + 1], j] = (r - base[i]) / steps[j]
        return J

    def _rig_or_none(self, z: np.ndarray) -> Rig | None:
        try:
            return self.rig(z)
        except IdentificationError:
            return None

    def solve(self, z0: np.ndarray, max_nfev: int = 60,
              tol: float = 1e-7) -> tuple[np.ndarray, np.ndarray, Any]:
        """Least squares from ``z0``; returns (z, J at z, the SciPy result)."""
        _, lo, hi = self.z_bounds()
        z0 = np.clip(z0, lo, hi)
        sol = least_squares(self.fun, z0, jac=lambda z: self.jac(z, lo, hi), bounds=(lo, hi), method="trf",
                            x_scale=1.0, ftol=tol, xtol=tol, gtol=tol, max_nfev=max_nfev)
        return sol.x, self.jac(sol.x, lo, hi), sol

    def cost(self, z: np.ndarray) -> float:
        """½‖r‖² of the weighted residuals at ``z`` (inf when not finite)."""
        r = self.fun(z)
        c = 0.5 * float(r @ r)
        return c if math.isfinite(c) else math.inf

    def cost_unless_above(self, z: np.ndarray, limit: float) -> float:
        """:meth:`cost` at ``z``, or ``inf`` as soon as the blocks evaluated so far (in order) exceed
        ``limit``: a screen that keeps only its few best points need not replay the rest of a point
        already worse than them (the cost only grows block by block). Leaves the residual cache alone."""
        rig = self._rig_or_none(z)
        nuis = self.nuisance_values(z)
        parts, total = [], 0.0
        for b, v in zip(self.blocks, nuis, strict=True):
            parts.append(self._weighted(b, rig, v))
            total += 0.5 * float(parts[-1] @ parts[-1])
            if not total <= limit * (1.0 + 1e-9):  # above (a rounding margin), or a NaN sum
                return math.inf
        r = np.concatenate(parts)  # summed as cost() sums, to the last bit
        c = 0.5 * float(r @ r)
        return c if math.isfinite(c) else math.inf

    def costs_of_best(self, points: Sequence[np.ndarray], keep: int | None) -> list[float]:
        """:meth:`cost` of each point in order, except that a point that can no longer be one of the
        ``keep`` lowest so far is ``inf`` (:meth:`cost_unless_above`: its blocks are replayed only
        while it still can); every cost in full when ``keep`` is None. The first point's cost is
        always in full, and the ``keep`` lowest come out exactly as with every cost in full.

        A screen keeps only its few best points; on a long recording in windows most screened points
        are far worse than those after a few windows (jahoyosr's staircase: 44 windows, a stiff point's
        replay up to 0.8 s; the screen along the open directions took 20.0 s, now 11.8 s, same start).
        """
        costs: list[float] = []
        for z in points:
            if keep is None or not costs:
                costs.append(self.cost(z))
                continue
            limit = sorted(costs)[keep - 1] if len(costs) >= keep else math.inf
            costs.append(self.cost_unless_above(z, limit))
        return costs

    def screen(self, z0: np.ndarray, names: Sequence[str], n: int = SCREEN_POINTS,
               seed: int = 0, keep: int | None = None) -> list[tuple[float, np.ndarray]]:
        """Global search before the local refinement: the cost ½‖r‖² at ``z0`` and at ``n``
        scrambled-Sobol points spread over the bounds of the main parameters ``names`` (every
        other coordinate at ``z0``), best first.

        A free-run output error of a lightly damped rod is many-valleyed (the phase of its swing),
        and a steady-state table is flat wherever the model cannot hold the recorded angles: a
        local least-squares solve from ``rig new``'s starting values stops in whichever valley it
        starts in. Screening the searched range first puts the local solve in the right one.

        ``keep``: only the ``keep`` best points are used; the others' costs may be ``inf``
        (:meth:`costs_of_best`), the ``keep`` best come out exactly as with every cost in full.

        Returns
        -------
        list of (cost, z), ``n + 1`` entries sorted by cost (non-finite costs last).
        """
        _, lo, hi = self.z_bounds()
        idx = [j for j, s in enumerate(self.specs) if s.name in set(names)]
        pts = [np.asarray(z0, dtype=float)]
        if idx and n > 0:
            u = qmc.Sobol(len(idx), scramble=True, seed=seed).random(n)
            for row in u:
                z = pts[0].copy()
                z[idx] = lo[idx] + row * (hi[idx] - lo[idx])
                pts.append(z)
        return sorted(zip(self.costs_of_best(pts, keep), pts, strict=True), key=lambda cz: cz[0])

    def screen_open(self, z0: np.ndarray, blocks: Sequence[int], n: int = SCREEN_POINTS,
                    seed: int = 0) -> np.ndarray:
        """A better start than ``z0`` along the directions of the main parameters that ``blocks``
        (the tables) leave open, or ``z0`` itself.

        The steady-state tables fix some combinations tightly (the command-to-angle map fixes
        mgd/J against L/J·K_q) and say nothing of others (the rod's time scale, the damping): a
        screen of the whole box would hardly ever land on the narrow ridge the tables allow, a local
        solve from ``rig new``'s value along the open directions stops in the nearest valley.
        Open: right singular vectors of the blocks' Jacobian (main parameters, z coordinates) whose
        singular value is below 1 % of the largest (all when no block is given). ``n``
        scrambled-Sobol points along them over the whole box, then :func:`nelder_mead_best` from the
        best; ``z0`` when none is lower. A lower start is not a lower optimum: solve from both
        (:meth:`solve_best_of`).
        """
        _, lo, hi = self.z_bounds()
        k = len(self.specs)
        if k == 0:
            return z0
        if blocks:
            J = self.jac(z0, lo, hi, blocks=blocks)
            sizes = [b.size() for b in self.blocks]
            edges = np.concatenate([[0], np.cumsum(sizes)])
            rows = np.concatenate([np.arange(edges[i], edges[i + 1]) for i in blocks])
            _, sv, vt = np.linalg.svd(J[rows, :k], full_matrices=rows.size < k)
            sv = np.concatenate([sv, np.zeros(k - sv.size)])
            open_ = vt[sv < 0.01 * max(float(sv[0]), 1e-300)]
        else:
            open_ = np.eye(k)
        if open_.shape[0] == 0:
            return z0
        span = float(np.max(hi[:k] - lo[:k]))

        def point(u: np.ndarray) -> np.ndarray:
            z = z0.copy()
            z[:k] = np.clip(z0[:k] + u @ open_ * span, lo[:k], hi[:k])
            return z

        def cost(u: np.ndarray) -> float:
            return self.cost(point(u))

        m = open_.shape[0]
        us = [np.zeros(m), *(qmc.Sobol(m, scramble=True, seed=seed).random(n) - 0.5)]
        keep = SCREEN_STARTS + 1
        costs = self.costs_of_best([point(u) for u in us], keep)
        ranked = [us[i] for i in np.argsort(costs, kind="stable")[:keep]]
        best = nelder_mead_best(cost, ranked, [(-0.5, 0.5)] * m, OPEN_NFEV, fatol=1e-9)
        return point(best.x) if best.fun < costs[0] else z0

    def solve_each(self, starts: Sequence[np.ndarray], max_nfev: int = 60,
                   tol: float = 1e-7) -> list[tuple[np.ndarray, np.ndarray, Any]]:
        """:meth:`solve` from each distinct start, in order: every (z, J, SciPy result)."""
        out: list[tuple[np.ndarray, np.ndarray, Any]] = []
        seen: list[np.ndarray] = []
        for z in starts:
            if any(np.array_equal(z, w) for w in seen):
                continue
            seen.append(z)
            out.append(self.solve(z, max_nfev=max_nfev, tol=tol))
        return out

    def solve_best_of(self, starts: Sequence[np.ndarray], max_nfev: int = 60,
                      tol: float = 1e-7) -> tuple[np.ndarray, np.ndarray, Any]:
        """:meth:`solve` from each distinct start; the result with the lowest final cost (the
        first on a tie)."""
        got = self.solve_each(starts, max_nfev=max_nfev, tol=tol)
        return min(got, key=lambda r: r[2].cost)  # min keeps the first of equal costs

    def reweight(self, z: np.ndarray, known: bool = True) -> list[float]:
        """Each block's σ from its residual at ``z`` (tables with stated errors: scaled only up by
        their χ², and only when ``known``), time series inflated by their residual's
        autocorrelation. Returns the factors σ_old/σ_new that rescale the blocks' rows of a
        Jacobian."""
        parts = self.block_residuals(z)
        factors = []
        n_main = max(len(self.specs), 1)
        total = sum(p.size for p in parts)
        for b, r in zip(self.blocks, parts, strict=True):
            old = b.sigma
            raw = r * b.sigma
            k = len(b.nuisance) + n_main * r.size / total
            dof = max(r.size - k, 1.0)
            rms = math.sqrt(float(raw @ raw) / dof)
            if b.sigma_known:
                b.sigma = max(1.0, rms) if known else old
            else:
                b.sigma = max(rms, b.floor, 1e-12)
            if isinstance(b, TimeBlock):
                b.sigma *= math.sqrt(autocorrelation_factor(raw))
            factors.append(old / b.sigma)
        self._cache = None
        return factors


def nelder_mead_best(cost: Callable[[np.ndarray], float], starts: Sequence[np.ndarray],
                     bounds: Sequence[tuple[float, float]], maxfev: int, fatol: float = 1e-6) -> Any:
    """Bounded Nelder-Mead (SciPy) from each of ``starts``; the result with the lowest cost.

    Derivative-free: used where a few parameters trade off along a curved valley that a
    Gauss-Newton step crawls along (a dead time against a lag; the rod's time scale)."""
    runs = [minimize(cost, x, method="Nelder-Mead", bounds=list(bounds),
                     options={"maxfev": maxfev, "xatol": 1e-3, "fatol": fatol}) for x in starts]
    return min(runs, key=lambda r: r.fun)


def autocorrelation_factor(r: np.ndarray) -> float:
    """Variance inflation of a correlated residual's mean-like statistics: 1 + 2 Σ (1 − k/(K+1))·ρ_k
    over K = ⌊4·(m/100)^(2/9)⌋ lags (Bartlett window, Newey-West's rule), at least 1."""
    r = np.asarray(r, dtype=float) - float(np.mean(r))
    m = r.size
    den = float(r @ r)
    if m < 10 or den == 0.0:
        return 1.0
    lags = max(1, int(4.0 * (m / 100.0) ** (2.0 / 9.0)))
    s = sum((1.0 - k / (lags + 1.0)) * float(r[:-k] @ r[k:]) / den for k in range(1, min(lags, m - 1) + 1))
    return max(1.0, 1.0 + 2.0 * s)


#: A coordinate whose weight in a direction the data do not inform is at least this is undetermined
#: (:func:`covariance`); the others' variances are then conditional on it.
BLIND_SHARE = 0.2


def covariance(J: np.ndarray, pinned: np.ndarray, blind: bool = True) -> np.ndarray:
    """(JᵀJ)⁻¹ of the free coordinates (pinned ones: NaN rows and columns; with ``blind``, the
    coordinates that dominate a direction the data do not inform have an infinite variance and the
    others' covariance is taken with them held; without, the pseudo-inverse's, whose correlations
    still show which coordinates only a combination fixes).

    From the SVD of J (V·diag(1/s²)·Vᵀ over the singular values with s² > 1e-15·s_max², the cut of
    ``pinv(JᵀJ)``), not by inverting JᵀJ: forming JᵀJ squares J's condition number, and on an
    ill-conditioned J (YangZhu's step: rig check's joint σ) its pseudo-inverse came out with negative
    variances. A blind direction (cut) makes the coordinates with weight ≥ :data:`BLIND_SHARE` in it
    undetermined (inf), not "known exactly" as the pseudo-inverse says; the SVD is then taken again
    without them, so that a well-determined coordinate with a round-off share in that direction keeps
    its finite variance (jahoyosr's dead zone, ± 0.007, beside a c/J the staircase cannot see).
    """
    n = J.shape[1]
    cov = np.full((n, n), math.nan)
    free = np.flatnonzero(~pinned)
    undetermined: list[int] = []
    while free.size:
        # the full V only when there are fewer rows than columns (its extra rows are blind directions);
        # a full U of a 15 000-row J alone took 2.9 s a call
        _, s, vt = np.linalg.svd(J[:, free], full_matrices=J.shape[0] < free.size)
        s = np.concatenate([s, np.zeros(free.size - s.size)])
        keep = s**2 > 1e-15 * (float(s[0]) ** 2 if s.size else 0.0)
        if blind and not np.all(keep):
            w = np.abs(vt[~keep])
            dom = np.any(w >= BLIND_SHARE, axis=0)
            if not np.any(dom):
                dom[int(np.argmax(w.max(axis=0)))] = True
            undetermined += [int(j) for j in free[dom]]
            free = free[~dom]
            continue
        v = vt[keep].T / s[keep]
        cov[np.ix_(free, free)] = v @ v.T
        break
    for j in undetermined:
        cov[j, :] = math.nan
        cov[:, j] = math.nan
        cov[j, j] = math.inf
    return cov


def robust_covariance(J: np.ndarray, r: np.ndarray, sizes: Sequence[int], cov: np.ndarray) -> np.ndarray:
    """Cluster-robust (sandwich) covariance of the coordinates, the blocks as clusters.

    ``cov`` (:func:`covariance`) is the bread B = (JᵀJ)⁻¹; the meat is Σ_b g_b g_bᵀ over the blocks'
    scores g_b = J_bᵀ r_b (a table, a fit window); the estimate B·meat·B·G/(G − 1) (CR1, G blocks)
    holds when the residuals are correlated within a block or the model misses something the noise
    weights do not know of, where (JᵀJ)⁻¹ alone gave ± 0.001 % on a fit at NRMSE 0.2.

    Parameters
    ----------
    J : ndarray, shape (N, P)
        Weighted Jacobian (rows in block order).
    r : ndarray, shape (N,)
        Weighted residuals at the solution.
    sizes : sequence of int
        Rows of each block (sum N).
    cov : ndarray, shape (P, P)
        :func:`covariance` of ``J`` (NaN pinned, inf undetermined coordinates: those stay so).

    Returns
    -------
    ndarray, shape (P, P)
    """
    bread = np.where(np.isfinite(cov), cov, 0.0)
    edges = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    meat = np.zeros_like(bread)
    for a, b in itertools.pairwise(edges):
        g = J[a:b].T @ r[a:b]
        meat += np.outer(g, g)
    g_n = len(sizes)
    out = bread @ meat @ bread * (g_n / (g_n - 1) if g_n > 1 else 1.0)
    bad = ~np.isfinite(np.diag(cov))
    out[bad, bad] = np.diag(cov)[bad]
    return out


def weak_directions(J: np.ndarray, names: Sequence[str], order: Sequence[float],
                    threshold: float = 1.0) -> list[tuple[str, list[str], np.ndarray]]:
    """What the blocks cannot determine: greedily, the right singular vector v of the (weighted,
    z-coordinate) Jacobian with the smallest singular value s while 1/s > ``threshold`` (its
    standard error); the parameters with |v_i| ≥ 0.2 form a group and the one with the largest
    weight (on a tie within 10 %: the earliest in the signal chain, ``order``) is held fixed.

    Returns
    -------
    list of (fixed name, group names, exponents)
        ``exponents``: the group's determined combination ∏ p_i^{e_i} (for a pair, from v).
    """
    keep = list(range(len(names)))
    out = []
    while keep:
        sub = J[:, keep]
        _, s, vt = np.linalg.svd(sub, full_matrices=False)
        if s.size == 0 or s[-1] * threshold >= 1.0:
            break
        v = vt[-1]
        weights = np.abs(v)
        group = [keep[i] for i in np.flatnonzero(weights >= 0.2)] or [keep[int(np.argmax(weights))]]
        top = float(weights.max())
        ties = [keep[i] for i in np.flatnonzero(weights >= 0.9 * top)]
        fixed = min(ties, key=lambda g: order[g])
        vg = np.array([v[keep.index(g)] for g in group])
        if len(group) == 2:
            exps = np.array([-vg[1], vg[0]])
            exps = exps / np.min(np.abs(exps)) if np.min(np.abs(exps)) > 0 else exps
        else:
            exps = np.zeros(len(group))
        out.append((names[fixed], [names[g] for g in group], exps))
        keep.remove(fixed)
    return out
