"""Issue 63, `rig fit`'s side: does one designed recording determine the parameters a first log left
undetermined?

Each case is an independent rig of :mod:`bench.fixtures.family_lab` (ESC, voltage amplifier,
H-bridge; angle only at 100 Hz on a 12-bit encoder or a 10-bit potentiometer, drawn from physics
outside aeropend). A lab's first log is either its 61 s of steps (``steps.csv``) or its balance
table and a free decay (a rig not yet driven dynamically): ``rig new`` with what the lab states,
then ``rig fit`` on that log alone. The parameters that fit leaves STILL TO BE FITTED
(refused) or AT SEARCH BOUND are the ones to determine. ``excitation --design-for`` designs 40 s
for them (seed 0, its default limits: commands up to the largest recorded, the recorded angle
range ± 0.15 rad); the design is played on the rig's own plant (its noise, lattice and rate), and
``rig fit`` runs again on the first log and the designed recording. Control: a seeded APRBS of the same
length over the same command range, played and fitted the same way.

Per parameter to determine: *determined* = the second fit reports it FITTED with a relative 1σ of
at most 10 % (issue 63's bar: ≥ 80 % of the refused parameters), and whether the truth lies within
3σ of it where the drawn rig has that parameter by name. Written to
``bench/results/design_parameters.{json,md}``.

Usage: ``PYTHONPATH=. python bench/bench_design_parameters.py [--families esc,voltage_amplifier,dc_hbridge]
[--rigs 2] [--first-logs steps,decay]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import re
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.fixtures import family_lab as fl  # noqa: E402
from bench.fixtures import truth_plant as tp  # noqa: E402
from bench.fixtures.provenance import run_meta  # noqa: E402

RESULTS = ROOT / "bench" / "results"
#: Relative 1σ at which a parameter counts as determined (issue 63's bar).
DETERMINED = 0.10
DURATION = 40.0
FITTED = re.compile(r"rig fit: FITTED (\S+) ± (\S+)")


def _quiet(fn, argv: list[str]) -> tuple[int, str]:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        try:
            rc = fn(argv)
        except SystemExit as exc:
            rc = int(exc.code or 0)
    return rc, buf.getvalue()


def fit_status(path: Path) -> dict[str, dict[str, Any]]:
    """``section.name`` → {status: fitted | refused | bound, value, sd} from a rig fit result's comments."""
    out: dict[str, dict[str, Any]] = {}
    section, pending = None, None
    for line in path.read_text(encoding="utf-8").splitlines():
        m = re.match(r"^([a-z_]+):\s*$", line)
        if m:
            section = m.group(1)
            continue
        c = line.strip()
        if c.startswith("# rig fit: STILL TO BE FITTED"):
            pending = {"status": "refused"}
        elif c.startswith("# rig fit") and "AT SEARCH BOUND" in c:
            pending = {"status": "bound"}
        elif (f := FITTED.search(c)) is not None:
            pending = {"status": "fitted", "value": float(f.group(1)), "sd": float(f.group(2))}
        elif pending is not None and (k := re.match(r"^\s+([A-Za-z_][A-Za-z_0-9]*):\s*\{", line)):
            out[f"{section}.{k.group(1)}"] = pending
            pending = None
    return out


#: Rig-file key -> the names family_lab's truth uses for the same physics.
TRUTH_NAMES = {"motor.T_m": ("response_s",), "actuator.input_delay": ("dead_time_s",),
               "pendulum.inertia": ("inertia",), "motor.R_a": ("R_a",), "motor.K_t": ("k_t",),
               "motor.J_m": ("J_m", "J_r"), "pendulum.mgd_over_J": ("mgd_over_J",),
               "pendulum.c_over_J": ("c_over_J",), "pendulum.L_over_J": ("L_over_J",)}


def _truth(rig: fl.LabRig, key: str) -> float | None:
    for name in TRUTH_NAMES.get(key, ()):
        if name in rig.truth:
            return float(rig.truth[name])
    return None


def _play(rig: fl.LabRig, design_csv: Path, out: Path, seed: int) -> Path:
    """The design (t, command) played on the rig's plant at its period; written as a lab log."""
    t, u = np.loadtxt(design_csv, delimiter=",", skiprows=1, unpack=True)
    grid = np.arange(0.0, t[-1] + 1e-9, fl.PERIOD)
    cmd = u[np.clip(np.searchsorted(t, grid, side="right") - 1, 0, u.size - 1)]
    fl._write(out, cmd, fl.run_open_loop(rig, cmd, seed))
    return out


