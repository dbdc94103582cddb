"""``rig check``: what a rig file states, fits and defaults; what recordings say about it; its reach.

* **Table**: every parameter of the rig's family (and the rod's geometry, when the file gives it)
  with its status (stated / derived / fitted / to be fitted / not modelled / default), value,
  unit and source.
* **Reach** (always): the largest angle the rig holds at full command (τ = 1) and with the
  control headroom of :data:`aeropend_control.design.REACH_DUTY_MARGIN`, from
  :func:`aeropend_control.design.reachable_angle` (the model's equilibrium; one home).
* **With recordings** (and static tables): the free-run θ NRMSE of the rig on each recording
  (the one replay, :func:`aeropend_ident.greybox.replay.free_run`, with its start and divergence),
  the normalised sensitivity of the inputs to each modelled parameter — the Fisher information
  ‖∂r/∂ln p‖² of the noise-weighted residuals (:mod:`aeropend_ident.greybox.rig_problem`), shown as
  the relative 1σ it would allow alone and its rank — and the pairs the inputs cannot separate
  (correlation of the joint estimate beyond ±:data:`CORRELATED`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from aeropend_ident.errors import IdentificationError
from aeropend_ident.greybox.parameters import ParameterSpec
from aeropend_ident.greybox.replay import free_run
from aeropend_ident.greybox.rig_inputs import read_inputs
from aeropend_ident.greybox.rig_problem import Problem, covariance
from aeropend_ident.greybox.rig_search import blocks_of
from aeropend_sim.components import registry
from aeropend_sim.files.safe_yaml import load_yaml
from aeropend_sim.params import Rig, load_rig
from aeropend_sim.rigfile.template import GEOMETRY_NEEDED, INERTIA, fittable

#: Pairs with |correlation| above this are reported as not separable.
CORRELATED = 0.95
#: Longest source shown in the table.
SOURCE_WIDTH = 72


def status_table(rig: Rig, doc: dict) -> list[str]:
    """One line per parameter: status, key, value, unit, source."""
    lines = [f"{'status':<13} {'parameter':<28} {'value':>12}  unit            source"]
    geometry = doc.get("pendulum") or {}
    for key, p in registry.family_params(rig.family).items():
        src = rig.sources.get(key, "")
        lines.append(f"{rig.status(key):<13} {key:<28} {rig.value(key):>12.5g}  {p.unit:<15} {_cut(src)}")
    for key in (*GEOMETRY_NEEDED, INERTIA):
        node = geometry.get(key.partition(".")[2])
        if isinstance(node, dict):
            src = str(node.get("source", ""))
            status = "to be fitted" if src.startswith("to be fitted") else (
                "fitted" if src.startswith("fitted") else "stated")
            lines.append(f"{status:<13} {key:<28} {float(node['value']):>12.5g}  {node.get('unit', ''):<15} "
                         f"{_cut(src)}")
    return lines


def _cut(text: str) -> str:
    return text if len(text) <= SOURCE_WIDTH else text[: SOURCE_WIDTH - 1] + "…"


def reach_lines(rig: Rig) -> list[str]:
    """The reach at τ = 1 and with the control headroom."""
    from aeropend_control.design import REACH_DUTY_MARGIN, DesignError, reachable_angle

    out = []
    for margin, what in ((0.0, "at full command (τ = 1)"),
                         (REACH_DUTY_MARGIN, f"with {REACH_DUTY_MARGIN:.0%} control headroom")):
        try:
            th = reachable_angle(rig, duty_margin=margin)
            out.append(f"reach {what}: {th:.3f} rad ({math.degrees(th):.1f}°)")
        except (DesignError, ValueError) as exc:
            out.append(f"reach {what}: none ({exc})")
    return out


def _sensitivity_specs(rig: Rig) -> list[ParameterSpec]:
    specs = []
    for key, p in registry.family_params(rig.family).items():
        v = rig.value(key)
        if rig.status(key) in ("not modelled", "default") or not fittable(key) or not math.isfinite(v):
            continue
        if v > 0.0:
            specs.append(ParameterSpec(key, p.unit, v, v * 1e-6, v * 1e6, True, 1.0))
        else:
            specs.append(ParameterSpec(key, p.unit, v, v - 1.0, v + 1.0, False, 0.01))
    return specs


def sensitivity_lines(rig: Rig, problem: Problem) -> list[str]:
    """Sensitivity ranking and the pairs that cannot be separated."""
    names = [s.name for s in problem.specs]
    z0, lo, hi = problem.z_bounds()
    J = problem.jac(z0, lo, hi)
    n = len(names)
    fisher = np.sum(J[:, :n] ** 2, axis=0)
    seen = fisher > 1e-12 * max(float(fisher.max()), 1e-300)
    pinned = np.concatenate([~seen, np.zeros(J.shape[1] - n, dtype=bool)])
    cov = covariance(J, pinned)[:n, :n]
    pseudo = covariance(J, pinned, blind=False)[:n, :n]  # its correlations name the confounded pairs
    lines = ["sensitivity of the inputs to each parameter (Fisher information of the noise-weighted "
             "residuals per ln p; 'alone': the relative 1σ it would allow if every other parameter were "
             "known; 'joint': with all of them fitted together):"]
    for rank, j in enumerate(np.argsort(-fisher), start=1):
        if not seen[j]:
            lines.append(f"  {rank:>2}. {names[j]:<28} not sensitive: these inputs do not depend on it")
            continue
        alone = 1.0 / math.sqrt(fisher[j])
        joint = math.sqrt(cov[j, j]) if math.isfinite(cov[j, j]) else math.inf
        unit = "%" if problem.specs[j].log else problem.specs[j].unit
        f = 100.0 if problem.specs[j].log else problem.specs[j].scale
        lines.append(f"  {rank:>2}. {names[j]:<28} information {fisher[j]:10.3g}   "
                     f"alone ±{alone * f:.3g} {unit}   joint ±{joint * f:.3g} {unit}")
    d = np.sqrt(np.clip(np.diag(pseudo), 1e-300, None))
    corr = pseudo / np.outer(d, d)
    pairs = [(names[i], names[j], corr[i, j]) for i in range(n) for j in range(i + 1, n)
             if seen[i] and seen[j] and math.isfinite(corr[i, j]) and abs(corr[i, j]) > CORRELATED]
    if pairs:
        lines.append(f"not separable by these inputs (|correlation| > {CORRELATED}):")
        lines += [f"  {a} and {b}: {c:+.3f}" for a, b, c in pairs]
    else:
        lines.append(f"every pair is separable by these inputs (|correlation| ≤ {CORRELATED})")
    return lines


def check_rig(rig_path: str | Path, inputs: Sequence[str] = (), preset: str | None = None) -> str:
    """The ``rig check`` report (module docstring).

    Raises
    ------
    RigFileError, IdentificationError, RecordingInputError
        An unreadable rig file or input (ValueErrors).
    """
    path = Path(rig_path)
    rig = load_rig(path)
    doc = load_yaml(path, "a rig file") if path.suffix in (".yaml", ".yml") else {}
    counts = {s: 0 for s in ("stated", "derived", "fitted", "to be fitted", "not modelled", "default")}
    for key in registry.family_params(rig.family):
        counts[rig.status(key)] = counts.get(rig.status(key), 0) + 1
    tally = ", ".join(f"{v} {k}" for k, v in counts.items() if v)
    lines = [f"rig check: {path.name} ({rig.family}): {tally}"]
    lines += status_table(rig, doc)
    lines += reach_lines(rig)
    if counts.get("to be fitted") and counts.get("fitted"):
        lines.append(f"note: {counts['to be fitted']} parameter(s) rig fit could not determine from its "
                     "inputs still hold their starting values (STILL TO BE FITTED above, with the input "
                     "that would determine each): the reach and the figures below use them")
    elif counts.get("to be fitted"):
        lines.append(f"note: {counts['to be fitted']} parameter(s) still hold rig new's starting values: the "
                     "reach and the figures below use them (rig fit first)")
    if not inputs:
        return "\n".join(lines)
    tables, series = read_inputs(list(inputs), preset)
    blocks = blocks_of(tables, series)
    diverged = []
    for ser in series:  # the whole recording, as every command replays it (a block may start later)
        try:
            d = ser.replayed
            run = free_run(rig, d.t, d.duty, d.theta, source=d.source)
            lines.append(run.line(f"{ser.source} ({ser.kind})"))
            if run.diverged:
                diverged.append(ser.source)
        except IdentificationError as exc:
            lines.append(f"free-run θ on {ser.source} ({ser.kind}): not computed ({exc})")
            diverged.append(ser.source)
    specs = _sensitivity_specs(rig)
    if specs and diverged:
        lines.append(f"sensitivity: not computed: the free run diverges on {', '.join(diverged)} (the "
                     "derivatives of a run that left the recorded range say nothing of the parameters; "
                     "fit the rig first, or check it on recordings it follows)")
    elif specs:
        problem = Problem(rig, {}, specs, blocks)
        lines += sensitivity_lines(rig, problem)
    return "\n".join(lines)

