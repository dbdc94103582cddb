"""The candidate models a discrimination design separates, from a gap diagnosis.

A gap diagnosis leaves a chosen set of effects and a ranking of the others; where the data did
not separate them (``ambiguous_with``, ``confusable_with``, a ranked effect that explains almost as
much) the truth may be another set. The candidates are:

* the chosen set (the corrected rig; the nominal rig when nothing was chosen),
* the chosen set plus each of the best-ranked other effects (while the set is below
  ``max_effects``), and
* the chosen set with one of its members, or two at once, swapped for an effect confusable or
  ambiguous with it (or from the same subsystem), and
* every compatible set of up to ``max_effects`` effects from a pool of the chosen effects and the
  best-ranked others (:data:`POOL` in all), and
* once those are fitted, every set one swap away from the best fit: one of its effects replaced by
  any other effect of the rig's catalog the logged channels can identify
  (:func:`swap_neighbours`; an effect the ranking put low, a dead zone under a thrust law's
  stronger single-effect signature, is reached this way), and
* beside every kept set, the sets with one of its effects replaced by the special case it nests
  (:func:`nested_sets`: a thrust coefficient for a thrust law, a Coulomb friction for a Stribeck
  curve), kept unless the earlier data refute them: a fit always prefers the richer effect, and
  the designed recording is what tells whether it is needed,

each fitted on the earlier recordings by the diagnosis' own fit
(:func:`aeropend_ident.gap.which.fit_effects`, started from the ranking's single-effect values),
so every candidate explains the earlier data as well as it can. Candidates whose fit leaves more
than :data:`KEEP_SSE_FACTOR` times the best candidate's error are already refuted by those data
and dropped; at most ``max_candidates`` are kept, best fit first.

A diagnosis that found no significant gap ranks nothing: its candidates are the nominal rig and
every single effect the channels identify (:func:`diagnosis_candidates`, what the command runs).

No rclpy import: this module runs without ROS.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aeropend_ident.errors import GapError
from aeropend_ident.gap.effects import (
    EffectContext,
    MeasurementMap,
    catalog,
    check_recordings,
    get_effect,
    identifiable,
)
from aeropend_ident.gap.which.context import each_in_fit_threads
from aeropend_ident.gap.which.data import Prepared, prepare, residuals
from aeropend_ident.gap.which.fitting import fit_effects
from aeropend_ident.gap.which.ranking import excluded_with
from aeropend_ident.greybox.batch import single_blas
from aeropend_ident.greybox.fit import measurement_noise
from aeropend_ident.io.resampling import detect_quantum
from aeropend_sim.params import Rig
from aeropend_sim.recording import Recording

#: A candidate whose fit error exceeds this multiple of the best one is refuted by the earlier data.
KEEP_SSE_FACTOR = 1.25
#: Ranked effects (besides the chosen ones) turned into candidates, best-ranked first.
N_ALTERNATIVES = 9
#: Effects (the chosen ones first) whose compatible subsets are candidates (:func:`candidate_sets`).
POOL = 6
#: Most candidates when the earlier recordings show no significant gap (:func:`diagnosis_candidates`).
MAX_UNRANKED = 12
#: An effect whose fitted parameters all lie within this share of their search span (or this
#: log-distance) of their "off" value is fitted absent (:func:`absent_effects`).
ABSENT_TOL = 0.01


@dataclass
class Candidate:
    """One explanation of the earlier recordings: an effect set fitted on them.

    Attributes
    ----------
    name : str
        Readable label (``"+".join(effects)`` or ``"nominal"``).
    effects : tuple of str
        Catalog effect names.
    rig : Rig
        Nominal rig with the fitted effects.
    meas : MeasurementMap
        Recorded-angle map of the fitted sensor effects.
    fit_sse : float
        Normalised output error of the fit on the earlier recordings (NaN when not fitted here).
    values : dict
        Fitted values ``{effect: {parameter: value}}``.
    """

    name: str
    effects: tuple[str, ...]
    rig: Rig
    meas: MeasurementMap = field(default_factory=MeasurementMap)
    fit_sse: float = math.nan
    values: dict[str, dict[str, float]] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "effects": list(self.effects), "fit_sse": self.fit_sse,
                "values": self.values, "theta_offset": self.meas.theta_offset,
                "theta_scale": self.meas.theta_scale}


def label(effects: Sequence[str]) -> str:
    """``"a+b"`` of an effect set, ``"nominal"`` when empty."""
    return "+".join(effects) if effects else "nominal"


def channel_noise(recordings: Sequence[Recording], channels: Sequence[str]) -> dict[str, float]:
    """Measurement-noise σ per channel [its unit], the median over the recordings of
    :func:`aeropend_ident.greybox.fit.measurement_noise`, at least q/√12 of a detected quantum."""
    out = {}
    for c in channels:
        vals = []
        for r in recordings:
            y = np.asarray(r.channels[c], dtype=float)
            q = detect_quantum(y)
            vals.append(max(measurement_noise(y), q / math.sqrt(12.0)))
        out[c] = float(max(np.median(vals), 1e-9))
    return out


def candidate_sets(chosen: Sequence[str], ranking: Sequence[Mapping[str, Any]], max_effects: int = 3,
                   n_alternatives: int = N_ALTERNATIVES, pool: int = POOL) -> list[tuple[str, ...]]:
    """The effect sets to fit (module doc), the chosen set first, no duplicates.

    Besides the chosen set with one effect added or swapped, every compatible set of at most
    ``max_effects`` effects drawn from a pool of ``pool`` effects (the chosen ones, then the
    others in the order below) is a candidate: a diagnosis that chose a wrong effect (a sensor
    gain standing in for a thrust law and a dry friction) has its truth among those.

    Parameters
    ----------
    chosen : sequence of str
        The diagnosis' chosen effects (empty: nothing chosen).
    ranking : sequence of dict
        The diagnosis' ranking entries (``effect``, optional ``detected``, ``confusable_with``,
        ``ambiguous_with``, ``subsystem``), best first.
    max_effects : int
        Largest set size.
    n_alternatives : int
        Ranked effects outside the chosen set used.
    """
    chosen = tuple(sorted(chosen))
    amb = {a for r in ranking for a in (r.get("ambiguous_with") or [])}
    others = [r for r in ranking if r.get("effect") not in chosen and not r.get("detected")
              and r.get("effect") != "quantisation"]
    # effects the diagnosis could not separate come first, then the ranking order
    order = {id(r): i for i, r in enumerate(others)}
    others.sort(key=lambda r: (r.get("effect") not in amb, order[id(r)]))
    sets: list[tuple[str, ...]] = [chosen]
    conf = {c: set(get_effect(c).confusable_with) for c in chosen}
    sub = {c: get_effect(c).subsystem for c in chosen}
    stand_in: dict[str, list[str]] = {c: [] for c in chosen}  # ranked effects that may stand for c
    for r in others[:n_alternatives]:
        e = str(r["effect"])
        e_conf = set(get_effect(e).confusable_with) | set(r.get("confusable_with") or [])
        if len(chosen) < max_effects and e not in excluded_with(chosen):
            sets.append(tuple(sorted((*chosen, e))))
        for c in chosen:
            if e in conf[c] or c in e_conf or e in amb or sub[c] == get_effect(e).subsystem:
                stand_in[c].append(e)
                swapped = _swap(chosen, c, e)
                if swapped is not None:
                    sets.append(swapped)
    # two chosen effects each standing for another (a sensor gain for a thrust coefficient and an
    # input delay for an actuator lag at once)
    for c1, c2 in itertools.combinations(chosen, 2):
        rest = tuple(x for x in chosen if x not in (c1, c2))
        for e1, e2 in itertools.product(stand_in[c1], stand_in[c2]):
            if e1 != e2 and e1 not in excluded_with(rest) and e2 not in excluded_with((*rest, e1)):
                sets.append(tuple(sorted((*rest, e1, e2))))
    names = list(chosen) + [str(r["effect"]) for r in others if r["effect"] not in chosen]
    names = names[:max(pool, len(chosen))]
    for k in range(1, max_effects + 1):
        for combo in itertools.combinations(names, k):
            if all(e not in excluded_with([x for x in combo if x != e]) for e in combo):
                sets.append(tuple(sorted(combo)))
    out: list[tuple[str, ...]] = []
    for s in sets:
        if s not in out:
            out.append(s)
    return out


def unseparated_sets(chosen: Sequence[str], ranking: Sequence[Mapping[str, Any]]
                     ) -> list[tuple[str, ...]]:
    """The diagnosis' answer and the sets it could not separate from it: the chosen set (the
    nominal rig when nothing was chosen), then the chosen set with one member swapped for an
    effect its ranking entry lists as ``ambiguous_with`` it (compatible with the rest).

    Parameters
    ----------
    chosen : sequence of str
    ranking : sequence of dict
        The diagnosis' ranking entries.

    Returns
    -------
    list of tuple of str
        Sorted sets, the chosen one first, no duplicates.
    """
    base = tuple(sorted(chosen))
    amb = {str(r.get("effect")): list(r.get("ambiguous_with") or []) for r in ranking}
    out = [base]
    for c in base:
        for a in amb.get(c, []):
            s = _swap(base, c, a) if a not in base else None
            if s is not None and s not in out:
                out.append(s)
    return out


def swap_neighbours(effects: Sequence[str], family: str, channels: frozenset[str] | set[str]
                    ) -> list[tuple[str, ...]]:
    """Every set one swap away from ``effects``: one member replaced by another effect of
    ``family``'s catalog that ``channels`` can identify and that goes with the rest (sorted sets,
    catalog order; the quantisation effect is never swapped in).

    Parameters
    ----------
    effects : sequence of str
        A fitted set.
    family : str
        Actuator family of the rig (:func:`aeropend_ident.gap.effects.catalog`).
    channels : set of str
        The logged channels.

    Returns
    -------
    list of tuple of str
    """
    names = identifiable_effects(family, channels)
    out: list[tuple[str, ...]] = []
    for member in effects:
        for e in names:
            s = _swap(effects, member, e) if e not in effects else None
            if s is not None and s not in out:
                out.append(s)
    return out


def nested_sets(effects: Sequence[str]) -> list[tuple[str, ...]]:
    """The sets in which one member of ``effects`` is replaced by an effect it nests (contains as a
    special case: a thrust law its thrust coefficient, a Stribeck friction its Coulomb friction;
    the catalog's ``nests``), sorted, compatible with the rest.

    A fit on the earlier recordings always prefers the richer effect (it can only fit as well or
    better), so the best fits and their swap neighbours carry thrust laws and Stribeck curves where
    the truth may have the special case; the designed recording is what tells whether the richer
    one is needed (:func:`aeropend_ident.design.discriminate.verdict` names the special case when
    it is not refuted, as the gap diagnosis' ranking does).

    Parameters
    ----------
    effects : sequence of str
        A fitted set.

    Returns
    -------
    list of tuple of str
    """
    out: list[tuple[str, ...]] = []
    for member in effects:
        for simple in get_effect(member).nests:
            s = _swap(effects, member, simple) if simple not in effects else None
            if s is not None and s not in out:
                out.append(s)
    return out


def identifiable_effects(family: str, channels: frozenset[str] | set[str]) -> list[str]:
    """The effects of ``family``'s catalog that ``channels`` can identify, catalog order (the
    quantisation effect left out: it is not fitted)."""
    return [e.name for e in catalog(family)
            if e.name != "quantisation" and identifiable(e, frozenset(channels)) is None]


def held_setting_effects(family: str) -> frozenset[str]:
    """The effects of ``family``'s catalog with a held setting (a parameter the fits keep at the
    rig file's value unless freed: the dry friction's onset width v_ε), the names
    :attr:`aeropend_ident.gap.effects.EffectContext.free_settings` takes."""
    return frozenset(e.name for e in catalog(family) if any(p.held for p in e.parameters))


def _swap(effects: Sequence[str], member: str, other: str) -> tuple[str, ...] | None:
    """``effects`` with ``member`` replaced by ``other`` (sorted), or None when ``other`` cannot go
    with the rest (:func:`aeropend_ident.gap.which.ranking.excluded_with`)."""
    rest = tuple(x for x in effects if x != member)
    return None if other in excluded_with(rest) else tuple(sorted((*rest, other)))


def _starts(ranking: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, float]]:
    """The ranking's single-effect fitted values ``{effect: {parameter: value}}``."""
    out: dict[str, dict[str, float]] = {}
    for r in ranking:
        vals = {p: float(v["value"]) for p, v in (r.get("parameters") or {}).items()
                if isinstance(v, Mapping) and v.get("value") is not None}
        if vals:
            out[str(r["effect"])] = vals
    return out


