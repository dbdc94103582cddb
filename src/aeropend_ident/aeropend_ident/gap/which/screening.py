"""Which, stage 3 — screening by discrepancy SINDy under group sparsity (:func:`screen`).

Part of the effect diagnosis of :mod:`aeropend_ident.gap.which` (step 2 of its pipeline); no rclpy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import savgol_filter

from aeropend_ident.errors import GapError
from aeropend_ident.gap.effects import (
    Effect,
    EffectContext,
    MeasurementMap,
    apply_effects,
    get_effect,
)
from aeropend_ident.gap.which.data import Prepared, _sim_rig, replay_many
from aeropend_ident.gap.which.fitting import BIC_DECIMATION
from aeropend_ident.gap.which.metrics import SEGMENT
from aeropend_ident.sindy.model import IdentData
from aeropend_ident.sindy.weak_form import weak_matrices
from aeropend_sim.compiled.plant import derivatives
from aeropend_sim.components import registry
from aeropend_sim.model import I_A, OMEGA, TAU_F, THETA, THETA_DOT, plant_model
from aeropend_sim.params import Rig

#: BIC gain (negative change) an effect must reach on the fit data.
MIN_BIC_GAIN = 10.0


#: Number of shortlisted effects confirmed by grey-box fits.
SHORTLIST = 5


#: Bootstrap resamples for screening inclusion and the ranking's bootstrap frequencies.
N_BOOTSTRAP = 30


#: Savitzky-Golay window [s] of the derivative estimates (strong form) and initial rates.
SAVGOL_WINDOW = 0.06


#: Sample period [s] of the screening regressions (the recordings are decimated to it).
SCREEN_DT = 0.016


def _delayed(duty: np.ndarray, dt: float, delay: float) -> np.ndarray:
    if delay <= 0.0:
        return duty
    k = np.arange(duty.size)
    idx = np.floor((k * dt - delay) / dt + 1e-9).astype(int)
    return np.where(idx >= 0, duty[np.clip(idx, 0, None)], duty[0])


def _savgol(y: np.ndarray, dt: float, deriv: int) -> np.ndarray:
    w = max(round(SAVGOL_WINDOW / dt) | 1, 7)
    w = min(w, (y.size - 1) | 1 if y.size % 2 == 0 else y.size)
    return savgol_filter(y, w, 3, deriv=deriv, delta=dt, mode="interp")


def motor_channels(rig: Rig) -> tuple[str, ...]:
    """Channels of a replay that give the motor chain's states (i_a when the family has an
    armature, ω₁, τ_f) and the states of the rig's effects (a winding temperature, which no
    recording holds): what :func:`hybrid_rhs` takes from a simulation."""
    armature = "armature" not in registry.family(rig.family).lacks
    extra = plant_model(_sim_rig(rig)).states.extra_names
    return (*(("i_a",) if armature else ()), "omega_rotor", "tau_f", *extra)


def _replay_probes(rows: Sequence[tuple[Rig, MeasurementMap]], prep: Prepared
                   ) -> list[dict[str, np.ndarray] | None]:
    """:func:`replay_many` of the probe rigs, in order, each with its own :func:`motor_channels`
    (a probe of an effect with a state of its own replays that state too): one batch per set of
    channels."""
    chans = [motor_channels(r) for r, _ in rows]
    out: list[dict[str, np.ndarray] | None] = [None] * len(rows)
    for names in dict.fromkeys(chans):
        idx = [i for i, c in enumerate(chans) if c == names]
        for i, sim in zip(idx, replay_many([rows[i] for i in idx], prep, names), strict=True):
            out[i] = sim
    return out


def hybrid_rhs(rig: Rig, meas: MeasurementMap, prep: Prepared, theta_dot: np.ndarray,
               equations: Sequence[str], step: int = 1,
               sim: Mapping[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """Model right-hand side on the recorded states, in the recording's frame.

    θ and θ̇ come from the recording (through the inverse measurement map); i_a and ω₁ from the
    recording when recorded, else from a simulation of the rig driven by the recorded duty cycle
    (the motor chain does not depend on θ); τ_f and the delayed input from that simulation.

    ``step`` evaluates every ``step``-th sample only (the simulation still runs at full rate).
    ``sim`` is that simulation when the caller has replayed it already (the :func:`motor_channels`
    of a :func:`replay_many` row, so that many rigs are simulated in one batch); by default the
    rig is replayed here the same way.

    Returns
    -------
    dict
        ``equation -> (ceil(N/step),)``: ``"theta_dot"`` θ̈_recorded [rad/s²], ``"i_a"`` [A/s],
        ``"omega_rotor"`` [rad/s²], ``"v_a"`` [V].

    Raises
    ------
    GapError
        If the replay fails.
    """
    model = plant_model(_sim_rig(rig))
    if sim is None:
        sim = replay_many([(rig, meas)], prep, motor_channels(rig))[0]
        if sim is None:
            raise GapError(f"replay of {prep.rec.source or 'a recording'} with rig {rig.name!r} failed")
    st = model.states
    x = np.tile(st.initial(), (prep.n, 1))
    s = meas.theta_scale
    x[:, THETA] = meas.to_model(prep.y["theta"])
    x[:, THETA_DOT] = theta_dot / s
    x[:, I_A] = sim.get("i_a", 0.0)
    x[:, OMEGA] = sim["omega_rotor"]
    x[:, TAU_F] = sim["tau_f"]
    for extra in st.extra:  # an effect's own state (a winding temperature) is the replay's
        x[:, st.index(extra.name)] = sim.get(extra.name, extra.initial)
    if "i_a" in prep.y and model.dynamic_current:
        x[:, I_A] = prep.y["i_a"]
    if "omega_rotor" in prep.y:
        x[:, OMEGA] = prep.y["omega_rotor"]
    u = _delayed(prep.duty, prep.dt, model.delay)
    x, u = x[::step], u[::step]
    need = set(equations)
    f, drive = derivatives(model, x, u)  # = model.rhs per sample, bit for bit, in one compiled loop
    out: dict[str, np.ndarray] = {}
    if "theta_dot" in need:
        out["theta_dot"] = s * f[:, 1]
    if "i_a" in need:
        out["i_a"] = f[:, 2]
    if "omega_rotor" in need:
        out["omega_rotor"] = f[:, 3]
    if "v_a" in need:
        model.armature_voltage(0.0)  # a family without an armature voltage (ESC) raises here
        out["v_a"] = drive  # v_a of τ_f (lag on) or of u: the drive quantity
    return out


def _probe_rigs(rig: Rig, meas: MeasurementMap, effs: Sequence[Effect],
                ranges: Mapping[str, Mapping[str, Any]]) -> list[tuple[Rig, MeasurementMap] | None]:
    """The screening's probe of each effect parameter, in order: the rig with that parameter at its
    probe value and the effect's others off, or None where the effect cannot be applied so."""
    out: list[tuple[Rig, MeasurementMap] | None] = []
    for e in effs:
        for prm in e.parameters:
            vals = {k: (r.probe if k == prm.name else r.off) for k, r in ranges[e.name].items()}
            try:
                out.append(apply_effects(rig, {e.name: vals}, meas))
            except GapError:
                out.append(None)
    return out


