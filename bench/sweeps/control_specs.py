"""Exploration (issue 19): position-loop pole specs on a tuning set of the independent closed-loop bench.

Runs ``bench_control_independent.py`` on plants 100-139 (drawn like the reported plants 0-39, other
seeds, so nothing is tuned on the reported set) with the strategies' default pole specs
(:attr:`aeropend_control.strategies.Strategy.default_spec` of every registered class) replaced by
each configuration below, and writes one summary row per configuration to
``bench/results/control_spec_sweep.{json,md}``.
The defaults are not changed by this script.

Usage: ``python -m bench.sweeps.control_specs [CONFIG ...]`` (default: all).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from aeropend_control.design import PoleSpec
from aeropend_control.strategies import strategy_class, strategy_names
from bench import bench_control_independent as bci

RESULTS = Path(__file__).resolve().parents[1] / "results"
#: name -> ((ω_n, ζ, ρ) of fl_pid / small_signal, (ω_n, ζ, ρ) of cascade / fl_cascade)
CONFIGS = {
    "current": ((9.5, 0.7, 1.0), (9.0, 0.7, 1.0)),
    "zeta085": ((9.5, 0.85, 1.0), (9.0, 0.85, 1.0)),
    "w105": ((10.5, 0.7, 1.0), (10.0, 0.7, 1.0)),
    "w105_z085": ((10.5, 0.85, 1.0), (10.0, 0.85, 1.0)),
    "w85": ((8.5, 0.7, 1.0), (8.0, 0.7, 1.0)),
    "rho15": ((9.5, 0.7, 1.5), (9.0, 0.7, 1.5)),
    "zeta060": ((9.5, 0.6, 1.0), (9.0, 0.6, 1.0)),
    "zeta065": ((9.5, 0.65, 1.0), (9.0, 0.65, 1.0)),
    "casc_zeta060": ((9.5, 0.7, 1.0), (9.0, 0.6, 1.0)),
    "casc_zeta050": ((9.5, 0.7, 1.0), (9.0, 0.5, 1.0)),
    "casc_zeta065": ((9.5, 0.7, 1.0), (9.0, 0.65, 1.0)),
    "casc_zeta055": ((9.5, 0.7, 1.0), (9.0, 0.55, 1.0)),
}
KEYS = ("table_6_1", "late_peak_only", "table_6_1_or_late_peak", "no_limit_cycle", "goal", "median_ts",
        "p90_ts", "median_mp", "per_strategy")


def run(name: str, tmp: Path) -> dict:
    (fw, fz, fr), (cw, cz, cr) = CONFIGS[name]
    for k in strategy_names():  # the cascades (motor-cascade drive) get the second spec
        cls = strategy_class(k)
        cls.default_spec = (PoleSpec(cw, zeta=cz, rho=cr) if cls.drive_kind == "cascade"
                            else PoleSpec(fw, zeta=fz, rho=fr))
    out = tmp / f"sweep_{name}"
    bci.main(["--first", "100", "--plants", "40", "--workers", "2", "--out", str(out)])
    s = json.loads(out.with_suffix(".json").read_text(encoding="utf-8"))["summary"]
    s = s.get("nominal", s)
    fl_ss, cascades = CONFIGS[name]
    return {"config": name, "fl_ss": fl_ss, "cascades": cascades, **{k: s[k] for k in KEYS}}


def main(argv: list[str] | None = None) -> int:
    import tempfile

    names = (argv if argv is not None else sys.argv[1:]) or list(CONFIGS)
    with tempfile.TemporaryDirectory() as tmp:
        new = {n: run(n, Path(tmp)) for n in names}
    path = RESULTS / "control_spec_sweep.json"
    old = json.loads(path.read_text(encoding="utf-8")) if path.exists() else []
    rows = [new.pop(r["config"], r) for r in old] + list(new.values())  # re-run configs replace their row
    (RESULTS / "control_spec_sweep.json").write_text(json.dumps(rows, indent=1), encoding="utf-8")
    lines = ["# Pole-spec sweep on the tuning plants 100-139 (bench/sweeps/control_specs.py)", "",
             "Within-reach runs, designed on the nominal rig; (ω_n, ζ, ρ) of FL/small-signal and of the "
             "cascades.", "",
             "| config | FL/SS | cascades | Table 6.1 | late peak only | T6.1 or late peak | no limit cycle "
             "| goal | median ts [s] | p90 ts [s] | median Mp [%] |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['config']} | {r['fl_ss']} | {r['cascades']} | {100 * r['table_6_1']:.1f} % | "
                     f"{r['late_peak_only']} | {100 * r['table_6_1_or_late_peak']:.1f} % | "
                     f"{100 * r['no_limit_cycle']:.1f} % | {100 * r['goal']:.1f} % | {r['median_ts']:.3f} | "
                     f"{r['p90_ts']:.3f} | {r['median_mp']:.2f} |")
    (RESULTS / "control_spec_sweep.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