def absent_effects(values: Mapping[str, Mapping[str, float]], ctx: EffectContext,
                   tol: float = ABSENT_TOL) -> list[str]:
    """Effects of a fit whose every searched parameter ended at its "off" value (within ``tol`` of
    the search span, or ``tol`` in log for a log parameter): fitted absent, so the set is the same
    model as the set without them."""
    out = []
    for name, vals in values.items():
        e = get_effect(name)
        off = True
        for p in e.parameters:
            if p.held or p.name not in vals:
                continue
            r = p.bind(ctx)
            v = float(vals[p.name])
            if r.log and r.off > 0.0 and v > 0.0:
                off &= abs(math.log(v / r.off)) <= tol
            else:
                off &= abs(v - r.off) <= tol * max(r.upper - r.lower, 1e-12)
        if off:
            out.append(name)
    return out


@single_blas
def fit_candidates(rig: Rig, recordings: Sequence[Recording], sets: Sequence[Sequence[str]], *,
                   ranking: Sequence[Mapping[str, Any]] = (), max_candidates: int = 6,
                   keep_factor: float = KEEP_SSE_FACTOR, keep: Sequence[Sequence[str]] = (),
                   neighbours: bool = False, free_settings: Sequence[str] = (),
                   climb: Callable[[Sequence[Candidate]], Sequence[tuple[str, ...]]] | None = None,
                   max_rounds: int = 1
                   ) -> tuple[list[Candidate], list[dict[str, Any]]]:
    """Fit each effect set on the earlier recordings and keep the ones the data do not refute.

    Parameters
    ----------
    rig : Rig
        Nominal rig.
    recordings : sequence of Recording
        Earlier recordings (the gap diagnosis' fit recordings), recording frame.
    sets : sequence of sequences of str
        Effect sets (:func:`candidate_sets`).
    ranking : sequence of dict
        Ranking entries whose ``parameters`` start the fits.
    max_candidates : int
        Most candidates kept (best fit first).
    keep_factor : float
        Candidates whose fit error exceeds ``keep_factor`` × the best are dropped.
    keep : sequence of sequences of str
        Sets fitted and kept whatever their fit error, in the places of the last kept ones
        (:func:`unseparated_sets`: the diagnosis' own answer and the sets it could not separate
        from it; a fit on the earlier data always favours more effects, and a designed recording is what
        tells whether they are needed).
    neighbours : bool
        Then fit every set one swap away from the best fit (:func:`swap_neighbours`): the truth of
        a diagnosis that ranked one of its effects low is often there; and, once the candidates are
        chosen, each kept set's nested special cases (:func:`nested_sets`), kept beside it (beyond
        ``max_candidates``) unless their fit error exceeds ``keep_factor`` × the best.
    climb : callable, optional
        With ``neighbours``: called with every candidate fitted so far after each round of swap
        neighbours, it returns the sets to climb from next (empty: stop); the sets one swap from
        each of them not climbed from yet are fitted in the next round (a search through the
        catalog one swap a round, from every set its caller cannot tell from the best), at most
        ``max_rounds`` rounds in all. None: one round, from the best fit.
    max_rounds : int
        Most rounds of swap neighbours (with ``climb``).

    Returns
    -------
    (list of Candidate, list of dict)
        The kept candidates, best fit first, and one row per set (fit error, kept or why not;
        ``refuted`` True where its fit error exceeds ``keep_factor`` × the best).

    Raises
    ------
    GapError
        When the nominal rig cannot be replayed on the recordings, or no set could be fitted.
    """
    channels = check_recordings(list(recordings), "earlier")
    preps: list[Prepared] = prepare(list(recordings), channels)
    ctx = dataclasses.replace(EffectContext.from_prepared(rig, preps), free_settings=frozenset(free_settings))
    starts = _starts(ranking)
    fitted: list[Candidate] = []
    rows: list[dict[str, Any]] = []
    tried: set[tuple[str, ...]] = set()

    # The nominal rig is replayed first, on this thread: a log's first replay decides how it began
    # (at rest or running, gap.which.data._initial_states) for every later one, as in the diagnosis.
    # Left to the fit threads, whichever candidate's first probe came first decided it (a thread
    # race: the same fits then ended 1.7× worse on one run than on another).
    nominal_sse = float(np.sum(residuals(rig, MeasurementMap(), preps) ** 2))

    def fit(s: tuple[str, ...]) -> Candidate | str:
        if not s:
            return Candidate("nominal", (), rig, MeasurementMap(), nominal_sse)
        try:
            fr = fit_effects(rig, s, preps, ctx, start={e: starts[e] for e in s if e in starts})
            return Candidate(label(s), s, fr.rig, fr.meas, float(fr.sse), fr.values)
        except (GapError, ValueError) as exc:
            return str(exc)

    def fit_all(todo: Sequence[tuple[str, ...]]) -> None:
        """Fit ``todo`` (independent fits in the diagnosis' fit threads,
        :func:`~aeropend_ident.gap.which.context.each_in_fit_threads`) and file each result in
        order, so the outcome does not depend on them."""
        todo = [s for s in dict.fromkeys(todo) if s not in tried]
        tried.update(todo)
        for s, cand in each_in_fit_threads(todo, lambda s, _say: fit(s), preps=preps):
            if isinstance(cand, str):
                rows.append({"effects": list(s), "error": cand, "kept": False})
                continue
            gone = absent_effects(cand.values, ctx)
            if gone and {x for x in s if x not in gone} in [set(c.effects) for c in fitted]:
                rows.append({"effects": list(s), "fit_sse": cand.fit_sse, "kept": False,
                             "why_not": f"{', '.join(gone)} fitted absent: the same model as a smaller set"})
                continue
            fitted.append(cand)
            rows.append({"effects": list(s), "fit_sse": cand.fit_sse})

    fit_all([tuple(s) for s in (*sets, *keep)])
    climbed: set[tuple[str, ...]] = set()
    frontier = [min(fitted, key=lambda c: c.fit_sse).effects] if neighbours and fitted else []
    for _round in range(max(max_rounds, 1)):
        climbed.update(frontier)
        fit_all([n for f in frontier for n in swap_neighbours(f, rig.family, channels)])
        if climb is None:
            break
        frontier = [tuple(f) for f in climb(fitted) if tuple(f) not in climbed]
        if not frontier:
            break
    if not fitted:
        raise GapError("no candidate effect set could be fitted on the earlier recordings")
    best = min(c.fit_sse for c in fitted)
    kept, forced = _kept(fitted, keep_factor * best, keep, max_candidates)
    if neighbours:  # each kept set's nested special cases, kept beside it unless the data refute them
        simpler = [s for c in kept for s in nested_sets(c.effects)]
        fit_all(simpler)
        extra = [c for c in fitted if c.effects in simpler and c.fit_sse <= keep_factor * best
                 and all(c is not k for k in kept)]
        kept += extra
        nested = {c.name for c in extra}
    else:
        nested = set()
    _file_rows(rows, {c.name for c in kept}, forced, nested, keep_factor * best, best)
    return kept, rows


