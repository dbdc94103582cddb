"""Which, stage 2 — grey-box output-error fits of effect parameters (:func:`fit_effects`), covariance.

Part of the effect diagnosis of :mod:`aeropend_ident.gap.which` (step 3 of its pipeline); no rclpy.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares

from aeropend_ident.errors import GapError
from aeropend_ident.gap.effects import (
    Effect,
    EffectContext,
    EffectParameter,
    MeasurementMap,
    ParamRange,
    apply_effects,
    catalog,
    drift_only,
    get_effect,
)
from aeropend_ident.gap.which.data import Prepared, residuals_many
from aeropend_sim.params import Rig

#: Residual samples per independent sample in the BIC (free-run residuals are autocorrelated), at
#: the thesis rig's 490 Hz; see :data:`BIC_RESIDUAL_TIME` for other rates.
BIC_DECIMATION = 20


#: Time block [s] of the block-sandwich parameter covariance (:func:`parameter_covariance`): longer
#: than the few tenths of a second a rod's free-run error stays correlated by its own dynamics, short
#: enough that a 40 s recording holds 20 blocks.
COVARIANCE_BLOCK_S = 2.0


#: Absolute finite-difference step of the fits' Jacobian, in optimiser units (log parameters:
#: 0.1 % of the value; linear ones: 0.1 % of the search range).
FD_STEP = 1e-3


#: Values scanned over the range of a one-parameter effect before the local refinement.
N_SCAN = 7


#: Most starts refined per fit, and the largest cost ratio (to the best start) of a second start.
MAX_STARTS = 2


MULTISTART_COST_RATIO = 3.0


#: Most residual evaluations of one local refinement.
MAX_NFEV = 15


#: Exponents the thrust-law fit starts from (the level kept at the reference speed).
THRUST_LAW_EXPONENTS = (1.5, 1.8, 2.2, 2.6)


@dataclass
class EffectFit:
    """Fitted effect set: values, standard errors, fitted rig and measurement map, fit SSE."""

    effects: tuple[str, ...]
    values: dict[str, dict[str, float]]
    std: dict[str, dict[str, float]]
    rig: Rig
    meas: MeasurementMap
    sse: float
    n: int
    nfev: int
    #: Covariance of the optimiser coordinates (log value for a log parameter, share of the range
    #: otherwise), shape (k, k), in the order of ``labels`` ((effect, parameter) pairs); None when
    #: not computed.
    cov: np.ndarray | None = None
    labels: tuple[tuple[str, str], ...] = ()
    log: tuple[bool, ...] = ()
    #: Per coordinate, the change of its parameter (log value for a log one, the value otherwise) per
    #: unit of the coordinate: 1 for a log parameter, the search range's span for a linear one.
    spans: tuple[float, ...] = ()
    #: Reference rotor speed ω_ref [rad/s] of the search ranges (:attr:`EffectContext.omega_ref`).
    omega_ref: float | None = None


class _Coord(NamedTuple):
    """One optimiser coordinate: effect, parameter and its search range."""

    effect: Effect
    param: EffectParameter
    range: ParamRange


def _coords(effects: Sequence[Effect], ctx: EffectContext) -> list[_Coord]:
    """The optimiser's coordinates: every parameter, but a held one (the onset width v_ε) only where
    ``ctx`` frees it (:attr:`aeropend_ident.gap.effects.EffectContext.free_settings`)."""
    return [_Coord(e, p, p.bind(ctx)) for e in effects for p in e.parameters
            if not p.held or e.name in ctx.free_settings]


def _n_fitted(name: str, ctx: EffectContext) -> int:
    """Parameters of effect ``name`` its fits search (BIC's k): a held parameter counts only
    where ``ctx`` frees it (:func:`_coords`)."""
    return sum(1 for p in get_effect(name).parameters if not p.held or name in ctx.free_settings)


def _to_z(r: ParamRange, v: float) -> float:
    """Optimiser coordinate of a physical value: log(v), or (v − lower)/(upper − lower)."""
    v = r.clip(v)
    return math.log(v) if r.log else (v - r.lower) / (r.upper - r.lower)


def _from_z(r: ParamRange, z: float) -> float:
    v = math.exp(z) if r.log else r.lower + z * (r.upper - r.lower)
    return r.clip(v)


def _assemble(rig: Rig, coords: Sequence[_Coord], z: np.ndarray) -> tuple[Rig, MeasurementMap, dict]:
    vals: dict[str, dict[str, float]] = {}
    for c, zi in zip(coords, z, strict=True):
        vals.setdefault(c.effect.name, {})[c.param.name] = _from_z(c.range, float(zi))
    new, meas = apply_effects(rig, vals)
    return new, meas, vals


def _thrust_law_starts(ctx: EffectContext, start: Mapping[str, float]) -> list[dict[str, float]]:
    """Starts of a thrust-law fit: exponents across the physical range, each with the coefficient
    that keeps the start's thrust at the reference propeller speed ω_ref (level kept, shape varied)."""
    w = max(ctx.omega_ref, 1e-9)
    k0, a0 = start["K_q"], start["exponent"]
    return [{"K_q": k0 * w ** (a0 - a), "exponent": a} for a in THRUST_LAW_EXPONENTS]


def fit_effects(rig: Rig, effects: Sequence[str], preps: Sequence[Prepared], ctx: EffectContext, *,
                start: Mapping[str, Mapping[str, float]] | None = None, scan: bool = True,
                starts: Sequence[Mapping[str, Mapping[str, float]]] = (),
                max_nfev: int = MAX_NFEV) -> EffectFit:
    """Fit the physical parameters of one or more catalog effects by free-run output error.

    Each parameter is searched over its physical range (:meth:`Effect.ranges` of ``ctx``), log(value)
    for strictly positive ones; a held parameter (the dry friction's onset width v_ε) only where
    ``ctx.free_settings`` frees it, else it keeps ``rig``'s value. The objective is the normalised
    output error of every compared channel (:func:`residuals`). Output error in a delay, dead
    zone, stop angle or friction level has local minima, so the fit is **multi-start**: the given
    start (default: the probe values), the extra ``starts`` (e.g. the equation-error estimates of
    the screening), and, for a one-parameter effect with ``scan``, :data:`N_SCAN` values spread
    over the whole range (:func:`_scan_starts`; for the thrust law: exponents over [1.4, 3] at a
    kept thrust level); the best :data:`MAX_STARTS`
    distinct starts are refined by :func:`scipy.optimize.least_squares` (trust-region reflective)
    and the best result is kept.

    The Jacobian is a forward difference with an **absolute** step of :data:`FD_STEP` optimiser
    units (0.1 % of the value for log parameters, 0.1 % of the range otherwise): scipy's relative
    ``diff_step`` collapses to 1e-8 at a coordinate of 0 (a log parameter at its nominal value),
    below the integrator's tolerance, where the gradient then reads zero.

    Parameters
    ----------
    rig : Rig
        Nominal rig (the effects are added to it with :func:`apply_effects`).
    effects : sequence of str
        Catalog names (model or measurement effects).
    preps : sequence of Prepared
        Fit recordings.
    ctx : EffectContext
        Search ranges (rig and data scales).
    start : mapping, optional
        Main start ``{effect: {parameter: value}}`` (missing values: probe values).
    scan : bool
        Scan the range of a one-parameter effect (and the thrust law's exponent).
    starts : sequence of mappings
        Further starts (partial mappings are completed from ``start``).
    max_nfev : int
        Most residual evaluations of each local refinement.

    Returns
    -------
    EffectFit

    Raises
    ------
    GapError
        On an unknown or directly detected effect, or one that is not a hypothesis for the rig's
        actuator family (an ESC's speed response on an H-bridge rig).
    """
    effs = [get_effect(n) for n in effects]
    bad = [e.name for e in effs if e.kind == "direct"]
    if bad:
        raise GapError(f"effect(s) {bad} are detected from the data, not fitted")
    own = {e.name for e in (*catalog(rig.family), *drift_only(rig.family))}
    foreign = [e.name for e in effs if e.name not in own]
    if foreign:
        raise GapError(f"effect(s) {foreign} are not hypotheses for a {rig.family} rig; its catalog has "
                       f"{sorted(own)}")
    coords = _coords(effs, ctx)
    base = {e.name: {**e.probe_values(ctx), **dict((start or {}).get(e.name, {}))} for e in effs}

    def z_of(vals: Mapping[str, Mapping[str, float]]) -> np.ndarray:
        merged = {e: {**base[e], **dict(vals.get(e, {}))} for e in base}
        return np.array([_to_z(c.range, merged[c.effect.name][c.param.name]) for c in coords])

    lo = np.array([_to_z(c.range, c.range.lower) for c in coords])
    hi = np.array([_to_z(c.range, c.range.upper) for c in coords])
    obj = _Objective(rig, coords, preps, hi)
    funs, fun, jac = obj.rows, obj, obj.jacobian

    candidates = [z_of({})] + [z_of(s) for s in starts]
    candidates += _scan_starts(coords, z_of, lo, hi) if scan else []
    if scan and "thrust_law" in effects:
        for s in _thrust_law_starts(ctx, base["thrust_law"]):
            candidates.append(z_of({"thrust_law": s}))
    candidates = [np.clip(c, lo, hi) for c in candidates]
    costs = [float(np.sum(r**2)) for r in funs(candidates)]
    order = np.argsort(costs)
    picked: list[np.ndarray] = []
    width = np.maximum(hi - lo, 1e-12)
    for i in order:
        c = candidates[i]
        if costs[i] > MULTISTART_COST_RATIO * costs[order[0]] and picked:
            break
        if all(np.max(np.abs(c - q) / width) > 0.05 for q in picked):
            picked.append(c)
        if len(picked) >= MAX_STARTS:
            break
    best = None
    for z0 in picked:
        z0 = np.clip(z0, lo + 1e-12, hi - 1e-12)
        sol = least_squares(fun, z0, jac=jac, bounds=(lo, hi), method="trf", x_scale=1.0, max_nfev=max_nfev,
                            ftol=1e-7, xtol=1e-7, gtol=1e-9)
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    new, meas, vals = _assemble(rig, coords, best.x)
    for e in effs:  # a held setting keeps the rig's value (no standard error: not fitted)
        for k, v in e.held_values(rig).items():
            vals.setdefault(e.name, {}).setdefault(k, v)
    std: dict[str, dict[str, float]] = {}
    cov_z: np.ndarray | None = None
    try:
        cov_z = parameter_covariance(jac(best.x), best.fun, block_ids(preps))
        sz = np.sqrt(np.clip(np.diag(cov_z), 0.0, None))
    except (np.linalg.LinAlgError, ValueError):
        sz = np.full(len(coords), math.nan)
    for c, zi, sd in zip(coords, best.x, sz, strict=True):
        v = _from_z(c.range, float(zi))
        span = c.range.upper - c.range.lower
        std.setdefault(c.effect.name, {})[c.param.name] = float(abs(v) * sd if c.range.log else sd * span)
    return EffectFit(effects=tuple(effects), values=vals, std=std, rig=new, meas=meas,
                     sse=float(np.sum(best.fun**2)), n=int(best.fun.size), nfev=obj.nfev, cov=cov_z,
                     labels=tuple((c.effect.name, c.param.name) for c in coords),
                     log=tuple(bool(c.range.log) for c in coords),
                     spans=tuple(1.0 if c.range.log else c.range.upper - c.range.lower for c in coords),
                     omega_ref=float(ctx.omega_ref))


def _scan_starts(coords: Sequence[_Coord], z_of: Callable[[Mapping[str, Mapping[str, float]]], np.ndarray],
                 lo: np.ndarray, hi: np.ndarray) -> list[np.ndarray]:
    """Starts of :func:`fit_effects` from a scan: where one coordinate is a physical size and the
    others held parameters (a dry friction's level and its onset width v_ε), :data:`N_SCAN`
    values over the size's range, with the settings at the main start and at the rig's own
    values (the fit as it was with the setting held)."""
    sizes = [i for i, c in enumerate(coords) if not c.param.held]
    if len(sizes) != 1:
        return []
    k = sizes[0]
    held = {}
    for c in coords:
        if c.param.held:
            held.setdefault(c.effect.name, {})[c.param.name] = c.range.off
    out = []
    for fixed in ([{}, held] if held else [{}]):
        z0 = z_of(fixed)
        for g in np.linspace(lo[k], hi[k], N_SCAN):
            z = z0.copy()
            z[k] = g
            out.append(z)
    return out


def block_ids(preps: Sequence[Prepared], block_s: float = COVARIANCE_BLOCK_S) -> np.ndarray:
    """Time block of every element of the :func:`residuals` vector, shape (M,): the recordings'
    :data:`COVARIANCE_BLOCK_S` s stretches, every channel of a stretch in the same block."""
    out, base = [], 0
    for p in preps:
        k = np.floor(np.arange(p.n) * p.dt / block_s).astype(int)
        out.extend([base + k] * len(p.y))
        base += int(k[-1]) + 1 if p.n else 0
    return np.concatenate(out) if out else np.zeros(0, dtype=int)


def parameter_covariance(jac: np.ndarray, res: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Covariance of least-squares parameters whose residuals are correlated in time.

    The classical estimate (JᵀJ)⁻¹·s², s² the residual variance with the effective sample size
    M/:data:`BIC_DECIMATION`, assumes independent residuals; a free-run output error is correlated
    over seconds, and where the model misses something its error depends on the stretch of data.
    The block sandwich (cluster-robust) estimate
    (JᵀJ)⁻¹ (Σ_b J_bᵀ r_b r_bᵀ J_b) (JᵀJ)⁻¹ · B/(B − 1) over time blocks b (the linearised block
    bootstrap of the fit: how far the estimate moves when whole stretches are resampled) measures
    that within-session variation. Returned: the sandwich, its diagonal raised to the classical one
    where that is larger (a few blocks can underestimate), correlations kept; the classical estimate
    alone with fewer than 2k + 2 blocks.

    Parameters
    ----------
    jac : numpy.ndarray
        Shape (M, k), Jacobian of the residuals at the optimum.
    res : numpy.ndarray
        Shape (M,), residuals at the optimum.
    blocks : numpy.ndarray
        Shape (M,), block id of each residual (:func:`block_ids`).

    Returns
    -------
    numpy.ndarray
        Shape (k, k), covariance of the optimiser coordinates. A coordinate the residuals do not
        depend on at all (a zero Jacobian column: an end stop the recording never reaches) has
        infinite variance and no covariance: the data do not determine it (a pseudo-inverse alone
        would give it variance 0, an exactly known value).
    """
    norms = np.sqrt(np.sum(jac**2, axis=0))
    dead = ~(norms > 1e-12 * max(float(norms.max(initial=0.0)), 1e-300))
    if np.any(dead):
        live = np.flatnonzero(~dead)
        out = np.zeros((jac.shape[1],) * 2)
        out[dead, dead] = math.inf
        if live.size:
            out[np.ix_(live, live)] = parameter_covariance(jac[:, live], res, blocks)
        return out
    k = jac.shape[1]
    a_inv = np.linalg.pinv(jac.T @ jac)
    dof = max(res.size // BIC_DECIMATION - k, 1)
    classical = a_inv * float(np.sum(res**2)) / dof
    ids, inv = np.unique(blocks, return_inverse=True)
    if ids.size < 2 * k + 2:
        return classical
    g = np.zeros((ids.size, k))
    np.add.at(g, inv, jac * res[:, None])
    sandwich = a_inv @ (g.T @ g) @ a_inv * ids.size / (ids.size - 1)
    sd_s = np.sqrt(np.clip(np.diag(sandwich), 0.0, None))
    sd = np.maximum(sd_s, np.sqrt(np.clip(np.diag(classical), 0.0, None)))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.where(np.outer(sd_s, sd_s) > 0.0, sandwich / np.outer(sd_s, sd_s), 0.0)
    np.fill_diagonal(corr, 1.0)
    return corr * np.outer(sd, sd)


class _Objective:
    """The normalised output error of :func:`fit_effects` and its forward-difference Jacobian.

    Residuals of many coordinate vectors are one batched replay per recording
    (:func:`residuals_many`); evaluated vectors are cached (the Jacobian's base point is the
    optimiser's last evaluation). A vector whose effects cannot be applied or whose replay fails
    gets a constant penalty residual. ``nfev`` counts the vectors replayed.
    """

    def __init__(self, rig: Rig, coords: Sequence[_Coord], preps: Sequence[Prepared], hi: np.ndarray) -> None:
        self.rig, self.coords, self.preps, self.hi = rig, list(coords), list(preps), hi
        self.n_res = sum(len(p.y) * p.n for p in preps)
        self.penalty = 10.0 / math.sqrt(max(self.n_res, 1))
        self.nfev = 0
        self._cache: dict[bytes, np.ndarray] = {}

    def __call__(self, z: np.ndarray) -> np.ndarray:
        return self.rows([z])[0]

    def rows(self, zs: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Residuals of many coordinate vectors: the new ones in one batched replay."""
        keys = [np.asarray(z, dtype=float).tobytes() for z in zs]
        got = {k: self._cache[k] for k in keys if k in self._cache}
        new = [k for k in dict.fromkeys(keys) if k not in got]
        if new:
            self.nfev += len(new)
            rows, where = [], []
            for k in new:
                got[k] = np.full(self.n_res, self.penalty)
                try:
                    r_rig, r_meas, _ = _assemble(self.rig, self.coords, np.frombuffer(k))
                except (GapError, ValueError):
                    continue
                rows.append((r_rig, r_meas))
                where.append(k)
            for k, r in zip(where, residuals_many(rows, self.preps) if rows else (), strict=True):
                if np.all(np.isfinite(r)):
                    got[k] = r
            if len(self._cache) + len(new) > 256:
                self._cache.clear()
            self._cache.update({k: got[k] for k in new})
        return [got[k] for k in keys]

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        """Forward differences with the absolute step :data:`FD_STEP` (backward at the upper
        bound): 1 + n_p residuals in one batched replay."""
        steps = [FD_STEP if z[j] + FD_STEP <= self.hi[j] else -FD_STEP for j in range(z.size)]
        shifted = []
        for j, h in enumerate(steps):
            zz = np.array(z, dtype=float)
            zz[j] += h
            shifted.append(zz)
        f0, *fs = self.rows([z, *shifted])
        out = np.empty((f0.size, z.size))
        for j, (h, f) in enumerate(zip(steps, fs, strict=True)):
            out[:, j] = (f - f0) / h
        return out

