"""``rig fit``: every "to be fitted" parameter of a rig file from what the lab has.

Inputs (:mod:`aeropend_ident.greybox.rig_inputs`) are told apart and each gets its method, a block
of the joint problem (:mod:`aeropend_ident.greybox.rig_problem`):

1. **static tables** first: a balance table (command vs angle) fits the static map up to a scale
   and the dead zone / idle throttle, a thrust table (load cell) K_q and the map; only the
   parameters the steady state depends on move;
2. **free decays**: the envelope (:func:`aeropend_ident.greybox.decay.analyse_decay`) gives the
   starting mgd/J (or the inertia, when the geometry is stated) and c/J, and decides whether the
   rod has dry friction (a linear envelope switches ``rod_coulomb_friction`` on, fitted too);
   then the output-error fit of the swing;
3. **steps, PRBS/APRBS and closed-loop logs**: the dead time's start from a grid over
   [0, min(1 s, ¼ of the shortest recording)] (ESC dead times reach 1 s), then
4. the **joint fit** of every block (output error, free run, each block weighted by its noise) in
   windows of a few seconds, from two starts; the optimum kept, the parameters held at their
   starting values freed when that fits better, and the result refined on each recording whole
   (:mod:`aeropend_ident.greybox.rig_search`); then each block's σ re-estimated from its residual
   (time series inflated by the residual's autocorrelation) for the uncertainties.

What the inputs cannot determine is **refused by name** before the joint fit (and judged again at
the fit when held parameters were freed): the weak directions
of the Jacobian (:func:`~aeropend_ident.greybox.rig_problem.weak_directions`) — a product only
determined as a whole (K_q·L/J from θ) or a parameter nothing is sensitive to — and, after it, any
parameter whose standard error exceeds half its value (a tenth of its range for a linear one). A
refused parameter stays "to be fitted" with the reason and the experiment that would determine it
(its declaration's :attr:`~aeropend_sim.components.base.Param.measure`, or for a timing parameter
the hold length the recordings would need); members of a product hold the determined combination
(the others at their starting values), so the rig still predicts. A value on its search bound is
flagged (terminal and file).

Uncertainty: 1σ standard errors, the larger of the Jacobian's of the joint weighted fit and a
cluster-robust sandwich over windows and tables (not a bootstrap: with
one recording per kind there is nothing to resample, and the autocorrelation inflation covers the
correlated residuals a bootstrap over recordings would show). Provenance: the inputs that hold at
least 10 % of a parameter's Fisher information, with their method.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from aeropend_ident.errors import IdentificationError
from aeropend_ident.greybox.batch import single_blas
from aeropend_ident.greybox.decay import analyse_decay
from aeropend_ident.greybox.parameters import ParameterSpec
from aeropend_ident.greybox.replay import FreeRun, free_run
from aeropend_ident.greybox.rig_fit_result import (
    HOLDS_NOTE,
    Outcome,
    RigFitResult,
    near_bound,
)
from aeropend_ident.greybox.rig_inputs import TimeSeries, fit_grid, read_inputs, shortest_hold
from aeropend_ident.greybox.rig_problem import (
    INERTIA,
    SCREEN_STARTS,
    Block,
    Problem,
    TimeBlock,
    covariance,
    nelder_mead_best,
    robust_covariance,
    weak_directions,
)
from aeropend_ident.greybox.rig_search import (
    GIVEN_SIGMAS,
    OpenProfile,
    blocks_of,
    by_replay,
    clusters,
    free_held,
    open_profile,
    whole_runs,
)
from aeropend_ident.io.resampling import detect_quantum
from aeropend_sim.components import registry
from aeropend_sim.components.base import SECTIONS, Effect
from aeropend_sim.components.pendulum.rod import G
from aeropend_sim.files.safe_yaml import parse_yaml
from aeropend_sim.params import TO_BE_FITTED, Rig, load_rig
from aeropend_sim.rigfile.template import GEOMETRY_NEEDED, plausible_range

#: A fitted parameter is refused when its standard error exceeds this fraction of its value (log
#: parameters) ...
MAX_RELATIVE_STD = 0.5
#: ... or this fraction of its search range (linear parameters).
MAX_RANGE_STD = 0.1
#: Largest dead time searched [s].
MAX_DEAD_TIME = 1.0
#: A nuisance coordinate (a block's initial angle or velocity) whose weighted Jacobian column is below
#: this norm (a standard error above 10 search units) is unseen by the data: jahoyosr's 222 s staircase
#: forgets its start (columns 0.012 and 0.004 beside 700-12 500), and kept in the covariance its blind
#: direction made the dead zone and the dry friction "± inf".
NUISANCE_UNSEEN = 0.1
#: Share of a parameter's Fisher information that makes an input part of its provenance.
PROVENANCE_SHARE = 0.1


# ------------------------------------------------------------------------------ reading the rig file
def to_be_fitted(doc: Mapping[str, Any]) -> dict[str, tuple[float, str]]:
    """Keys of a parsed rig file whose source marks them to be fitted -> (starting value, unit)."""
    out = {}
    for section in SECTIONS:
        for name, node in (doc.get(section) or {}).items():
            if isinstance(node, dict) and str(node.get("source", "")).startswith(TO_BE_FITTED):
                out[f"{section}.{name}"] = (float(node["value"]), str(node.get("unit", "")))
    return out


def stated_values(doc: Mapping[str, Any], todo: Mapping[str, Any]) -> dict[str, float]:
    """Every number the file gives that is not to be fitted (the geometry included)."""
    out = {}
    for section in SECTIONS:
        for name, node in (doc.get(section) or {}).items():
            key = f"{section}.{name}"
            if isinstance(node, dict) and "value" in node and key not in todo:
                out[key] = float(node["value"])
    return out


def timing_keys() -> frozenset[str]:
    """Rig keys of the timing hypotheses (a lag, a delay, a slow rotor: they act in transients only)."""
    return frozenset(s.target for d in registry.diagnoses() if d.timing for s in d.search)


def _spec(key: str, unit: str, start: float, stated: Mapping[str, float], top_delay: float) -> ParameterSpec:
    lo, hi, _ = plausible_range(key, stated)
    if key == "actuator.input_delay":
        hi = top_delay
    p = registry.params().get(key)
    declared = p.fit if p is not None else None
    log = lo > 0.0
    scale = 1.0 if log else ((declared.scale if declared is not None and declared.scale else None)
                             or (hi - lo) / 20.0)
    start = min(max(start, lo), hi)
    if log and start <= 0.0:
        start = math.sqrt(lo * hi)
    return ParameterSpec(key, unit, float(start), float(lo), float(hi), log, float(scale))


# ------------------------------------------------------------------------------ stages
def _stage(problem: Problem, blocks: Sequence[int], names: Sequence[str], start: dict[str, float],
           max_nfev: int = 40) -> dict[str, float]:
    """Fit ``names`` on the ``blocks`` alone (the rest held at ``start``); what these blocks cannot
    determine stays where it is, and the blocks' σ are re-estimated from their residuals. Returns the
    updated starting values."""
    specs = [replace(s, initial=start[s.name]) for s in problem.specs if s.name in names]
    if not specs or not blocks:
        return start
    sub = Problem(problem.base, problem.geometry, specs, [problem.blocks[i] for i in blocks],
                  fixed={k: v for k, v in start.items() if k not in names}, timing=problem.timing)
    z0, lo, hi = sub.z_bounds()
    # global screen first: at rig new's start a table is often flat (the model holds none of the
    # recorded angles), which would make every parameter look undetermined
    ranked = [z for _, z in sub.screen(z0, [s.name for s in specs], keep=SCREEN_STARTS)[:SCREEN_STARTS]]
    J = sub.jac(ranked[0], lo, hi)[:, : len(specs)]
    order = [_chain_order(s.name) for s in specs]
    weak = {f for f, _, _ in weak_directions(J, [s.name for s in specs], order)}
    keep = [j for j, s in enumerate(specs) if s.name not in weak]
    sub.specs = [specs[j] for j in keep]
    sub.fixed.update({s.name: s.initial for s in specs if s.name in weak})
    if not sub.specs:
        return start
    best = None
    for zs in ranked:
        got = sub.solve(np.concatenate([zs[keep], zs[len(specs):]]), max_nfev=max_nfev, tol=1e-6)
        if best is None or got[2].cost < best[2].cost:
            best = got
    z = best[0]  # type: ignore[index]
    sub.reweight(z, known=False)  # the blocks' σ from their residuals: what the refusals weigh
    return {**start, **{s.name: s.from_z(zi) for s, zi in zip(sub.specs, z, strict=False)}}


def _chain_order(key: str) -> float:
    """Position of a parameter's owner along the signal chain (ties of weak_directions: fix upstream)."""
    if key == INERTIA:
        return 1e6
    return float(registry.owners()[key].order)