def _file_rows(rows: list[dict[str, Any]], kept: set[str], forced: set[str], nested: set[str],
               max_sse: float, best: float) -> None:
    """Say in each fitted row of :func:`fit_candidates` whether its set was kept and why (or why not)."""
    for row in rows:
        if "fit_sse" in row and "why_not" not in row:
            row["kept"] = label(row["effects"]) in kept
            if label(row["effects"]) in forced:
                row["why"] = "the diagnosis' answer or a set it could not separate from it, kept to be tested"
            elif label(row["effects"]) in nested:
                row["why"] = "the special case of a kept set's richer effect, kept to be tested"
            elif not row["kept"]:
                row["refuted"] = row["fit_sse"] > max_sse
                row["why_not"] = (f"fit error {row['fit_sse'] / best:.2f}× the best: refuted by the earlier "
                                  "data" if row["refuted"] else "over max_candidates")


def _kept(fitted: Sequence[Candidate], max_sse: float, keep: Sequence[Sequence[str]],
          max_candidates: int) -> tuple[list[Candidate], set[str]]:
    """The candidates :func:`fit_candidates` keeps: the best ``max_candidates`` of those within
    ``max_sse``, best fit first, the sets of ``keep`` in the places of the last ones; and the names
    of those kept only because ``keep`` asks."""
    top = sorted((c for c in fitted if c.fit_sse <= max_sse), key=lambda c: (c.fit_sse, len(c.effects)))
    top = top[:max_candidates]
    musts: list[Candidate] = []
    for k in keep:
        m = next((c for c in fitted if c.effects == tuple(k)), None)
        if m is not None and all(m is not x for x in musts):
            musts.append(m)
    musts = musts[:max_candidates]
    in_top = [c for c in top if any(c is m for m in musts)]
    extra = [m for m in musts if all(m is not c for c in top)]
    others = [c for c in top if all(c is not m for m in musts)][:max(max_candidates - len(musts), 0)]
    kept = [c for c in top if any(c is x for x in (*in_top, *others))] + extra
    return kept, {c.name for c in extra}


