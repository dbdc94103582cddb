"""Pre-registered real-rig runs of the gap prediction, attainable shrink and drift table (issue 16).

The protocol is in docs/gap.md ("Pre-registered real-rig protocol for the prediction and the
split"), written before these runs: one new session held out per rig, default settings, each
recording with its own CSV preset. Runs the ``gap`` command in-process per case and collects
from each ``report.json``: predicted vs actual held-out θ NRMSE, the split of the held-out gap,
the best constant-parameter fit there and the drift table.

Writes ``bench/results/gap_sessions_real.json`` and ``.md``; report folders under
``bench/results/gap_sessions_real/``.

Usage: ``python -m bench.bench_gap_sessions_real [--only CASE ...] [--md-only]`` (``--only`` replaces
those cases' rows in the stored results and keeps the others)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"
RESULTS = ROOT / "bench" / "results"
AERO = REAL / "gergelytakacs__AutomationShield" / "AeroShield"
JAHO = REAL / "jahoyosr__Aeropendulum"
ETCH = REAL / "BA-Etchepareborda__adaptive-control-aeropendulum"

CASES: dict[str, dict[str, Any]] = {
    "aeroshield_sessions": {
        "rig": "aeroshield_rig",
        "fit": [f"{AERO / 'Identification_Data.csv'}:aeroshield_ident"],
        "held": [f"{AERO / 'Identification_Data2.csv'}:aeroshield_ident2"],
    },
    "jahoyosr_sessions": {
        "rig": "jahoyosr_rig",
        "fit": [f"{JAHO / 'sheet_Hoja3_pwm_steps_openloop.csv'}:jahoyosr_hoja3"],
        "held": [f"{JAHO / 'sheet_datosEscalones_colsST_pwm_steps_no_time.csv'}:jahoyosr_escalones"],
    },
    "etchepareborda_sessions": {
        "rig": "etchepareborda_rig",
        "fit": [
            f"{ETCH / n}:etchepareborda_openloop"
            for n in (
                "openloop_steps_0_100_180.csv",
                "openloop_steps_0_100_130.csv",
                "openloop_gaussian_pwm.csv",
                "openloop_random_binary_80_120.csv",
            )
        ],
        "held": [f"{ETCH / 'closedloop_IMC_reference_steps.csv'}:etchepareborda_openloop"],
    },
}


def run(name: str, case: dict[str, Any]) -> dict[str, Any]:
    from aeropend_ident.cli.gap import main

    out = RESULTS / "gap_sessions_real" / name
    t0 = time.perf_counter()
    # the bench replaces its own earlier result folder (bench/results/gap_sessions_real/<case>)
    rc = main([*case["fit"], "--held-out", *case["held"], "--rig", case["rig"], "-o", str(out), "-q",
               "--overwrite"])
    return from_report(name, out, rc, time.perf_counter() - t0)


def from_report(name: str, out: Path, rc: int = 0, elapsed_s: float | None = None) -> dict[str, Any]:
    """A result row from a case's report folder (``report.json`` written by ``gap``)."""
    row: dict[str, Any] = {"case": name, "exit": rc, "elapsed_s": elapsed_s}
    if rc != 0:
        return row
    rep = json.loads((out / "report.json").read_text(encoding="utf-8"))
    att = rep["after"]["attainable"]
    row.update(
        chosen=rep["headline"]["effects_chosen"],
        prediction=rep["prediction"],
        not_computed=rep.get("not_computed") or {},
        check=rep["after"]["prediction_check"],
        heldout=[
            {
                k: a.get(k)
                for k in (
                    "source",
                    "nominal",
                    "corrected",
                    "oracle_same",
                    "oracle_drift",
                    "oracle_best",
                    "oracle_best_effects",
                    "oracle",
                    "noise_floor",
                    "split",
                )
            }
            for a in att
        ],
        drift=[a.get("drift") for a in att],
    )
    return row


def _change(x: dict[str, Any]) -> str:
    """Effect and its change: relative, or absolute where the reference value is ~0 (the rule of
    :func:`aeropend_ident.gap.sessions.drift_rows`, also applied to rows written before it)."""
    from aeropend_ident.gap.sessions import RELATIVE_FLOOR

    v0, v1 = x["values"][0], x["values"][1]
    if abs(v0) > RELATIVE_FLOOR * max(abs(v0), abs(v1)):
        return f"{x['effect']} {(v1 - v0) / abs(v0):+.0%}"
    return f"{x['effect']} {v1 - v0:+.3g} {x['unit']}"


def write_md(path: Path, rows: list[dict[str, Any]]) -> None:
    lines = [
        "# Real rigs: predicted vs actual held-out NRMSE, attainable shrink, drift (issue 16)",
        "",
        "Protocol: docs/gap.md, pre-registered. θ NRMSE = RMS error / θ range of the held-out recording.",
        "",
        "| case | chosen | predicted [80 %] | actual | inside | nominal → corrected | refitted there: same "
        "set / + drift-prone parameters / best catalog set | removed / removable not removed / "
        "not removable | drifting (fit vs held out) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r["exit"] != 0:
            lines.append(f"| {r['case']} | exit {r['exit']} | | | | | | | |")
            continue
        p, c = r["prediction"], r["check"]
        for h, d in zip(r["heldout"], r["drift"], strict=True):
            sp = h["split"]
            drifting = ", ".join(_change(x) for x in (d or {}).get("rows", []) if x["drifts"]) or "none"
            # a prediction the report could not make (not_computed) is a row, not a crash
            pred = (f"{p['predicted']:.4f} [{p['interval'][0]:.4f}, {p['interval'][1]:.4f}] | "
                    f"{c['actual']:.4f} | {'yes' if c['inside'] else 'no'}" if p and c else
                    f"not computed: {(r.get('not_computed') or {}).get('prediction', '?')} | | ")
            lines.append(
                f"| {r['case']} | {'+'.join(r['chosen']) or 'none'} | {pred} | "
                f"{h['nominal']:.4f} → {h['corrected']:.4f} | "
                f"{h['oracle_same']:.4f} / {h['oracle_drift']:.4f} / {h['oracle_best']:.4f} "
                f"({'+'.join(h['oracle_best_effects'])}) | {sp['removed']:.0%} / "
                f"{sp['removable_not_removed']:.0%} / {sp['not_removable']:.0%} | {drifting} |"
            )
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", default=None, choices=sorted(CASES))
    ap.add_argument("--md-only", action="store_true", help="rewrite the .md from the stored .json")
    args = ap.parse_args(argv)
    if args.md_only:
        rows = json.loads((RESULTS / "gap_sessions_real.json").read_text(encoding="utf-8"))
        write_md(RESULTS / "gap_sessions_real.md", rows)
        return 0
    rows = []
    for name, case in CASES.items():
        if args.only and name not in args.only:
            continue
        print(f"{name} ...", flush=True)
        rows.append(run(name, case))
        print(
            json.dumps({k: rows[-1].get(k) for k in ("case", "exit", "chosen", "check")}, default=str),
            flush=True,
        )
    stored_path = RESULTS / "gap_sessions_real.json"
    if args.only and stored_path.exists():  # keep the other cases' rows: replace only the re-run ones
        fresh = {r["case"]: r for r in rows}
        stored = json.loads(stored_path.read_text(encoding="utf-8"))
        rows = [fresh.pop(r["case"], r) for r in stored] + list(fresh.values())
    stored_path.write_text(json.dumps(rows, indent=1, default=float) + "\n", encoding="utf-8")
    write_md(RESULTS / "gap_sessions_real.md", rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