def _decay_starts(series: Sequence[TimeSeries], todo: Mapping[str, Any], start: dict[str, float],
                  stated: Mapping[str, float], notes: list[str]) -> tuple[dict[str, float], str | None]:
    """Starting values from the free decays' envelopes; the dry-friction key to add, if any."""
    add = None
    for s in series:
        if s.kind != "free decay":
            continue
        try:
            env = analyse_decay(s.data.t, s.data.theta, s.noise)
        except (ValueError, ArithmeticError) as exc:
            notes.append(f"{s.source}: free-decay envelope not analysed ({exc})")
            continue
        notes.append(f"{s.source}: free decay, period {env.period:.3g} s, {env.envelope} envelope "
                     f"(c/J ≈ {env.c_over_J:.3g} 1/s, T_f/J ≈ {env.coulomb_over_J:.3g} ± "
                     f"{env.coulomb_std:.2g} rad/s², mgd/J ≈ {env.mgd_over_J:.4g} 1/s²)")
        _rod_starts(todo, start, stated, env.c_over_J,
                    env.mgd_over_J if float(s.data.duty[0]) == 0.0 else None)
        dry = "pendulum.coulomb_over_J"
        if env.dry_friction and dry not in todo and dry not in stated:
            add = dry
            start[add] = env.coulomb_over_J
            notes.append(f"{s.source}: the envelope decays linearly: dry friction T_f/J switched on and "
                         "fitted")
    return start, add