def screening_equations(channels: frozenset[str]) -> list[str]:
    """Equations the recorded channels support: θ̈ always, then i_a, ω₁, v_a when recorded."""
    eqs = ["theta_dot"]
    for c in ("i_a", "omega_rotor", "v_a"):
        if c in channels:
            eqs.append(c)
    return eqs


def _bic(rss: float, n: int, k: int) -> float:
    return n * math.log(max(rss, 1e-300) / n) + k * math.log(n)


def group_select(X: np.ndarray, y: np.ndarray, groups: Sequence[int], *, max_groups: int = 3,
                 n_eff: int | None = None, min_gain: float = MIN_BIC_GAIN) -> list[int]:
    """Group orthogonal matching pursuit with a BIC stop (group sparsity over the catalog).

    At each step the whole group (all its columns) whose addition lowers the least-squares
    residual most is selected; selection stops when the BIC (with ``n_eff`` independent samples)
    no longer falls by ``min_gain``.

    Parameters
    ----------
    X : ndarray, shape (N, M)
        Columns (already normalised).
    y : ndarray, shape (N,)
        Residual target.
    groups : sequence of int, length M
        Group index of each column.
    max_groups : int
    n_eff : int, optional
        Effective sample count of the BIC (default N).

    Returns
    -------
    list of int
        Selected group indices in order of selection.
    """
    groups = np.asarray(groups)
    n = y.size
    n_eff = n if n_eff is None else max(int(n_eff), 2)
    rss0 = float(y @ y)
    chosen: list[int] = []
    cols: list[int] = []
    best_bic = _bic(rss0 * n_eff / n, n_eff, 0)
    for _ in range(max_groups):
        best = None
        for g in np.unique(groups):
            if g in chosen:
                continue
            c = cols + list(np.flatnonzero(groups == g))
            coef, *_ = np.linalg.lstsq(X[:, c], y, rcond=None)
            r = y - X[:, c] @ coef
            rss = float(r @ r)
            if best is None or rss < best[0]:
                best = (rss, int(g), c)
        if best is None:
            break
        bic = _bic(best[0] * n_eff / n, n_eff, len(best[2]))
        if bic > best_bic - min_gain:
            break
        best_bic = bic
        chosen.append(best[1])
        cols = best[2]
    return chosen


