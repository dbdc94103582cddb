"""Stress check: the simavr ESC firmware tests as three xdist workers would run them, commands every 1 ms.

Three concurrent runs of ``test/firmware/test_simavr_esc.py`` whose host sends a command every
1 ms (``AEROPEND_SIMAVR_CMD_PERIOD_S``; a 1 kHz controller, ten times the test's rate),
``--rounds`` times; per run the failed tests and their assertion lines. It found the cause of the
intermittent failures of the clean-clone CI run at d13b121 (a finished test's serial link reading
the next test's emulator, made deterministic by ``simavr_pty_reuse.py``) and checks the harness's
own pty link (``firmware/sim/harness.c``) under contention.

Usage: ``python -m bench.repro.simavr_parallel_stress [--rounds 5] [--repo DIR] [--out FILE]``
(``--repo``: a checkout whose firmware and test are run, e.g. a worktree with an older
``firmware/sim/harness.c``); writes ``bench/results/repro_simavr_parallel_stress.json`` by default.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TEST = "test/firmware/test_simavr_esc.py"
PARALLEL = 3


def run(repo: Path, rounds: int) -> dict:
    env = {**os.environ, "AEROPEND_SIMAVR_CMD_PERIOD_S": "0.001"}
    runs = []
    for _ in range(rounds):
        procs = [subprocess.Popen([sys.executable, "-m", "pytest", "-p", "no:xdist", "-p", "no:cacheprovider",
                                   "-q", TEST], cwd=repo, env=env, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True) for _ in range(PARALLEL)]
        for p in procs:
            out, _ = p.communicate(timeout=900)
            failed = sorted(set(re.findall(r"^FAILED \S+::(\S+)", out, re.M)))
            widths = re.findall(r"width error min (\S+) max (\S+) µs", out)
            errors = [ln.strip() for ln in out.splitlines() if ln.startswith("E   ")][:12]
            runs.append({"failed": failed, "pulse_width_error_us": widths, "assertions": errors})
    return {"repo": str(repo), "parallel": PARALLEL, "command_period_s": 0.001, "runs": len(runs),
            "runs_failed": sum(bool(r["failed"]) for r in runs), "detail": runs}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=5, help="rounds of three concurrent runs (default 5)")
    ap.add_argument("--repo", type=Path, default=ROOT, help="checkout to run (default: this one)")
    ap.add_argument("--out", type=Path, help="result file (JSON)",
                    default=ROOT / "bench" / "results" / "repro_simavr_parallel_stress.json")
    args = ap.parse_args(argv)
    res = run(args.repo.resolve(), args.rounds)
    res["repo"] = "this checkout" if args.repo.resolve() == ROOT else str(args.repo)
    args.out.write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps({k: v for k, v in res.items() if k != "detail"}, indent=1))
    return 0 if res["runs_failed"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