#: A hold of a step log rings like a free decay about its new level after this long [s] (the motor's
#: lag and dead time are over); holds shorter than :data:`HOLD_MIN_S` are not analysed.
HOLD_SETTLE_S = 0.3
HOLD_MIN_S = 3.0


def _hold_starts(series: Sequence[TimeSeries], todo: Mapping[str, Any], start: dict[str, float],
                 stated: Mapping[str, float], notes: list[str]) -> bool:
    """Starting values of the rod's damping and time scale from the ringing of the step logs' holds,
    when no free decay is given (``start`` updated in place); whether any hold rang.

    Under a held command the thrust is constant and the rod swings about its new level as in a
    free decay (:func:`aeropend_ident.greybox.decay.analyse_decay`: ω_n² = (mgd/J)·cos θ_eq, c/J from
    the envelope); the medians over the holds that ring are the starts. Output error on oscillating
    records has a valley per swing period a local solve cannot leave: without this start a step log
    alone ended with the rod 4× too heavy and 3× too damped (NRMSE 0.08 where 0.003 was there).
    """
    found = []
    for s in series:
        if s.kind != "steps":
            continue
        d = s.data
        edges = np.concatenate([[0], np.flatnonzero(np.abs(np.diff(d.duty)) > 1e-9) + 1, [len(d)]])
        skip = round(HOLD_SETTLE_S / d.dt)
        for a, b in itertools.pairwise(edges):
            if (b - a) * d.dt < HOLD_MIN_S or a == 0:
                continue
            try:
                env = analyse_decay(d.t[a + skip:b], d.theta[a + skip:b], s.noise)
            except (ValueError, ArithmeticError):
                continue
            if env.mgd_over_J > 0.0 and math.isfinite(env.mgd_over_J) and env.c_over_J >= 0.0:
                found.append((s.source, env))
    if not found:
        return False
    mgd = float(np.median([e.mgd_over_J for _, e in found]))
    cj = float(np.median([e.c_over_J for _, e in found]))
    period = float(np.median([e.period for _, e in found]))
    names = ", ".join(dict.fromkeys(src for src, _ in found))
    notes.append(f"{names}: {len(found)} hold(s) ring with period {period:.3g} s (median): "
                 f"c/J ≈ {cj:.3g} 1/s, mgd/J ≈ {mgd:.4g} 1/s² (starting values)")
    _rod_starts(todo, start, stated, cj, mgd)
    return True


def _rod_starts(todo: Mapping[str, Any], start: dict[str, float], stated: Mapping[str, float],
                c_over_J: float, mgd_over_J: float | None) -> None:
    """Starting values of the rod's damping c/J [1/s] (when > 0) and, given its gravity term mgd/J
    [1/s²], of mgd/J or the inertia J = m·g·d/(mgd/J) from the stated geometry (``start`` updated)."""
    if "pendulum.c_over_J" in todo and c_over_J > 0.0:
        start["pendulum.c_over_J"] = c_over_J
    if mgd_over_J is None:
        return
    if "pendulum.mgd_over_J" in todo:
        start["pendulum.mgd_over_J"] = mgd_over_J
    if INERTIA in todo and all(k in stated for k in GEOMETRY_NEEDED):
        start[INERTIA] = stated["pendulum.mass"] * G * stated["pendulum.com_distance"] / mgd_over_J


#: Local searches of the timing parameters alone (Nelder-Mead, the windows' initial states held at
#: their measured values), from the best points of their global screen: a dead time and a lag trade
#: off along a curved valley that a Gauss-Newton step with 50 initial-state coordinates crawls along.
TIMING_STARTS = 3
#: Cost evaluations of each of those searches.
TIMING_NFEV = 60


