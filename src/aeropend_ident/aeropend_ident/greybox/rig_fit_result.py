"""What ``rig fit`` returns and writes: each parameter's :class:`Outcome` (fitted ± σ, still to be
fitted and why, at a search bound), the whole :class:`RigFitResult`, the fitted rig file
(:func:`fitted_text`, :func:`write_fitted`) and the bound flags a later ``gap`` reads from it
(:func:`bound_flags`).

The fit is :func:`aeropend_ident.greybox.rig_fit.fit_rig`. No rclpy import.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from aeropend_ident.errors import IdentificationError
from aeropend_ident.greybox.replay import NRMSE_RULE, START_RULE, FreeRun
from aeropend_sim.components.base import SECTIONS
from aeropend_sim.files.safe_yaml import parse_yaml
from aeropend_sim.output_folder import write_file_atomically
from aeropend_sim.params import FITTED, TO_BE_FITTED, Rig, rig_from_dict

#: A fitted value within this share of its search range (in the search coordinate: logarithmic for a
#: scale parameter) of a bound is flagged: the bound, not the data, may have set it.
BOUND_SHARE = 0.02
#: The flag written in the rig file's source and comments (``gap`` reads it back: :func:`bound_flags`).
BOUND_FLAG = "AT SEARCH BOUND"
#: How a refused member's reason says what its value holds (cut when the group's reason is printed once).
HOLDS_NOTE = " (its value holds "
#: How the standard errors are estimated (the fitted file and the terminal say it).
SE_METHOD = ("1σ standard errors of the joint weighted fit (each input weighted by its residual noise, time "
             "series inflated by their residual's autocorrelation): the larger of the Jacobian's and a "
             "cluster-robust sandwich estimate over the fit's windows and tables, which a misfit widens")


@dataclass
class Outcome:
    """One to-be-fitted parameter after ``rig fit``.

    Attributes
    ----------
    key, unit : str
    value : float
        Fitted value (or, refused, the best value found: the next fit's start).
    std : float
        1σ standard error (NaN when refused or on a bound).
    status : str
        ``"fitted"`` or ``"to be fitted"`` (refused).
    reason : str
        Why it was refused (empty when fitted).
    provenance : str
        The inputs and methods that determined it.
    bound : float or None
        The search bound it lies within :data:`BOUND_SHARE` of (flagged), else None.
    lower, upper : float
        The search range.
    """

    key: str
    unit: str
    value: float
    std: float = math.nan
    status: str = "fitted"
    reason: str = ""
    provenance: str = ""
    bound: float | None = None
    lower: float = math.nan
    upper: float = math.nan

    @property
    def source(self) -> str:
        """The rig-file source written for it."""
        if self.status != "fitted":
            return f"{TO_BE_FITTED}: {self.reason}"
        err = f" ± {self.std:.2g}" if math.isfinite(self.std) else ""
        text = (f"{FITTED}: {self.value:.6g}{err} {self.unit} (1σ, Jacobian or sandwich) from "
                f"{self.provenance}")
        if self.bound is not None:
            text += (f"; {BOUND_FLAG} {self.bound:.4g} (within {BOUND_SHARE:.0%} of it; searched "
                     f"{self.lower:.4g} … {self.upper:.4g}): the bound, not the data, may have set it")
        return text


@dataclass
class RigFitResult:
    """Outcome of :func:`aeropend_ident.greybox.rig_fit.fit_rig`: per parameter, the fitted rig, the
    inputs and the notes."""

    rig_path: Path
    text: str
    family: str
    outcomes: list[Outcome]
    rig: Rig
    inputs: list[tuple[str, str]]
    nrmse: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    sample_period: tuple[float, str] | None = None
    #: Recordings on which the fitted rig's free run diverges (io.overlay_axes.diverges): the reason,
    #: reported instead of an NRMSE (their entry in ``nrmse`` is None).
    divergence: dict[str, str] = field(default_factory=dict)
    #: The fitted rig's free run on each recording (:func:`aeropend_ident.greybox.replay.free_run`,
    #: the one replay of every command: its start, divergence and NRMSE); ``nrmse`` and ``divergence``
    #: are read from it.
    runs: dict[str, FreeRun] = field(default_factory=dict)
    #: The angle LSB q [rad] every recording's θ lies on
    #: (:func:`aeropend_ident.greybox.rig_fit.angle_quantum`), written into the fitted rig
    #: (``sensors.theta_quantum``, ``effects.quantisation``) with its source; None: none.
    theta_quantum: tuple[float, str] | None = None

    def outcome(self, key: str) -> Outcome:
        """The outcome of one key (KeyError if it was not to be fitted)."""
        for o in self.outcomes:
            if o.key == key:
                return o
        raise KeyError(key)

    def summary(self) -> str:
        """The terminal summary: inputs, a line per parameter, refusals, bound flags, NRMSE."""
        lines = [f"rig fit: {self.rig_path.name} ({self.family}), {len(self.inputs)} input(s):"]
        lines += [f"  {src}: {kind}" for src, kind in self.inputs]
        lines.append("parameters:")
        for o in self.outcomes:
            if o.status == "fitted":
                err = f" ± {o.std:.2g}" if math.isfinite(o.std) else ""
                flag = f"   {BOUND_FLAG}" if o.bound is not None else ""
                lines.append(f"  fitted        {o.key} = {o.value:.5g}{err} {o.unit}   "
                             f"[{o.provenance}]{flag}")
            else:
                lines.append(f"  REFUSED       {o.key} (still to be fitted; best value "
                             f"{o.value:.4g} {o.unit})")
        refused = [o for o in self.outcomes if o.status != "fitted"]
        if refused:
            lines.append("not determined by these inputs (left to be fitted):")
            # a group's reason is each member's (plus what that member's value holds): said once
            lines += [f"  {r}" for r in dict.fromkeys(o.reason.split(HOLDS_NOTE)[0] for o in refused)]
        flagged = [o for o in self.outcomes if o.bound is not None and o.status == "fitted"]
        if flagged:
            lines.append(f"AT A SEARCH BOUND (within {BOUND_SHARE:.0%} of the searched range from it: the "
                         "bound, not the data, may have set these; gap screens the effects they can absorb):")
            lines += [f"  {o.key} = {o.value:.4g} {o.unit} (bound {o.bound:.4g}; searched {o.lower:.4g} … "
                      f"{o.upper:.4g})" for o in flagged]
        if self.runs:
            lines.append(f"free-run θ of the fitted rig ({START_RULE}; NRMSE = {NRMSE_RULE}):")
            lines += [f"  {run.line(k)}" for k, run in self.runs.items()]
        if self.theta_quantum is not None:
            lines.append(f"sensor: sensors.theta_quantum = {self.theta_quantum[0]:.5g} rad "
                         f"({self.theta_quantum[1]}); effects.quantisation on")
        lines += [f"note: {n}" for n in self.notes]
        lines.append(f"uncertainty: {SE_METHOD}")
        return "\n".join(lines)


# ------------------------------------------------------------------------------ the fitted file
_LINE = re.compile(r"^(?P<indent>\s+)(?P<name>[A-Za-z_][A-Za-z0-9_]*):\s*\{.*\}\s*$")


def _quantity(value: float, unit: str, source: str) -> str:
    return f"{{value: {value!r}, unit: {json.dumps(unit)}, source: {json.dumps(source, ensure_ascii=False)}}}"


def fitted_text(result: RigFitResult) -> str:
    """The rig file with every to-be-fitted line replaced by its outcome (value, source) and a
    comment above it (FITTED ± σ, STILL TO BE FITTED with the reason, AT SEARCH BOUND); lines of
    parameters ``rig fit`` added (dry friction) are appended to their section."""
    lines = result.text.splitlines()
    todo = {o.key: o for o in result.outcomes}
    section = None
    out: list[str] = []
    ends: dict[str, int] = {}
    done = set()
    head: int | None = None
    for line in lines:
        if line and not line[0].isspace() and not line.startswith("#"):
            section = line.split(":")[0].strip()
            if section == "sample_period" and result.sample_period is not None:
                v, src = result.sample_period
                out.append(f"sample_period: {_quantity(v, 's', src)}")
                continue
        m = _LINE.match(line)
        key = f"{section}.{m.group('name')}" if m else None
        if line.lstrip().startswith("#") and line.rstrip().endswith("— TO BE FITTED"):
            head = len(out)
        elif m is not None and key not in todo:
            head = None
        if key in todo:
            o = todo[key]
            ind = m.group("indent")  # type: ignore[union-attr]
            if head is not None:  # rig new's header of this entry: say what rig fit made of it
                mark = "FITTED (rig fit)" if o.status == "fitted" else "STILL TO BE FITTED (rig fit)"
                out[head] = out[head].replace("— TO BE FITTED", f"— {mark}")
            out += _comments(o, ind)
            out.append(f"{ind}{m.group('name')}: {_quantity(o.value, o.unit, o.source)}")  # type: ignore[union-attr]
            done.add(key)
        else:
            out.append(line)
        if section in SECTIONS and line.strip():
            ends[section] = len(out)
    for key in [k for k in todo if k not in done][::-1]:
        sec, _, name = key.partition(".")
        o = todo[key]
        block = [*_comments(o, "  "), f"  {name}: {_quantity(o.value, o.unit, o.source)}"]
        at = ends.get(sec)
        out = out[:at] + block + out[at:] if at is not None else [*out, f"{sec}:", *block]
    if result.theta_quantum is not None:
        out = _with_quantum(out, *result.theta_quantum)
    return "\n".join(out) + "\n"


def _with_quantum(lines: list[str], q: float, source: str) -> list[str]:
    """The rig file's lines with ``sensors.theta_quantum`` set to ``q`` and ``effects.quantisation``
    on (each line replaced where the file has it, else added to its section or a new section)."""
    def put(out: list[str], section: str, name: str, line: str) -> list[str]:
        start = next((i for i, x in enumerate(out) if x.split("#")[0].strip() == f"{section}:"), None)
        if start is None:
            return [*out, f"{section}:", line]
        end = start + 1
        while end < len(out) and (not out[end] or out[end][0].isspace() or out[end].startswith("#")):
            if re.match(rf"^\s+{name}\s*:", out[end]):
                return [*out[:end], line, *out[end + 1:]]
            end += 1
        while end > start + 1 and not out[end - 1].strip():
            end -= 1
        return [*out[:end], line, *out[end:]]

    lines = put(lines, "sensors", "theta_quantum", f"  theta_quantum: {_quantity(q, 'rad', source)}")
    return put(lines, "effects", "quantisation", "  quantisation: true  # the logs' angle LSB (rig fit)")


def near_bound(z: float, lo: float, hi: float, lower: float, upper: float, value: float = math.nan,
               std: float = math.nan) -> float | None:
    """The search bound (``lower`` or ``upper``, in the parameter's unit) a fitted value lies within
    :data:`BOUND_SHARE` of, in the search coordinate ``z`` with bounds ``lo``, ``hi``; else None.

    A lower bound of exactly 0 on a linear coordinate is the parameter's physical limit (a friction,
    an offset's magnitude), not a choice of the search: a value ``value`` there is flagged only when
    it lies within 3 standard deviations ``std`` of 0 (a T_f/J of 0.80 ± 0.02 rad/s² in a search of
    0 … 1000 is 40σ from the bound: the data set it)."""
    width = hi - lo
    if not (math.isfinite(width) and width > 0.0):
        return None
    if z - lo <= BOUND_SHARE * width:
        if lower == 0.0 and math.isfinite(value) and math.isfinite(std) and value > 3.0 * std:
            return None
        return lower
    if hi - z <= BOUND_SHARE * width:
        return upper
    return None


def bound_flags(sources: Mapping[str, str]) -> dict[str, str]:
    """``section.name`` -> source text of every parameter a fitted rig flags at a search bound
    (:data:`BOUND_FLAG` in its source; ``sources`` is :attr:`aeropend_sim.params.Rig.sources`), e.g. to
    have ``gap`` screen the effect the parameter may have absorbed."""
    return {k: str(v) for k, v in sources.items() if BOUND_FLAG in str(v)}


def _comments(o: Outcome, ind: str) -> list[str]:
    if o.status != "fitted":
        return [f"{ind}# rig fit: STILL TO BE FITTED — {o.reason}"]
    err = f" ± {o.std:.2g}" if math.isfinite(o.std) else ""
    out = [f"{ind}# rig fit: FITTED {o.value:.5g}{err} {o.unit} from {o.provenance}"]
    if o.bound is not None:
        out.append(f"{ind}# rig fit: {BOUND_FLAG} {o.bound:.4g} {o.unit} (within {BOUND_SHARE:.0%} of it; "
                   f"searched {o.lower:.4g} … {o.upper:.4g}): the bound, not the data, may have set it")
    return out


def write_fitted(result: RigFitResult, path: str | Path) -> Path:
    """Write the fitted rig file (:func:`fitted_text`) and check that it loads.

    Raises
    ------
    IdentificationError
        If the written text does not load (the file is not written then).
    """
    text = fitted_text(result)
    try:
        rig_from_dict(parse_yaml(text, str(path), "a rig file"), str(path))
    except ValueError as exc:
        raise IdentificationError(f"rig fit: the fitted rig file would not load ({exc}); not "
                                  "written") from exc
    return write_file_atomically(path, text)
