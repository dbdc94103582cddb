"""Markdown table of ``bench/results/sindy.json`` (written by ``bench/bench_sindy.py``).

Run: ``.venv/bin/python bench/bench_sindy_table.py`` -> ``bench/results/sindy.md``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent
SRC = ROOT / "results" / "sindy.json"
OUT = ROOT / "results" / "sindy.md"
SHORT = {"theta_dot": "θ̈", "i_a": "di_a/dt", "omega_rotor": "dω₁/dt"}


def _eq(res: dict[str, Any], tg: str) -> str:
    e = res.get(tg)
    if e is None:
        return "–"
    return f"{e['n_fp']}/{e['n_fn']}, {100 * e['max_rel_error']:.3g} %, {e['test_mse']:.2g}"


def table(result: dict[str, Any]) -> str:
    lines = [
        "Each equation cell: false positives / false negatives, max relative coefficient error, "
        "held-out derivative MSE against the true derivatives (samples next to duty steps left out).",
        "",
        "| excitation | SNR | method/library | λ (BIC) | θ̈ | di_a/dt | dω₁/dt | K_q error | fit time |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for case in result["cases"]:
        snr = "none" if case["snr_db"] is None else f"{case['snr_db']:g} dB"
        for key, res in case["methods"].items():
            if "error" in res:
                lines.append(f"| {case['excitation']} | {snr} | {key} | – | {res['error'][:60]} | | | | |")
                continue
            kq = res.get("K_q_error")
            kq_s = "–" if kq is None else f"{100 * kq:+.2f} %"
            lines.append(
                f"| {case['excitation']} | {snr} | {key} | {res['threshold']:g} | {_eq(res, 'theta_dot')} | "
                f"{_eq(res, 'i_a')} | {_eq(res, 'omega_rotor')} | {kq_s} | {res['fit_time_s']:.2f} s |"
            )
    return "\n".join(lines) + "\n"


CONDENSED = ("sindy/thesis", "weak/thesis", "sindy/physics", "weak/physics", "sindy/structured",
             "ensemble/structured", "weak/structured")


def _nrmse(res: dict[str, Any], state: str) -> str:
    v = res.get("free_run_nrmse", {}).get(state, "–")
    return "diverged" if v is None else (v if isinstance(v, str) else f"{v:.3g}")


def condensed(result: dict[str, Any]) -> str:
    """θ̈ structure, K_q, θ̈ test MSE, worst electrical coefficient, free-run NRMSE of θ."""
    lines = [
        "| excitation | SNR | method/library | θ̈ FP/FN | θ̈ max coef err | K_q error | θ̈ test MSE "
        "| di_a/dt, dω₁/dt FP (max coef err) | free-run NRMSE θ |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for case in result["cases"]:
        snr = "none" if case["snr_db"] is None else f"{case['snr_db']:g} dB"
        for key in CONDENSED:
            res = case["methods"].get(key)
            if res is None or "error" in res:
                continue
            th = res["theta_dot"]
            kq = res.get("K_q_error")
            el = ", ".join(
                f"{res[tg]['n_fp']} ({100 * res[tg]['max_rel_error']:.3g} %)" for tg in ("i_a", "omega_rotor")
            )
            lines.append(
                f"| {case['excitation']} | {snr} | {key} | {th['n_fp']}/{th['n_fn']} | "
                f"{100 * th['max_rel_error']:.3g} % | {'–' if kq is None else f'{100 * kq:+.2f} %'} | "
                f"{th['test_mse']:.2g} | {el} | {_nrmse(res, 'theta')} |"
            )
    return "\n".join(lines) + "\n"


def main() -> None:
    result = json.loads(SRC.read_text(encoding="utf-8"))
    text = "## Condensed\n\n" + condensed(result) + "\n## All methods\n\n" + table(result)
    OUT.write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()