def _timing_start(problem: Problem, start: dict[str, float]) -> dict[str, float]:
    """Starts of the timing parameters (dead time, lags, the rotor's time constant): the best point
    of a global screen over their searched ranges on the dynamic recordings (the static tables and
    the decays cannot see them), every other parameter at its start."""
    keys = [k for k in start if k in problem.timing]
    dyn = [b for b in problem.blocks if isinstance(b, TimeBlock) and b.kind != "free decay"]
    if not keys or not dyn:
        return start
    specs = [replace(s, initial=start[s.name]) for s in problem.specs if s.name in keys]
    sub = Problem(problem.base, problem.geometry, specs, dyn,
                  fixed={k: v for k, v in start.items() if k not in keys}, timing=problem.timing)
    z0, lo, hi = sub.z_bounds()
    k = len(specs)
    best = nelder_mead_best(lambda x: sub.cost(np.concatenate([x, z0[k:]])),
                            [z[:k] for _, z in sub.screen(z0, keys, keep=TIMING_STARTS)[:TIMING_STARTS]],
                            list(zip(lo[:k], hi[:k], strict=True)), TIMING_NFEV)
    return {**start, **{s.name: s.from_z(best.x[j]) for j, s in enumerate(specs)}}


# ------------------------------------------------------------------------------ refusals
def _symbol(key: str) -> str:
    p = registry.params().get(key)
    return (p.symbol or p.name) if p is not None else key.partition(".")[2]


def _measure(key: str) -> str:
    p = registry.params().get(key)
    if key == INERTIA:
        return "a free decay with the motor off (its swing frequency)"
    return (p.measure if p is not None and p.measure else "state it")


def _combination(group: Sequence[str], exps: np.ndarray) -> str:
    """``K_q·L/J`` (a product) or ``A/B`` (a ratio) of a pair, from the exponents of its invariant."""
    if len(group) != 2 or not np.all(np.isfinite(exps)) or np.any(exps == 0):
        return "a combination of " + ", ".join(_symbol(k) for k in group)
    a, b = (round(abs(float(e)) * 2.0) / 2.0 for e in exps)
    pa = _symbol(group[0]) + ("" if a == 1 else f"^{a:g}")
    pb = _symbol(group[1]) + ("" if b == 1 else f"^{b:g}")
    return f"{pa}·{pb}" if exps[0] * exps[1] > 0 else f"{pa}/{pb}"


def _timing_hint(key: str, value: float, hold: float, dt: float) -> str:
    """What would determine a timing parameter (a dead time, a lag, a time constant, in s) of value
    ``value``, given the recordings' shortest hold ``hold`` and their sample period ``dt``."""
    if math.isfinite(value) and 0.0 < value < 3.0 * dt:
        return (f"at {value:.2g} s it is shorter than three samples of these logs ({dt:.2g} s each): it "
                "hardly shapes the angle at this logging rate; state it from a data sheet, or log faster "
                f"(a sample period of {value / 3.0:.2g} s or less) with steps")
    need = max(2.0 * value, 10.0 * dt) if math.isfinite(value) and value > 0 else 10.0 * dt
    if not math.isfinite(hold):
        return (f"no recording changes the command (tables and free decays only); a step or PRBS with holds "
                f"of about {need:.2g} s would")
    return (f"the recordings never change the command faster than {hold:.3g} s; a step or PRBS with holds "
            f"of about {need:.2g} s would")


def _hint(key: str, value: float, timing: frozenset[str], hold: float, dt: float) -> str:
    p = registry.params().get(key)
    if key in timing and p is not None and p.unit == "s":
        return _timing_hint(key, value, hold, dt)
    return _measure(key)




def _refusals(weak: Sequence[tuple[str, list[str], np.ndarray]], names_inputs: str,
              start: Mapping[str, float], timing: frozenset[str], hold: float, dt: float) -> dict[str, str]:
    """Reason per refused key (module docstring)."""
    out: dict[str, str] = {}
    for fixed, group, exps in weak:
        if len(group) == 1:
            hint = _hint(fixed, start.get(fixed, math.nan), timing, hold, dt)
            out[fixed] = (f"{fixed}: the inputs ({names_inputs}) are not sensitive to it (a factor e "
                          f"changes no fit by more than its noise); {hint}")
            continue
        combo = _combination(group, exps)
        states = "; ".join(f"{k} — {_hint(k, start.get(k, math.nan), timing, hold, dt)}" for k in group)
        text = (f"{' and '.join(group)}: only {combo} is determined by {names_inputs}; state one: {states}")
        for k in group:
            extra = "" if k == fixed else f"{HOLDS_NOTE}{combo} with the others at their starting values)"
            out.setdefault(k, text + extra)
    return out