@dataclass
class Screening:
    """Result of :func:`screen` (discrepancy SINDy with group sparsity)."""

    effects: list[str]
    explained_strong: dict[str, float]
    explained_weak: dict[str, float]
    explained_equation: dict[str, float]
    selected_strong: list[str]
    selected_weak: list[str]
    inclusion: dict[str, float]
    equations: list[str]
    columns: dict[str, list[str]]
    estimates: dict[str, dict[str, float]] = field(default_factory=dict)

    def shortlist(self, k: int = SHORTLIST) -> list[str]:
        """Selected groups first (strong, then weak), then by mean explained residual."""
        out: list[str] = []
        for name in self.selected_strong + self.selected_weak:
            if name not in out:
                out.append(name)
        score = {e: max(0.5 * (self.explained_strong[e] + self.explained_weak[e]), self.explained_equation[e])
                 for e in self.effects}
        for name in sorted(self.effects, key=lambda e: -score[e]):
            if len(out) >= k:
                break
            if name not in out:
                out.append(name)
        return out[: max(k, len(self.selected_strong))]

    def as_dict(self) -> dict[str, Any]:
        return {
            "equations": self.equations,
            "per_effect": {e: {"explained_strong": self.explained_strong[e],
                               "explained_weak": self.explained_weak[e],
                               "inclusion": self.inclusion[e], "terms": self.columns[e],
                               "equation_error_estimate": self.estimates.get(e)}
                           for e in self.effects},
            "selected_strong": self.selected_strong,
            "selected_weak": self.selected_weak,
        }


def _estimates(effs: Sequence[Any], multipliers: dict[str, np.ndarray], ranges: dict[str, Any]
               ) -> dict[str, dict[str, float]]:
    """Each effect's equation-error estimate from its strong-form coefficients (:func:`screen`):
    off + coefficient·(probe − off) per parameter, clipped to its range."""
    estimates: dict[str, dict[str, float]] = {}
    for e in effs:
        est = {}
        for prm, m in zip(e.parameters, multipliers.get(e.name, ()), strict=False):
            r = ranges[e.name][prm.name]
            v = r.off + float(m) * (r.probe - r.off)
            if math.isfinite(v):
                est[prm.name] = r.clip(v)
        if est:
            estimates[e.name] = est
    return estimates


@dataclass
class _Rows:
    """The discrepancy regression rows of :func:`screen`, stacked over the recordings: strong form
    (every equation, scaled by its nominal residual's RMS; the equation and the resampling segment
    of each row) and weak form, with each column's name and effect group."""

    strong: list[np.ndarray] = field(default_factory=list)
    strong_y: list[np.ndarray] = field(default_factory=list)
    equation: list[np.ndarray] = field(default_factory=list)
    segment: list[np.ndarray] = field(default_factory=list)
    weak: list[np.ndarray] = field(default_factory=list)
    weak_y: list[np.ndarray] = field(default_factory=list)
    columns: dict[str, list[str]] = field(default_factory=dict)
    groups: list[int] = field(default_factory=list)