@single_blas
def diagnosis_candidates(report: Mapping[str, Any], rig: Rig, recordings: Sequence[Recording], *,
                         max_effects: int = 3) -> tuple[list[Candidate], list[dict[str, Any]]]:
    """The candidates a discrimination design separates, from a gap diagnosis and the recordings
    it was made from (what ``excitation_design --design-for GAP_REPORT`` tests).

    * The diagnosis found a significant gap: :func:`candidate_sets` of its answer and ranking, its
      answer and the sets it could not separate from it always kept (:func:`unseparated_sets`),
      then the sets one swap from the best fit (:func:`swap_neighbours`); at most
      ``max_candidates`` (6) of them, best fit first (:func:`fit_candidates`).
    * It found none: then the earlier recordings hold no evidence for one effect over another (the
      fit errors of the single effects differ by noise, and ranking by them would pick six of the
      catalog at random). The candidates are the nominal rig and every single effect the logged
      channels identify that is not fitted absent on those recordings (then it is the nominal
      rig), at most :data:`MAX_UNRANKED`.

    Parameters
    ----------
    report : mapping
        A gap ``report.json`` or ``EffectDiagnosis.as_dict()``.
    rig : Rig
        The nominal rig the diagnosis was made against.
    recordings : sequence of Recording
        Its fit recordings, recording frame.
    max_effects : int
        Largest set size.

    Returns
    -------
    (list of Candidate, list of dict)
        As :func:`fit_candidates`.

    Raises
    ------
    GapError
        Bad recordings; no set could be fitted.
    """
    which = report.get("which", report)
    chosen, ranking = diagnosis_view(report)
    if which.get("significant", True):
        return fit_candidates(rig, recordings, candidate_sets(chosen, ranking, max_effects=max_effects),
                              ranking=ranking, keep=unseparated_sets(chosen, ranking), neighbours=True)
    channels = check_recordings(list(recordings), "earlier")
    singles = [(e,) for e in identifiable_effects(rig.family, channels)]
    return fit_candidates(rig, recordings, [(), *singles], ranking=ranking, keep=[()],
                          max_candidates=MAX_UNRANKED)


def diagnosis_view(report: Mapping[str, Any]) -> tuple[list[str], list[dict[str, Any]]]:
    """``(chosen, ranking)`` of a gap ``report.json`` (its ``which`` section) or of
    ``EffectDiagnosis.as_dict()``; nothing chosen when the gap was not significant."""
    which = report.get("which", report)
    chosen = list(which.get("chosen") or []) if which.get("significant", True) else []
    return chosen, list(which.get("ranking") or [])