def _play_closed(rig: fl.LabRig, design: Path, controller_rig: Path, out: Path, seed: int,
                 baseline: bool = False) -> Path:
    """A closed-loop design's set points (or, ``baseline``, the seeded ones its search started from)
    followed by the lab's controller (the design's strategy and pole pattern on the lab's fitted rig
    file, at the rig's period) on the rig's own plant: the logged command and the measured angle
    (its noise and lattice), written as a lab log."""
    from aeropend_ident.design.reference import lab_controller

    spec = json.loads((design / "design.json").read_text(encoding="utf-8"))
    steps = [tuple(s) for s in spec["baseline_steps" if baseline else "steps"]]
    c = spec["controller"]
    loop = lab_controller(str(controller_rig), {k: c[k] for k in ("strategy", "omega_n", "zeta", "rho")},
                          fl.PERIOD)
    loop.reference.steps = steps
    st, rng = rig.stepper(), np.random.default_rng(seed)
    n = round(spec["duration_s"] / fl.PERIOD)
    cmd, y = np.empty(n), np.empty(n)
    for k in range(n):
        y[k] = fl._measure(rig, st, rng)
        cmd[k] = min(max(float(loop.on_sample(round(k * fl.PERIOD * 1e9), y[k])), 0.0), 1.0)
        st.step(cmd[k])
    return fl._write(out, cmd, y)


def _limits_on_truth(played: Path, limits: dict[str, float]) -> dict[str, Any]:
    """The design's limits (command range, slew, angle range) checked on the command played and
    the angle the rig's plant recorded (issue 63: every design, on the truth plant)."""
    from aeropend_ident.design.sequence import Limits, check_limits

    _, duty, theta = np.loadtxt(played, delimiter=",", skiprows=1, unpack=True)
    return check_limits(duty, Limits(**limits), theta)


def run_case(family: str, index: int, seed: int, first_log: str = "steps", mode: str = "open_loop"
             ) -> dict[str, Any]:
    from aeropend_ident.cli.rig import main as rig_main
    from aeropend_ident.design.cli import main as design_main

    rig = fl.draw_rigs(family, index + 1, seed=seed)[index]
    row: dict[str, Any] = {"rig": rig.name, "family": family, "sensor": rig.sensor, "first_log": first_log}
    with tempfile.TemporaryDirectory(prefix=f"dp_{rig.name}_") as tmp:
        d = Path(tmp)
        inputs = fl.lab_logs(rig, d / "logs")
        steps = next(i for i in inputs if "steps.csv" in i)
        preset = steps.partition(":")[2]
        first_logs = [steps] if first_log == "steps" else \
            [i for i in inputs if "balance.csv" in i or "decay.csv" in i]
        new, first = d / "new.yaml", d / "first.yaml"
        rc, text = _quiet(rig_main, ["new", "--actuator", family, "--stated", *fl.stated(rig), "-o",
                                     str(new)])
        if rc:
            return {**row, "failed": f"rig new: {text[-300:]}"}
        t0 = time.perf_counter()
        rc, text = _quiet(rig_main, ["fit", str(new), *first_logs, "-o", str(first), "-q"])
        row["fit_first_s"] = time.perf_counter() - t0
        if rc:
            return {**row, "failed": f"rig fit (steps): {text[-300:]}"}
        before = fit_status(first)
        todo = sorted(k for k, v in before.items() if v["status"] != "fitted"
                      or (v["sd"] / abs(v["value"]) > DETERMINED if v["value"] else True))
        row["to_determine"] = {k: before[k] for k in todo}
        if not todo:
            return {**row, "note": "the steps determined every parameter"}
        t0 = time.perf_counter()
        rc, text = _quiet(design_main, ["--design-for", str(first), *first_logs, "-o", str(d / "design"),
                                        "--duration", str(DURATION), "--parameters", *todo, "--mode", mode])
        row["design_s"] = time.perf_counter() - t0
        if rc:
            return {**row, "failed": f"design: {text[-400:]}"}
        spec = json.loads((d / "design" / "design.json").read_text(encoding="utf-8"))
        # the design's own prediction (relative 1σ under its unit prior): before, with the design,
        # with its seeded APRBS
        row["predicted"] = {k: spec.get(k) for k in ("sd_before", "sd_after", "sd_after_baseline")}
        row["search"] = {k: spec.get(k) for k in ("evaluations", "stopped_by", "elapsed_s",
                                                  "angle_margin_rad", "angle_spread_rad",
                                                  "angle_limits_assured")}
        row["limits"] = spec["limits"]
        if mode == "reference":  # played by the lab's controller; control: the seeded set points
            designed = _play_closed(rig, d / "design", first, d / "designed.csv", seed=77)
            ctrl = _play_closed(rig, d / "design", first, d / "aprbs_control.csv", seed=78, baseline=True)
        else:
            designed = _play(rig, d / "design" / "design.csv", d / "designed.csv", seed=77)
            cmd = np.loadtxt(d / "design" / "design.csv", delimiter=",", skiprows=1)[:, 1]
            aprbs = tp.aprbs(DURATION, seed=5, lo=float(cmd.min()), hi=float(cmd.max()), min_hold=0.2,
                             max_hold=1.5, rest=0.5, dt=fl.PERIOD)
            ctrl = d / "aprbs_control.csv"
            fl._write(ctrl, aprbs, fl.run_open_loop(rig, aprbs, 78))
        row["limits_on_truth"] = _limits_on_truth(designed, spec["limits"])
        for label, rec in (("design", designed), ("aprbs", ctrl)):
            out = d / f"after_{label}.yaml"
            t0 = time.perf_counter()
            rc, text = _quiet(rig_main, ["fit", str(new), *first_logs, f"{rec}:{preset}", "-o", str(out),
                                         "-q"])
            row[f"fit_{label}_s"] = time.perf_counter() - t0
            if rc:
                row[label] = {"failed": text[-300:]}
                continue
            after = fit_status(out)
            res = {}
            for k in todo:
                a = after.get(k, {"status": "absent"})
                rel = a["sd"] / abs(a["value"]) if a["status"] == "fitted" and a["value"] else math.inf
                tru = _truth(rig, k)
                res[k] = {**a, "rel_sd": rel, "determined": bool(rel <= DETERMINED), "truth": tru,
                          "within_3sd": (None if tru is None or a["status"] != "fitted"
                                         else bool(abs(a["value"] - tru) <= 3 * a["sd"]))}
            row[label] = res
    return row


