"""Same results before and after a restructure: run the lab path in two checkouts and compare.

Issue 64 moves code between modules ("what exists today behaves bit for bit as before"). This
script runs one fixed set of commands in each of two checkouts of this repository with the same
Python environment — each checkout's own console-script entry points (read from its
``src/*/setup.py``) and its own ``src/`` first on ``PYTHONPATH`` — and compares every result file:

* ``rig fit`` on a real lab's logs (matheusbucater: the sawtooth and the free fall, docs/onboarding.md),
* ``rig check`` of that fitted rig on the held-out step,
* ``compare`` of the fitted rig on the step,
* ``gap`` on the sawtooth with the step held out (the report's JSON),
* ``gap`` on a synthetic case with a known effect (viscous friction 1.5×; ``gap.synth.make_case``),
  written as CSV logs first so both checkouts read the same files.

Files are compared after dropping what is not a result (wall times, the command line, paths of
the checkout, provenance dates): JSON/YAML values must be equal, text outputs equal line by line.

Usage: ``python -m bench.compare_restructure BEFORE AFTER [--out bench/results/restructure_identical]``
(writes ``.json`` and ``.md``; exit 1 when any result differs).
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real" / "matheusbucater__aeropendulo"
OB = "docs/onboarding/matheusbucater"
#: Keys whose values are not results (times, command lines, paths, dates).
VOLATILE = re.compile(r"^(seconds|.*_seconds|elapsed.*|wall.*|cpu.*|timing|timings|command|command_line|argv|"
                      r"created|created_utc|date|written|host|versions?|output_folder|folder|path|paths)$",
                      re.I)


def _entry_points(checkout: Path) -> dict[str, str]:
    """console-script name -> ``module:function`` of every package's setup.py in ``checkout``."""
    out: dict[str, str] = {}
    for setup in sorted((checkout / "src").glob("*/setup.py")):
        tree = ast.parse(setup.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Dict):
                for k, v in zip(node.keys, node.values, strict=True):
                    if isinstance(k, ast.Constant) and k.value == "console_scripts":
                        for item in ast.literal_eval(v):
                            name, _, target = item.partition("=")
                            out[name.strip()] = target.strip()
    return out


def _run(checkout: Path, work: Path, script: str, *args: str) -> dict[str, Any]:
    target = _entry_points(checkout)[script]
    module, _, func = target.partition(":")
    src = sorted((checkout / "src").glob("aeropend_*"))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(str(p) for p in src), AEROPEND_DASK="0")
    code = f"import sys; from {module} import {func} as m; sys.exit(m(sys.argv[1:]))"
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code, *args], cwd=work, env=env, capture_output=True,
                          text=True, timeout=1800)
    return {"script": script, "args": list(args), "rc": proc.returncode, "seconds": time.perf_counter() - t0,
            "stdout": proc.stdout, "stderr": proc.stderr[-2000:]}


def _synthetic_logs(folder: Path) -> list[str]:
    """A viscous-friction gap (×1.5) on the shipped simulated rig, as two CSV logs (fit, held-out)."""
    from aeropend_sim.params import load_rig
    from bench.fixtures.gap_synth import make_case

    rig = load_rig("thesis_sim")
    truth = {"viscous_friction": {"c_over_J": 1.5 * rig.pendulum.c_over_J}}
    case = make_case(rig, list(truth), 11, fit_duration=20.0, held_out_steps=3, truth=truth, snr_db=45.0,
                     channels=("theta",))
    names = []
    for tag, recs in (("fit", case.fit), ("held", case.held_out)):
        for k, rec in enumerate(recs):
            path = folder / f"synth_{tag}{k}.csv"
            rows = ["t,duty,theta"] + [f"{t:.6f},{u:.9f},{y:.12g}" for t, u, y in
                                       zip(rec.t, rec.duty, rec.channels["theta"], strict=True)]
            path.write_text("\n".join(rows) + "\n", encoding="utf-8")
            names.append(path.name)
    return names


def run_checkout(checkout: Path, work: Path, synth: list[str]) -> list[dict[str, Any]]:
    """Every command of the module docstring in ``checkout``, results under ``work``."""
    d = str(REAL)
    ob = str(checkout / OB)
    preset = f"{work}/synth_preset.yaml"
    Path(preset).write_text("name: synth\ntime_col: t\ntime_unit: s\ninput_col: duty\ninput_kind: duty\n"
                            "angle_col: theta\nangle_unit: rad\n", encoding="utf-8")
    fit_logs = [f"{s}:{preset}" for s in synth if "_fit" in s]
    held_logs = [f"{s}:{preset}" for s in synth if "_held" in s]
    return [
        _run(checkout, work, "rig", "fit", f"{ob}/stated.yaml",
             f"{d}/aeropendulum.csv:matheusbucater_sawtooth", f"{d}/pendulum.csv:{ob}/free_fall.yaml",
             "-o", "fitted.yaml", "-q"),
        _run(checkout, work, "rig", "check", "fitted.yaml", f"{d}/aeropendulum_step.csv:matheusbucater_step"),
        _run(checkout, work, "compare", f"{d}/aeropendulum_step.csv:matheusbucater_step",
             "--rig", "fitted.yaml", "-o", "compare_out"),
        _run(checkout, work, "gap", f"{d}/aeropendulum.csv:matheusbucater_sawtooth", "--rig", "fitted.yaml",
             "--held-out", f"{d}/aeropendulum_step.csv:matheusbucater_step", "-o", "gap_real", "-q"),
        _run(checkout, work, "gap", *fit_logs, "--rig", "thesis_sim", "--held-out", *held_logs,
             "-o", "gap_synth", "-q"),
    ]


