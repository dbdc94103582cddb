"""Compare two runs of a gap benchmark case by case (names, shrinks, magnitudes, time).

For ``bench_gap_independent.py`` and ``bench_gap_blind.py`` results (a ``cases`` list whose
entries have ``case``, ``chosen``, ``shrink`` and, for the independent benchmark, ``magnitude`` and
``pass``; the blind one ``top1``): every case of the new run that the reference run also has, with
what changed. A difference is listed when the first named effect, the pass / top-1 verdict or
the effects chosen change, when the held-out shrink moves by more than ``--shrink-tol``
(absolute) or a magnitude error by more than ``--magnitude-tol`` (absolute, of the effect size).

Usage: ``python -m bench.compare_gap_runs REFERENCE.json NEW.json [--out FILE.md]``
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path
from typing import Any


def _mag(c: dict[str, Any]) -> dict[str, float]:
    out = {}
    for name, m in (c.get("magnitude") or {}).items():
        if isinstance(m, dict) and m.get("relative_error") is not None:
            out[name] = float(m["relative_error"])
    return out


def _verdict(c: dict[str, Any]) -> Any:
    return c.get("pass", c.get("top1"))


def compare(ref: dict[str, Any], new: dict[str, Any], shrink_tol: float,
            magnitude_tol: float) -> dict[str, Any]:
    """Per-case differences and summary figures of two benchmark runs."""
    old = {c["case"]: c for c in ref["cases"]}
    rows, same = [], 0
    shrinks, mags, times, cpus = [], [], [], []
    for c in new["cases"]:
        o = old.get(c["case"])
        if o is None:
            continue
        why = []
        if (o.get("chosen") or [None])[0] != (c.get("chosen") or [None])[0]:
            why.append(f"first named {(o.get('chosen') or ['none'])[0]} → {(c.get('chosen') or ['none'])[0]}")
        elif list(o.get("chosen") or []) != list(c.get("chosen") or []):
            why.append(f"chosen {o.get('chosen')} → {c.get('chosen')}")
        if _verdict(o) != _verdict(c):
            why.append(f"pass {_verdict(o)} → {_verdict(c)}")
        ds = (c.get("shrink") or 0.0) - (o.get("shrink") or 0.0)
        shrinks.append(abs(ds))
        if abs(ds) > shrink_tol:
            why.append(f"shrink {o.get('shrink', 0):.3f} → {c.get('shrink', 0):.3f}")
        mo, mn = _mag(o), _mag(c)
        for k in mo.keys() & mn.keys():
            mags.append(abs(mn[k] - mo[k]))
            if abs(mn[k] - mo[k]) > magnitude_tol:
                why.append(f"magnitude error of {k} {mo[k]:.4f} → {mn[k]:.4f}")
        times.append((o.get("elapsed_s"), c.get("elapsed_s")))
        cpus.append((o.get("cpu_s"), c.get("cpu_s")))
        if why:
            rows.append({"case": c["case"], "changes": why})
        else:
            same += 1

    def med(pairs: list[tuple[Any, Any]], k: int) -> float | None:
        v = [p[k] for p in pairs if p[k] is not None]
        return statistics.median(v) if v else None

    return {"compared": same + len(rows), "unchanged": same, "differences": rows,
            "max_abs_shrink_change": max(shrinks, default=0.0),
            "max_abs_magnitude_change": max(mags, default=0.0),
            "median_case_s": [med(times, 0), med(times, 1)],
            "median_case_cpu_s": [med(cpus, 0), med(cpus, 1)]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reference", type=Path)
    ap.add_argument("new", type=Path)
    ap.add_argument("--shrink-tol", type=float, default=0.02)
    ap.add_argument("--magnitude-tol", type=float, default=0.02)
    ap.add_argument("--out", type=Path, default=None, help="write the comparison as JSON")
    args = ap.parse_args(argv)
    res = compare(json.loads(args.reference.read_text(encoding="utf-8")),
                  json.loads(args.new.read_text(encoding="utf-8")), args.shrink_tol, args.magnitude_tol)
    res["reference"], res["new"] = str(args.reference), str(args.new)
    res["tolerances"] = {"shrink": args.shrink_tol, "magnitude": args.magnitude_tol}
    text = json.dumps(res, indent=1)
    if args.out:
        args.out.write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