def _provenance(J: np.ndarray, sizes: Sequence[int], blocks: Sequence[Block], j: int) -> str:
    """The inputs holding ≥ PROVENANCE_SHARE of column j's Fisher information, with their method."""
    edges = np.concatenate([[0], np.cumsum(sizes)])
    cols = [J[edges[b]:edges[b + 1], j] for b in range(len(blocks))]
    per: dict[tuple[str, str], float] = {}
    for b, c in zip(blocks, cols, strict=True):  # a recording's windows count as the recording
        per[(b.source, b.label)] = per.get((b.source, b.label), 0.0) + float(c @ c)
    total = sum(per.values())
    if total <= 0.0:
        return "no input"
    keep = sorted((k for k, v in per.items() if v >= PROVENANCE_SHARE * total), key=lambda k: -per[k])
    return ", ".join(f"{src} ({label}, {100 * per[(src, label)] / total:.0f} %)" for src, label in keep)


# ------------------------------------------------------------------------------ the command
@single_blas
def fit_rig(rig_path: str | Path, inputs: Sequence[str], preset: str | None = None,
            progress: Callable[[str], None] | None = None) -> RigFitResult:
    """Fit every "to be fitted" parameter of a rig file (module docstring).

    BLAS runs on one thread (:func:`~aeropend_ident.greybox.batch.single_blas`, as the grey-box fit
    and the gap diagnosis): the joint solve's trust region takes an SVD of its tall Jacobian every
    iteration (jahoyosr's staircase: 15 556 × 93, 145 times), and OpenBLAS' second thread spun against
    the replays and any other process on a 2-core machine: that fit took 57-192 s wall (user time
    up to 2× the wall time), 48 s on one BLAS thread with the same result.

    Parameters
    ----------
    rig_path : str or Path
        A rig file (``rig new``'s, or any with ``source: "to be fitted (rig fit)"`` entries).
    inputs : sequence of str
        Static tables (CSV, :mod:`~aeropend_ident.greybox.rig_inputs`) and recordings (bags,
        ``FILE.csv:PRESET``).
    preset : str, optional
        CSV preset for recordings without their own.
    progress : callable, optional
        Called with one line per stage.

    Raises
    ------
    IdentificationError
        Nothing to be fitted, no inputs, or an unusable input; RigFileError and the readers' errors
        (ValueErrors) pass through.
    """
    say = progress or (lambda _m: None)
    path = Path(rig_path)
    rig = load_rig(path)  # refuses an alias or an oversized file with the file's name
    text = path.read_text(encoding="utf-8")
    doc = parse_yaml(text, str(path), "a rig file")
    todo = to_be_fitted(doc)
    sample_todo = str((doc.get("sample_period") or {}).get("source", "")).startswith(TO_BE_FITTED)
    if not todo:
        raise IdentificationError(f"{path}: no parameter is marked to be fitted (source \"{TO_BE_FITTED}\"); "
                                  "nothing to do (rig check shows what the file states)")
    if not inputs:
        raise IdentificationError("rig fit needs at least one input (a static table or a recording)")
    say(f"[1/5] reading {len(inputs)} input(s)")
    tables, series = read_inputs(list(inputs), preset, grid=fit_grid(rig))
    notes: list[str] = [
        f"{s.source}: fitted on a {s.data.dt * 1e3:.3g} ms grid (1 sample in {s.data.decimate} of its "
        f"{s.replayed.dt * 1e3:.3g} ms uniform grid: the rod's dynamics need no finer; the figures replay "
        "the whole grid)" for s in series if s.full is not None]
    sample_period = None
    if sample_todo and series:
        dt = min(s.replayed.dt for s in series)
        dt = float(f"{dt:.9g}")
        sample_period = (dt, f"median sample interval of {series[0].source} (rig fit)")
        rig = replace(rig, sample_period=dt)
    stated = stated_values(doc, todo)
    geometry = {k: v for k, v in stated.items() if k in (*GEOMETRY_NEEDED, INERTIA)}
    for key in todo:
        owner = registry.owners().get(key)
        if isinstance(owner, Effect) and not owner.is_on(getattr(rig.effects, owner.name)):
            rig = rig.with_effects(**{owner.name: owner.on})
    dyn = [s for s in series if s.kind != "free decay"]
    top_delay = min([MAX_DEAD_TIME, *(0.25 * s.data.t[-1] for s in dyn)]) if dyn else MAX_DEAD_TIME
    start = {k: v for k, (v, _) in todo.items()}
    start, add = _decay_starts(series, todo, start, stated, notes)
    decay_given = any(s.kind == "free decay" for s in series)
    rang = not decay_given and _hold_starts(series, todo, start, stated, notes)
    units = {k: u for k, (_, u) in todo.items()}
    if add is not None:
        units[add] = registry.param(add).unit
        rig = rig.with_effects(rod_coulomb_friction=True)
    specs = [_spec(k, units[k], start[k], stated, top_delay) for k in units]
    start = {s.name: s.initial for s in specs}
    problem = Problem(rig, geometry, specs, blocks_of(tables, series, windows=True), timing=timing_keys())
    static_idx = [i for i, b in enumerate(problem.blocks) if b.static]
    if static_idx:
        say(f"[2/5] static tables: {', '.join(problem.blocks[i].source for i in static_idx)}")
        start = _stage(problem, static_idx, [k for k in start if k not in problem.timing], start)
    decays = [i for i, b in enumerate(problem.blocks) if isinstance(b, TimeBlock) and b.kind == "free decay"]
    if decays:
        say(f"[3/5] free decays: {', '.join(problem.blocks[i].source for i in decays)}")
        start = _stage(problem, decays, list(start), start)
    elif not static_idx and rang:
        # the rod's time scale and damping from the holds' ringing: the gain-side parameters first with
        # them held, or the joint solve trades a wrong static gain against a heavy, damped rod
        rod = {"pendulum.c_over_J", "pendulum.mgd_over_J", INERTIA}
        say("[3/5] holds: the static gain with the rod's ringing held")
        start = _stage(problem, list(range(len(problem.blocks))),
                       [k for k in start if k not in rod and k not in problem.timing], start)
    start = _timing_start(problem, start)
    say(f"[4/5] joint fit of {len(start)} parameter(s) on {len(problem.blocks)} input(s)")
    return _joint(problem, start, path, text, doc, rig, notes, sample_period, series, say)