def _clean(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items() if not VOLATILE.search(str(k))}
    if isinstance(value, list):
        return [_clean(v) for v in value]
    return value


def _first_difference(a: Any, b: Any, where: str = "") -> str | None:
    if type(a) is not type(b):
        return f"{where or '/'}: {a!r} vs {b!r}"
    if isinstance(a, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                return f"{where}/{k}: only in {'after' if k not in a else 'before'}"
            found = _first_difference(a[k], b[k], f"{where}/{k}")
            if found:
                return found
        return None
    if isinstance(a, list):
        if len(a) != len(b):
            return f"{where}: {len(a)} vs {len(b)} items"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            found = _first_difference(x, y, f"{where}[{i}]")
            if found:
                return found
        return None
    same = a == b or (isinstance(a, float) and a != a and b != b)
    return None if same else f"{where or '/'}: {a!r} vs {b!r}"


def _load(path: Path) -> Any:
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".json":
        return _clean(json.loads(text))
    if path.suffix in (".yaml", ".yml"):
        return _clean(yaml.safe_load(text))
    return [line for line in text.splitlines() if not VOLATILE.search(line.split(":", 1)[0])]


def compare_folders(before: Path, after: Path) -> list[dict[str, Any]]:
    """Every result file of both folders (figures excepted) compared after :func:`_clean`."""
    rows = []
    names = sorted({p.relative_to(before) for p in before.rglob("*") if p.is_file()}
                   | {p.relative_to(after) for p in after.rglob("*") if p.is_file()})
    for rel in names:
        if rel.suffix in (".png", ".svg", ".pdf", ".html", ".csv", ".mcap", ".db3", ".lock"):
            continue
        a, b = before / rel, after / rel
        if not (a.is_file() and b.is_file()):
            rows.append({"file": str(rel), "identical": False, "difference": "only in one run"})
            continue
        diff = _first_difference(_load(a), _load(b))
        rows.append({"file": str(rel), "identical": diff is None, "difference": diff})
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run both checkouts, compare, write the result files; exit 1 when anything differs."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "restructure_identical")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="aeropend-restructure-") as tmp:
        base = Path(tmp)
        synth_dir = base / "logs"
        synth_dir.mkdir()
        synth = _synthetic_logs(synth_dir)
        runs = {}
        for tag, checkout in (("before", args.before), ("after", args.after)):
            work = base / tag
            work.mkdir()
            for name in synth:
                (work / name).write_bytes((synth_dir / name).read_bytes())
            runs[tag] = run_checkout(checkout.resolve(), work, synth)
            (work / "stdout.txt").write_text("".join(r["stdout"] for r in runs[tag]), encoding="utf-8")
            for name in synth:
                (work / name).unlink()
        rows = compare_folders(base / "before", base / "after")
    stdout_same = all(a["stdout"] == b["stdout"] for a, b in zip(runs["before"], runs["after"], strict=True))
    result = {
        "before": str(args.before), "after": str(args.after),
        "commits": {tag: subprocess.run(["git", "-C", str(p), "rev-parse", "--short", "HEAD"],
                                        capture_output=True, text=True).stdout.strip()
                    for tag, p in (("before", args.before), ("after", args.after))},
        "commands": [{"script": r["script"], "args": r["args"], "rc_before": r["rc"], "rc_after": s["rc"],
                      "seconds_before": r["seconds"], "seconds_after": s["seconds"],
                      "stdout_identical": r["stdout"] == s["stdout"]}
                     for r, s in zip(runs["before"], runs["after"], strict=True)],
        "files": rows, "all_identical": stdout_same and all(r["identical"] for r in rows),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    lines = [f"# Same results before and after the restructure ({result['commits']['before']} → "
             f"{result['commits']['after']})", "",
             "Command: `python -m bench.compare_restructure BEFORE AFTER` (bench/compare_restructure.py: "
             "what is run and what is left out of the comparison).", "",
             "| command | exit before / after | terminal output identical |", "|---|---|---|"]
    lines += [f"| `{c['script']} {' '.join(c['args'])[:90]}` | {c['rc_before']} / {c['rc_after']} | "
              f"{'yes' if c['stdout_identical'] else 'NO'} |" for c in result["commands"]]
    lines += ["", "| result file | identical | first difference |", "|---|---|---|"]
    lines += [f"| {r['file']} | {'yes' if r['identical'] else 'NO'} | {r['difference'] or ''} |"
              for r in rows]
    lines += ["", f"All identical: **{'yes' if result['all_identical'] else 'no'}**."]
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    return 0 if result["all_identical"] else 1


if __name__ == "__main__":
    sys.exit(main())
