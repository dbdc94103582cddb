#!/usr/bin/env python3
"""Write the docs' tables of the plant's components and the gap catalog from the registry.

``docs/model.md``: families, slots, components, effects and parameters; ``docs/gap.md``: the gap
diagnosis' catalog (every hypothesis, the part that declares it, its parameters and search ranges,
the channels it needs, the families it belongs to). Each table sits between
``<!-- BEGIN generated: NAME -->`` and ``<!-- END generated: NAME -->`` markers and is rewritten
from :mod:`aeropend_sim.components.registry`, so the docs cannot drift from the code;
``test/sim/components/test_registry.py`` fails when a file is not current.

Usage: ``python tools/gen_model_tables.py [--check] [--file docs/model.md ...]``
(``--check``: exit 1 and name the stale tables instead of writing).
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path

from aeropend_sim.components import registry
from aeropend_sim.components.base import SLOTS, Effect, Param

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _num(v: float) -> str:
    if math.isinf(v):
        return "+∞" if v > 0 else "−∞"
    return f"{v:g}"


def _absent(p: Param) -> str:
    if p.absent is None:
        return "required"
    return f"default {_num(p.absent)}" if p.setting else f"{_num(p.absent)} (not modelled)"


def _keys(params: tuple[Param, ...]) -> str:
    return ", ".join(f"`{p.key}`" for p in params) or "—"


def families_table() -> str:
    rows = ["| family | drive quantity | what it is | parameters | has no |", "|---|---|---|---|---|"]
    for f in registry.families():
        comps = [c for c in registry.family_parts(f.name) if c is not f]
        params = [p for c in registry.family_parts(f.name) for p in c.params]
        lacks = "; ".join(f"{slot}: {why}" for slot, why in f.lacks.items()) or "—"
        rows.append(f"| `{f.name}` | {f.drive} | {_cell(f.description)} (components: "
                    f"{', '.join(c.name for c in comps)}) | {_keys(tuple(params))} | {_cell(lacks)} |")
    return "\n".join(rows)


def components_table() -> str:
    rows = ["| component | part | families | equation | parameters |", "|---|---|---|---|---|"]
    for c in registry.components():
        on = [f.name for f in registry.families() if c.applies_to(f) is None]
        fams = "all" if len(on) == len(registry.families()) else ", ".join(on)
        geo = f"; or from {_keys(c.geometry)}" if c.geometry else ""
        rows.append(f"| `{c.name}` | {c.part} | {fams} | {_cell(c.description)} | {_keys(c.params)}{geo} |")
    return "\n".join(rows)


def effects_table() -> str:
    rows = ["| switch | part | equation | parameters | families | before issue 35 |",
            "|---|---|---|---|---|---|"]
    for e in registry.effects():
        fams = ", ".join(f.name for f in registry.families() if e in registry.family_effects(f.name))
        sw = f"`{e.name}`" + (f" (`{e.on}` / `{e.off}`)" if e.modes else "")
        legacy = f"`{e.legacy_switch}`" if e.legacy_switch else ""
        rows.append(f"| {sw} | {e.part} | {_cell(e.description)} | {_keys(e.params)} | {fams} | {legacy} |")
    return "\n".join(rows)


def params_table() -> str:
    rows = ["| key | symbol | unit | meaning | declared by | when absent | sign | grey-box fit bounds |",
            "|---|---|---|---|---|---|---|---|"]
    owners = registry.owners()
    for key, p in registry.params().items():
        owner = owners[key]
        kind = "effect" if isinstance(owner, Effect) else "component"
        fit = "—"
        if p.fit is not None:
            lo = "×1e-3 of start" if p.fit.lower is None else _num(p.fit.lower)
            hi = "×1e3 of start" if p.fit.upper is None else _num(p.fit.upper)
            log = " log" if p.fit.log else ""
            scale = f", scale {p.fit.scale:g}" if p.fit.scale else ""
            fit = f"[{lo}, {hi}]{log}{scale}"
        sign = {"positive": "> 0", "nonneg": "≥ 0", "": "any"}[p.sign]
        if p.below < math.inf:
            sign += f", < {p.below:g}"
        rows.append(f"| `{key}` | {_cell(p.symbol or p.name)} | {p.unit} | {_cell(p.doc)} | "
                    f"{kind} `{owner.name}` | {_absent(p)} | {sign} | {fit} |")
    return "\n".join(rows)


def slots_table() -> str:
    rows = ["| slot | a term returns | it may read |", "|---|---|---|"]
    from aeropend_sim.components.base import SLOT_INPUTS

    for slot, what in SLOTS.items():
        rows.append(f"| `{slot}` | {_cell(what)} | {', '.join(SLOT_INPUTS[slot])} |")
    return "\n".join(rows)


def states_table() -> str:
    """The state vector: the chain's states in their fixed positions, then each effect's own."""
    from aeropend_sim.components.states import CHAIN

    rows = ["| index | state | symbol | unit | meaning | declared by |", "|---|---|---|---|---|---|"]
    for k, st in enumerate(CHAIN):
        rows.append(f"| {k} | `{st.name}` | {st.symbol} | {st.unit} | {_cell(st.description)} | the chain |")
    for e in registry.effects():
        for st in e.states:
            rows.append(f"| after the chain's, when it acts | `{st.name}` | {st.symbol} | {st.unit} | "
                        f"{_cell(st.description)} | `{e.name}` |")
    return "\n".join(rows)


def catalog_table() -> str:
    """The gap diagnosis' hypotheses (``aeropend_ident.gap.effects.catalog`` per family), by catalog order."""
    fams = [f.name for f in registry.families()]
    rows = ["| hypothesis | declared by | subsystem | parameter [unit]: search range | needs | "
            + " | ".join(f"`{f}`" for f in fams) + " |",
            "|---|---|---|---|---|" + "---|" * len(fams)]
    for d in registry.diagnoses():
        owner = registry.diagnosis_owner(d.name)
        params = "; ".join(f"{s.name} [{s.unit}]: {s.range_doc}" for s in d.search)
        kinds = {"drift": " (drift only)", "measurement": " (sensor transform)", "direct": " (detected)"}
        kind = kinds.get(d.kind, "")
        marks = " | ".join("✓" if owner.applies_to(registry.family(f)) is None else "—" for f in fams)
        rows.append(f"| `{d.name}`{kind} | `{owner.name}` | {d.subsystem} | {_cell(params)} | "
                    f"{', '.join(d.reveals)} | {marks} |")
    return "\n".join(rows)