#: Recordings' angle LSBs agree when the largest is within this factor of the smallest.
QUANTUM_AGREEMENT = 1.02


def angle_quantum(series: Sequence[TimeSeries]) -> tuple[float, str] | None:
    """The angle LSB q [rad] the recordings' θ lies on, and its source (written into the fitted rig
    unless the rig file states a quantum, :func:`_joint`); None when a recording is not
    quantised (its values off a lattice, :func:`aeropend_ident.io.resampling.detect_quantum`)
    or the recordings' lattices differ by more than :data:`QUANTUM_AGREEMENT`.

    The sensor's resolution is a fact of the logs, not a parameter to fit: a 10-bit potentiometer
    ADC or a 12-bit encoder puts every recorded angle on k·q. The fitted rig carries it so that a
    closed-loop design checked on that rig (``design_gains``) sees the sensor the controller will
    read (a small step can limit-cycle within one LSB). Replays compare the model's angle without
    quantisation (:mod:`aeropend_ident.greybox.replay`), so no fit figure changes.
    """
    qs = [detect_quantum(s.replayed.theta) for s in series]
    if not qs or min(qs) <= 0.0 or max(qs) > QUANTUM_AGREEMENT * min(qs):
        return None
    q = float(np.median(qs))
    return q, f"detected in the logs (rig fit): every recorded angle on a lattice of {q:.5g} rad"


def _outcomes(problem: Problem, z: np.ndarray, J: np.ndarray, refused: Mapping[str, str], sources: str,
              hold: float | None, dt: float) -> dict[str, Outcome]:
    """Each fitted parameter's :class:`Outcome` at the joint fit's end ``z`` (Jacobian ``J``, rows
    weighted): the larger of the Jacobian's and the sandwich standard error, the search bound it
    lies at, and whether it is refused (by ``refused``, or as not determined by the inputs)."""
    outcomes: dict[str, Outcome] = {}
    _, lo, hi = problem.z_bounds()
    pinned = (np.abs(z - lo) <= 1e-4) | (np.abs(z - hi) <= 1e-4)
    # a block's start (angle, velocity) the data do not see — a long free run forgets it — is held
    # out of the covariance, where its blindness would spread to the parameters it barely touches
    unseen = np.linalg.norm(J, axis=0) < NUISANCE_UNSEEN
    unseen[: len(problem.specs)] = False
    pinned |= unseen
    cov = covariance(J, pinned)
    sizes = [b.size() for b in problem.blocks]
    # the larger of the Jacobian's and the blocks' sandwich variance: a misfit widens it (a whole
    # recording counts as its windows: stretches of a few seconds, as the windowed fit's clusters)
    robust = robust_covariance(J, problem.fun(z), clusters(problem.blocks), cov)
    for j, s in enumerate(problem.specs):
        v = s.from_z(z[j])
        var = max(cov[j, j], robust[j, j]) if math.isfinite(cov[j, j]) else cov[j, j]
        std = (abs(s.dp_dz(v)) * math.sqrt(var) if math.isfinite(var)
               else math.inf if var == math.inf else math.nan)
        bound = near_bound(z[j], lo[j], hi[j], s.lower, s.upper, v, std)
        o = Outcome(s.name, s.unit, v, std, provenance=_provenance(J, sizes, problem.blocks, j),
                    bound=bound, lower=s.lower, upper=s.upper)
        loose = std > _refusal_limit(s, v)
        if s.name in refused:
            o.status, o.reason = "to be fitted", refused[s.name]
        elif math.isinf(std) or (math.isfinite(std) and loose):
            o.status = "to be fitted"
            o.reason = (f"{s.name}: not determined by {sources} ({v:.3g} ± {std:.2g} {s.unit}); "
                        f"{_hint(s.name, v, problem.timing, hold, dt)}")
        outcomes[s.name] = o
    return outcomes


