"""How ``rig fit``'s joint fit searches (:mod:`aeropend_ident.greybox.rig_fit`).

* its **blocks** (:func:`blocks_of`): a table each, a recording whole or in windows of a few seconds
  (:func:`fit_windows`: multiple shooting), a free decay from the release of a held rod;
* the **choice among local optima** (:func:`by_replay`): the lowest fit cost, unless another end's
  fitted rig predicts the recordings clearly better in the one free run
  (:func:`aeropend_ident.greybox.replay.free_run`);
* **held parameters freed** (:func:`free_held`) when the fit improves by more than its noise;
* the **refinement on whole recordings** (:func:`whole_runs`) from the windowed optimum, and the
  sandwich's clusters of a whole recording (:func:`clusters`).

No rclpy.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from aeropend_ident.errors import IdentificationError
from aeropend_ident.greybox.parameters import ParameterSpec
from aeropend_ident.greybox.replay import free_run, release_index
from aeropend_ident.greybox.rig_inputs import StaticTable, TimeSeries
from aeropend_ident.greybox.rig_problem import BalanceBlock, Block, Problem, ThrustBlock, TimeBlock
from aeropend_ident.greybox.uniform import UniformData
from aeropend_sim.params import Rig

#: Length [s] of the fit's free-run windows of a long recording (:func:`fit_windows`).
FIT_WINDOW_S = 5.0
#: A window starts where the command has been constant this long [s].
WINDOW_SETTLE_S = 0.3


def fit_windows(data: UniformData, length: float = FIT_WINDOW_S, settle: float = WINDOW_SETTLE_S
                ) -> list[tuple[int, int]]:
    """(start, stop) sample windows of a recording for the fit's free runs: about ``length`` s each,
    each starting where the command has been constant for ``settle`` s (the motor then sits near the
    steady state a free run starts it in), the last window merged when shorter than half ``length``.
    One window when the recording is shorter than two.

    Why windows: a lightly damped rod driven near π/2 is marginal; over a whole recording a free run
    of slightly wrong parameters goes over the top and the cost surface turns into plateaus (every
    diverged run scores the same penalty) with narrow valleys between them. Windows of a few
    seconds, each from its own measured initial angle and velocity (multiple shooting), keep the
    surface smooth; the reported figures are still the whole recordings' free runs.
    """
    n, dt = len(data), data.dt
    if n * dt < 2.0 * length:
        return [(0, n)]
    m = max(1, round(settle / dt))
    steady = np.zeros(n, dtype=bool)
    same = np.concatenate([[False], np.diff(data.duty) == 0.0])
    run = 0
    for k in range(n):
        run = run + 1 if same[k] else 0
        steady[k] = run >= m
    cuts, target = [0], round(length / dt)
    while True:
        k = cuts[-1] + target
        if k >= n - target // 2:
            break
        later = np.flatnonzero(steady[k:])
        if not later.size or k + later[0] >= n - target // 2:
            break
        cuts.append(int(k + later[0]))
    return list(itertools.pairwise([*cuts, n]))


def blocks_of(tables: Sequence[StaticTable], series: Sequence[TimeSeries], windows: bool = False
              ) -> list[Block]:
    """The fit's blocks: one per table, one per recording (``windows``: one per
    :func:`fit_windows` window of each recording other than a free decay; a free decay whose rod was
    held before it was let go from its release on, :func:`~aeropend_ident.greybox.replay.release_index`)."""
    out: list[Block] = []
    for t in tables:
        known = t.std is not None
        cls = BalanceBlock if t.kind == "balance" else ThrustBlock
        guess = 0.01 if t.kind == "balance" else 0.02 * float(np.max(np.abs(t.value)))
        kw = {"angle": t.value} if t.kind == "balance" else {"thrust": t.value}
        out.append(cls(source=t.source, label=t.label, sigma=1.0 if known else guess, static=True,
                       sigma_known=known, command=t.command, std=t.std, **kw))
    for s in series:
        if s.kind == "free decay":
            cut = [(release_index(s.data.theta, s.data.duty, s.data.dt), len(s.data))]
        else:
            cut = fit_windows(s.data) if windows else [(0, len(s.data))]
        for a, b in cut:
            data = s.data if (a, b) == (0, len(s.data)) else s.data.window(a, b)
            out.append(TimeBlock(source=s.source, label=s.label, data=data, kind=s.kind))
    return out


def replay_score(rig: Rig, series: Sequence[TimeSeries]) -> tuple[int, float]:
    """(runs that diverge or fail, mean free-run θ NRMSE of the others) of a rig on the recordings."""
    bad, scores = 0, []
    for ser in series:
        d = ser.replayed
        try:
            run = free_run(rig, d.t, d.duty, d.theta, source=d.source)
        except IdentificationError:
            bad += 1
            continue
        if run.nrmse is None or not math.isfinite(run.nrmse):
            bad += 1
        else:
            scores.append(run.nrmse)
    return bad, float(np.mean(scores)) if scores else math.inf


#: Another end of the joint fit replaces the lowest-cost one when its mean free-run NRMSE is lower by
#: more than this share (or fewer of its runs diverge).
REPLAY_MARGIN = 0.05


def predicts_better(a: tuple[int, float], b: tuple[int, float]) -> bool:
    """Whether score ``a`` (:func:`replay_score`: diverging runs, mean NRMSE) is clearly better than
    ``b``: fewer diverging runs, or as many and a mean NRMSE lower by more than :data:`REPLAY_MARGIN`."""
    return a[0] < b[0] or (a[0] == b[0] and a[1] < (1.0 - REPLAY_MARGIN) * b[1])


def by_replay(problem: Problem, ends: Sequence[tuple[np.ndarray, np.ndarray, Any]],
               series: Sequence[TimeSeries], notes: list[str]) -> tuple[np.ndarray, np.ndarray, Any]:
    """The joint fit's end (of the local solves from several starts) with the lowest fit cost, unless
    another end's fitted rig predicts the recordings clearly better in the one free run
    (:func:`predicts_better`); the lowest fit cost when there are no recordings.

    The fit's cost scores windows of a few seconds, each from its own fitted initial state (multiple
    shooting: a basin wide enough to find); a compromise rig of a model that cannot follow the
    recordings may score lower there by following each window slowly, and then lag behind the
    whole recording (jahoyosr's staircase: mgd/J 0.17 and L/J 0.37 beat 18.6 and 67 on the windows,
    free-run NRMSE 0.063 against 0.050). Among the fit's local optima the one that predicts is kept,
    and the note says so when that is not the lowest cost.
    """
    lowest = min(range(len(ends)), key=lambda k: ends[k][2].cost)
    if len(ends) < 2 or not series:
        return ends[lowest]
    scores = []
    for z, _, _ in ends:
        try:
            scores.append(replay_score(problem.rig(z), series))
        except IdentificationError:
            scores.append((len(series) + 1, math.inf))
    best = lowest
    for k in range(len(ends)):  # another end only when it predicts clearly better
        if predicts_better(scores[k], scores[best]):
            best = k
    if best != lowest:
        notes.append(f"joint fit: of {len(ends)} local optima the one with the lowest fit cost "
                     f"({ends[lowest][2].cost:.4g}) predicts the recordings worse in free run (mean θ NRMSE "
                     f"{scores[lowest][1]:.3g}, {scores[lowest][0]} diverging) than the one kept (cost "
                     f"{ends[best][2].cost:.4g}, mean θ NRMSE {scores[best][1]:.3g}, "
                     f"{scores[best][0]} diverging)")
    return ends[best]


def clusters(blocks: Sequence[Block]) -> list[int]:
    """Row counts of the sandwich's clusters: a table whole, a recording in stretches of about
    :data:`FIT_WINDOW_S` (the last one merged when shorter than half of it)."""
    out: list[int] = []
    for b in blocks:
        n = b.size()
        if not isinstance(b, TimeBlock) or b.data is None:
            out.append(n)
            continue
        m = max(round(FIT_WINDOW_S / b.data.dt), 1)
        cuts = list(range(0, n, m))
        if len(cuts) > 1 and n - cuts[-1] < m / 2:
            cuts.pop()
        out += [b2 - a for a, b2 in itertools.pairwise([*cuts, n])]
    return out


def whole_runs(problem: Problem, z: np.ndarray, series: Sequence[TimeSeries], notes: list[str]
                ) -> tuple[Problem, np.ndarray, np.ndarray] | None:
    """The fit refined on each recording whole (one free run from its first samples: what every
    command replays and scores), from the windowed fit's point ``z``; (the whole-run problem, its z,
    its J) when its free runs predict the recordings better (:func:`predicts_better`), else None.

    The windowed fit (multiple shooting: windows of a few seconds, each from its own fitted angle and
    velocity, the motor steady at the window's first command) finds the basin on records a single
    free run cannot follow from rig new's values; but a window that starts while the motor is still
    following a short APRBS hold starts it from the wrong state, and that bias stays in the fit
    (an amplifier rig: free-run NRMSE 0.0034 on its own APRBS, 0.00036 refined whole).
    """
    if not series or not problem.specs:
        return None
    tables = [b for b in problem.blocks if b.static]
    whole = Problem(problem.base, problem.geometry, list(problem.specs), [*tables, *blocks_of([], series)],
                    fixed=dict(problem.fixed), timing=problem.timing)
    k = len(problem.specs)
    z0, _, _ = whole.z_bounds()
    z0[:k] = z[:k]
    try:
        before = replay_score(whole.rig(z0), series)
    except IdentificationError:
        return None
    whole.reweight(z0, known=False)  # each recording weighed by its residual at the windowed fit
    z1, J1, _ = whole.solve(z0, max_nfev=60)
    try:
        after = replay_score(whole.rig(z1), series)
    except IdentificationError:
        return None
    if predicts_better(after, before):
        notes.append(f"joint fit refined on each recording whole (one free run each): mean θ NRMSE "
                     f"{before[1]:.3g} -> {after[1]:.3g} ({before[0]} -> {after[0]} diverging)")
        return whole, z1, J1
    return None


#: Freeing the parameters held at their starting values is kept when the fit's cost ½‖r‖² falls by
#: more than this share and by more than :data:`FREE_CHI2` per freed parameter (:func:`free_held`).
FREE_SHARE = 0.05
FREE_CHI2 = 4.5


def free_held(problem: Problem, all_specs: Sequence[ParameterSpec], held: set[str], z: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """The joint fit again with the parameters held at their starting values freed, from the fitted
    point; (z, J) when it fits better by more than the noise (:data:`FREE_SHARE`, :data:`FREE_CHI2`),
    else None (``problem`` unchanged).

    Which parameters the data cannot see is judged on the Jacobian at the *starting* values, where a
    parameter can look blind because another is still far off, and the misfit that follows inflates
    every block's σ: an ESC's idle duty held at rig new's 0.05 on a step log left the thrust curve's
    exponent at 1.18 and the free run 7× worse than the fit with it free (0.0022 against 0.0003, the
    truth 0.1126 and 1.00 found). Freed, the refusals are judged again at the fitted point.
    """
    values = problem.values(z)
    before = problem.cost(z)
    saved = problem.specs, problem.fixed
    k = len(problem.specs)
    problem.specs = [replace(s, initial=values[s.name]) for s in all_specs]
    problem.fixed = {}
    z1 = np.concatenate([[s.to_z(s.initial) for s in problem.specs], z[k:]])
    z2, J2, sol = problem.solve(z1, max_nfev=80)
    if sol.cost < before - max(FREE_SHARE * before, FREE_CHI2 * len(held)):
        return z2, J2
    problem.specs, problem.fixed = saved
    problem._cache = None
    return None


#: Points probed along each direction the refused parameters leave open, on each side of the fit's
#: end, evenly out to the search box's edge (:func:`open_profile`).
PROFILE_POINTS = 6
#: A side of the fit's end narrower than this (in the pivot's coordinate: 0.1 is 10 % of a log-scaled
#: parameter) is not probed: the pivot is refused because its 1σ exceeds one coordinate unit, so its
#: points would lie well inside what the fit's end already stands for (:func:`_probes`).
PROFILE_MIN_SPAN = 0.1
#: Where the refused parameters fit as well, a fitted parameter may move by this many of its 1σ; its
#: 1σ is widened to cover a larger move (:func:`open_profile`, ``rig_fit._profiled``).
GIVEN_SIGMAS = 2.0


@dataclass(frozen=True)
class OpenProfile:
    """What :func:`open_profile` found along the directions the refused parameters leave open.

    Attributes
    ----------
    lower : ndarray or None
        A point (the problem's coordinates) whose cost is below the fit's by more than the noise,
        the lowest probed: the fit stopped in a worse valley. None when no probe is lower.
    given : dict
        Fitted parameter -> (its largest move where the refused parameters fit as well, in its
        unit; the refused parameters held in those probes), for the parameters that moved by more
        than :data:`GIVEN_SIGMAS` × their 1σ.
    """

    lower: np.ndarray | None
    given: dict[str, tuple[float, list[str]]]


def open_profile(problem: Problem, z: np.ndarray, J: np.ndarray, refused: Sequence[str],
                 std: dict[str, float]) -> OpenProfile:
    """Profile of the fit along the directions its refused parameters leave open.

    A parameter refused at the fit keeps its best value, which the inputs do not determine locally;
    further along the same direction the fit may be better, or as good with the fitted parameters
    elsewhere. A free decay that shows a heavily damped rod at rest was fitted by a creep without
    restoring force (mgd/J at 0.082 1/s², refused; cost ½‖r‖² 28.8) with c/J = 14.9 ± 2.2 1/s,
    while the rod's own mgd/J and L/J (127 1/s², 493) fit it at cost 8.2 with c/J = 9.8
    (``bench/repro/rig_fit_flat_decay.py``). For each direction of the refused parameters the inputs
    leave open (a right singular vector of their columns of ``J`` whose standard error exceeds one
    coordinate unit, as :func:`~aeropend_ident.greybox.rig_problem.weak_directions` refuses), the
    refused parameter that weighs most in it is held at :data:`PROFILE_POINTS` points on each side
    of its best value, out to its search bound (a side narrower than :data:`PROFILE_MIN_SPAN` is
    skipped), and every other parameter solved again (the others
    refused beside it follow what the inputs do fix: a balance table's ratio of mgd/J to L/J). A
    probe lower than the fit by more than the noise (:data:`FREE_SHARE`, and :data:`FREE_CHI2` for the
    one parameter a probe holds) is a better valley; one within it fits as well, and a fitted
    parameter that moved there by more than :data:`GIVEN_SIGMAS` × its 1σ is known only within that
    move while the refused ones stay open.

    Parameters
    ----------
    problem : Problem
        The joint problem at the fit's end (its blocks' σ as they weigh the refusals); left as it was.
    z : ndarray
        The fit's end (the specs' coordinates, then the blocks' nuisance coordinates).
    J : ndarray, shape (rows, len(z))
        The weighted Jacobian at ``z``.
    refused : sequence of str
        The parameters among ``problem.specs`` refused at the fit.
    std : dict
        1σ of each fitted parameter (its unit).

    Returns
    -------
    OpenProfile
    """
    names = [s.name for s in problem.specs]
    r_idx = [names.index(n) for n in refused if n in names]
    k_idx = [j for j, n in enumerate(names) if n not in refused and math.isfinite(std.get(n, math.nan))]
    none = OpenProfile(None, {})
    if not r_idx or not k_idx:
        return none
    _, sv, vt = np.linalg.svd(J[:, r_idx], full_matrices=False)
    pivots = list(dict.fromkeys(r_idx[int(np.argmax(np.abs(vt[i])))] for i in range(sv.size) if sv[i] < 1.0))
    if not pivots:
        return none
    best = problem.cost(z)
    tolerance = max(FREE_SHARE * best, FREE_CHI2)  # a probe holds one parameter
    lower, lowest, given = None, best - tolerance, {}
    for pivot in pivots:
        for zp, cost in _probes(problem, z, pivot):
            if cost < lowest:
                lower, lowest = zp, cost
            elif cost <= best + tolerance:
                for j in k_idx:
                    spec = problem.specs[j]
                    move = abs(spec.from_z(zp[j]) - spec.from_z(z[j]))
                    if move > GIVEN_SIGMAS * std[names[j]]:
                        was, on = given.get(names[j], (0.0, []))
                        given[names[j]] = (max(was, move), on + [names[pivot]] * (names[pivot] not in on))
    return OpenProfile(lower, given)


def _probes(problem: Problem, z: np.ndarray, pivot: int) -> list[tuple[np.ndarray, float]]:
    """(point, cost) of each probe of :func:`open_profile`: the parameter ``pivot`` held, every other
    coordinate solved again (``problem`` left as it was); none on a side narrower than
    :data:`PROFILE_MIN_SPAN`."""
    specs, fixed = problem.specs, problem.fixed
    _, lo, hi = problem.z_bounds()
    free = [j for j in range(len(z)) if j != pivot]
    out = []
    try:
        problem.specs = [replace(sp, initial=sp.from_z(z[j])) for j, sp in enumerate(specs) if j != pivot]
        for end in (lo[pivot], hi[pivot]):
            if abs(end - z[pivot]) < PROFILE_MIN_SPAN:  # the pivot sits at this bound already
                continue
            for share in np.arange(1, PROFILE_POINTS + 1) / PROFILE_POINTS:
                zk = z[pivot] + share * (end - z[pivot])
                problem.fixed = {**fixed, specs[pivot].name: specs[pivot].from_z(float(zk))}
                problem._cache = None
                try:
                    z2, _, sol = problem.solve(z[free], max_nfev=80)
                except (IdentificationError, ValueError, ArithmeticError):
                    continue
                if math.isfinite(sol.cost):
                    zp = z.copy()
                    zp[pivot], zp[free] = zk, z2
                    out.append((zp, float(sol.cost)))
    finally:
        problem.specs, problem.fixed = specs, fixed
        problem._cache = None
    return out