TABLES = {"families": families_table, "components": components_table, "effects": effects_table,
          "parameters": params_table, "slots": slots_table, "states": states_table}
#: Tables of each docs file.
FILES = {"model.md": TABLES, "gap.md": {"catalog": catalog_table}}


def render(text: str, tables: dict | None = None) -> tuple[str, list[str]]:
    """``text`` with every generated table rewritten, and the names of the tables that changed.

    Parameters
    ----------
    text : str
    tables : mapping, optional
        Table name -> function; default the ``docs/model.md`` tables (:data:`FILES`).

    Raises
    ------
    ValueError
        If a table's markers are missing.
    """
    changed = []
    for name, make in (TABLES if tables is None else tables).items():
        pat = re.compile(rf"(<!-- BEGIN generated: {name} -->\n)(.*?)(<!-- END generated: {name} -->)", re.S)
        m = pat.search(text)
        if m is None:
            raise ValueError(f"no '<!-- BEGIN generated: {name} -->' ... END markers in the file")
        body = make() + "\n"
        if m.group(2) != body:
            changed.append(name)
            text = text[: m.start(2)] + body + text[m.end(2):]
    return text, changed


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="do not write; exit 1 if a table is stale")
    ap.add_argument("--file", type=Path, nargs="+", default=[DOCS / name for name in FILES],
                    help=f"docs files (named {sorted(FILES)}; default all of them)")
    args = ap.parse_args()
    status = 0
    for path in args.file:
        tables = FILES.get(path.name)
        if tables is None:
            print(f"gen_model_tables: {path}: no generated tables for a file of that name; expected one of "
                  f"{sorted(FILES)}", file=sys.stderr)
            return 2
        try:
            text, changed = render(path.read_text(encoding="utf-8"), tables)
        except (OSError, ValueError) as exc:
            print(f"gen_model_tables: {path}: {exc}", file=sys.stderr)
            return 2
        if args.check:
            if changed:
                print(f"{path}: stale table(s) {changed}; run tools/gen_model_tables.py", file=sys.stderr)
                status = 1
            continue
        path.write_text(text, encoding="utf-8")
        print(f"{path}: {'rewrote ' + ', '.join(changed) if changed else 'already current'}")
    return status


if __name__ == "__main__":
    sys.exit(main())
