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
from dataclasses import replace
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