def _refusal_limit(spec: ParameterSpec, value: float) -> float:
    """The 1σ above which a fitted parameter is refused (:data:`MAX_RELATIVE_STD` of its value for a
    log parameter, :data:`MAX_RANGE_STD` of its search range for a linear one)."""
    return MAX_RELATIVE_STD * abs(value) if spec.log else MAX_RANGE_STD * (spec.upper - spec.lower)


def _reweighted(problem: Problem, z: np.ndarray, J: np.ndarray) -> np.ndarray:
    """``J`` with each block's rows rescaled after its σ is re-estimated at ``z``
    (:meth:`~aeropend_ident.greybox.rig_problem.Problem.reweight`)."""
    return J * np.repeat(problem.reweight(z), [b.size() for b in problem.blocks])[:, None]


def _refusals_at(problem: Problem, J: np.ndarray, sources: str, start: Mapping[str, float],
                 hold: float | None, dt: float) -> dict[str, str]:
    """:func:`_refusals` judged on the weighted Jacobian ``J`` at the fit, not at the start."""
    names = [sp.name for sp in problem.specs]
    return _refusals(weak_directions(J[:, : len(names)], names, [_chain_order(n) for n in names]),
                     sources, start, problem.timing, hold, dt)


def _profiled(problem: Problem, z: np.ndarray, J: np.ndarray, outcomes: dict[str, Outcome],
              start: Mapping[str, float], sources: str, hold: float | None, dt: float, notes: list[str]
              ) -> tuple[dict[str, Outcome], np.ndarray]:
    """The outcomes after the profile along what the refused parameters leave open
    (:func:`~aeropend_ident.greybox.rig_search.open_profile`): fitted again from a better valley
    found there (refusals judged at the new end), and the 1σ of a fitted parameter that moves where
    refused ones fit as well widened to half that move (refused when that exceeds the refusal
    limits, with a note when not). Returns (outcomes, the fit's end)."""
    def profile() -> OpenProfile:
        return open_profile(problem, z, J, [k for k, o in outcomes.items() if o.status != "fitted"],
                            {k: o.std for k, o in outcomes.items() if o.status == "fitted"})

    prof = profile()
    if prof.lower is not None:
        was = sorted(k for k, o in outcomes.items() if o.status != "fitted")
        z, J, _ = problem.solve(prof.lower, max_nfev=80)
        J = _reweighted(problem, z, J)
        outcomes = _outcomes(problem, z, J, _refusals_at(problem, J, sources, start, hold, dt), sources, hold,
                             dt)
        notes.append(f"{', '.join(was)}: not determined where the fit first ended; further along what the "
                     "inputs left open the fit was better by more than its noise, and it was fitted again "
                     "from there")
        prof = profile()
    for k, (move, on) in prof.given.items():
        o = outcomes[k]
        spec = next(sp for sp in problem.specs if sp.name == k)
        was, o.std = o.std, move / GIVEN_SIGMAS
        why = (f"where {' and '.join(on)}, which {sources} leave open, {'fits' if len(on) == 1 else 'fit'} "
               f"as well, {k} moves by up to {move:.2g} {o.unit}")
        if o.std > _refusal_limit(spec, o.value):
            o.status = "to be fitted"
            o.reason = (f"{k}: determined by {sources} only given {' or '.join(on)} ({why}); "
                        f"state {' or '.join(on)}")
        else:
            notes.append(f"{k}: 1σ widened from {was:.2g} to {o.std:.2g} {o.unit}: {why}")
    return outcomes, z


def _with_logged_quantum(fitted: Rig, rig: Rig, series: Sequence[TimeSeries], notes: list[str]
                         ) -> tuple[Rig, tuple[float, str] | None]:
    """The fitted rig with the angle lattice the logs show (:func:`angle_quantum`) as its sensor's
    quantisation, unless the lab stated one (then a disagreement is noted)."""
    quantum = angle_quantum(series)
    stated_q = rig.sensors.theta_quantum if rig.effects.quantisation else 0.0
    if quantum is not None and stated_q > 0.0:  # the lab's own statement stands; a disagreement is said
        if abs(quantum[0] / stated_q - 1.0) > QUANTUM_AGREEMENT - 1.0:
            notes.append(f"the logs' angles lie on a lattice of {quantum[0]:.5g} rad, the rig file states "
                         f"sensors.theta_quantum {stated_q:.5g} rad: check the sensor's resolution")
        quantum = None
    if quantum is not None:
        quantisation = next(d for d in registry.diagnoses() if d.name == "quantisation")
        fitted = quantisation.apply(fitted, {"theta_quantum": quantum[0]})
    return fitted, quantum


