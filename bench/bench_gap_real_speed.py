"""Time the real Etchepareborda diagnosis as a lab runs it (issue 37's bar: ≤ 60 s; 725 s before).

The ``gap`` command on the four BA-Etchepareborda open-loop runs (fit: the 0/100/180 step cycle
and the 80/120 random-binary run; validation: the Gaussian-PWM run; held out: the 0/100/130 step
cycle; ``etchepareborda_rig``; the command's defaults, the oracle of the attainable shrink
included), run as a child process: wall time, and the CPU time of the process and its children
(the operating system's accounting). Its diagnosis is compared with the same command run on commit
8559cc8 (LSODA, before the component registry and the compiled backend;
``bench/results/gap_real_speed_reference_8559cc8.json``): effects chosen, held-out θ NRMSE before
and after, and every ranked effect's validation share. The older stored case of
``bench/results/gap_real.json`` (``etchepareborda_all``, 2026-11-22) is listed too: the diagnosis
changed between that run and 8559cc8 (the effects are chosen on a validation part since), not with
the simulator.

Writes ``bench/results/gap_real_speed.json``. Needs ``../shared/data/real`` beside the checkout
(the recordings are not in the repository).

Usage: ``python -m bench.bench_gap_real_speed [--repeat 1]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "real" / "BA-Etchepareborda__adaptive-control-aeropendulum"
RESULTS = ROOT / "bench" / "results"
STORED = ("gap_real.json", "etchepareborda_all")
#: The same command's diagnosis on commit 8559cc8 (module doc).
REFERENCE = "gap_real_speed_reference_8559cc8.json"


def _ranking_change(now: list[dict], ref: list[dict]) -> float | None:
    """Largest |Δ validation share| over the effects ranked in both runs (None if one is missing)."""
    a = {r["effect"]: r["validation_explained"] for r in now}
    b = {r["effect"]: r["validation_explained"] for r in ref}
    if set(a) != set(b):
        return None
    return max((abs(a[k] - b[k]) for k in a), default=0.0)


def command(out: Path) -> list[str]:
    d = DATA
    gap = str(Path(sys.executable).with_name("gap"))
    return [gap, str(d / "openloop_steps_0_100_180.csv"), str(d / "openloop_random_binary_80_120.csv"),
            "--validation", str(d / "openloop_gaussian_pwm.csv"), "--held-out",
            str(d / "openloop_steps_0_100_130.csv"), "--preset", "etchepareborda_openloop",
            "--rig", "etchepareborda_rig", "-o", str(out), "-q"]


def run_once(out: Path) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load = os.getloadavg()
    t0 = time.perf_counter()
    proc = subprocess.run(command(out), capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"gap failed ({proc.returncode}): {proc.stderr.strip()[-400:]}")
    doc = json.loads((out / "report.json").read_text(encoding="utf-8"))
    test = doc["after"]["test"]
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu,
            "load_before": [round(x, 2) for x in load], "load_after": [round(x, 2) for x in os.getloadavg()],
            "chosen": doc["which"]["chosen"], "nrmse_before": test[0]["nrmse"],
            "nrmse_after": test[-1]["nrmse"],
            "ranking": [{"effect": r["effect"], "validation_explained": r["validation_explained"]}
                        for r in doc["which"]["ranking"]]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--out", default=str(RESULTS / "gap_real_speed.json"))
    args = ap.parse_args(argv)
    if not DATA.is_dir():
        raise SystemExit(f"{DATA} not found: the real recordings live in ../shared/data/real")
    runs = []
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as tmp:
            runs.append(run_once(Path(tmp) / "gap"))
            print(json.dumps(runs[-1]), flush=True)
    reference = json.loads((RESULTS / REFERENCE).read_text(encoding="utf-8"))
    stored = json.loads((RESULTS / STORED[0]).read_text(encoding="utf-8"))["cases"][STORED[1]]
    ref = {"elapsed_s": stored["elapsed_s"], "chosen": stored["test"][-1]["effects"],
           "nrmse_before": stored["test"][0]["nrmse"], "nrmse_after": stored["test"][-1]["nrmse"]}
    best = min(runs, key=lambda r: r["wall_s"])
    doc = {"command": " ".join(command(Path("OUT"))[1:]).replace(str(ROOT.parent), ".."),
           "runs": runs, "best": best, "stored": {"file": STORED[0], "case": STORED[1], **ref},
           "same_effects_as_stored": sorted(best["chosen"]) == sorted(ref["chosen"]),
           "reference": {"file": REFERENCE, "commit": reference["commit"], "chosen": reference["chosen"],
                         "nrmse_before": reference["nrmse_before"], "nrmse_after": reference["nrmse_after"],
                         "wall_s_approx": reference["wall_s_approx"]},
           "same_effects": sorted(best["chosen"]) == sorted(reference["chosen"]),
           "nrmse_after_change": best["nrmse_after"] - reference["nrmse_after"],
           "ranking_max_abs_change": _ranking_change(best["ranking"], reference["ranking"]),
           "meta": {"machine": f"{os.cpu_count()} cores, {platform.platform()}",
                    "python": platform.python_version(),
                    "commit": subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                                             capture_output=True, text=True, check=False).stdout.strip()}}
    Path(args.out).write_text(json.dumps(doc, indent=1), encoding="utf-8")
    print(json.dumps({k: doc[k] for k in ("best", "reference", "same_effects", "nrmse_after_change",
                                          "ranking_max_abs_change")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