def _screening_rows(rig: Rig, base_meas: MeasurementMap, preps: Sequence[Prepared], effs: Sequence[Any],
                    eqs: list[str], ranges: dict[str, Any], *, weak_K: int, seed: int) -> _Rows:
    """Each recording's rows of :func:`screen` (module doc, step 2): the change of every
    equation's right-hand side when one parameter goes from off to its probe value."""
    out = _Rows(columns={e.name: [] for e in effs})
    strong_rows, strong_y, eq_of_row, seg_id = out.strong, out.strong_y, out.equation, out.segment
    weak_rows, weak_y, col_names = out.weak, out.weak_y, out.columns
    seg_base = 0
    for pi, p in enumerate(preps):
        dec = max(1, round(SCREEN_DT / p.dt))
        th = p.y["theta"]
        thd = _savgol(th, p.dt, 1)
        lhs = {"theta_dot": _savgol(th, p.dt, 2)[::dec]}
        for c in ("i_a", "omega_rotor"):
            if c in eqs:
                lhs[c] = _savgol(p.y[c], p.dt, 1)[::dec]
        if "v_a" in eqs:
            lhs["v_a"] = p.y["v_a"][::dec]
        n_d = lhs["theta_dot"].size
        nominal = hybrid_rhs(rig, base_meas, p, thd, eqs, dec)
        cols: dict[str, list[np.ndarray]] = {q: [] for q in eqs}
        grp: list[int] = []
        probes = _probe_rigs(rig, base_meas, effs, ranges)
        sims = iter(_replay_probes([r for r in probes if r is not None], p))
        probe_of = iter(probes)
        for gi, e in enumerate(effs):
            for prm in e.parameters:
                probe = next(probe_of)
                sim = next(sims) if probe is not None else None
                alt = {q: nominal[q] for q in eqs}
                if sim is not None:
                    alt = hybrid_rhs(*probe, p, thd, eqs, dec, sim=sim)
                for q in eqs:
                    cols[q].append(alt[q] - nominal[q])
                grp.append(gi)
                if pi == 0:
                    col_names[e.name].append(
                        f"{prm.name}: " + ", ".join(e.terms.get(q, ("Δf",))[0] for q in eqs if q in e.terms))
        if pi == 0:
            out.groups = grp
        # strong form: rows of every equation stacked, scaled by the RMS of its left side
        for q in eqs:
            res = lhs[q] - nominal[q]
            sc = float(np.sqrt(np.mean(res**2))) or 1.0
            strong_rows.append(np.column_stack(cols[q]) / sc)
            strong_y.append(res / sc)
            eq_of_row.append(np.full(res.size, eqs.index(q)))
            w = max(round(SEGMENT / (p.dt * dec)), 1)
            seg_id.append(seg_base + np.arange(n_d) // w)
        seg_base += n_d // max(round(SEGMENT / (p.dt * dec)), 1) + 1
        # weak form (differential equations only; the v_a map is algebraic)
        data = IdentData(t=np.arange(n_d) * p.dt * dec,
                         variables={"theta_dot": thd[::dec], **{c: p.y[c][::dec] for c in p.y}},
                         source=p.rec.source)
        for q in eqs:
            if q == "v_a":
                continue
            mat, lw = weak_matrices(data, np.column_stack([nominal[q], *cols[q]]), [q], K=weak_K,
                                    seed=seed + pi)
            res = lw[:, 0] - mat[:, 0]
            sc = float(np.sqrt(np.mean(res**2))) or 1.0
            weak_rows.append(mat[:, 1:] / sc)
            weak_y.append(res / sc)
    return out


def screen(rig: Rig, preps: Sequence[Prepared], effects: Sequence[str], channels: frozenset[str],
           ctx: EffectContext, *, n_bootstrap: int = N_BOOTSTRAP, seed: int = 0, weak_K: int = 150,
           meas: MeasurementMap | None = None, estimate: bool = True) -> Screening:
    """Discrepancy SINDy (strong and weak form) over the catalog's term groups.

    ``rig``/``meas`` are the base model (the nominal rig, or a corrected one when screening for a
    second effect). See the module docstring, step 2. Each equation's rows are scaled by the RMS of its
    nominal residual so the equations weigh alike; each column is scaled to unit RMS. The column of
    parameter j is the change of the right-hand side when that parameter goes from its ``off`` value
    to its probe value (``ctx``), the others staying off.

    With ``estimate`` (base = the nominal rig), each effect's own strong-form regression coefficient
    gives its **equation-error estimate**, off + coefficient·(probe − off) per parameter (exact for
    parameters that enter the equations linearly, a start value for the others), reported in
    :attr:`Screening.estimates` and used to start the output-error fits.

    Returns
    -------
    Screening
    """
    eqs = screening_equations(channels)
    effs = [get_effect(n) for n in effects]
    rng = np.random.default_rng(seed)
    ranges = {e.name: e.ranges(ctx) for e in effs}
    rows = _screening_rows(rig, meas or MeasurementMap(), preps, effs, eqs, ranges, weak_K=weak_K, seed=seed)
    strong_rows, strong_y, eq_of_row, seg_id = rows.strong, rows.strong_y, rows.equation, rows.segment
    weak_rows, weak_y, col_names, groups = rows.weak, rows.weak_y, rows.columns, rows.groups
    Xs, ys, seg = np.vstack(strong_rows), np.concatenate(strong_y), np.concatenate(seg_id)
    Xw, yw = np.vstack(weak_rows), np.concatenate(weak_y)
    cs = np.sqrt(np.mean(Xs**2, axis=0))
    cw = np.sqrt(np.mean(Xw**2, axis=0))
    Xs = Xs / np.where(cs > 0, cs, 1.0)
    Xw = Xw / np.where(cw > 0, cw, 1.0)
    groups_a = np.asarray(groups)

    multipliers: dict[str, np.ndarray] = {}

    def explained(X: np.ndarray, y: np.ndarray, g: int, scale: np.ndarray | None = None) -> float:
        c = np.flatnonzero(groups_a == g)
        if not np.any(np.abs(X[:, c]) > 0):
            return 0.0
        coef, *_ = np.linalg.lstsq(X[:, c], y, rcond=None)
        if scale is not None:
            multipliers[effs[g].name] = coef / np.where(scale[c] > 0, scale[c], 1.0)
        r = y - X[:, c] @ coef
        return float(max(0.0, 1.0 - (r @ r) / max(y @ y, 1e-300)))

    n_eff_s = max(ys.size // BIC_DECIMATION, 10)
    exp_s = {e.name: explained(Xs, ys, g, cs) for g, e in enumerate(effs)}
    estimates = _estimates(effs, multipliers, ranges) if estimate else {}
    exp_w = {e.name: explained(Xw, yw, g) for g, e in enumerate(effs)}
    # the best share an effect explains within one equation: stacking the equations with equal
    # weight lets equations whose residual is noise dilute a gap that lives in one of them
    rows_eq = np.concatenate(eq_of_row)
    exp_eq = {e.name: max(explained(Xs[rows_eq == j], ys[rows_eq == j], g) for j in range(len(eqs)))
              for g, e in enumerate(effs)}
    sel_s = [effs[g].name for g in group_select(Xs, ys, groups_a, n_eff=n_eff_s)]
    sel_w = [effs[g].name for g in group_select(Xw, yw, groups_a, n_eff=yw.size)]
    counts = dict.fromkeys(exp_s, 0)
    segs = np.unique(seg)
    for _ in range(n_bootstrap):
        pick = rng.choice(segs, size=segs.size, replace=True)
        rows = np.concatenate([np.flatnonzero(seg == s_) for s_ in pick])
        sub = rows[:: max(BIC_DECIMATION // 4, 1)]
        for g in group_select(Xs[sub], ys[sub], groups_a, n_eff=max(sub.size * 4 // BIC_DECIMATION, 10)):
            counts[effs[g].name] += 1
    return Screening(
        effects=[e.name for e in effs], explained_strong=exp_s, explained_weak=exp_w,
        explained_equation=exp_eq,
        selected_strong=sel_s, selected_weak=sel_w,
        inclusion={k: v / max(n_bootstrap, 1) for k, v in counts.items()}, equations=eqs, columns=col_names,
        estimates=estimates,
    )