def render(res: dict[str, Any]) -> str:
    s = res["summary"]
    lines = ["# One designed recording for the parameters a first log left undetermined (issue 63)", "",
             f"`PYTHONPATH=. python bench/bench_design_parameters.py` ({res['meta'].get('commit', '?')}, "
             f"{s['wall_s']:.0f} s). What it does: its module docstring. Determined = FITTED with a relative "
             f"1σ ≤ {DETERMINED:.0%} in the second fit.", "",
             f"- parameters to determine after the first log: **{s['n_todo']}** in {s['n_cases']} cases",
             f"- determined after the designed recording: **{s['design_determined']}/{s['n_todo']}**; "
             f"after a seeded APRBS of the same length and range: {s['aprbs_determined']}/{s['n_todo']}",
             f"- of those determined, truth within 3σ: design {s['design_within']}, APRBS "
             f"{s['aprbs_within']} (where the drawn rig has the parameter by name)",
             f"- of those the first fit **refused** (STILL TO BE FITTED) or left AT SEARCH BOUND "
             f"({_refused(res, 'design')[1]} of {s['n_todo']}; issue 63's bar: ≥ 80 % determined within "
             "10 %): "
             f"design **{_refused(res, 'design')[0]}/{_refused(res, 'design')[1]}**, APRBS "
             f"{_refused(res, 'aprbs')[0]}/{_refused(res, 'aprbs')[1]}",
             f"- where the drawn rig has the parameter by name ({s['n_named']} of {s['n_todo']}; the "
             f"others are the amplifier's output offset, 0 on these rigs, where a relative 1σ says nothing): "
             f"determined **and** within 3σ of the truth: design **{s['design_right']}/{s['n_named']}**, "
             f"APRBS {s['aprbs_right']}/{s['n_named']}",
             f"- the design's limits (command range, slew, angle range) held on the rig's own recorded "
             f"angle in {s['limits_held']}/{s['n_designs']} designs; the design said its limits were not "
             f"assured (the angle depends on parameters the first log does not determine) in "
             f"{s['not_assured']}, of which {s['not_assured_held']} held",
             f"- design time median {s['design_s_median']:.0f} s, max {s['design_s_max']:.0f} s", "",
             "| rig | sensor | first log | parameter | after it | design's prediction | after design "
             "(rel 1σ) | after APRBS (rel 1σ) | truth |", "|---|---|---|---|---|---|---|---|---|"]

    def cell(x: dict[str, Any] | None) -> str:
        if not x:
            return "—"
        if x.get("status") != "fitted":
            return x.get("status", "—")
        return f"{x['value']:.4g} ({x['rel_sd']:.1%}){' ✓' if x['determined'] else ''}"

    for r in res["rows"]:
        if "failed" in r or "note" in r:
            why = r.get("failed") or r.get("note")
            lines.append(f"| {r['rig']} | {r['sensor']} | {r['first_log']} | {why} | | | | | |")
            continue
        for k, b in r["to_determine"].items():
            first = b["status"] if b["status"] != "fitted" else f"{b['value']:.4g} ± {b['sd']:.2g}"
            tru = r.get("design", {}).get(k, {}).get("truth")
            pred = (r.get("predicted") or {}).get("sd_after") or {}
            said = f"{pred[k]:.1%}" if isinstance(pred.get(k), (int, float)) else "—"
            lines.append(f"| {r['rig']} | {r['sensor']} | {r['first_log']} | `{k}` | {first} | {said} | "
                         f"{cell(r.get('design', {}).get(k))} | {cell(r.get('aprbs', {}).get(k))} | "
                         f"{'—' if tru is None else f'{tru:.4g}'} |")
    return "\n".join(lines) + "\n"


