"""Wall time of the ``identify`` command on a 60 s, 490 Hz bag (issue 4 bar: < 10 s on this machine).

Bag: ``thesis_sim`` with sensor noise at 50 dB SNR (noise seed 7), APRBS duty cycle 60 s, levels
0.2-0.9, holds 20-300 ms, seed 1 (the excitation of ``test/ident/sindy/test_identify.py``, three times as
long), written as a contract bag (mcap) with :func:`aeropend_ident.io.bag_writer.write_bag`.

The command ``.venv/bin/identify BAG --rig thesis_sim --out DIR [--no-plots]`` (default method:
weak form, structured library, λ by BIC over 7 values) runs as a subprocess ``--repeats`` times
with and without plots; recorded per run: wall time of the whole process (interpreter start,
imports, bag reading, identification, plots, writing), the time inside ``identify`` (its
``summary.json`` ``wall_time_s``), the machine load before the run (``os.getloadavg``), and the
identified λ and held-out free-run NRMSE (so a faster run with a worse result would show).

``--baseline REF`` also times the code of git revision REF (``git archive`` of ``src/aeropend_ident``
and ``src/aeropend_sim`` into a temporary folder, put first on ``PYTHONPATH``), interleaved run by run
with the current code, so both see the same machine load (other jobs share this 2-core machine).

Run: ``.venv/bin/python -m bench.bench_identify [--repeats 3] [--tag after] [--baseline a5d6ba2]`` ->
``bench/results/identify.{json,md}`` (about 1-2 min). ``--keep DIR`` keeps the bag and results.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent
REPO = ROOT.parent
OUT = ROOT / "results"
DURATION_S = 60.0
SNR_DB = 50.0
EXCITATION = {"lo": 0.2, "hi": 0.9, "min_hold": 0.02, "max_hold": 0.3, "seed": 1}
NOISE_SEED = 7


def make_bag(path: Path) -> Path:
    """Simulate the 60 s, 490 Hz, 50 dB thesis_sim run and write it as a contract bag."""
    from aeropend_ident.io.bag_writer import write_bag
    from aeropend_sim.excitation import aprbs
    from aeropend_sim.params import load_rig
    from aeropend_sim.recording import Recording
    from aeropend_sim.simulation import simulate

    rig = load_rig("thesis_sim").with_effects(sensor_noise=True).with_params("sensors", snr_db=SNR_DB)
    traj = simulate(rig, aprbs(DURATION_S, **EXCITATION).duty, seed=NOISE_SEED)
    return write_bag(Recording.from_trajectory(traj), path)


def run_once(exe: Path, bag: Path, out: Path, plots: bool, src: Path | None = None,
             stages: bool = False) -> dict[str, Any]:
    """One ``identify`` subprocess; wall time, load before, time inside identify, results.

    ``src``: a source tree (``git archive`` of a revision) whose packages shadow the installed ones.
    ``stages``: run with progress messages and split the time by stage (:func:`_stages`).
    """
    # the structured library named explicitly: identify's default became physics-structured (issue 18)
    args = [str(bag), "--rig", "thesis_sim", "--library", "structured", "--out", str(out)] + (
        [] if stages else ["--quiet"])
    if not plots:
        args.append("--no-plots")
    env = dict(os.environ)
    if src is None:
        cmd = [str(exe), *args]
    else:  # the same entry point, importing the packages of the older revision
        code = "import sys; from aeropend_ident.sindy.identify import main; sys.exit(main())"
        cmd = [sys.executable, "-c", code, *args]
        env["PYTHONPATH"] = os.pathsep.join(str(src / "src" / p) for p in ("aeropend_ident", "aeropend_sim"))
    load = os.getloadavg()
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr}")
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    res = {"plots": plots, "wall_s": round(wall, 3), "inside_identify_s": summary["wall_time_s"],
           "loadavg_1_5_15": [round(x, 2) for x in load], "threshold": summary["threshold"],
           "heldout_nrmse_range_theta": summary["heldout"][0]["nrmse_range"],
           "equations": summary["equations"], "files": summary["files"]}
    if stages:
        res["stages_s"] = _stages(proc.stderr, wall, summary["wall_time_s"])
    return res


#: Progress message (start of its text) -> the stage it ends (identify's stderr, 0.1 s resolution).
STAGE_ENDS = [(" samples at ", "read bag"),
              ("sweeping λ", "derivatives, equation checks / training regression"),
              ("λ = ", "λ sweep (7 λ on the first 75 % of training)"),
              ("free runs on the held-out", "refit, test MSE (+ matplotlib import and fork with plots)"),
              ("held-out free-run NRMSE", "held-out free run"),
              ("plots: ", "plots (after the held-out free run)")]


def _stages(stderr: str, wall: float, inside: float) -> dict[str, float]:
    """Split one run's time by stage from identify's time-stamped progress messages."""
    marks = []
    for line in stderr.splitlines():
        m = re.match(r"\[identify\s+([\d.]+) s\] (.*)$", line)
        if m:
            marks.append((float(m.group(1)), m.group(2)))
    out = {"start-up (interpreter, imports, rig file)": round(wall - inside, 2)}
    last = 0.0
    for key, stage in STAGE_ENDS:
        hit = next((t for t, msg in marks if key in msg), None)
        if hit is not None:
            out[stage] = round(hit - last, 2)
            last = hit
    out["writing model.yaml / summary.json"] = round(max(0.0, inside - last), 2)
    return out


def _stats(xs: list[float]) -> dict[str, float]:
    return {"median": round(statistics.median(xs), 3), "min": round(min(xs), 3), "max": round(max(xs), 3)}


def _archive(ref: str, dest: Path) -> Path:
    """``git archive`` of the two packages identify imports at revision ``ref`` into ``dest``."""
    dest.mkdir(parents=True, exist_ok=True)
    tar = subprocess.run(["git", "-C", str(REPO), "archive", ref, "src/aeropend_ident", "src/aeropend_sim"],
                         capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=tar, check=True)
    return dest


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tag", default="current", help="label of this measurement in the results")
    ap.add_argument("--baseline", default=None, metavar="REF", help="also time git revision REF, interleaved")
    ap.add_argument("--keep", type=Path, default=None, help="keep bag and results in this folder")
    args = ap.parse_args(argv)
    exe = Path(sys.executable).parent / "identify"
    if not exe.exists():
        raise SystemExit(f"{exe}: identify entry point not found (install the packages into this venv)")
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True, check=False).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        bag = make_bag(work / "bag_60s_490hz_50db")
        t_bag = time.perf_counter() - t0
        variants: list[tuple[str, Path | None]] = [(args.tag, None)]
        if args.baseline:
            variants.append((f"baseline {args.baseline}", _archive(args.baseline, Path(tmp) / "baseline")))
        runs = []
        for rep in range(args.repeats):
            for label, src in variants:
                for plots in (True, False):
                    out = work / f"res_{label.replace(' ', '_')}_{'plots' if plots else 'noplots'}_{rep}"
                    r = {"code": label, **run_once(exe, bag, out, plots, src)}
                    print(f"run {rep} {label} plots={plots}: {r['wall_s']:.2f} s wall, "
                          f"{r['inside_identify_s']:.2f} s in identify, load {r['loadavg_1_5_15'][0]:.2f}",
                          file=sys.stderr)
                    runs.append(r)
        stage_runs = {}
        for label, src in variants:  # one more run each with progress messages: where the time goes
            stage_runs[label] = run_once(exe, bag, work / f"res_{label.replace(' ', '_')}_stages", True, src,
                                         stages=True)["stages_s"]
    res: dict[str, Any] = {
        "tag": args.tag, "head": head, "baseline": args.baseline,
        "bag": {"plant": "thesis_sim", "duration_s": DURATION_S, "rate_hz": 490, "snr_db": SNR_DB,
                "excitation": {"kind": "aprbs", **EXCITATION}, "noise_seed": NOISE_SEED,
                "generation_s": round(t_bag, 2)},
        "command": "identify BAG --rig thesis_sim --out DIR --quiet [--no-plots]",
        "cpu_count": os.cpu_count(), "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "bar_s": 10.0, "runs": runs, "stages_with_plots_s": stage_runs,
    }
    for plots in (True, False):
        key = "with_plots" if plots else "without_plots"
        for label, _src in variants:
            sel = [r for r in runs if r["plots"] == plots and r["code"] == label]
            stats = {"wall_s": _stats([r["wall_s"] for r in sel]),
                     "inside_identify_s": _stats([r["inside_identify_s"] for r in sel]),
                     "loadavg_1min": _stats([r["loadavg_1_5_15"][0] for r in sel])}
            if label == args.tag:
                res[key] = stats
            else:
                base = res.setdefault("interleaved_baseline", {"tag": label, "date_utc": res["date_utc"]})
                base[key] = stats
    OUT.mkdir(exist_ok=True)
    path = OUT / "identify.json"
    old = json.loads(path.read_text(encoding="utf-8")) if path.exists() else {}
    history = [h for h in old.get("history", []) if h.get("tag") != args.tag]
    if old.get("tag") and old["tag"] != args.tag:
        history.append({k: old[k] for k in ("tag", "date_utc", "with_plots", "without_plots") if k in old})
    res["history"] = history
    path.write_text(json.dumps(res, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
    (OUT / "identify.md").write_text(_markdown(res), encoding="utf-8")
    print(_markdown(res))
    return 0


def _markdown(res: dict[str, Any]) -> str:
    b = res["bag"]
    lines = [
        "# identify on a 60 s, 490 Hz bag (bench/bench_identify.py)",
        "",
        f"Bag: {b['plant']}, {b['duration_s']:g} s at {b['rate_hz']} Hz, {b['snr_db']:g} dB SNR (noise seed "
        f"{b['noise_seed']}), APRBS levels {b['excitation']['lo']}-{b['excitation']['hi']}, holds "
        f"{b['excitation']['min_hold'] * 1e3:g}-{b['excitation']['max_hold'] * 1e3:g} ms, seed "
        f"{b['excitation']['seed']}. Command: `{res['command']}` as a subprocess; wall = whole process "
        f"(interpreter start included), inside = `summary.json` `wall_time_s`. {res['cpu_count']} CPUs, "
        f"{res['date_utc']} UTC. Bar: < {res['bar_s']:g} s wall.",
        "",
        "| measurement | plots | wall median [s] | wall min-max [s] | inside identify median [s] "
        "| load (1 min) |",
        "|---|---|---|---|---|---|",
    ]
    inter = [res["interleaved_baseline"]] if "interleaved_baseline" in res else []
    rows = [*res.get("history", []), *inter, res]
    for h in rows:
        for key, label in (("with_plots", "yes"), ("without_plots", "no")):
            if key not in h:
                continue
            s = h[key]
            lines.append(f"| {h['tag']} ({h.get('date_utc', '')}) | {label} | {s['wall_s']['median']:.2f} | "
                         f"{s['wall_s']['min']:.2f}-{s['wall_s']['max']:.2f} | "
                         f"{s['inside_identify_s']['median']:.2f} | "
                         f"{s['loadavg_1min']['min']:.2f}-{s['loadavg_1min']['max']:.2f} |")
    r0 = next(r for r in res["runs"] if r["code"] == res["tag"])
    lines += ["", f"Result of the current code: λ = {r0['threshold']:g}, held-out free-run NRMSE(range) of θ "
              f"{r0['heldout_nrmse_range_theta']:.4g}:", ""]
    lines += [f"    {e}" for e in r0["equations"]]
    st = res.get("stages_with_plots_s", {})
    if st:
        labels = list(st)
        names = list(dict.fromkeys(k for v in st.values() for k in v))
        lines += ["", "Where the time goes (one further run with plots each, from identify's progress "
                  "time stamps, 0.1 s resolution) [s]:", "", "| stage | " + " | ".join(labels) + " |",
                  "|---|" + "---|" * len(labels)]
        lines += [f"| {n} | " + " | ".join(f"{st[lab].get(n, float('nan')):.2f}" for lab in labels) + " |"
                  for n in names]
    others = [r for r in res["runs"] if r["code"] != res["tag"]]
    if others:
        same = all(r["equations"] == r0["equations"] and r["threshold"] == r0["threshold"]
                   and r["heldout_nrmse_range_theta"] == r0["heldout_nrmse_range_theta"] for r in others)
        lines += ["", f"Baseline {res['baseline']}: {'the same' if same else 'DIFFERENT'} equations, λ and "
                  "held-out NRMSE."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