def _free_runs(fitted: Rig, series: Sequence[TimeSeries], notes: list[str]) -> dict[str, FreeRun]:
    """The fitted rig's figure on each whole recording: the one replay of every command (not the
    fit's own start values; the fit's windows are its own business)."""
    runs: dict[str, FreeRun] = {}
    for ser in series:
        d = ser.replayed
        try:
            runs[ser.source] = free_run(fitted, d.t, d.duty, d.theta, source=d.source)
        except IdentificationError as exc:
            notes.append(f"{ser.source}: free run of the fitted rig failed ({exc})")
    return runs


def _joint(problem: Problem, start: dict[str, float], path: Path, text: str, doc: Mapping[str, Any], rig: Rig,
           notes: list[str], sample_period: tuple[float, str] | None, series: Sequence[TimeSeries],
           say: Callable[[str], None]) -> RigFitResult:
    """The joint fit, its refusals and the result (:func:`fit_rig`)."""
    all_specs = [replace(s, initial=start[s.name]) for s in problem.specs]
    problem.specs = all_specs
    names = [s.name for s in all_specs]
    z0, lo, hi = problem.z_bounds()
    J0 = problem.jac(z0, lo, hi)[:, : len(names)]
    weak = weak_directions(J0, names, [_chain_order(n) for n in names])
    sources = ", ".join(dict.fromkeys(b.source for b in problem.blocks))  # a recording once, not per window
    dyn = [s for s in series if s.kind != "free decay"]
    hold = shortest_hold(dyn)
    dt = min((s.data.dt for s in series), default=0.01)
    refused = _refusals(weak, sources, start, problem.timing, hold, dt)
    held = {f for f, _, _ in weak}
    problem.specs = [s for s in all_specs if s.name not in held]
    problem.fixed = {s.name: s.initial for s in all_specs if s.name in held}
    outcomes: dict[str, Outcome] = {}
    z = np.zeros(0)
    if problem.specs:
        z0, lo, hi = problem.z_bounds()
        # global screen first along what the tables leave open (the rod's time scale, its damping;
        # the decays' values are the screen's centre, not a constraint: a decay recorded after the
        # rod came to rest carries no swing): a local solve from rig new's value there settles in the
        # nearest valley. A lower start is not a lower optimum: both are solved, and the end whose
        # free runs predict the recordings best wins (by_replay)
        tables = [i for i, b in enumerate(problem.blocks) if b.static]
        ends = problem.solve_each([z0, problem.screen_open(z0, tables)], max_nfev=80)
        z, J, _ = by_replay(problem, ends, series, notes)
        freed = free_held(problem, all_specs, held, z) if held else None
        if freed is not None:
            z, J = freed
            notes.append(f"{', '.join(sorted(held))}: held at the starting values, where the data did not "
                         "see them; fitted with the others the fit improved by more than its noise, so they "
                         "are fitted (what stays undetermined is said below)")
            held = set()
        refined = whole_runs(problem, z, series, notes)
        if refined is not None:
            problem, z, J = refined
        say("[5/5] uncertainties: each input weighted by its residual noise")
        J = _reweighted(problem, z, J)
        if freed is not None:  # what the data do not determine, judged at the fit, not at the start
            refused = _refusals_at(problem, J, sources, start, hold, dt)
        outcomes = _outcomes(problem, z, J, refused, sources, hold, dt)
        outcomes, z = _profiled(problem, z, J, outcomes, start, sources, hold, dt, notes)
    for s in all_specs:
        if s.name in held:
            outcomes[s.name] = Outcome(s.name, s.unit, s.initial, status="to be fitted",
                                       reason=refused[s.name], lower=s.lower, upper=s.upper)
    fitted, quantum = _with_logged_quantum(problem.rig(z), rig, series, notes)
    runs = _free_runs(fitted, series, notes)
    nrmse = {k: r.nrmse for k, r in runs.items()}
    divergence = {k: r.divergence for k, r in runs.items() if r.divergence is not None}
    ordered = [outcomes[s.name] for s in all_specs]
    inputs = list(dict.fromkeys((b.source, b.label) for b in problem.blocks))
    return RigFitResult(path, text, rig.family, ordered, fitted, inputs, nrmse, notes,  # type: ignore[arg-type]
                        sample_period, divergence, runs, quantum)