def _not_assured(row: dict[str, Any]) -> bool:
    """The design said its angle limits were not assured (design.json ``angle_limits_assured``)."""
    return (row.get("search") or {}).get("angle_limits_assured") is False


def _refused(res: dict[str, Any], label: str) -> tuple[int, int]:
    """(determined after the ``label`` recording, total) over the parameters the first fit refused or
    left at a search bound (not those it fitted with a wide 1σ)."""
    rows = [(r, k) for r in res["rows"] if "to_determine" in r and "failed" not in r
            for k, b in r["to_determine"].items() if b["status"] in ("refused", "bound")]
    return sum(bool(r.get(label, {}).get(k, {}).get("determined")) for r, k in rows), len(rows)


def _within(v: list[dict[str, Any]]) -> str:
    """'k/n': of the determined parameters with a truth by name, those within 3σ of it."""
    judged = [x for x in v if x.get("determined") and x.get("within_3sd") is not None]
    return f"{sum(bool(x['within_3sd']) for x in judged)}/{len(judged)}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", default="esc,voltage_amplifier,dc_hbridge")
    ap.add_argument("--rigs", type=int, default=2, help="rigs per family")
    ap.add_argument("--seed", type=int, default=63000)
    ap.add_argument("--out", type=Path, help="output stem (default design_parameters, or "
                                             "design_parameters_reference with --mode reference)")
    ap.add_argument("--mode", choices=("open_loop", "reference"), default="open_loop",
                    help="reference: closed-loop designs (set points for the controller node's default "
                         "strategy on the fitted rig file), played by that controller on the rig's plant; "
                         "the control is the seeded set points")
    ap.add_argument("--first-logs", default="steps,decay",
                    help="a lab's first logs, one case each: steps (61 s of steps) and/or decay (the "
                         "balance table and a free decay)")
    args = ap.parse_args(argv)
    args.out = args.out or RESULTS / ("design_parameters_reference" if args.mode == "reference"
                                      else "design_parameters")
    t0, load = time.perf_counter(), os.getloadavg()
    rows = []
    for fam in args.families.split(","):
        for i in range(args.rigs):
            for first_log in args.first_logs.split(","):
                r = run_case(fam, i, args.seed, first_log, args.mode)
                print(json.dumps({k: r.get(k) for k in ("rig", "first_log", "failed", "note")}), flush=True)
                rows.append(r)
    ok = [r for r in rows if "to_determine" in r and "failed" not in r]
    todo = [(r, k) for r in ok for k in r["to_determine"]]
    det = {lab: [r.get(lab, {}).get(k, {}) for r, k in todo] for lab in ("design", "aprbs")}
    times = [r["design_s"] for r in ok if "design_s" in r] or [math.nan]
    summary = {"n_cases": len(rows), "n_todo": len(todo), "wall_s": time.perf_counter() - t0,
               "design_s_median": float(np.median(times)), "design_s_max": float(np.max(times)),
               **{f"{lab}_determined": sum(bool(x.get("determined")) for x in v) for lab, v in det.items()},
               **{f"{lab}_within": _within(v) for lab, v in det.items()},
               "n_named": sum(1 for x in det["design"] if x.get("truth") is not None),
               **{f"{lab}_right": sum(bool(x.get("determined") and x.get("within_3sd")) for x in v)
                  for lab, v in det.items()},
               "n_designs": sum(1 for r in ok if "limits_on_truth" in r),
               "limits_held": sum(bool(r["limits_on_truth"]["ok"]) for r in ok if "limits_on_truth" in r),
               "not_assured": sum(1 for r in ok if _not_assured(r)),
               "not_assured_held": sum(1 for r in ok if _not_assured(r) and r["limits_on_truth"]["ok"])}
    res = {"summary": summary, "meta": run_meta(t0, load, argv), "rows": rows}
    args.out.with_suffix(".json").write_text(json.dumps(res, indent=1, default=str), encoding="utf-8")
    args.out.with_suffix(".md").write_text(render(res), encoding="utf-8")
    print(render(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
